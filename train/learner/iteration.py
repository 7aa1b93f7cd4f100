"""One PPO iteration of one seed, as the compiled epoch runs it: the policy's rollouts in
the training environment (:meth:`Iteration.collect`), then the normalizer update and the
SGD passes over them with Brax's loss (:meth:`Iteration.update`).

:class:`train.learner.ppo.Learner` builds what these use (the environments, the policy's
inference function, the loss and its gradient, the optimizer) and scans the iterations
into its epoch; ``run.parallel = "split"`` (:mod:`train.learner.split_epoch`) runs the two
halves (:meth:`Iteration.iteration_rollouts`, :meth:`Iteration.iteration_update`) in
programs of their own.
"""

from __future__ import annotations

from collections.abc import Callable

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import optax
from brax.envs.base import State
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses

from mecanum_jax.task.env import MecanumEnv, TrainingEnv
from train.config import TrainConfig
from train.learner import losses
from train.learner.parallel import AXIS
from train.learner.shapes import Metrics, Updated
from train.learner.state import TrainingState

Carry = tuple[State, jax.Array]  # a rollout's scan carry: environment state, key
Rollout = tuple[State, types.Transition, Metrics]
Rollouts = tuple[State, types.Transition, jax.Array, Metrics]  # Learner.iteration_rollouts
Sgd = tuple[optax.OptState, ppo_losses.PPONetworkParams, jax.Array]  # an SGD scan's carry


class Iteration:
    """A PPO iteration's two halves for one seed, rollouts and update, on the pieces that
    :class:`train.learner.ppo.Learner` (a subclass) builds."""

    cfg: TrainConfig
    env: MecanumEnv
    train_env: TrainingEnv
    unrolls_per_iteration: int
    make_policy: Callable[..., types.Policy]
    optimizer: optax.GradientTransformation
    # ``(loss, metrics), gradients`` of the loss at (params, normalizer, batch, key)
    _loss_and_grad: Callable[..., tuple[tuple[jax.Array, Metrics], ppo_losses.PPONetworkParams]]

    def _unroll(self, policy: types.Policy, env_state: State, key: jax.Array) -> Rollout:
        env = self.train_env

        def step(carry: Carry, _: None) -> tuple[Carry, tuple[types.Transition, Metrics]]:
            s, k = carry
            k, k_act = jax.random.split(k)
            actions, extras = policy(s.obs, k_act)
            ns = env.step(s, actions)
            transition = types.Transition(
                observation=s.obs,
                action=actions,
                reward=ns.reward,
                discount=1.0 - ns.done,
                next_observation=ns.obs,
                extras={
                    "policy_extras": extras,
                    "state_extras": losses.state_extras(
                        self.env, s.info, ns.info, self.cfg.ppo.anchor
                    ),
                },
            )
            return (ns, k), (transition, ns.metrics)

        (env_state, _), (data, metrics) = jax.lax.scan(
            step, (env_state, key), None, length=self.cfg.ppo.unroll_length
        )
        return env_state, data, metrics

    def _iteration(
        self, carry: tuple[TrainingState, State], _: None
    ) -> tuple[tuple[TrainingState, State], Metrics]:
        ts, env_state = carry
        env_state, data, keys, env_metrics = self.iteration_rollouts(ts, env_state)
        ts, metrics = self.iteration_update(ts, data, keys, env_metrics)
        return (ts, env_state), metrics

    def iteration_rollouts(self, ts: TrainingState, env_state: State) -> Rollouts:
        """An iteration's first half, one seed: ``(env_state, data, keys, env metrics)``,
        ``keys`` the next loop key and the update's, stacked."""
        key, k_unroll, k_sgd = jax.random.split(ts.key, 3)
        policy = self.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))
        env_state, data, env_metrics = self.collect(policy, env_state, k_unroll)
        metrics = {k: jnp.mean(v) for k, v in env_metrics.items()}
        metrics["reward"] = jnp.mean(data.reward)
        return env_state, data, jnp.stack([key, k_sgd]), metrics

    def iteration_update(
        self, ts: TrainingState, data: types.Transition, keys: jax.Array, env_metrics: Metrics
    ) -> Updated:
        """An iteration's second half, one seed: the update of :meth:`update` (averaged
        across devices), the next loop key, and the iteration's metrics."""
        ts, loss_metrics = self.update(ts, data, keys[1])
        ts = TrainingState(ts.optimizer_state, ts.params, ts.normalizer_params, keys[0])
        metrics = {f"loss/{k}": jnp.mean(v) for k, v in loss_metrics.items()}
        return ts, metrics | env_metrics

    def collect(self, policy: types.Policy, env_state: State, key: jax.Array) -> Rollout:
        """One iteration's rollouts: ``(env_state, data (unrolls·E, T, ...), metrics)``."""

        def unroll(c: Carry, _: None) -> tuple[Carry, tuple[types.Transition, Metrics]]:
            s, k = c
            k, k_now = jax.random.split(k)
            s, data, metrics = self._unroll(policy, s, k_now)
            return (s, k), (data, metrics)

        (env_state, _), (data, env_metrics) = jax.lax.scan(
            unroll, (env_state, key), None, length=self.unrolls_per_iteration
        )
        # (unrolls, T, E, ...) -> (unrolls * E, T, ...)
        data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
        data = jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), data)
        return env_state, data, env_metrics

    def update(self, ts: TrainingState, data: types.Transition, key: jax.Array) -> Updated:
        """Normalizer update and SGD passes over ``data``: ``(state, loss metrics)``, same key."""
        p = self.cfg.ppo
        normalizer = running_statistics.update(
            ts.normalizer_params, data.observation, pmap_axis_name=AXIS
        )

        def minibatch(c: Sgd, batch: types.Transition) -> tuple[Sgd, Metrics]:
            opt_state, params, k = c
            k, k_loss = jax.random.split(k)
            (_, metrics), grads = self._loss_and_grad(params, normalizer, batch, k_loss)
            updates, opt_state = self.optimizer.update(grads, opt_state)
            params = optax.apply_updates(params, updates)
            return (opt_state, params, k), metrics

        def sgd(c: Sgd, _: None) -> tuple[Sgd, Metrics]:
            opt_state, params, k = c
            k, k_perm, k_grad = jax.random.split(k, 3)

            def shuffle(x: jax.Array) -> jax.Array:
                x = jax.random.permutation(k_perm, x)
                return x.reshape((p.num_minibatches, -1, *x.shape[1:]))

            (opt_state, params, _grad_key), metrics = jax.lax.scan(
                minibatch, (opt_state, params, k_grad), jax.tree.map(shuffle, data)
            )
            return (opt_state, params, k), metrics

        (opt_state, params, _), loss_metrics = jax.lax.scan(
            sgd, (ts.optimizer_state, ts.params, key), None, length=p.num_updates_per_batch
        )
        return TrainingState(opt_state, params, normalizer, ts.key), loss_metrics


__all__ = ["Iteration"]
