"""The learner's state and what shapes it: :class:`TrainingState`, the networks, the
optimizer, and a seed's fresh state.

The learner (:mod:`train.learner.ppo`) updates this state and the checkpoints
(:mod:`train.store.checkpoint`) save and restore it; both import it from here, so neither
imports the other.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import flax
import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.types import Params
from flax import linen
from jax.typing import ArrayLike

from mecanum_jax.task.shapes import Shaped
from train.config import TrainConfig

# Domain tags: training and evaluation rng streams never meet, whatever the seeds are.
TRAIN_STREAM = 0x7A1


@flax.struct.dataclass
class TrainingState:
    """Everything the learner updates; one seed's (leaves gain S and D axes when batched)."""

    optimizer_state: optax.OptState
    params: ppo_losses.PPONetworkParams
    normalizer_params: running_statistics.RunningStatisticsState
    key: jax.Array


def make_networks(env: Shaped, cfg: TrainConfig) -> ppo_networks.PPONetworks:
    """Brax PPO networks for this task (an environment or its shapes): the policy reads the
    sensors' observation, the critic also the privileged state; both read it normalized
    (and clipped)."""
    normalize = functools.partial(
        running_statistics.normalize, max_abs_value=cfg.ppo.clip_observations or None
    )
    n = cfg.network
    networks = ppo_networks.make_ppo_networks(
        env.observation_size,
        env.action_size,
        preprocess_observations_fn=normalize,
        policy_hidden_layer_sizes=n.policy_hidden,
        value_hidden_layer_sizes=n.value_hidden,
        activation=linen.swish,
        policy_obs_key="state",
        value_obs_key="privileged_state",
        init_noise_std=n.init_noise_std,
    )
    if cfg.env.symmetric:
        networks = symmetric_networks(networks, env)
    return networks


def symmetric_networks(networks: ppo_networks.PPONetworks, env: Shaped) -> ppo_networks.PPONetworks:
    """``networks`` with the policy averaged over the robot's mirror group
    (:func:`mecanum_jax.control.symmetry.symmetrize`): its mean is exactly equivariant and
    its spread invariant, so the whole action distribution is."""
    from brax.training.networks import FeedForwardNetwork

    from mecanum_jax.control.symmetry import mirrors

    policy, size = networks.policy_network, env.action_size
    group = [(jnp.asarray(oi), jnp.asarray(os), jnp.asarray(ai), jnp.asarray(sg))
             for (oi, os), (ai, sg) in mirrors(env.control)]  # fmt: skip

    def apply(
        processor_params: running_statistics.RunningStatisticsState,
        params: Params,
        obs: dict[str, jax.Array],
    ) -> jax.Array:
        state = obs["state"]  # the four images as one call: 5% faster on a GPU (benchmarks.md)
        views = [state] + [jnp.take(state, oi, axis=-1) * os for oi, os, _, _ in group]
        out = policy.apply(processor_params, params, {**obs, "state": jnp.stack(views)})
        total = out[0]
        for k, (_, _, ai, sign) in enumerate(group, start=1):
            loc = jnp.take(out[k, ..., :size], ai, axis=-1) * sign
            total = total + jnp.concatenate([loc, jnp.take(out[k, ..., size:], ai, axis=-1)], -1)
        return total / 4.0

    return dataclasses.replace(networks, policy_network=FeedForwardNetwork(policy.init, apply))


def gradient_clip(cfg: TrainConfig) -> optax.GradientTransformation:
    """Gradient-norm clipping at ``ppo.max_grad_norm``, of the policy's and the value
    function's gradients each by its own norm (PPO's loss is a sum, so each network's
    gradient comes from its own term). One global norm over both would let a large value
    error (the returns' tails) shrink the policy's step in that minibatch by the same
    factor.
    """
    clip = optax.clip_by_global_norm(cfg.ppo.max_grad_norm)
    return optax.multi_transform({"policy": clip, "value": clip}, _labels)


def make_optimizer(cfg: TrainConfig) -> optax.GradientTransformation:
    """Adam after :func:`gradient_clip`, its rate decayed to ``ppo.learning_rate_final``
    of itself over ``ppo.num_timesteps`` (cosine)."""
    p = cfg.ppo
    rate: optax.ScalarOrSchedule = p.learning_rate
    if p.learning_rate_final < 1:
        updates = cfg.num_iterations * p.num_minibatches * p.num_updates_per_batch
        rate = optax.cosine_decay_schedule(p.learning_rate, updates, p.learning_rate_final)
    return optax.chain(gradient_clip(cfg), optax.adam(rate))


def _labels(params: ppo_losses.PPONetworkParams) -> ppo_losses.PPONetworkParams:
    return ppo_losses.PPONetworkParams(
        policy=jax.tree.map(lambda _: "policy", params.policy),
        value=jax.tree.map(lambda _: "value", params.value),
    )


def initial_policy(
    networks: ppo_networks.PPONetworks, key: jax.Array, action_size: int, cfg: TrainConfig
) -> Params:
    """Brax's policy initialisation, with the exploration noise ``init_noise_std``.

    Brax's tanh-normal policy MLP outputs the action means ``[0, a)`` and the scales
    ``[a, 2a)``, ``std = softplus(out) + 0.001``, and ignores ``init_noise_std``: its
    random output layer starts the std anywhere in 0.25–2 (mean ≈ 0.7) per state. Here
    the scale outputs start state-independent at ``init_noise_std`` (zero kernel, bias
    ``softplus⁻¹(init_noise_std − 0.001)``); they stay learnable and state-dependent.
    The mean outputs start at zero too (the untrained policy is then the base, with
    residual actions).
    """
    params = networks.policy_network.init(key)
    layers = params["params"]
    last = max(layers, key=lambda name: int(name.rsplit("_", 1)[-1]))
    a = action_size
    out = dict(layers[last])
    kernel, bias = out["kernel"], out["bias"]
    std = max(cfg.network.init_noise_std - 0.001, 1e-6)
    kernel = kernel.at[:, a:].set(0.0)
    bias = bias.at[a:].set(math.log(math.expm1(std)))  # softplus⁻¹
    kernel = kernel.at[:, :a].set(0.0)
    bias = bias.at[:a].set(0.0)
    out["kernel"], out["bias"] = kernel, bias
    return {**params, "params": {**layers, last: out}}


def fresh_state(
    cfg: TrainConfig,
    env: Shaped,
    networks: ppo_networks.PPONetworks,
    optimizer: optax.GradientTransformation,
    seed: int,
) -> tuple[TrainingState, jax.Array]:
    """One seed's initial training state, and the key its environments are drawn from."""
    root = jax.random.fold_in(jax.random.PRNGKey(seed), TRAIN_STREAM)
    k_policy, k_value, k_env, k_loop = jax.random.split(root, 4)
    params = ppo_losses.PPONetworkParams(
        policy=initial_policy(networks, k_policy, env.action_size, cfg),
        value=networks.value_network.init(k_value),
    )
    obs_spec = {
        k: specs.Array(shape, jnp.dtype("float32")) for k, shape in env.observation_size.items()
    }
    state = TrainingState(
        optimizer_state=optimizer.init(params),
        params=params,
        normalizer_params=running_statistics.init_state(obs_spec),
        key=k_loop,
    )
    return state, k_env


FreshProgram = Callable[[ArrayLike], tuple[TrainingState, jax.Array]]
"""A seed in, :func:`fresh_state`'s state and environment key out (compiled)."""
_FRESH: dict[tuple[TrainConfig, tuple[tuple[str, tuple[int, ...]], ...], int], FreshProgram] = {}


def fresh_state_program(
    cfg: TrainConfig,
    env: Shaped,
    networks: ppo_networks.PPONetworks,
    optimizer: optax.GradientTransformation,
) -> FreshProgram:
    """:func:`fresh_state` of a seed as one jitted program (not some 60 eager operations,
    each a program of its own: at a warm start on a GPU each was read back from the
    compilation cache one by one), bit-identical to it. Kept per config and environment
    shape, which are all that ``networks`` and ``optimizer`` are made from, so learners of
    one config share it."""
    key = (cfg, tuple(sorted(env.observation_size.items())), env.action_size)
    if key not in _FRESH:
        _FRESH[key] = jax.jit(lambda seed: fresh_state(cfg, env, networks, optimizer, seed))
    return _FRESH[key]


def state_template(cfg: TrainConfig, env: Shaped, devices: int) -> TrainingState:
    """Zero arrays shaped like a saved training state ``(devices, seeds, ...)``, built from
    shapes alone (nothing is initialised or compiled): what a checkpoint restores into."""
    networks = make_networks(env, cfg)
    one, _ = jax.eval_shape(
        lambda: fresh_state(cfg, env, networks, make_optimizer(cfg), cfg.run.seeds[0])
    )
    lead = (devices, len(cfg.run.seeds))
    return jax.tree.map(lambda x: np.zeros((*lead, *x.shape), x.dtype), one)


def all_finite(tree: object) -> jax.Array:
    """Whether every floating-point leaf of ``tree`` is finite (a traced bool)."""
    leaves = [
        x for x in jax.tree.leaves(tree) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def epoch_metrics(
    ts: TrainingState, metrics: dict[str, jax.Array], axis: str
) -> dict[str, jax.Array]:
    """An epoch's metrics from its iterations' (leading axis of each leaf): the mean over
    iterations and over the devices of ``axis``, and ``finite``, 1.0 where every device's
    parameters and normalizer are finite."""
    metrics = jax.lax.pmean(jax.tree.map(jnp.mean, metrics), axis_name=axis)
    finite = all_finite(ts.params) & all_finite(ts.normalizer_params.mean)
    metrics["finite"] = jax.lax.pmin(finite.astype(jnp.float32), axis_name=axis)
    return metrics


__all__ = [
    "TRAIN_STREAM",
    "TrainingState",
    "all_finite",
    "epoch_metrics",
    "fresh_state",
    "fresh_state_program",
    "gradient_clip",
    "initial_policy",
    "make_networks",
    "make_optimizer",
    "state_template",
]
