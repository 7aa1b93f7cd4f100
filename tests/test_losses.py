"""The CAPS-style smoothness terms (train/learner/losses.py): zero for a constant policy,
positive for one that moves with its input, on Brax's own policy network."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import pytest
from brax.training.acme import running_statistics

from mecanum_jax.config import ConfigError
from train.config import TrainConfig
from train.learner.losses import smoothness_loss
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


CFG = SmoothnessConfig(temporal=1.0, spatial=0.5, sigma=0.05)


def test_zero_for_a_constant_policy():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    total, terms = smoothness_loss(_policy(True), obs, nxt, jax.random.PRNGKey(2), CFG)
    assert float(total) == 0.0
    assert float(terms["smooth_temporal"]) == 0.0
    assert float(terms["smooth_spatial"]) == 0.0


def test_positive_for_a_policy_that_follows_its_input():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    total, terms = smoothness_loss(_policy(False), obs, nxt, jax.random.PRNGKey(2), CFG)
    assert float(terms["smooth_temporal"]) > 0
    assert float(terms["smooth_spatial"]) > 0
    expected = terms["smooth_temporal"] + 0.5 * terms["smooth_spatial"]
    assert float(total) == pytest.approx(float(expected), rel=1e-6)
    # the spatial term grows with the perturbation
    wide = dataclasses.replace(CFG, sigma=0.5)
    _, wider = smoothness_loss(_policy(False), obs, nxt, jax.random.PRNGKey(2), wide)
    assert float(wider["smooth_spatial"]) > float(terms["smooth_spatial"])


def test_terms_off_cost_nothing_and_bad_weights_are_rejected():
    obs, nxt = _batch(jax.random.PRNGKey(1))
    off = SmoothnessConfig(temporal=0.0, spatial=0.0)
    total, _ = smoothness_loss(_policy(False), obs, nxt, jax.random.PRNGKey(2), off)
    assert float(total) == 0.0
    assert not off.enabled
    assert SmoothnessConfig().enabled  # the shipped recipe's are on
    with pytest.raises(ConfigError, match=r"ppo\.smoothness\.temporal = -1"):
        SmoothnessConfig(temporal=-1.0).validate()
    with pytest.raises(ConfigError, match=r"ppo\.smoothness\.sigma = 0"):
        SmoothnessConfig(sigma=0.0).validate()
