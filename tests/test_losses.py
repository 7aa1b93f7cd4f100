"""The CAPS-style smoothness terms (train/learner/losses.py): zero for a constant policy,
positive for one that moves with its input, on Brax's own policy network; the loss's one
policy pass shared with Brax's loss and the successors' actions."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses

from mecanum_jax.config import ConfigError
from train.config import TrainConfig
from train.learner.losses import ppo_loss_with_terms, smoothness_loss, successor_actions
from train.learner.state import make_networks
from train.loss_config import SmoothnessConfig

OBS = {"state": 20, "privileged_state": 30}


class _Shapes:  # what make_networks reads of the environment
    def __init__(self):
        self.observation_size = {k: (v,) for k, v in OBS.items()}
        self.action_size = 3


def _policy(constant: bool):
    networks = make_networks(_Shapes(), TrainConfig())  # type: ignore[arg-type]
    params = networks.policy_network.init(jax.random.PRNGKey(0))
    if constant:  # every kernel zero: the output is the bias alone, whatever the input
        params = jax.tree.map(jnp.zeros_like, params)
    spec = {k: jax.ShapeDtypeStruct((v,), jnp.float32) for k, v in OBS.items()}
    normalizer = running_statistics.init_state(spec)
    dist = networks.parametric_action_distribution

    def mean_action(obs):
        with jax.numpy_rank_promotion("allow"):  # as the learner runs it (train/learner/state.py)
            return dist.mode(networks.policy_network.apply(normalizer, params, obs))

    return mean_action


def _batch(key):
    k1, k2 = jax.random.split(key)
    obs = {k: jax.random.normal(k1, (64, v)) for k, v in OBS.items()}
    nxt = {k: x + 0.3 * jax.random.normal(k2, x.shape) for k, x in obs.items()}
    return obs, nxt


def _smoothness(mean_action, obs, nxt, cfg):
    action = mean_action(obs)
    return smoothness_loss(mean_action, obs, action, mean_action(nxt), jax.random.PRNGKey(2), cfg)


CFG = SmoothnessConfig(temporal=1.0, spatial=0.5, sigma=0.05)


def test_zero_for_a_constant_policy():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    total, terms = _smoothness(_policy(True), obs, nxt, CFG)
    assert float(total) == 0.0
    assert float(terms["smooth_temporal"]) == 0.0
    assert float(terms["smooth_spatial"]) == 0.0


def test_positive_for_a_policy_that_follows_its_input():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    total, terms = _smoothness(_policy(False), obs, nxt, CFG)
    assert float(terms["smooth_temporal"]) > 0
    assert float(terms["smooth_spatial"]) > 0
    expected = terms["smooth_temporal"] + 0.5 * terms["smooth_spatial"]
    assert float(total) == pytest.approx(float(expected), rel=1e-6)
    # the spatial term grows with the perturbation
    wide = dataclasses.replace(CFG, sigma=0.5)
    _, wider = _smoothness(_policy(False), obs, nxt, wide)
    assert float(wider["smooth_spatial"]) > float(terms["smooth_spatial"])


def test_terms_off_cost_nothing_and_bad_weights_are_rejected():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    off = SmoothnessConfig(temporal=0.0, spatial=0.0)
    total, _ = _smoothness(_policy(False), obs, nxt, off)
    assert float(total) == 0.0
    assert not off.enabled
    assert SmoothnessConfig().enabled  # the shipped recipe's are on
    with pytest.raises(ConfigError, match=r"ppo\.smoothness\.temporal = -1"):
        SmoothnessConfig(temporal=-1.0).validate()
    with pytest.raises(ConfigError, match=r"ppo\.smoothness\.sigma = 0"):
        SmoothnessConfig(sigma=0.0).validate()


def test_successor_actions_are_the_policy_on_the_next_observations():
    """On trajectories whose next observation at t is the observation at t + 1, the
    shifted actions and the one new last step equal the policy applied to every next
    observation (what the loss computed before it shared the pass)."""
    mean_action = _policy(False)
    seq = {k: jax.random.normal(jax.random.PRNGKey(5), (8, 6, v)) for k, v in OBS.items()}
    obs = {k: x[:, :-1] for k, x in seq.items()}
    nxt = {k: x[:, 1:] for k, x in seq.items()}
    shared = successor_actions(mean_action, mean_action(obs), nxt)
    np.testing.assert_allclose(shared, mean_action(nxt), rtol=1e-6, atol=1e-7)


def test_the_ppo_loss_shares_its_policy_pass_without_changing_brax_loss():
    """With the extra terms weighted 0 the total is Brax's own loss (the logits handed to it
    are its own, transposed), and the temporal term is the direct one on consecutive data."""
    cfg = TrainConfig()
    networks = make_networks(_Shapes(), cfg)  # type: ignore[arg-type]
    key = jax.random.PRNGKey(2)
    params = _params(networks, key)
    spec = {k: jax.ShapeDtypeStruct((v,), jnp.float32) for k, v in OBS.items()}
    normalizer = running_statistics.init_state(spec)
    b, t = 4, 5
    seq = {k: jax.random.normal(key, (b, t + 1, v)) for k, v in OBS.items()}
    raw = jax.random.normal(jax.random.PRNGKey(3), (b, t, 3))
    data = types.Transition(
        observation={k: x[:, :-1] for k, x in seq.items()}, action=jnp.tanh(raw),
        reward=jax.random.normal(key, (b, t)), discount=jnp.ones((b, t)),
        next_observation={k: x[:, 1:] for k, x in seq.items()},
        extras={"policy_extras": {"raw_action": raw, "log_prob": -jnp.ones((b, t)),
                                  "distribution_params": jnp.zeros((b, t, 6))},
                "state_extras": {"truncation": jnp.zeros((b, t))}},
    )  # fmt: skip
    kwargs = dict(ppo_network=networks, entropy_cost=0.0)
    off = SmoothnessConfig(temporal=0.0, spatial=0.0)
    temporal = SmoothnessConfig(temporal=1.0, spatial=0.0)
    with jax.numpy_rank_promotion("allow"):
        brax, _ = ppo_losses.compute_ppo_loss(params, normalizer, data, key, **kwargs)
        ours, _ = ppo_loss_with_terms(params, normalizer, data, key, smoothness=off, **kwargs)
        _, terms = ppo_loss_with_terms(params, normalizer, data, key, smoothness=temporal, **kwargs)
        dist = networks.parametric_action_distribution
        mode = lambda o: dist.mode(networks.policy_network.apply(normalizer, params.policy, o))  # noqa: E731
        direct = jnp.mean(jnp.sum((mode(data.observation) - mode(data.next_observation)) ** 2, -1))
    assert float(ours) == pytest.approx(float(brax), rel=1e-6)
    assert float(terms["smooth_temporal"]) > 0
    assert float(terms["smooth_temporal"]) == pytest.approx(float(direct), rel=1e-5)


def _params(networks, key):
    return ppo_losses.PPONetworkParams(
        policy=networks.policy_network.init(key), value=networks.value_network.init(key)
    )


def test_the_trainers_trajectories_are_consecutive():
    """:func:`successor_actions` reads a trajectory's next observation at t as its
    observation at t + 1: the trainer's batches keep each environment's steps in order
    across the iteration's unrolls (an environment whose observation counts its steps)."""
    from brax.envs.base import State

    from train.learner.iteration import Iteration

    envs, unrolls, length = 3, 2, 4

    class Counting:
        def step(self, s, action):
            return s.replace(obs={"state": s.obs["state"] + 1.0})

    iteration = Iteration.__new__(Iteration)
    iteration.cfg = SimpleNamespace(  # type: ignore[assignment]
        ppo=SimpleNamespace(unroll_length=length, anchor=SimpleNamespace(enabled=False))
    )
    iteration.env = iteration.train_env = Counting()  # type: ignore[assignment]
    iteration.unrolls_per_iteration = unrolls
    zero = jnp.zeros(envs)
    start = {"state": 100.0 * jnp.arange(envs, dtype=jnp.float32)[:, None]}
    state = State(None, start, zero, zero, {}, {"truncation": zero})

    def policy(obs: object, key: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
        return jnp.zeros((envs, 1)), {}

    _, data, _ = iteration.collect(policy, state, jax.random.PRNGKey(0))
    obs, nxt = data.observation["state"][..., 0], data.next_observation["state"][..., 0]
    assert obs.shape == (unrolls * envs, length)
    np.testing.assert_array_equal(nxt[:, :-1], obs[:, 1:])
    np.testing.assert_array_equal(nxt - obs, 1.0)
