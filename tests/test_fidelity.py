"""The reference roller model as a judge: its mounted roller angle, the task in either
fidelity, ``mecanum-eval --fidelity`` and ``run.eval_fidelity``."""

import dataclasses
import json
import math
import warnings

import mujoco
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics.geometry import SingularLayoutWarning
from mecanum_jax.sim import mjcf
from mecanum_jax.sim.description import builtin_description
from mecanum_jax.sim.state import RobotParams
from mecanum_jax.task import EnvConfig, MecanumEnv
from mecanum_jax.task import fidelity as fid
from train.cli import evaluate as cli
from train.config_loading import load_train_config, parse_train_config
from train.learner.periodic import PeriodicEvaluation

SPIN = (-10.0, -10.0, 10.0, 10.0)
MODEL_FIELDS = (
    "geom_friction",
    "geom_size",
    "geom_pos",
    "body_pos",
    "body_mass",
    "body_ipos",
    "body_inertia",
    "actuator_gainprm",
    "actuator_forcerange",
)
"""The mjx.Model arrays that Robot.model_for writes a robot's parameters into."""


def _desc(name, **geometry):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        desc = builtin_description(name)
    if geometry:
        desc = dataclasses.replace(desc, geometry=dataclasses.replace(desc.geometry, **geometry))
    return desc


def _mean_effective_tan(desc):
    """Mean over the floor roller's sweep |α| ≤ π/n of tan γ(α), the angle of the direction
    a roller drives (across the floor projection of its axis), read from the compiled
    reference model's first roller of the first wheel (hub frame: x drive, y axle)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        model, index = mjcf.build_model(desc, "reference")
    joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{index.wheel_names[0]}_roller0")
    axis = model.jnt_axis[joint]  # roller 0 sits at α = 0, its body frame the hub's
    n = desc.sim.rollers
    alphas = np.linspace(-math.pi / n, math.pi / n, 2001)
    ax = axis[0] * np.cos(alphas) + axis[2] * np.sin(alphas)  # the axis turned about y
    return float(np.mean(np.abs(axis[1] / ax)))


def test_reference_rollers_act_at_the_described_angle_on_average():
    """The mounting compensates the tilt of the floor roller's axis: 44.52° for 10 rollers
    makes the mean effective angle the described 45°; rollers mounted at 45° act as 45.48°
    (the X-square's spin artefact), so the check can fail."""
    assert _mean_effective_tan(_desc("o_rectangle")) == pytest.approx(1.0, abs=2e-4)
    assert _mean_effective_tan(_desc("x_square")) == pytest.approx(1.0, abs=2e-4)
    assert math.degrees(mjcf.mounted_roller_angle(math.radians(45.0), 10)) == pytest.approx(
        44.52, abs=0.01
    )
    assert math.degrees(mjcf.mounted_roller_angle(math.radians(-45.0), 10)) == pytest.approx(
        -44.52, abs=0.01
    )
    at_45 = _desc("o_rectangle", roller_angle_deg=math.degrees(math.atan(1.0169)))
    assert _mean_effective_tan(at_45) > 1.015  # these rollers are mounted at 45°


def _spin_of_x_square(desc, seconds=2.0):
    """C MuJoCo (same MJCF as MJX, faster on the CPU): the X-square held at the O spin
    pattern; the mean yaw rate of the last 0.5 s."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        m, idx = mjcf.build_model(desc, "reference", visual=False)
    d = mujoco.MjData(m)
    steps = round(seconds / m.opt.timestep)
    wz = np.zeros(steps)
    for k in range(steps):
        d.ctrl[idx.actuators] = SPIN
        mujoco.mj_step(m, d)
        wz[k] = d.qvel[idx.free_dof + 5]
    return float(wz[-steps // 4 :].mean())


def test_reference_x_square_does_not_spin_under_the_o_spin_pattern():
    """Kinematics: its rollers point at the centre, the wheels fight with no lever arm
    (seed 002). Rollers mounted at 45° spun it at −0.65 rad/s."""
    assert abs(_spin_of_x_square(_desc("x_square"))) < 0.15
    at_45 = _desc("x_square", roller_angle_deg=math.degrees(math.atan(1.0169)))
    assert _spin_of_x_square(at_45) < -0.4


def test_reference_env_runs_the_descriptions_physics_at_the_task_control_period():
    env = MecanumEnv(EnvConfig(), fidelity="reference")
    desc = builtin_description("o_rectangle")
    assert env.robot.fidelity == "reference"
    assert env.robot.dt == pytest.approx(desc.sim.reference_timestep)
    assert env.substeps == round(env.config.control_dt / desc.sim.reference_timestep) == 20
    # the judge keeps the validated contact time constant, not the fast model's tuning
    solref = env.robot.sim_model.geom_solref[env.robot.index.wheel_geoms[0, 0], 0]
    assert solref == pytest.approx(desc.sim.contact_timeconst) != EnvConfig().contact_timeconst
    fast = MecanumEnv(EnvConfig())
    assert (fast.robot.fidelity, fast.substeps) == ("fast", 4)
    with pytest.raises(ConfigError, match=r"fidelity = 'exact': expected one of"):
        MecanumEnv(EnvConfig(), fidelity="exact")


def test_every_scenario_parameter_reaches_the_reference_model():
    """A scenario's physics must act on the reference model as on the fast one: every
    :class:`RobotParams` field changes the reference robot's MJX model, except the two the
    servo applies in the physics step for both fidelities alike. A new field must be placed
    here, so a parameter that cannot reach the reference model is not silently dropped."""
    env = MecanumEnv(EnvConfig(), fidelity="reference")
    robot = env.robot
    in_step = {"ki", "max_accel"}  # physics.Robot._physics_step, fidelity-independent
    loaded = {"payload_mass": 2.0}  # a payload, so that its centre of mass matters
    nominal = robot.model_for(robot.nominal_params(**loaded))
    changed = {
        "friction": 0.3,
        "payload_mass": 3.0,
        "payload_com": (0.05, 0.02, 0.01),
        "radius_scale": 1.03,
        "torque_limit": 1.0,
        "kp": 1.0,
    }
    assert set(changed) | in_step == set(RobotParams._fields)
    for field, value in changed.items():
        model = robot.model_for(robot.nominal_params(**{**loaded, field: value}))
        differs = [
            name
            for name in MODEL_FIELDS
            if not np.array_equal(np.asarray(getattr(model, name)), getattr(nominal, name))
        ]
        assert differs, f"{field} does not reach the reference model"


def test_timestep_that_does_not_divide_the_control_period_is_rejected(tmp_path):
    robot = tmp_path / "robot.toml"
    robot.write_text(
        '[robot]\nname = "odd"\n[geometry]\nlayout = "O-rectangle"\nwheel_radius = 0.05\n'
        "half_wheelbase = 0.10\nhalf_track = 0.125\n[motors]\nmax_motor_rpm = 9000.0\n"
        "gear_ratio = 19.0\n[sim]\nreference_timestep = 0.0015\n"
    )
    cfg = EnvConfig(robot=str(robot))
    fid.check_task(cfg, "fast", "--fidelity")  # the fast model runs: 4 steps of 5 ms
    with pytest.raises(
        ConfigError, match=r"--fidelity = 'reference': .*reference_timestep = 0\.0015"
    ):
        fid.check_task(cfg, "reference", "--fidelity")
    base = load_train_config("tiny").to_dict()
    base["env"]["robot"] = str(robot)
    base["run"]["eval_fidelity"] = "reference"
    with pytest.raises(ConfigError, match=r"run\.eval_fidelity = 'reference': .*0\.0015"):
        parse_train_config(base, "cfg")
    base["run"]["eval_fidelity"] = "exact"
    with pytest.raises(ConfigError, match=r"run\.eval_fidelity = 'exact': expected one of"):
        parse_train_config(base, "cfg")


def test_periodic_evaluation_in_the_reference_model():
    cfg = load_train_config("tiny")
    env = MecanumEnv(cfg.env)
    default = PeriodicEvaluation(cfg, env, networks=None, on_gpu=False)
    assert default.env is env
    assert default.evaluator.max_batch == 64
    ref_cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, eval_fidelity="reference"))
    ref = PeriodicEvaluation(ref_cfg.validate(), env, networks=None, on_gpu=False)
    assert ref.env.robot.fidelity == "reference"
    assert ref.evaluator.max_batch == fid.CPU_EVAL_BATCH["reference"] == 4


def _run_cli(argv):
    return cli.main([str(a) for a in argv])


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--fidelity", "exact"], "--fidelity = 'exact': expected one of ['fast', 'reference']"),
        (["--fidelity", "reference", "--max-batch", 6], "--max-batch = 6: the reference model"),
    ],
)
def test_eval_cli_rejects_a_bad_fidelity_or_a_batch_that_hangs(extra, message, tmp_path, capsys):
    out = tmp_path / "o"
    assert _run_cli(["baseline", "--episodes", 2, "--out", out, *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.full  # a minute of XLA compilation of the two rollouts on 2 cores
def test_eval_cli_in_the_reference_model(tmp_path):
    """The same episodes in both models: the report names its model, and the references
    track alike in both (the models agree on the nominal robot, docs/physics_model.md)."""
    argv = ["baseline", "--only", "nominal", "--episodes", 2, "--seconds", 1, "--no-plots"]
    reports = {}
    for fidelity in ("reference", "fast"):
        out = tmp_path / fidelity
        assert _run_cli([*argv, "--fidelity", fidelity, "--out", out]) == 0
        reports[fidelity] = json.loads((out / "report.json").read_text())
        assert reports[fidelity]["fidelity"] == fidelity
    assert reports["reference"]["label"] == "references in the reference model"
    assert reports["fast"]["label"] == "references"
    ref, fast = (reports[f]["scenarios"]["nominal"] for f in ("reference", "fast"))
    for who in ("analytic", "analytic_nearest", "feedback"):
        assert ref[who]["unstable"] == 0
        assert ref[who]["rmse_lin"] == pytest.approx(fast[who]["rmse_lin"], rel=0.25)
