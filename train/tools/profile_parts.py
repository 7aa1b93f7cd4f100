"""The parts of a training epoch as programs of their own, for :mod:`train.tools.profile`.

Each program runs one part for the whole epoch's control steps (its ``epoch_iterations``
rollouts, from the epoch's starting state, so that the robots go through the same part of
their episodes as in the epoch) or, for the update, for one iteration. They run on the
learner's own shapes and devices (:meth:`train.learner.ppo.Learner.program`: vmapped over seeds,
parallel over the devices as the epoch is), and are built from the learner's own pieces
(``Learner.collect``, ``Learner.update``, the environment, the robot) so that they compute
what the epoch does:

- ``physics``: the MJX step alone (``Robot.step``, all substeps) for the epoch's control
  steps, holding each robot's wheel setpoints of the zero action;
- ``task``: :meth:`MecanumEnv.step` under the zero action with the physics replaced
  (:func:`physics_replaced`): setpoints, sensors, observations, reward, commands, the
  observations and rewards kept per step;
- ``env``: :meth:`Learner.collect` (once per iteration) with a policy that returns zeros,
  physics replaced (adds the training environment's automatic resets and the transitions
  it stores);
- ``rollout``: :meth:`Learner.collect` with the network's policy, physics replaced (adds
  the policy's inference);
- ``update``: :meth:`Learner.update` on a stored iteration's data (normalizer, GAE, the
  losses' forward and backward passes, the optimizer);
- ``normalizer`` and ``gae``: those two inside it, alone (GAE once per minibatch and
  pass, on minibatch shapes, as Brax's loss computes it);
- ``call``: nothing; the cost of one call (dispatch, arguments, waiting), which the
  epoch pays once, is taken off each part program's time.

Replacing the physics in the nested programs measures the small parts directly, rather
than as small differences of programs that the physics dominates, and keeps the MJX step
(slow to compile) out of all but one of them.
Every program returns all it computes (the new state, the stacked data), so XLA cannot
drop work that the epoch needs.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
from brax.envs.base import State
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from jax.typing import ArrayLike

from mecanum_jax.sim.batching import chunked_vmap
from mecanum_jax.sim.physics import Robot
from mecanum_jax.sim.state import RobotParams, SimState
from train.learner.parallel import AXIS
from train.learner.ppo import Learner, TrainingState, allow_rank_promotion
from train.learner.shapes import Metrics, PackedEnv, Updated

Collected = tuple[PackedEnv, types.Transition, Metrics]
"""The epoch's rollouts: the packed environment state after them, their stacked data and
metrics (:meth:`EpochParts._collect`)."""


def zero_policy(policy: types.Policy) -> types.Policy:
    """A policy with ``policy``'s outputs (actions and extras), all zeros, and no network."""

    def zero(obs: types.Observation, key: jax.Array) -> tuple[types.Action, types.Extra]:
        shapes = jax.eval_shape(policy, obs, key)
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    return zero


@contextlib.contextmanager
def physics_replaced(robot: Robot) -> Iterator[None]:
    """While a part program is traced, ``robot.step`` only holds the wheel setpoints it is
    given (the data flow stays: nothing that reads the state or the setpoints is dropped),
    without an MJX step."""

    def hold(
        state: SimState, command: ArrayLike, params: RobotParams, substeps: int = 1
    ) -> SimState:
        return state.replace(setpoint=jnp.asarray(command, jnp.float32))

    robot.__dict__["step"] = hold  # shadows the method on this instance only
    try:
        yield
    finally:
        robot.__dict__.pop("step")


class EpochParts:
    """The part programs of one learner (see the module docstring)."""

    def __init__(self, learner: Learner):
        self.learner = learner
        cfg = learner.cfg
        self.iterations = cfg.run.epoch_iterations
        self.steps = self.iterations * learner.unrolls_per_iteration * cfg.ppo.unroll_length
        parts = {
            "physics": self._physics,
            "task": self._task,
            "env": self._env,
            "rollout": self._rollout,
            "update": self._update,
            "normalizer": self._normalizer,
            "gae": self._gae,
            "call": self._call,
        }
        self.programs = {k: learner.program(allow_rank_promotion(f)) for k, f in parts.items()}

    def _policy(self, ts: TrainingState) -> types.Policy:
        return self.learner.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))

    def _physics(self, ts: TrainingState, packed: PackedEnv) -> PackedEnv:
        learner = self.learner
        env, menv = learner.unpack_env(packed), learner.env
        info = env.info
        zeros = jnp.zeros((info["command"].shape[0], menv.action_size))
        rates = jax.vmap(menv.wheel_setpoints)(
            info["command"], zeros, info
        )  # a feedback base reads the state
        step = chunked_vmap(
            lambda s, r, p: menv.robot.step(s, r, p, menv.substeps), learner.train_env.chunk
        )

        def body(sim: SimState, _: None) -> tuple[SimState, None]:
            return step(sim, rates, info["params"]), None

        sim, _ = jax.lax.scan(body, env.pipeline_state, None, length=self.steps)
        return learner.pack_env(env.replace(pipeline_state=sim))

    def _task(
        self, ts: TrainingState, packed: PackedEnv
    ) -> tuple[PackedEnv, tuple[jax.Array, jax.Array, Metrics]]:
        learner = self.learner
        env, menv = learner.unpack_env(packed), learner.env
        zeros = jnp.zeros((env.reward.shape[0], menv.action_size))
        step = chunked_vmap(menv.step, learner.train_env.chunk)

        def body(s: State, _: None) -> tuple[State, tuple[jax.Array, jax.Array, Metrics]]:
            s = step(s, zeros)
            return s, (s.obs, s.reward, s.metrics)

        with physics_replaced(menv.robot):
            env, out = jax.lax.scan(body, env, None, length=self.steps)
        return learner.pack_env(env), out

    def _env(self, ts: TrainingState, packed: PackedEnv) -> Collected:
        return self._collect(zero_policy(self._policy(ts)), ts, packed)

    def _rollout(self, ts: TrainingState, packed: PackedEnv) -> Collected:
        return self._collect(self._policy(ts), ts, packed)

    def _collect(self, policy: types.Policy, ts: TrainingState, packed: PackedEnv) -> Collected:
        """The epoch's rollouts (same policy throughout); the last iteration's data last."""
        learner = self.learner

        def iteration(env: State, key: jax.Array) -> tuple[State, tuple[types.Transition, Metrics]]:
            env, data, metrics = learner.collect(policy, env, key)
            return env, (data, metrics)

        keys = jax.random.split(ts.key, self.iterations)
        with physics_replaced(learner.env.robot):
            env, (data, metrics) = jax.lax.scan(iteration, learner.unpack_env(packed), keys)
        return learner.pack_env(env), data, metrics

    def _call(self, ts: TrainingState, packed: PackedEnv) -> jax.Array:
        """Nothing: the cost of calling a program with the parts' arguments."""
        return ts.key

    def _update(self, ts: TrainingState, data: types.Transition) -> Updated:
        return self.learner.update(ts, data, ts.key)

    def _normalizer(
        self, ts: TrainingState, data: types.Transition
    ) -> running_statistics.RunningStatisticsState:
        return running_statistics.update(
            ts.normalizer_params, data.observation, pmap_axis_name=AXIS
        )

    def _gae(self, ts: TrainingState, data: types.Transition) -> tuple[jax.Array, jax.Array]:
        """GAE as the loss computes it: per minibatch ``(T, B)``, each pass over the data."""
        p = self.learner.cfg.ppo
        truncation = data.extras["state_extras"]["truncation"]
        termination = (1 - data.discount) * (1 - truncation)
        values = data.discount * 0.5 + data.reward  # any (N, T) array: GAE's cost is the same
        fields = (truncation, termination, data.reward * p.reward_scaling, values)

        def minibatch(
            c: None, xs: tuple[jax.Array, ...]
        ) -> tuple[None, tuple[jax.Array, jax.Array]]:
            trunc, term, reward, value = (jnp.swapaxes(x, 0, 1) for x in xs)
            return c, ppo_losses.compute_gae(
                truncation=trunc,
                termination=term,
                rewards=reward,
                values=value,
                bootstrap_value=value[-1],
                lambda_=p.gae_lambda,
                discount=p.discounting,
            )

        def one_pass(c: None, _: None) -> tuple[None, tuple[jax.Array, jax.Array]]:
            split = tuple(x.reshape((p.num_minibatches, -1, *x.shape[1:])) for x in fields)
            return jax.lax.scan(minibatch, c, split)

        _, out = jax.lax.scan(one_pass, None, None, length=p.num_updates_per_batch)
        return out


__all__ = ["EpochParts", "physics_replaced", "zero_policy"]
