"""Issue 67, the library's side: no input gets a traceback, nothing implausible is accepted
silently. A rank-deficient layout (the X-square) is driven on the twists it can reach; a
layout that cannot drive every translation, numbers no robot has, a name that is a path,
bad motor data and NumPy/JAX scalars where numbers go (tests/test_bad_inputs_cli.py has
the command lines)."""

import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import demo
from mecanum_jax._checks import InputError
from mecanum_jax.config import CONFIG_DIR, ConfigError, from_mapping
from mecanum_jax.kinematics import geometry, motors, singularity
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.geometry import SingularLayoutError, SingularLayoutWarning
from mecanum_jax.sim.description import (
    builtin_description,
    fingerprint,
    load_description,
    parse_description,
)
from mecanum_jax.task.commands import CommandConfig, sample_command
from mecanum_jax.task.constants import robot_constants

POS4 = [[0.1, 0.1], [-0.1, 0.1], [-0.1, -0.1], [0.1, -0.1]]


def _x_square() -> geometry.WheelGeometry:
    return builtin_description("x_square").build_geometry(warn_singular=False)


def test_x_square_commands_are_projected_onto_its_translations():
    geom = _x_square()
    P = singularity.reachable_projector(geom)
    np.testing.assert_allclose(P, np.diag([1.0, 1.0, 0.0]), atol=1e-6)
    t = singularity.project_reachable(jnp.array([[0.3, -0.2, 1.5]]), P)
    np.testing.assert_allclose(t, [[0.3, -0.2, 0.0]], atol=1e-6)
    full = geometry.o_rectangle(0.05, 0.1, 0.125)
    np.testing.assert_allclose(singularity.reachable_projector(full), np.eye(3), atol=1e-6)
    assert singularity.lost_directions(geom) == "ωz (spin)"
    # the constants are finite (the lost spin gets a finite scale), the odometry the
    # pseudo-inverse: the wheels report no spin rather than NaN
    c = robot_constants(builtin_description("x_square"), geom, None)
    assert np.all(np.isfinite(np.asarray(c.command_scale)))
    assert np.all(np.isfinite(np.asarray(c.forward_matrix)))
    rates = kinematics.inverse(geom, jnp.array([0.4, 0.1, 0.0]))
    np.testing.assert_allclose(c.forward_matrix @ rates, [0.4, 0.1, 0.0], atol=1e-5)
    # every command drawn has no spin, and reaches the wheels' limits as before
    keys = jax.random.split(jax.random.PRNGKey(0), 256)
    cmds = np.asarray(jax.vmap(lambda k: sample_command(c, k, CommandConfig()))(keys))
    assert np.all(np.isfinite(cmds))
    assert np.all(cmds[:, 2] == 0.0)
    assert np.abs(cmds[:, :2]).max() > 0.5  # translations still drawn (m/s)


def test_full_rank_commands_are_unchanged():
    desc = builtin_description("o_rectangle")
    c = robot_constants(desc, desc.build_geometry(), None)
    np.testing.assert_allclose(np.asarray(c.reachable), np.eye(3), atol=1e-6)
    keys = jax.random.split(jax.random.PRNGKey(1), 64)
    cmds = np.asarray(jax.vmap(lambda k: sample_command(c, k, CommandConfig()))(keys))
    assert np.abs(cmds[:, 2]).max() > 0.1  # spins kept


def test_demo_of_x_square_warns_once_naming_the_robot_and_the_spin(capsys):
    with pytest.warns(SingularLayoutWarning) as caught:
        assert demo.main(["--robot", "x_square"]) == 0
    assert len(caught) == 1
    assert "robot 'x_square'" in str(caught[0].message)
    assert "ωz (spin)" in str(caught[0].message)
    out = capsys.readouterr().out
    assert "spin clockwise" in out
    assert "nan" not in out.lower()


def _custom(name: str, wheels: list[tuple[float, float, float]], extra: str = "") -> str:
    text = f'[robot]\nname = "{name}"\n{extra}\n[geometry]\nlayout = "custom"\n'
    for i, (x, y, roller) in enumerate(wheels):
        text += (
            f'[[geometry.wheels]]\nname = "w{i}"\nx = {x}\ny = {y}\nradius = 0.05\n'
            f"roller_angle_deg = {roller}\n"
        )
    return text + "[motors]\nmax_motor_rpm = 9000.0\n"


def test_a_layout_losing_a_translation_is_refused_at_load(tmp_path):
    # every floor roller one way: it cannot move across them
    path = tmp_path / "oneway.toml"
    path.write_text(_custom("oneway", [(x, y, 45) for x, y in POS4]))
    with pytest.raises(ConfigError, match=r"robot 'oneway': the wheels cannot drive every planar"):
        load_description(path)
    with pytest.warns(SingularLayoutWarning):
        geom = geometry.make_geometry(POS4, 0.0, math.pi / 4, 0.05)
    with pytest.raises(SingularLayoutError, match=r"robot 'r'.*rank 2 of 3"):
        singularity.require_usable(geom, "r")
    singularity.require_usable(_x_square(), "x_square")  # the spin alone lost: usable


def _rect(name: str = "r", radius: float = 0.05, rx: float = 0.2, ry: float = 0.12) -> dict:
    return {
        "robot": {"name": name},
        "geometry": {
            "layout": "O-rectangle",
            "wheel_radius": radius,
            "half_wheelbase": rx,
            "half_track": ry,
        },
        "motors": {"max_motor_rpm": 9000.0},
    }


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"radius": 40.0, "rx": 120.0},
            r"geometry.wheel_radius = 40.0 m is outside 0.001–5 m \(millim",
        ),
        ({"rx": 120.0}, r"geometry.half_wheelbase = 120.0 m is outside 0.001–5 m"),
        ({"radius": 0.0005}, r"geometry.wheel_radius = 0.0005 m is outside"),
        ({"radius": 0.5}, r"wheel radius 0.5 m \(wheel 'left_front'\) is larger than the base"),
    ],
)
def test_implausible_dimensions_are_refused_with_the_override_named(change, message):
    data = _rect(**change)
    with pytest.raises(ConfigError, match=message) as err:
        parse_description(data, "x.toml")
    assert "set allow_implausible = true in [robot] to accept" in str(err.value)
    assert "\n" not in str(err.value)
    data["robot"]["allow_implausible"] = True  # the explicit override
    assert parse_description(data).geometry.wheel_radius == data["geometry"]["wheel_radius"]


@pytest.mark.parametrize(
    ("motors", "message"),
    [
        (
            {"max_motor_rpm": 1e9, "gear_ratio": 19.0},
            r"max_motor_rpm = 1000000000.0 .* 2.756e\+05 m/s",
        ),
        ({"max_motor_rpm": 9000.0, "gear_ratio": 0.001}, r"gear_ratio = 0.001 .* 4.712e\+04 m/s"),
        ({"max_motor_rpm": 0.5, "gear_ratio": 19.0}, r"max_motor_rpm = 0.5 .* 0.0001378 m/s"),
    ],
)
def test_motors_that_turn_no_wheel_plausibly_are_refused(motors, message):
    """A wheel's top rim speed (motor limit through the gears, times the radius) outside
    1 cm/s–100 m/s: rpm typed as rad/s, or an inverted gear ratio; the override accepts it."""
    data = {**_rect(), "motors": motors}
    with pytest.raises(ConfigError, match=message) as err:
        parse_description(data, "x.toml")
    assert "outside 0.01–100 m/s; set allow_implausible = true" in str(err.value)
    data["robot"]["allow_implausible"] = True
    assert parse_description(data).motors.max_motor_rpm == motors["max_motor_rpm"]


def test_a_wide_wheel_is_refused_and_the_override_keeps_the_fingerprint():
    data = {**_rect(), "body": {"wheel_width": 0.5}}
    with pytest.raises(ConfigError, match=r"body.wheel_width = 0.5 m is wider than 4 wheel radii"):
        parse_description(data)
    plain = parse_description(_rect())
    allowed = _rect()
    allowed["robot"]["allow_implausible"] = True
    assert fingerprint(parse_description(allowed)) == fingerprint(plain)


def test_two_wheels_at_one_place_are_refused_even_when_allowed(tmp_path):
    same = [(0.1, 0.1, 45), (0.1, 0.1, -45), (-0.1, -0.1, 45), (-0.1, 0.1, -45)]
    for extra in ("", "allow_implausible = true"):
        path = tmp_path / "same.toml"
        path.write_text(_custom("same", same, extra))
        with pytest.raises(ConfigError, match=r"wheels 'w0' and 'w1' are both at \[0.1, 0.1\] m"):
            load_description(path)
    point = tmp_path / "point.toml"  # all four at one point
    point.write_text(_custom("point", [(0, 0, 45), (0, 0, -45), (0, 0, 45), (0, 0, -45)]))
    with pytest.raises(ConfigError, match=r"are both at \[0.0, 0.0\] m"):
        load_description(point)


@pytest.mark.parametrize("name", ["", "a/b", "../up", "with space", ".hidden", "c:\\x"])
def test_a_robot_name_must_not_be_a_path(name):
    with pytest.raises(ConfigError, match=r"robot.name = .*letters, digits"):
        parse_description(_rect(name=name))


@pytest.mark.parametrize(
    "path", sorted((CONFIG_DIR / "robots").glob("*.toml")), ids=lambda p: p.stem
)
def test_every_built_in_robot_is_plausible(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at load either
        load_description(path)


def test_a_training_config_given_as_a_robot_is_one_short_line():
    with pytest.raises(ConfigError) as err:
        load_description(CONFIG_DIR / "train" / "tiny.toml")
    text = str(err.value)
    assert "not a robot description" in text
    assert "a training config" in text
    assert len(text) < 250
    assert "control_dt" not in text


def test_an_unknown_table_is_named_by_its_keys_not_dumped():
    with pytest.raises(ConfigError) as err:
        from_mapping(CommandConfig, {"extra": {f"k{i}": i for i in range(50)}})
    assert "a table of keys" in str(err.value)
    assert len(str(err.value)) < 400


@pytest.mark.parametrize(
    "number", [np.float32(0.05), jnp.float32(0.05), np.float64(0.05), jnp.asarray(0.05)]
)
def test_numpy_and_jax_scalars_are_numbers(number):
    g = geometry.o_rectangle(number, np.float32(0.1), jnp.float32(0.125))
    np.testing.assert_allclose(g.radii, 0.05, rtol=1e-6)
    assert geometry.centripetal(number, 0.15, np.int64(3)).n_wheels == 3
    cfg = from_mapping(CommandConfig, {"min_fraction": number, "p_zero": np.int64(0)})
    assert isinstance(cfg.min_fraction, float)
    assert cfg.p_zero == 0.0


@pytest.mark.parametrize("bad", [True, "0.05", float("nan"), np.array([0.05, 0.05]), None])
def test_what_is_not_a_number_is_still_refused(bad):
    with pytest.raises(InputError, match=r"radius = .*expected a finite number"):
        geometry.o_rectangle(bad, 0.1, 0.1)


def test_motor_data_errors_are_named():
    w = jnp.ones((5, 4))
    with pytest.raises(InputError, match=r"signs\[0\] = 2 \(signs = \[2, 0, -1, -1\]\)"):
        motors.wheel_rates_to_motor_rpm(w, [2, 0, -1, -1], 19.0)
    for ratio in (0.0, float("nan"), -3.0):
        with pytest.raises(InputError, match=r"gear_ratio = .*must be a finite number > 0"):
            motors.wheel_rates_to_motor_rpm(w, [1, 1, -1, -1], ratio)
        with pytest.raises(InputError, match=r"gear_ratio"):
            motors.max_wheel_rate(9000.0, ratio)
    with pytest.raises(InputError, match=r"gear_ratio\[1\] = 0"):
        motors.motor_rpm_to_wheel_rates(w, [1, 1, -1, -1], jnp.array([19.0, 0.0, 19.0, 19.0]))
    with pytest.raises(InputError, match=r"signs: shape \(3,\).*wheel_rates's shape \(5, 4\)"):
        motors.wheel_rates_to_motor_rpm(w, [1, 1, -1], 19.0)
    # under jit only shapes are checked; the values pass as they are
    rpm = jax.jit(motors.wheel_rates_to_motor_rpm)(w, jnp.array([1, 1, -1, -1]), 19.0)
    assert rpm.shape == (5, 4)


def test_an_infinite_twist_raises_eagerly_and_stays_in_its_row_under_jit():
    geom = geometry.o_rectangle(0.05, 0.1, 0.125)
    t = jnp.array([[0.1, 0.0, 0.0], [jnp.inf, 0.0, 0.0]])
    with pytest.raises(InputError, match=r"twist\[1, 0\] = inf: must be finite"):
        kinematics.inverse(geom, t)
    rates = jax.jit(kinematics.inverse)(geom, t)  # pure maths: documented in _checks
    assert bool(jnp.all(jnp.isfinite(rates[0])))
    assert not bool(jnp.any(jnp.isfinite(rates[1])))
