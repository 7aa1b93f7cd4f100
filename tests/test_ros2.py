"""ros2_control's mecanum_drive_controller parameters to and from robot descriptions."""

import tomllib

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from mecanum_jax.config import ConfigError
from mecanum_jax.deploy import ros2
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.description import builtin_description, load_description, parse_description

# the example parameters of ros2_controllers' mecanum_drive_controller, with its keys
EXAMPLE = """
controller_manager:
  ros__parameters:
    update_rate: 100
    mecanum_drive_controller:
      type: mecanum_drive_controller/MecanumDriveController

mecanum_drive_controller:
  ros__parameters:
    reference_timeout: 0.9
    front_left_wheel_command_joint_name: "front_left_wheel_joint"
    front_right_wheel_command_joint_name: "front_right_wheel_joint"
    rear_right_wheel_command_joint_name: "back_right_wheel_joint"
    rear_left_wheel_command_joint_name: "back_left_wheel_joint"
    kinematics:
      base_frame_offset: { x: 0.0, y: 0.0, theta: 0.0 }
      wheels_radius: 0.0485
      sum_of_robot_center_projection_on_X_Y_axis: 0.39
    base_frame_id: "base_link"
    odom_frame_id: "odom"
"""


def _ros_wheel_rates(params, twist):
    """The controller's inverse kinematics, spelled out as it documents them, returned in
    this project's order (front-left, rear-left, rear-right, front-right)."""
    r = params["kinematics"]["wheels_radius"]
    k = params["kinematics"][ros2.LEVER_ARM]
    vx, vy, wz = twist
    front_left = (vx - vy - k * wz) / r
    front_right = (vx + vy + k * wz) / r
    rear_left = (vx + vy - k * wz) / r
    rear_right = (vx - vy + k * wz) / r
    return np.array([front_left, rear_left, rear_right, front_right])


def test_example_round_trips_and_the_kinematics_agree(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(EXAMPLE)
    text = ros2.convert_file(path, "ros_example", half_track=0.21)
    desc = parse_description(tomllib.loads(text))
    assert desc.geometry.half_track == pytest.approx(0.21)
    assert desc.geometry.half_wheelbase == pytest.approx(0.18)
    # the wheel order: LF, LB, RB, RF <- front_left, rear_left, rear_right, front_right
    assert "front_left_wheel_joint, back_left_wheel_joint, back_right_wheel_joint, " in text
    params = ros2.controller_parameters(yaml.safe_load(EXAMPLE))
    joints = tuple(params[p] for p in ros2.JOINT_PARAMETERS)
    back = ros2.to_controller_parameters(desc, joints=joints)
    for key in ros2.JOINT_PARAMETERS:
        assert back[key] == params[key]
    assert back["kinematics"]["wheels_radius"] == pytest.approx(0.0485)
    assert back["kinematics"][ros2.LEVER_ARM] == pytest.approx(0.39)
    geom = desc.build_geometry()
    rng = np.random.default_rng(0)
    for twist in rng.uniform(-1, 1, (20, 3)):
        ours = np.asarray(kinematics.inverse(geom, jnp.asarray(twist, jnp.float32)))
        np.testing.assert_allclose(ours, _ros_wheel_rates(params, twist), rtol=1e-4, atol=1e-4)


def test_the_shipped_robot_converts_to_the_controller_and_back(tmp_path):
    desc = builtin_description("o_rectangle")
    params = ros2.to_controller_parameters(desc)
    assert params["kinematics"][ros2.LEVER_ARM] == pytest.approx(0.225)  # lx + ly
    text = ros2.description_toml(params, "again", half_track=0.125)
    again = parse_description(tomllib.loads(text))
    np.testing.assert_allclose(
        np.asarray(kinematics.jacobian(again.build_geometry())),
        np.asarray(kinematics.jacobian(desc.build_geometry())),
        rtol=1e-6,
    )


def test_cli_writes_a_description_and_never_overwrites(tmp_path, capsys):
    src = tmp_path / "params.yaml"
    src.write_text(EXAMPLE)
    out = tmp_path / "mine.toml"
    assert ros2.main([str(src), str(out), "--name", "mine"]) == 0
    desc = load_description(out)
    assert desc.robot.name == "mine"
    assert desc.geometry.half_track == pytest.approx(0.195)  # default: half of lx + ly
    before = out.read_text()
    assert ros2.main([str(src), str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_text() == before
    assert ros2.main(["o_rectangle", "--to-ros", str(tmp_path / "x.toml")]) == 2
    assert "--to-ros writes to standard output" in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()
    assert ros2.main(["o_rectangle", "--to-ros"]) == 0
    back = yaml.safe_load(capsys.readouterr().out)
    assert (
        back["mecanum_drive_controller"]["ros__parameters"]["kinematics"]["wheels_radius"] == 0.05
    )


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("wheels_radius: 0.0485", "wheels_radius: -0.05"), "kinematics.wheels_radius = -0.05"),
        (("sum_of_robot_center_projection_on_X_Y_axis: 0.39", ""), "kinematics.sum_of_robot"),
        (("{ x: 0.0, y: 0.0", "{ x: 0.1, y: 0.0"), "kinematics.base_frame_offset.x = 0.1"),
    ],
)
def test_bad_parameters_name_the_field(tmp_path, edit, message):
    path = tmp_path / "params.yaml"
    path.write_text(EXAMPLE.replace(*edit))
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        ros2.convert_file(path, "bad")


def test_bad_half_track_and_missing_file(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(EXAMPLE)
    with pytest.raises(ConfigError, match=r"half_track = 0\.5"):
        ros2.convert_file(path, "bad", half_track=0.5)
    with pytest.raises(ConfigError, match="no such file"):
        ros2.convert_file(tmp_path / "none.yaml", "bad")
    with pytest.raises(ConfigError, match="controller = 'other'"):
        ros2.convert_file(path, "bad", controller="other")
    with pytest.raises(ConfigError, match="only the O"):
        ros2.to_controller_parameters(builtin_description("x_rectangle"))
