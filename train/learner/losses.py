"""Losses added to Brax's PPO loss.

:func:`smoothness_loss` is a CAPS-style regularizer (Mysore et al., "Regularizing Action
Policies for Smooth Control with Reinforcement Learning", ICRA 2021) on the policy's
deterministic action ``μ(s)`` (the mode of its action distribution):

- temporal: ``‖μ(s_t) − μ(s_{t+1})‖²``, consecutive states of the collected trajectories;
- spatial: ``‖μ(s) − μ(s + ε)‖²`` with ``ε ~ N(0, σ²)`` on the policy's (scaled)
  observation, σ at the sensor noise's scale.

Both are means over the batch, scaled by their weights (:class:`SmoothnessConfig`), and
reported as ``smooth_temporal`` and ``smooth_spatial``. Unlike a low-pass filter of the
actions it adds no lag: it asks the policy itself not to flicker, and not to follow
sensor noise.

:func:`anchor_loss` asks the components of a twist-space residual to be zero where its base
is already exact (:func:`mecanum_jax.task.anchor.exact_components`: the yaw part on steady
no-yaw commands on the nominal robot; with ``spins`` every part on its steady pure spins and
stops too): the mean of ``μ_k(s)²`` over those states and components. Without it the policy
learns a constant, direction-dependent yaw correction on straight lines from the randomized
robots and applies it to every robot (measured with a probe since removed), and a constant
correction on spins. Its weight is :class:`AnchorConfig`; reported as ``anchor``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, ParamSpec, TypeVar

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo.networks import PPONetworks

from mecanum_jax.precision import matmul_precision_scope
from mecanum_jax.task.anchor import exact_components
from train.loss_config import AnchorConfig, SmoothnessConfig

if TYPE_CHECKING:
    from mecanum_jax.task.controller import TaskInfo
    from mecanum_jax.task.env import MecanumEnv

P = ParamSpec("P")
R = TypeVar("R")
Obs = Mapping[str, jax.Array]


def anchor_loss(action: jax.Array, mask: jax.Array) -> jax.Array:
    """Mean of ``action²`` over the samples and components where ``mask`` (same shape) is 1
    (0 without any)."""
    count = jnp.sum(mask)
    total = jnp.sum(mask * action**2)
    return jnp.where(count > 0, total / jnp.maximum(count, 1.0), 0.0)


def state_extras(
    env: MecanumEnv, info: TaskInfo, next_info: TaskInfo, anchor: AnchorConfig
) -> dict[str, jax.Array]:
    """What the loss reads of a batch of transitions besides the observations:
    ``truncation`` (Brax's), and with ``anchor`` on the mask of
    :func:`~mecanum_jax.task.anchor.exact_components` on the states acted from (``info``)."""
    extras = {"truncation": next_info["truncation"]}
    if anchor.enabled:
        hold = env.config.feedback.hold_steps(env.config.control_dt)
        exact = functools.partial(
            exact_components,
            env.constants,
            hold_steps=hold,
            spins=anchor.spins,
            translations=anchor.translations,
        )
        extras["anchor"] = jax.vmap(exact)(info)
    return extras


def successor_actions(
    mean_action: Callable[[Obs], jax.Array], action: jax.Array, next_observation: Obs
) -> jax.Array:
    """``mean_action(next_observation)`` for a batch of trajectories ``(B, T, ...)`` whose
    ``action = mean_action(observation)`` is known: a trajectory's next observation at step
    t is its observation at t + 1 (the rollouts act from the state they stepped to; an
    automatic reset replaces both alike), so only the last step's successor is new. The
    policy runs on 1/T of the batch instead of all of it."""
    last = jax.tree.map(lambda x: x[:, -1:], next_observation)
    return jnp.concatenate([action[:, 1:], mean_action(last)], axis=1)


def smoothness_loss(
    mean_action: Callable[[Obs], jax.Array],
    observation: Obs,
    action: jax.Array,
    next_action: jax.Array,
    key: jax.Array,
    cfg: SmoothnessConfig,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The weighted CAPS terms for a batch of transitions, and their unweighted values.

    ``mean_action(obs)`` maps a (batched) observation dict to the policy's deterministic
    action; ``action`` and ``next_action`` are its values on the transitions' states and on
    their successors (unread with ``cfg.temporal = 0``); the spatial term perturbs
    ``observation["state"]``, the entry the policy reads.
    """
    zero = jnp.zeros((), action.dtype)
    temporal = spatial = zero
    if cfg.temporal > 0:
        temporal = jnp.mean(jnp.sum((action - next_action) ** 2, axis=-1))
    if cfg.spatial > 0:
        state = observation["state"]
        noisy = dict(observation)
        noisy["state"] = state + cfg.sigma * jax.random.normal(key, state.shape, state.dtype)
        spatial = jnp.mean(jnp.sum((action - mean_action(noisy)) ** 2, axis=-1))
    total = cfg.temporal * temporal + cfg.spatial * spatial
    return total, {"smooth_temporal": temporal, "smooth_spatial": spatial}


def ppo_loss_with_terms(
    params: ppo_losses.PPONetworkParams,
    normalizer_params: running_statistics.RunningStatisticsState,
    data: types.Transition,
    rng: jax.Array,
    ppo_network: PPONetworks,
    smoothness: SmoothnessConfig,
    anchor_weight: float = 0.0,
    **ppo_kwargs: float,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Brax's ``compute_ppo_loss`` plus :func:`smoothness_loss`, and with ``anchor_weight``
    > 0 that times :func:`anchor_loss` on the mask ``data.extras["state_extras"]["anchor"]`` (same
    signature as Brax's loss once ``ppo_network``, these terms' settings and Brax's own
    keywords are bound). ``data`` is a batch of trajectories ``(B, T, ...)``, as Brax's
    loss takes it (:func:`successor_actions`).

    The policy runs once on the observations for Brax's loss (which applies it to them
    time-major: it gets these logits transposed), the CAPS terms and the anchor. Of the four
    calls a minibatch had (Brax's, the actions, their successors', the perturbed ones) two
    remain, plus 1/T of one, with the loss equal bit for bit; what that buys the
    mirror-averaged `gpu` config is in docs/benchmarks.md."""
    k_ppo, k_smooth = jax.random.split(rng)
    policy = ppo_network.policy_network
    logits = policy.apply(normalizer_params, params.policy, data.observation)
    time_major = jnp.swapaxes(logits, 0, 1)
    shared = dataclasses.replace(
        ppo_network, policy_network=dataclasses.replace(policy, apply=lambda *_: time_major)
    )
    loss, metrics = ppo_losses.compute_ppo_loss(
        params, normalizer_params, data, k_ppo, shared, **ppo_kwargs
    )
    dist = ppo_network.parametric_action_distribution

    def mean_action(obs: Obs) -> jax.Array:
        return dist.mode(policy.apply(normalizer_params, params.policy, obs))

    action = dist.mode(logits)
    next_action = action
    if smoothness.temporal > 0:
        next_action = successor_actions(mean_action, action, data.next_observation)
    extra, terms = smoothness_loss(
        mean_action, data.observation, action, next_action, k_smooth, smoothness
    )
    if anchor_weight > 0:
        anchor = anchor_loss(action, data.extras["state_extras"]["anchor"])
        extra = extra + anchor_weight * anchor
        terms = {**terms, "anchor": anchor}
    return loss + extra, {**metrics, **terms, "total_loss": loss + extra}


def at_precision(fn: Callable[P, R], name: str) -> Callable[P, R]:
    """``fn`` (the loss and its gradient) traced with matrix products at precision ``name``
    (``ppo.update_precision``; ``"run"``: ``fn`` itself, at the run's precision). Only the
    update's forward and backward passes change: the rollouts, the evaluation and the
    kinematics keep the run's precision."""
    if name == "run":
        return fn

    @functools.wraps(fn)
    def traced_at(*args: P.args, **kwargs: P.kwargs) -> R:
        with matmul_precision_scope(name, "ppo.update_precision"):
            return fn(*args, **kwargs)

    return traced_at


__all__ = [
    "anchor_loss",
    "at_precision",
    "ppo_loss_with_terms",
    "smoothness_loss",
    "state_extras",
    "successor_actions",
]
