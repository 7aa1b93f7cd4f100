"""The MJX robot model: builds, validates against the kinematics (small scale), batches."""

import dataclasses
import math
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mecanum_jax import ConfigError
from mecanum_jax.config import load_toml
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics.geometry import SingularLayoutWarning
from mecanum_jax.sim import mjcf, physics, validation
from mecanum_jax.sim.description import (
    CONFIG_DIR,
    builtin_description,
    check_physics,
    parse_description,
)
from mecanum_jax.sim.state import select, stack_params, unstable_robots

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
        ({"sim": {"solver": "pgs"}}, r"sim\.solver = 'pgs': expected one of \['newton', 'cg'\]"),
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


@pytest.mark.full
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


@pytest.mark.full
def test_reference_fidelity_forward_within_5_percent():
    robot = physics.Robot(builtin_description("o_rectangle"), "reference")
    t = (0.3, 0.0, 0.0)
    out = validation.simulate(
        robot, [validation.Case("f", "mode", validation._rates(robot.geometry, t), t)], 1.5, chunk=1
    )
    achieved = out["twist"][0, -25:].mean(axis=0)
    assert np.linalg.norm(achieved - np.asarray(t)) < 0.05 * 0.3


@pytest.mark.full
def test_batched_api_per_robot_params_and_nan_isolation(fast_robot):
    reset, step, sensors = fast_robot.batched(substeps=5)
    p = stack_params(
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
    report = unstable_robots(state, p)
    assert [r["robot"] for r in report] == [1]
    assert report[0]["params"]["payload_mass"] == 2.0
    assert float(sensors(state).twist[0, 0]) > 0.1


@pytest.mark.parametrize("fidelity", mjcf.FIDELITIES)
def test_simulated_model_drops_only_draw_geoms(fidelity):
    """The model MJX steps has no draw-only geoms but the same bodies, joints, masses and
    contact geoms (by name) as the full model that renders."""
    desc = builtin_description("o_rectangle")
    full, _ = mjcf.build_model(desc, fidelity)
    sim, index = mjcf.build_model(desc, fidelity, visual=False)
    drawn = (full.geom_contype == 0) & (full.geom_conaffinity == 0)
    assert drawn.sum() > 0
    assert sim.ngeom == full.ngeom - drawn.sum()
    assert np.all((sim.geom_contype != 0) | (sim.geom_conaffinity != 0))
    for attr in ("nq", "nv", "nu", "nbody"):
        assert getattr(sim, attr) == getattr(full, attr)
    for attr in ("body_mass", "body_inertia", "body_ipos", "dof_armature", "qpos0"):
        np.testing.assert_array_equal(getattr(sim, attr), getattr(full, attr))
    names = lambda m, ids: [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(i)) for i in ids]  # noqa: E731
    _, full_index = mjcf.build_model(desc, fidelity)
    assert names(sim, index.wheel_geoms.ravel()) == names(full, full_index.wheel_geoms.ravel())
    # and the same motion: 200 C MuJoCo steps of a spin-and-drive command
    states = []
    for m in (full, sim):
        d = mujoco.MjData(m)
        d.ctrl[:] = [8.0, -4.0, 6.0, -2.0]
        for _ in range(200):
            mujoco.mj_step(m, d)
        states.append(d.qpos.copy())
    assert np.abs(states[0][:2]).max() > 1e-3  # it moved
    np.testing.assert_allclose(states[1], states[0], rtol=1e-6, atol=1e-9)


def test_nominal_params_reject_unknown_fields(fast_robot):
    with pytest.raises(KeyError, match="frction"):
        fast_robot.nominal_params(frction=0.5)


def test_up_z_tells_upright_from_tipped(fast_robot):
    state = fast_robot.reset(fast_robot.nominal_params())
    assert float(fast_robot.up_z(state)) == pytest.approx(1.0, abs=1e-6)
    f = fast_robot.index.free_qpos
    for angle, tipped in ((0.5, False), (1.0, True), (math.pi, True)):  # roll about x
        quat = jnp.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])
        rolled = state.replace(
            data=state.data.replace(qpos=state.data.qpos.at[f + 3 : f + 7].set(quat))
        )
        up = float(fast_robot.up_z(rolled))
        assert up == pytest.approx(math.cos(angle), abs=1e-6)
        assert (up < physics.TIPPED_UP_Z) == tipped


@pytest.mark.full
def test_radius_error_changes_speed(fast_robot):
    cmd = kinematics.inverse(fast_robot.geometry, jnp.array([0.3, 0.0, 0.0]))
    big = fast_robot.nominal_params(radius_scale=1.05)
    got = jax.jit(lambda c: physics.steady_twist(fast_robot, big, c, 1.5, 0.5))(cmd)
    assert float(got[0]) == pytest.approx(0.3 * 1.05, rel=0.02)
    assert math.isfinite(float(got[1]))


def test_validation_cli_rejects_bad_solver_overrides(capsys, tmp_path):
    out = tmp_path / "v.md"
    with pytest.raises(SystemExit) as exc:
        validation.main(["--fidelities", "fast", "--iterations", "0", "--out", str(out)])
    assert exc.value.code == 2
    assert "sim.iterations = 0" in capsys.readouterr().err
    assert not out.exists()
    assert not out.with_suffix(".json").exists()


def _roller_reach(robot, model):
    """Per wheel, each roller geom's farthest reach from the axle (hub frame: axle = y)."""
    idx = robot.index
    body_pos = np.asarray(model.body_pos)
    geom_pos = np.asarray(model.geom_pos)
    size = np.asarray(model.geom_size)
    body = np.asarray(robot.sim_model.geom_bodyid)
    centres = body_pos[body[idx.wheel_geoms]] + geom_pos[idx.wheel_geoms]  # (n, k, 3)
    return np.hypot(centres[..., 0], centres[..., 2]) + size[idx.wheel_geoms, 0]


def test_reference_barrel_rollers_reach_exactly_the_wheel_radius():
    """Every sphere of every barrel roller reaches r below the axle (a round wheel, not a
    polygon), also under a per-wheel radius error; straight capsules overshoot by ~3%."""
    desc = builtin_description("o_rectangle")
    robot = physics.Robot(desc, "reference")
    r = np.asarray(robot.geometry.radii)[:, None]
    k = desc.sim.rollers * desc.sim.roller_spheres
    assert robot.index.wheel_geoms.shape == (robot.n_wheels, k)
    assert {
        int(t) for t in np.asarray(robot.sim_model.geom_type)[robot.index.wheel_geoms].ravel()
    } == {int(mujoco.mjtGeom.mjGEOM_SPHERE)}
    np.testing.assert_allclose(
        _roller_reach(robot, robot.sim_model), np.broadcast_to(r, (4, k)), rtol=1e-5
    )
    scale = np.array([0.95, 1.0, 1.02, 1.05], np.float32)
    model = robot.model_for(robot.nominal_params(radius_scale=scale))
    np.testing.assert_allclose(
        _roller_reach(robot, model), np.broadcast_to(r * scale[:, None], (4, k)), rtol=1e-5
    )
    # the old straight capsules: the contact at a roller's end stands beyond the radius
    capsules = dataclasses.replace(desc, sim=dataclasses.replace(desc.sim, roller_spheres=0))
    cap = physics.Robot(capsules, "reference").sim_model
    g = mujoco.mj_name2id(cap, mujoco.mjtObj.mjOBJ_GEOM, f"{robot.index.wheel_names[0]}_roller0")
    half = float(cap.geom_size[g, 1])
    axis = np.zeros(3)
    mujoco.mju_rotVecQuat(axis, np.array([0.0, 0.0, 1.0]), cap.geom_quat[g])
    centre = cap.body_pos[cap.geom_bodyid[g]] + cap.geom_pos[g]
    end = centre + half * axis
    reach_end = np.hypot(end[0], end[2]) + cap.geom_size[g, 0]
    assert reach_end > 1.03 * float(r[0, 0])


def test_roller_spheres_validated():
    desc = builtin_description("o_rectangle")
    bad = dataclasses.replace(desc, sim=dataclasses.replace(desc.sim, roller_spheres=1))
    with pytest.raises(ConfigError, match=r"sim\.roller_spheres = 1"):
        check_physics(bad, "robot")


# --- the MJX implementation (sim.impl) ------------------------------------------------------


def _with_impl(desc, impl):
    return dataclasses.replace(desc, sim=dataclasses.replace(desc.sim, impl=impl))


def test_sim_impl_is_checked_and_left_out_of_the_fingerprint():
    from mecanum_jax.sim.description import fingerprint

    desc = builtin_description("o_rectangle")
    assert desc.sim.impl == "jax"
    with pytest.raises(ConfigError, match=r"sim.impl = 'cuda'"):
        check_physics(_with_impl(desc, "cuda"), "robot")
    # the same robot, simulated another way: checkpoints stay compatible
    assert fingerprint(_with_impl(desc, "warp")) == fingerprint(desc)
    with pytest.raises(ValueError, match="robots = 0"):
        physics.Robot(desc, "fast", robots=0)


def test_warp_without_its_extra_is_refused_naming_the_field(capsys, tmp_path, monkeypatch):
    import importlib.util

    from mecanum_jax.task import EnvConfig
    from train.cli.train import main

    find_spec = importlib.util.find_spec  # as where the extra is not installed
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "warp" else find_spec(name, *a),
    )

    # a saved task that trained under warp still loads (restoring needs only its shapes)
    EnvConfig(physics_impl="warp").validate()
    run_dir = tmp_path / "run"
    assert main(["--config", "tiny", "--env.physics-impl", "warp", "--run-dir", str(run_dir)])
    assert "env.physics_impl = 'warp'" in " ".join(capsys.readouterr().err.split())
    assert not run_dir.exists()  # refused before anything was written
    with pytest.raises(ConfigError, match=r"sim.impl = 'warp'.*extra"):
        physics.Robot(_with_impl(builtin_description("o_rectangle"), "warp"), "fast")


@pytest.mark.full  # compiles a batched step of its own: ten seconds on 2 cores
def test_select_takes_fresh_robots_where_done(fast_robot):
    reset, step, _ = fast_robot.batched(substeps=2)
    p = stack_params([fast_robot.nominal_params()] * 3)
    fresh = reset(p, jnp.zeros((3, 3)))
    cmd = jnp.full((3, 4), 10.0)
    moved = step(step(fresh, cmd, p), cmd, p)
    done = jnp.array([True, False, True])
    merged = jax.jit(jax.vmap(select))(done, fresh, moved)  # one program, not op by op
    for leaf_m, leaf_f, leaf_s in zip(
        jax.tree.leaves(merged), jax.tree.leaves(fresh), jax.tree.leaves(moved), strict=True
    ):
        if np.size(leaf_m) == 0:
            continue
        np.testing.assert_array_equal(np.asarray(leaf_m)[[0, 2]], np.asarray(leaf_f)[[0, 2]])
        np.testing.assert_array_equal(np.asarray(leaf_m)[1], np.asarray(leaf_s)[1])
    assert not np.array_equal(np.asarray(moved.setpoint[1]), np.asarray(fresh.setpoint[1]))


@pytest.mark.full
def test_warp_steps_the_robot_as_jax_does():
    """With the warp extra installed (CPU is enough): the product's step (chord servo,
    re-zeroed carriers, per-robot friction, payload and wheel radius) under MuJoCo Warp
    follows MJX's JAX implementation to 1 mm/s."""
    pytest.importorskip("warp")
    base = builtin_description("o_rectangle")
    cases = [(1.0, 1.0, 0.0), (0.3, 1.05, 2.0), (0.1, 0.95, 0.0), (0.6, 1.0, 4.0)]
    cmd = jnp.array([[10.0, -10.0, 10.0, -10.0]]) * jnp.array([[1.0], [1.0], [-1.0], [0.5]])
    twists = {}
    for impl in ("jax", "warp"):
        robot = physics.Robot(_with_impl(base, impl), "fast", robots=len(cases))
        p = stack_params(
            [robot.nominal_params(friction=f, radius_scale=r, payload_mass=m) for f, r, m in cases]
        )
        reset, step, sensors = robot.batched(substeps=10)
        state, out = reset(p), []
        for _ in range(25):
            state = step(state, cmd, p)
            out.append(np.asarray(sensors(state).twist))
        assert int(np.asarray(state.unstable).sum()) == 0
        twists[impl] = np.stack(out)
    assert np.abs(twists["warp"] - twists["jax"]).max() < 1e-3
    assert abs(twists["jax"][-1, 2, 1] - 0.239) < 0.01  # on ice the robot still moves
