"""The PPO learner on the suite's tiny config: devices, its untrained policy, gradient
clipping, its paired evaluation; and the mirror-averaged policy network."""

import dataclasses

import jax
import numpy as np
import pytest
from brax.training.agents.ppo.losses import PPONetworkParams
from learners import deterministic_policy, random_obs

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation.compare import TRAINING_COMPARED
from mecanum_jax.evaluation.metrics import Part
from train.config import TrainConfig
from train.config_sections import PPOConfig
from train.learner.periodic import Result, beats, compare
from train.learner.state import gradient_clip, make_optimizer
from train.learner.transfer import to_host
from train.store import leaves


def test_learner_uses_both_devices(learner):
    assert learner.n_devices == 2
    assert learner.envs_per_device == 4
    assert learner.parallel == "pmap"  # "auto" on CPUs; "sharded" only for several GPUs


def test_evaluation_is_paired_and_held_out(learner):
    ts, _ = learner.init_training()
    one = jax.tree.map(lambda x: x[0], ts)
    a = learner.evaluate_baseline(one)
    b = learner.evaluate_baseline(one)
    assert a.values == b.values  # same fixed episodes every time
    assert set(a.values) == {"randomized", "nominal"}
    assert learner.cfg.run.eval_seed not in learner.cfg.run.seeds
    batches = learner.evaluation.batches()
    assert len(batches["randomized"].keys) == learner.cfg.run.num_eval_envs
    # the nominal scenario: nominal physics, no noise or latency
    assert np.all(np.asarray(batches["nominal"].noise_std) == 0)
    assert np.all(np.asarray(batches["nominal"].latency) == 0)
    assert np.ptp(np.asarray(batches["randomized"].params.friction)) > 0


def _result(ss_lin, ss_wz):
    """A periodic-evaluation result with per-episode steady-state errors."""
    parts = {}
    for key, err in (("ss_lin", ss_lin), ("ss_wz", ss_wz)):
        parts[key] = Part(np.asarray(err, float) ** 2, np.ones(len(err)), "rms")
    for key in set(TRAINING_COMPARED) - set(parts):
        parts[key] = Part(np.ones(len(ss_lin)), np.ones(len(ss_lin)), "mean")
    return Result({"randomized": {}}, {"randomized": parts})


def test_beating_the_baseline_takes_a_paired_interval_below_one():
    rng = np.random.default_rng(0)
    base = rng.uniform(0.5, 1.5, 200)
    baseline = _result(base, base)
    assert beats(compare(_result(0.8 * base, 0.9 * base), baseline))  # both clearly lower
    assert not beats(compare(_result(0.8 * base, 1.1 * base), baseline))  # one worse
    noisy = base * rng.choice([0.7, 1.3], 200)  # lower or higher by episode: a tie
    assert not beats(compare(_result(noisy, 0.8 * base), baseline))


def test_untrained_policy_is_the_baseline(learner):
    """The mean output starts at 0: with residual actions the deterministic untrained
    policy outputs 0."""
    ts, _ = learner.init_training()
    policy = deterministic_policy(learner, ts)
    obs = random_obs(learner, 7, seed=1)
    with jax.numpy_rank_promotion("allow"):
        action = np.asarray(policy(obs, jax.random.PRNGKey(0))[0])
    np.testing.assert_array_equal(action, np.zeros((7, learner.env.action_size)))
    assert learner.cfg.env.residual


def test_untrained_policy_explores_with_the_configured_noise(learner):
    """network.init_noise_std sets the initial exploration std, the same in every state
    (Brax's tanh-normal policy alone ignores it and starts at softplus of random outputs)."""
    ts, _ = learner.init_training()
    one = jax.tree.map(lambda x: x[0, 0], ts)
    obs = random_obs(learner, 16, seed=2)
    with jax.numpy_rank_promotion("allow"):
        logits = learner.networks.policy_network.apply(
            one.normalizer_params, one.params.policy, obs
        )
        dist = learner.networks.parametric_action_distribution.create_dist(logits)
    std = np.asarray(dist.scale)
    assert std.shape == (16, learner.env.action_size)
    np.testing.assert_allclose(std, learner.cfg.network.init_noise_std, rtol=1e-5)


def test_gradient_clipping_per_network():
    """Each network's gradient is clipped by its own norm: a huge value gradient does not
    shrink the policy's step."""
    cfg = TrainConfig(ppo=PPOConfig(max_grad_norm=1.0))
    clip = gradient_clip(cfg)
    zeros = {"w": np.zeros(2, np.float32)}
    grads = PPONetworkParams(
        policy={"w": np.array([0.3, 0.4], np.float32)},  # norm 0.5: under the limit
        value={"w": np.array([60.0, 80.0], np.float32)},  # norm 100
    )
    params = PPONetworkParams(policy=zeros, value=zeros)
    out, _ = clip.update(grads, clip.init(params), params)
    policy, value = np.asarray(out.policy["w"]), np.asarray(out.value["w"])
    np.testing.assert_allclose(policy, [0.3, 0.4], rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(value), 1.0, rtol=1e-5)


def test_learning_rate_decays_to_its_final_fraction():
    """ppo.learning_rate_final: Adam's steps (constant gradients: ±rate each) follow a cosine
    from learning_rate to that fraction of it over the run's updates, then stay there."""
    base = TrainConfig(ppo=PPOConfig(num_envs=8, batch_size=8, num_minibatches=2))
    cfg = dataclasses.replace(
        base,
        ppo=dataclasses.replace(
            base.ppo, num_timesteps=2 * base.steps_per_iteration, learning_rate_final=0.1
        ),
    )
    total = cfg.num_iterations * cfg.ppo.num_minibatches * cfg.ppo.num_updates_per_batch  # 16
    opt = make_optimizer(cfg)
    params = PPONetworkParams(
        policy={"w": np.zeros(1, np.float32)}, value={"w": np.zeros(1, np.float32)}
    )
    grads = PPONetworkParams(
        policy={"w": np.ones(1, np.float32)}, value={"w": np.ones(1, np.float32)}
    )
    state, steps = opt.init(params), []
    for _ in range(total + 3):
        out, state = opt.update(grads, state, params)
        steps.append(-float(out.policy["w"][0]))
    lr = cfg.ppo.learning_rate
    np.testing.assert_allclose(steps[0], lr, rtol=1e-4)
    half = lr * (0.1 + 0.9 * 0.5)  # cosine at half the updates: midway
    np.testing.assert_allclose(steps[total // 2], half, rtol=1e-3)
    np.testing.assert_allclose(steps[total:], 0.1 * lr, rtol=1e-3)
    with pytest.raises(ConfigError, match=r"ppo\.learning_rate_final.*1\.5"):
        dataclasses.replace(
            cfg, ppo=dataclasses.replace(cfg.ppo, learning_rate_final=1.5)
        ).validate()


def test_checkpoints_hold_only_numpy_arrays(learner):
    """Orbax refuses process-local jax.Arrays in multi-process runs; some optimizer states
    rebuild their leaves as jax arrays, so the packing converts leaf by leaf."""
    state, env_state = learner.init()
    for tree in (to_host(state), to_host(env_state)):
        packed = leaves.pack(tree)
        assert packed
        assert all(isinstance(v, np.ndarray) for v in packed.values())


def test_the_mirror_averaged_policy_network_is_equivariant_and_the_plain_average():
    """The trained policy's mirror average (train/learner/state.py): f(g·o) = g·f(o) for
    every mirror, and it is ¼ Σ_g g⁻¹·π(g·o) of the plain network on the same weights."""
    from brax.training.acme import running_statistics, specs

    from mecanum_jax.control.symmetry import mirrors
    from mecanum_jax.task import EnvConfig
    from mecanum_jax.task.shapes import task_shapes
    from train.learner.state import make_networks

    cfg = dataclasses.replace(TrainConfig(), env=EnvConfig(symmetric=True)).validate()
    env = task_shapes(cfg.env)
    nets = make_networks(env, cfg)
    plain = make_networks(env, dataclasses.replace(cfg, env=EnvConfig(symmetric=False)))
    key = jax.random.PRNGKey(1)
    params = nets.policy_network.init(jax.random.PRNGKey(0))  # the mean layer starts at 0
    params = jax.tree.map(lambda p: p + 0.3 * jax.random.normal(key, p.shape), params)

    (size,) = env.observation_size["state"]
    norm = running_statistics.init_state({"state": specs.Array((size,), np.float32)})
    rng = np.random.default_rng(0)
    state = rng.normal(size=(64, size)).astype(np.float32)
    n = env.action_size

    def loc(net, s):
        with jax.numpy_rank_promotion("allow"):  # Brax's normalizer broadcasts
            return np.asarray(net.policy_network.apply(norm, params, {"state": s}))[:, :n]

    got = loc(nets, state)
    want = loc(plain, state)
    for (oi, os), (ai, sign) in mirrors(env.control):
        want = want + loc(plain, state[:, oi] * os)[:, ai] * sign
        np.testing.assert_allclose(loc(nets, state[:, oi] * os), got[:, ai] * sign, atol=2e-6)
    np.testing.assert_allclose(got, want / 4.0, atol=2e-6)
    assert np.abs(loc(plain, state) - got).max() > 1e-3  # the average differs from one pass
