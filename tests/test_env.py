"""The tracking environment and the analytic baseline policy."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tasks import WHEEL

from mecanum_jax.kinematics import limits
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.batching import CPU_CHUNK, chunked_vmap, cpu_chunk
from mecanum_jax.sim.description import builtin_description
from mecanum_jax.task import (
    REWARD_TERMS,
    EnvConfig,
    MecanumEnv,
    RewardConfig,
    TrainingEnv,
    baseline_policy,
    reward_terms,
)
from mecanum_jax.task.commands import sample_command
from mecanum_jax.task.references import baseline_rates


@pytest.fixture(scope="session")
def env():
    # scales unlike the defaults, so the reward test sees each scale applied
    reward = RewardConfig(error_lin=0.5, error_ang=0.05, action_rate=0.2)
    return MecanumEnv(EnvConfig(episode_length=6, reward=reward, **WHEEL))


@pytest.fixture(scope="session")
def rollout(env):
    """Eight robots, twelve steps (two episodes) under the baseline; compiled once."""
    tenv = TrainingEnv(env)
    policy = baseline_policy(env.constants, env.config.residual, env.action_size)

    @jax.jit
    def run(keys):
        s0 = tenv.reset(keys)

        def f(s, _):
            a, _ = policy(s.obs, None)
            ns = tenv.step(s, a)
            return ns, (ns, a)

        return s0, jax.lax.scan(f, s0, None, length=12)

    return run(jax.random.split(jax.random.PRNGKey(0), 8))


def test_spaces(env):
    n = env.n_wheels
    assert env.action_size == n
    assert env.observation_size["state"] == (3 + n + 1 + 3 + 3 + n,)
    assert env.substeps == 4  # 20 ms control / 5 ms physics


def test_the_state_info_is_the_typed_task_info(env):
    """A state's ``info`` holds exactly :class:`TaskInfo`'s keys, and those after
    :class:`EpisodeInfo`'s are the controller state's fields, in its order: the typed
    description of ``info`` is the one the environment writes."""
    from mecanum_jax.control import ControllerState
    from mecanum_jax.task.controller import EpisodeInfo, TaskInfo

    own = list(EpisodeInfo.__annotations__)
    assert list(TaskInfo.__annotations__) == own + list(ControllerState._fields)
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    assert set(state.info) == set(TaskInfo.__annotations__)
    stepped = jax.eval_shape(env.step, state, jnp.zeros(env.action_size))
    assert set(stepped.info) == set(TaskInfo.__annotations__)


@pytest.mark.full
def test_default_physics_step_tracks_like_the_fine_step(env):
    """The environment's coarse physics step (5 ms, 4 substeps, for throughput) drives the
    nominal robot at a combined twist as the description's 2 ms step does."""
    from mecanum_jax.sim import physics

    fine = physics.Robot(builtin_description(env.config.robot), "fast")
    assert env.robot.dt > 2 * fine.dt
    # 5 ms: within 0.5%; a 10 ms step misses 1 m/s forward by 1.5% and fails here
    twists = jnp.array([[1.0, 0.0, 0.0], [0.0, 0.8, 0.0], [0.0, 0.0, 3.0], [0.6, 0.4, 1.5]])
    rates = jax.vmap(lambda t: kinematics.inverse(env.robot.geometry, t))(twists)

    def run(robot):
        f = jax.vmap(lambda c: physics.steady_twist(robot, robot.nominal_params(), c, 2.0, 0.5))
        return np.asarray(jax.jit(f)(rates))

    coarse, fine_twists = run(env.robot), run(fine)
    scale = np.linalg.norm(np.asarray(twists), axis=1)
    assert np.all(np.linalg.norm(coarse - np.asarray(twists), axis=1) < 0.01 * scale)
    assert np.all(np.linalg.norm(coarse - fine_twists, axis=1) < 0.01 * scale)


def test_commands_cover_kinds_and_respect_reach(env):
    draw = lambda k: sample_command(env.constants, k, env.config.commands)  # noqa: E731
    sample = jax.jit(jax.vmap(draw))  # one program, not op by op
    cmds = np.asarray(sample(jax.random.split(jax.random.PRNGKey(1), 4000)))
    sat = np.asarray(limits.saturation(env.geometry, cmds, env.max_rates))
    zero = np.all(cmds == 0, axis=1)
    spin = ~zero & (np.abs(cmds[:, 0]) < 1e-6) & (np.abs(cmds[:, 1]) < 1e-6)
    translation = ~zero & (cmds[:, 2] == 0)
    beyond = sat > 1.0
    c = env.config.commands
    total = c.p_zero + c.p_translation + c.p_spin + c.p_combined + c.p_beyond
    for name, mask, p in [
        ("zero", zero, c.p_zero),
        ("spin", spin, c.p_spin),
        ("translation", translation, c.p_translation),
        ("beyond", beyond, c.p_beyond),
    ]:
        assert abs(mask.mean() - p / total) < 0.03, (name, mask.mean())
    assert sat[~beyond & ~zero].max() <= c.max_fraction + 1e-4
    assert sat[~zero].min() >= c.min_fraction - 1e-4
    assert sat[beyond].max() <= c.beyond_max_fraction + 1e-4
    angles = np.arctan2(cmds[translation, 1], cmds[translation, 0])
    assert np.histogram(angles, bins=8, range=(-np.pi, np.pi))[0].min() > 0  # all directions
    assert (cmds[spin, 2] > 0).any()
    assert (cmds[spin, 2] < 0).any()


def test_baseline_is_desaturated_inverse(env):
    cmd = jnp.array([3.0, -1.0, 4.0])  # beyond reach
    rates = baseline_rates(env.constants, cmd)
    scaled, scale = limits.desaturate(env.geometry, cmd, env.max_rates)
    assert float(scale) < 1
    np.testing.assert_allclose(rates, kinematics.inverse(env.geometry, scaled), rtol=1e-5)
    assert float(jnp.max(jnp.abs(rates))) == pytest.approx(env.max_rate, rel=1e-5)
    # residual mode: the zero action is exactly the baseline
    np.testing.assert_allclose(env.wheel_setpoints(cmd, jnp.zeros(4)), rates, rtol=1e-6)


def test_direct_mode_baseline_action_reproduces_rates():
    env = MecanumEnv(EnvConfig(**{**WHEEL, "residual": False}))
    policy = baseline_policy(env.constants, env.config.residual, env.action_size)
    cmd = jnp.array([0.5, 0.2, -1.0])
    obs = {"state": jnp.concatenate([cmd / env.command_scale, jnp.zeros(14)])}
    action, _ = policy(obs, None)
    np.testing.assert_allclose(
        env.wheel_setpoints(cmd, action), baseline_rates(env.constants, cmd), atol=1e-4
    )


@pytest.mark.full  # compiles an auto-reset rollout; the tiny training run drives the same path
def test_rollout_resets_episodes_with_fresh_robots(env, rollout):
    s0, (_, (states, _)) = rollout
    done = np.asarray(states.done)  # (T, B)
    trunc = np.asarray(states.info["truncation"])
    np.testing.assert_array_equal(done[:, 0], [0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(done, trunc)
    # after the reset the robot's randomized parameters changed (not Brax's restore-first)
    f0 = np.asarray(s0.info["params"].friction)
    f_after = np.asarray(states.info["params"].friction[6])
    assert np.all(np.abs(f0 - f_after).max(axis=1) > 0)
    assert np.all(np.asarray(states.info["step"][6]) == 1)


def test_reward_terms_on_known_errors():
    cfg = RewardConfig(sigma_lin=0.25, sigma_ang=1.0)
    err = jnp.array([[0.0, 0.0, 0.0], [0.3, 0.4, 2.0]])  # |v_err| = 0.5 m/s, ω_err = 2 rad/s
    action = jnp.array([[0.5, 0.5, 0.0, 0.0], [1.0, -1.0, 0.0, 0.0]])
    last = jnp.array([[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    t = reward_terms(err, action, last, jnp.array([0.0, 40.0]), cfg)
    assert set(t) == set(REWARD_TERMS)
    # a perfect step earns the full tracking kernels and no penalty
    assert [float(t[k][0]) for k in REWARD_TERMS] == [1.0, 1.0] + [0.0] * 6
    np.testing.assert_allclose(t["tracking_lin"][1], np.exp(-1.0), rtol=1e-6)  # 0.25 / 0.25
    np.testing.assert_allclose(t["tracking_ang"][1], np.exp(-4.0), rtol=1e-6)
    np.testing.assert_allclose([t["error_lin"][1], t["error_ang"][1]], [-0.25, -4.0], rtol=1e-6)
    np.testing.assert_allclose(t["action_rate"][1], -2.0)
    np.testing.assert_allclose(t["energy"][1], -40.0)
    path = jnp.array([[0.0, 0.0, 0.0], [0.3, -0.4, 0.5]])  # 0.5 m off, 0.5 rad turned
    p = reward_terms(err, action, last, jnp.array([0.0, 40.0]), cfg, path)
    np.testing.assert_allclose([p["path_lin"][1], p["path_ang"][1]], [-0.25, -0.25], rtol=1e-6)


@pytest.mark.full  # shares that rollout
def test_rewards_and_metrics_are_consistent(env, rollout):
    _, (_, (states, _)) = rollout
    m = {k: np.asarray(v) for k, v in states.metrics.items()}
    r = env.config.reward
    # the logged terms are scaled, and the reward is their sum
    total = sum(m[f"reward/{name}"] for name in REWARD_TERMS)
    np.testing.assert_allclose(np.asarray(states.reward), total, rtol=1e-5, atol=1e-6)
    lin2, ang2 = m["error/vx2"] + m["error/vy2"], m["error/wz2"]
    np.testing.assert_allclose(m["reward/error_lin"], -r.error_lin * lin2, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(m["reward/error_ang"], -r.error_ang * ang2, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(
        m["reward/tracking_lin"], r.tracking_lin * np.exp(-lin2 / r.sigma_lin), rtol=1e-5
    )
    power = m["energy_j"] / env.config.control_dt
    np.testing.assert_allclose(m["reward/energy"], -r.energy * power, rtol=1e-5, atol=1e-8)
    np.testing.assert_array_equal(m["reward/action_rate"], 0.0)  # the baseline's action is 0
    assert np.all(m["energy_j"] >= 0)
    assert np.all((m["saturated"] >= 0) & (m["saturated"] <= 1))
    assert np.all(np.isfinite(np.asarray(states.obs["state"])))


def test_reward_target_feasible_scores_the_nearest_feasible_twist():
    """Beyond reach the feasible target's error is measured against the nearest feasible
    twist of the robot as it is, not the command (a command within reach: the same)."""
    env = MecanumEnv(EnvConfig(reward=RewardConfig(target="feasible")))
    s = env.reset(jax.random.PRNGKey(3))
    far = 3.0 * env.command_scale * jnp.array([1.0, 0.0, 0.5])  # beyond any wheel's reach
    s = env.set_command(s, far)
    nxt = jax.jit(env.step)(s, jnp.zeros(env.action_size))
    truth = np.asarray(env.robot.sensors(nxt.pipeline_state).twist)
    target = np.asarray(env.feasible_target(far, s.info["params"].radius_scale))
    assert np.linalg.norm(target - np.asarray(far)) > 0.5  # the target is not the command
    near = 0.3 * env.command_scale * jnp.array([1.0, 0.0, 0.0])
    np.testing.assert_array_equal(env.feasible_target(near, s.info["params"].radius_scale), near)
    m = nxt.metrics
    np.testing.assert_allclose(
        [m["error/vx2"], m["error/vy2"], m["error/wz2"]], (truth - target) ** 2, rtol=1e-4
    )


@pytest.mark.full
def test_observation_latency_delays_sensors():
    cfg = EnvConfig(
        **WHEEL,
        randomization=dataclasses.replace(
            EnvConfig().randomization, latency_steps=(2, 2), nominal_share=0.0
        ),
    )
    env = MecanumEnv(cfg)
    s = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    sensors = []
    for _ in range(4):
        s = step(s, jnp.full(4, 0.5))
        sensors.append(np.asarray(s.info["history"][0]))
    n = env.n_wheels
    # what the policy sees now is what the sensors read two steps ago
    np.testing.assert_allclose(np.asarray(s.obs["state"][3 : 3 + n + 7]), sensors[1], rtol=1e-6)


def test_nominal_scenario_is_deterministic_and_unrandomized():
    env = MecanumEnv(EnvConfig().nominal())
    reset = jax.jit(env.reset)  # one program, not op by op
    a = reset(jax.random.PRNGKey(0))
    b = reset(jax.random.PRNGKey(1))
    for x, y in zip(
        jax.tree.leaves(a.info["params"]), jax.tree.leaves(b.info["params"]), strict=True
    ):
        np.testing.assert_array_equal(x, y)
    assert int(a.info["latency"]) == 0


def test_a_share_of_nominal_robots_leaves_the_other_draws_alone(env):
    """randomization.nominal_share: that share of resets draws the nominal robot (no
    latency either); every other robot is the one drawn without the share."""
    from mecanum_jax.task.randomization import sample_params

    keys = jax.random.split(jax.random.PRNGKey(4), 400)
    base = env.config.randomization

    def draw(share):
        r = dataclasses.replace(base, nominal_share=share)
        return jax.vmap(lambda k: sample_params(env.constants, k, r))(keys)

    (p0, lat0), (p5, lat5), (p1, lat1) = draw(0.0), draw(0.5), draw(1.0)
    nom = env.nominal_params
    is_nom = np.all(np.asarray(p5.friction) == np.asarray(nom.friction), axis=-1)
    assert 0.4 < is_nom.mean() < 0.6
    assert not np.any(np.all(np.asarray(p0.friction) == np.asarray(nom.friction), axis=-1))
    for a, b, n in zip(jax.tree.leaves(p0), jax.tree.leaves(p5), jax.tree.leaves(nom), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        np.testing.assert_array_equal(b[~is_nom], a[~is_nom])
        np.testing.assert_array_equal(b[is_nom], np.broadcast_to(n, b[is_nom].shape))
    np.testing.assert_array_equal(np.asarray(lat5)[is_nom], 0)
    np.testing.assert_array_equal(np.asarray(lat5)[~is_nom], np.asarray(lat0)[~is_nom])
    np.testing.assert_array_equal(np.asarray(p1.payload_mass), 0.0)
    np.testing.assert_array_equal(np.asarray(lat1), 0)


@pytest.mark.full
def test_twist_residual_acts_only_through_the_inverse_model():
    """residual_space = "twist": three actions, the zero action is the baseline, and a
    correction changes the setpoints by exactly the inverse model's image of the twist
    correction, so it has no component in the wheels' null space (wheels fighting)."""
    env = MecanumEnv(EnvConfig(**{**WHEEL, "residual_space": "twist"}))
    assert env.action_size == 3
    assert dict(env.layout)["last_action"] == 3
    cmd = jnp.array([0.3, -0.2, 0.5])  # well within reach: nothing clips
    base = baseline_rates(env.constants, cmd)
    np.testing.assert_allclose(env.wheel_setpoints(cmd, jnp.zeros(3)), base, rtol=1e-6)
    a = jnp.array([0.5, -1.0, 0.25])
    delta = env.wheel_setpoints(cmd, a) - base
    expected = a * env.config.residual_scale * env.command_scale
    np.testing.assert_allclose(
        kinematics.forward(env.geometry, delta), expected, rtol=1e-4, atol=1e-6
    )
    np.testing.assert_allclose(delta, kinematics.inverse(env.geometry, expected), rtol=1e-4)
    state = env.step(env.reset(jax.random.PRNGKey(0)), a)
    assert state.obs["state"].shape == env.observation_size["state"]
    np.testing.assert_array_equal(state.info["last_action"], a)
    policy = baseline_policy(env.constants, env.config.residual, env.action_size)
    action, _ = policy(state.obs, None)
    assert action.shape == (3,)
    assert not np.any(np.asarray(action))


@pytest.mark.full  # an environment of its own to compile: tens of seconds on 2 cores
def test_action_filter_applies_and_observes_the_low_passed_action():
    """action_filter = f: the action applied is f·previous + (1 − f)·new, it is what the
    next observation's last_action carries, and the setpoints are those of that action."""
    f = 0.75
    env = MecanumEnv(EnvConfig(**{**WHEEL, "action_filter": f}).nominal())
    plain = MecanumEnv(EnvConfig(**WHEEL).nominal())
    state = env.reset(jax.random.PRNGKey(4))
    state = env.set_command(state, jnp.array([0.3, 0.0, 0.0]))
    twin = plain.set_command(plain.reset(jax.random.PRNGKey(4)), jnp.array([0.3, 0.0, 0.0]))
    step, plain_step = jax.jit(env.step), jax.jit(plain.step)
    names = [name for name, _ in env.layout]
    start = sum(size for _, size in env.layout[: names.index("last_action")])
    last = slice(start, start + env.action_size)
    applied = np.zeros(env.action_size, np.float32)
    for new in ([1.0, -1.0, 0.5, 0.0], [0.0, 0.0, 0.0, 0.0], [2.0, 0.2, -0.4, 1.0]):
        applied = f * applied + (1 - f) * np.clip(np.asarray(new, np.float32), -1, 1)
        state = step(state, jnp.asarray(new))
        twin = plain_step(twin, jnp.asarray(applied))  # the same action, unfiltered
        np.testing.assert_allclose(state.info["last_action"], applied, rtol=1e-6)
        np.testing.assert_allclose(state.obs["state"][last], applied, rtol=1e-6)
        # two programs, rounded apart by the contact solve (3e-5); a wrong action: ~0.1
        np.testing.assert_allclose(
            np.asarray(state.pipeline_state.data.qvel),
            np.asarray(twin.pipeline_state.data.qvel),
            rtol=1e-4,
            atol=1e-4,
        )
    assert abs(applied[0]) < 1.0  # the filter held the first step back


def test_chunked_vmap_equals_vmap():
    """CPU batches run in chunks (jaxlib's batched LAPACK deadlocks from 256 robots on)."""
    assert cpu_chunk() == CPU_CHUNK["fast"]  # the suite runs on CPU

    def f(x, y):
        return {"sum": x + y, "outer": jnp.outer(x, y)}

    x = jnp.arange(36.0).reshape(12, 3)
    y = jnp.ones((12, 3))
    want = jax.vmap(f)(x, y)
    for chunk in (0, 1, 5, 12, 64):  # 5: the largest divisor of 12 up to 5 is 4
        got = jax.jit(chunked_vmap(f, chunk))(x, y)
        jax.tree.map(np.testing.assert_array_equal, got, want)
    jaxpr = str(jax.make_jaxpr(chunked_vmap(f, 5))(x, y))
    assert "while" in jaxpr or "scan" in jaxpr  # a loop over 3 chunks of 4
