"""The MJX robot model: builds, validates against the kinematics (small scale), batches."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import ConfigError, kinematics, mjcf, physics, validation
from mecanum_jax.config import load_toml
from mecanum_jax.description import CONFIG_DIR, builtin_description, parse_description
from mecanum_jax.geometry import SingularLayoutWarning

ROBOTS = sorted(p.stem for p in (CONFIG_DIR / "robots").glob("*.toml"))


@pytest.fixture(scope="session")
def fast_robot():
    return physics.Robot(builtin_description("o_rectangle"), "fast")


@pytest.fixture(scope="session")
def fast_runs(fast_robot):
    """One vmapped rollout shared by several tests."""
    geom = fast_robot.geometry
    rates = lambda t: validation._rates(geom, t)  # noqa: E731
    cases = [
        validation.Case("forward", "mode", rates((0.3, 0.0, 0.0)), (0.3, 0.0, 0.0)),
        validation.Case("spin", "mode", rates((0.0, 0.0, 1.0)), (0.0, 0.0, 1.0)),
        validation.Case("mixed", "random", rates((0.2, -0.1, 0.8)), (0.2, -0.1, 0.8)),
        validation.Case(
            "slip", "slip", rates((1.0, 0.0, 0.0)), (1.0, 0.0, 0.0), (("friction", 0.1),)
        ),
        validation.Case("grip", "slip", rates((1.0, 0.0, 0.0)), (1.0, 0.0, 0.0)),
        validation.Case(
            "gentle", "odometry", rates((0.4, 0.2, 0.5)), (0.4, 0.2, 0.5), (("max_accel", 20.0),)
        ),
    ]
    return cases, validation.simulate(fast_robot, cases, 2.0, chunk=len(cases))


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("fidelity", mjcf.FIDELITIES)
def test_every_layout_builds(name, fidelity):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model, index = mjcf.build_model(builtin_description(name), fidelity)
    n = len(index.wheel_names)
    assert index.axle_dof.shape == (n,)
    assert model.nu == n
    singular = [w for w in caught if issubclass(w.category, SingularLayoutWarning)]
    assert bool(singular) == (name == "x_square")
    expected_nv = 6 + (2 * n if fidelity == "fast" else n * (1 + 10))
    assert model.nv == expected_nv


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        ({"body": {"mass": -1.0}}, r"body\.mass = -1\.0: must be > 0"),
        ({"sim": {"rollers": 2}}, r"sim\.rollers = 2"),
        (
            {"body": {"half_size": [0.2, 0.2, 0.03]}},
            r"body\.half_size = .*overlaps wheel 'left_front'",
        ),
        ({"actuators": {"kp": 0.0, "ki": 0.0}}, r"servo needs a gain"),
        ({"sim": {"contact_timeconst": 0.001}}, r"sim\.contact_timeconst = 0\.001"),
        ({"body": {"colour": "red"}}, r"body\.colour = 'red': unknown key"),
    ],
)
def test_unbuildable_descriptions(edit, match):
    data = load_toml(CONFIG_DIR / "robots" / "o_rectangle.toml")
    for table, values in edit.items():
        data.setdefault(table, {}).update(values)
    with pytest.raises(ConfigError, match=match):
        mjcf.build_model(parse_description(data), "fast")


def test_fast_model_tracks_the_kinematics(fast_runs):
    cases, out = fast_runs
    for i, case in enumerate(cases[:3]):
        achieved = out["twist"][i, -25:].mean(axis=0)
        _, _, ok = validation._tracking_error(achieved, np.asarray(case.twist), "fast")
        assert ok, (case.name, achieved, case.twist)
    assert int(out["unstable"].sum()) == 0


def test_low_friction_slips(fast_runs):
    _, out = fast_runs
    slip_early = out["twist"][3, :25, 0].mean()
    grip_early = out["twist"][4, :25, 0].mean()
    assert slip_early < 0.5 * grip_early  # measurably short while accelerating on μ = 0.1


def test_encoder_odometry_matches_truth_without_slip(fast_robot, fast_runs):
    _, out = fast_runs
    err, dist = validation.odometry_drift(fast_robot, out, 5)
    assert dist > 0.5
    assert err < 0.05 * dist
    err_slip, dist_slip = validation.odometry_drift(fast_robot, out, 3)
    assert err_slip > 0.5 * dist_slip  # with slip the encoders are far off


def test_x_square_cannot_spin():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SingularLayoutWarning)
        xs = physics.Robot(builtin_description("x_square"), "fast")
        os_ = physics.Robot(builtin_description("o_square"), "fast")
    pattern = (-10.0, -10.0, 10.0, 10.0)
    x = validation.simulate(xs, [validation.Case("x", "x", pattern)], 2.0, chunk=1)
    o = validation.simulate(os_, [validation.Case("o", "x", pattern)], 2.0, chunk=1)
    assert abs(x["twist"][0, -25:, 2].mean()) < 0.1
    assert o["twist"][0, -25:, 2].mean() > 1.0


def test_reference_fidelity_forward_within_5_percent():
    robot = physics.Robot(builtin_description("o_rectangle"), "reference")
    t = (0.3, 0.0, 0.0)
    out = validation.simulate(
        robot, [validation.Case("f", "mode", validation._rates(robot.geometry, t), t)], 1.5, chunk=1
    )
    achieved = out["twist"][0, -25:].mean(axis=0)
    assert np.linalg.norm(achieved - np.asarray(t)) < 0.05 * 0.3


def test_batched_api_per_robot_params_and_nan_isolation(fast_robot):
    reset, step, sensors = fast_robot.batched(substeps=5)
    p = physics.stack_params(
        [fast_robot.nominal_params(), fast_robot.nominal_params(payload_mass=2.0, friction=0.05)]
    )
    state = reset(p, jnp.zeros((2, 3)))
    cmd = jnp.broadcast_to(
        kinematics.inverse(fast_robot.geometry, jnp.array([0.5, 0.0, 0.0])), (2, 4)
    )
    for _ in range(4):
        state = step(state, cmd, p)
    early = sensors(state).twist
    assert float(early[1, 0]) < 0.8 * float(early[0, 0])  # on ice: slower start
    for _ in range(16):
        state = step(state, cmd, p)
    s = sensors(state)
    assert s.wheel_rate.shape == (2, 4)
    assert s.pose.shape == (2, 3)
    assert s.accel.shape == (2, 3)
    assert 8.0 < float(s.accel[0, 2]) < 11.5  # the accelerometer feels gravity
    # poison robot 1 only: it is reset and reported, robot 0 carries on
    bad = state.data.qvel.at[1, 0].set(jnp.nan)
    state = state.replace(data=state.data.replace(qvel=bad))
    state = step(state, cmd, p)
    assert bool(jnp.all(jnp.isfinite(state.data.qpos)))
    report = physics.unstable_robots(state, p)
    assert [r["robot"] for r in report] == [1]
    assert report[0]["params"]["payload_mass"] == 2.0
    assert float(sensors(state).twist[0, 0]) > 0.1


def test_nominal_params_reject_unknown_fields(fast_robot):
    with pytest.raises(KeyError, match="frction"):
        fast_robot.nominal_params(frction=0.5)


def test_radius_error_changes_speed(fast_robot):
    cmd = kinematics.inverse(fast_robot.geometry, jnp.array([0.3, 0.0, 0.0]))
    big = fast_robot.nominal_params(radius_scale=1.05)
    got = jax.jit(lambda c: physics.steady_twist(fast_robot, big, c, 1.5, 0.5))(cmd)
    assert float(got[0]) == pytest.approx(0.3 * 1.05, rel=0.02)
    assert math.isfinite(float(got[1]))
