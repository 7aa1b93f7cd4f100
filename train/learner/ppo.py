"""PPO on the mecanum tracking task, from Brax's PPO components, with full resume.

Brax's ``ppo.train`` restores only network weights, so this module drives Brax's own
pieces (``make_ppo_networks``, ``compute_ppo_loss``, ``loss_and_pgrad``, the running
observation normalizer) from an outer loop whose whole state is explicit:

- :class:`~train.learner.state.TrainingState` (optimizer state, parameters, normalizer, rng key;
  it, the networks and the optimizer are defined in :mod:`train.learner.state`) and the
  environment state are the only things that change between epochs, and both go into
  every checkpoint, so a resumed run continues exactly as the uninterrupted one would have;
- several seeds train side by side in one compiled program (``jax.vmap`` over a seed
  axis), and the program is spread over the devices as ``run.parallel`` says
  (train/learner/parallel.py: ``jax.pmap``, or jitted over a device mesh; gradients and normalizer
  statistics are averaged across devices, as in Brax);
- between epochs the host checks for NaNs, evaluates the policy and the analytic
  baseline on the same fixed, held-out episodes, logs and checkpoints.

An iteration's two halves, the rollouts and the update, are those of
:class:`~train.learner.iteration.Iteration`, which :class:`Learner` extends with what they
use; :mod:`train.learner.transfer` moves the states between the host and the devices.

Array layout on the host: training state ``(D, S, ...)`` (replicated over the D devices),
environment state ``(D, S, E/D, ...)``, where S is the number of seeds and E ``num_envs``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State
from brax.training import gradients, types
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from jax.sharding import NamedSharding
from jax.stages import Compiled, Lowered, Wrapped
from jax.typing import ArrayLike

from mecanum_jax.host import host_side
from mecanum_jax.task.controller import allow_rank_promotion
from mecanum_jax.task.env import MecanumEnv, TrainingEnv
from train.config import TrainConfig
from train.learner import losses, parallel
from train.learner.iteration import Iteration
from train.learner.parallel import AXIS
from train.learner.periodic import PeriodicEvaluation, Result
from train.learner.shapes import Epoch, Host, PackedEnv, Placed
from train.learner.split_epoch import SplitEpoch
from train.learner.state import (
    TrainingState,
    all_finite,
    epoch_metrics,
    fresh_state_program,
    make_networks,
    make_optimizer,
)
from train.learner.transfer import strip_weak_types
from train.store import leaves


class Learner(Iteration):
    """The compiled pieces of a run: init, the per-epoch training program, evaluation.

    ``cfg`` comes validated, as every way in gives it (``train.config_loading`` loads a
    config validated, :class:`~train.loop.run.Run` checks the one it is given): the
    learner does not check it again."""

    @host_side  # its constants and set-up on the CPU (mecanum_jax.host)
    def __init__(self, cfg: TrainConfig, devices: list[jax.Device] | None = None):
        self.cfg = cfg
        self.devices = devices or parallel.devices_for(cfg)
        self.n_devices = len(self.devices)
        self.n_processes = jax.process_count()
        cfg.check_devices(self.n_devices * self.n_processes)
        self.n_seeds = len(cfg.run.seeds)
        p = cfg.ppo
        self.envs_per_device = p.num_envs // (self.n_devices * self.n_processes)
        self.env = MecanumEnv(cfg.env, robots=self.envs_per_device * self.n_seeds)
        self.train_env = TrainingEnv(self.env)
        self.unrolls_per_iteration = p.batch_size * p.num_minibatches // p.num_envs
        self.networks = make_networks(self.env, cfg)
        self.make_policy = ppo_networks.make_inference_fn(self.networks)
        self.optimizer = make_optimizer(cfg)
        # a seed's fresh training state, one program (train.loop.warm_start may store it)
        self._fresh = fresh_state_program(cfg, self.env, self.networks, self.optimizer)
        loss: Callable[..., tuple[jax.Array, types.Metrics]] = ppo_losses.compute_ppo_loss
        if p.smoothness.enabled or p.anchor.enabled:  # losses.py's terms
            loss = functools.partial(
                losses.ppo_loss_with_terms,
                smoothness=p.smoothness,
                anchor_weight=p.anchor.weight,
            )
        loss_fn = functools.partial(
            loss,
            ppo_network=self.networks,
            entropy_cost=p.entropy_cost,
            discounting=p.discounting,
            reward_scaling=p.reward_scaling,
            gae_lambda=p.gae_lambda,
            clipping_epsilon=p.clipping_epsilon,
            normalize_advantage=True,
        )
        grad = gradients.loss_and_pgrad(loss_fn, pmap_axis_name=AXIS, has_aux=True)
        self._loss_and_grad = losses.at_precision(grad, p.update_precision)
        self._compiled_epoch: Compiled | None = None
        self.parallel = parallel.choose(cfg, self.devices, self.n_processes)
        if self.parallel == "pmap":
            self._identity = jax.pmap(lambda *x: x, axis_name=AXIS, devices=self.devices)
        devices = self.devices if self.n_processes == 1 else jax.devices()
        parallel.partitionable_draws(self.parallel, devices)
        self._sharding = parallel.mesh_sharding(self.parallel, devices)
        self._parallel_epoch: Any = (
            SplitEpoch(self) if self.parallel == "split" else self.program(self._epoch)
        )
        # reset on one device, then :meth:`place` spreads it (a pmapped MJX reset crashed
        # XLA's compiler on 2 H200s with jax 0.11.2)
        self._reset = jax.jit(jax.vmap(jax.vmap(self.train_env.reset)))
        self._env_template = jax.eval_shape(
            self.train_env.reset, jax.ShapeDtypeStruct((self.envs_per_device, 2), jnp.uint32)
        )
        # the environment state's batch-wide leaves (MuJoCo Warp's contact buffers; none
        # under MJX's JAX): out of the (D, S, E) layout, fresh (zeros) in every program
        self._shared_at = leaves.batch_wide(self._env_template, self.envs_per_device)
        self._shared = leaves.fresh_batch_wide(self._env_template, self._shared_at)
        on_gpu = all(d.platform == "gpu" for d in self.devices)
        self.evaluation = PeriodicEvaluation(cfg, self.env, self.networks, on_gpu)

    # --- state ------------------------------------------------------------------------------

    def init(self, host: Host | None = None, reset: Compiled | None = None) -> Placed:
        """Fresh training and environment state, laid out ``(D, S, ...)``; ``host``:
        :meth:`init_training`'s, if made, ``reset``: the reset compiled (train.loop.aot)."""
        state, env_keys = self.init_training() if host is None else host
        env_state = (self._reset if reset is None else reset)(env_keys)
        return self.place(state, self.pack_env(env_state))

    @host_side
    def init_training(self) -> Host:
        """Fresh host training state ``(D, S, ...)`` and environment keys ``(D, S, E/D, 2)``."""
        seeds = self.cfg.run.seeds
        D, E = self.n_devices, self.envs_per_device
        states, env_keys = [], []
        for seed in seeds:
            state, k_env = self._fresh(np.uint32(seed))  # (run.seeds: 0 <= seed < 2**32)
            states.append(state)
            k_env = jax.random.fold_in(k_env, jax.process_index())
            env_keys.append(jax.random.split(k_env, D * E).reshape(D, E, -1))
        seeded = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *states)
        # replicate over devices; each device gets its own loop key
        per_device = jax.tree.map(lambda x: np.broadcast_to(x, (D, *x.shape)).copy(), seeded)
        # numbered globally: processes' devices must not share loop keys
        first = jax.process_index() * D
        loop_keys = np.stack(
            [
                np.stack([np.asarray(jax.random.fold_in(s.key, first + d)) for s in states])
                for d in range(D)
            ]
        )
        per_device = per_device.replace(key=loop_keys)
        return per_device, np.stack(env_keys, axis=1)

    # --- training ---------------------------------------------------------------------------

    def program(self, fn: Callable[..., object]) -> Wrapped:
        """``fn`` of one seed's states as the epoch runs: vmapped over seeds, then spread over
        the devices as ``run.parallel`` says (train/learner/parallel.py)."""
        return parallel.spread(fn, self.parallel, self.devices, self._sharding)

    def epoch(self, ts: TrainingState, env_state: PackedEnv) -> Epoch:
        """One compiled epoch on all devices and seeds: ``(state, env_state, metrics)``.

        Pass states from :meth:`init`, :meth:`place` or a previous epoch: they share one
        signature (dtypes and shardings), so the program compiles once.
        """
        if self._compiled_epoch is not None:
            return self._compiled_epoch(ts, env_state)
        return self._parallel_epoch(ts, env_state)

    def compile_epoch(
        self, ts: TrainingState, env_state: PackedEnv, lowered: Lowered | None = None
    ) -> None:
        """Compile :meth:`epoch` for these states (or their ``ShapeDtypeStruct``s) now,
        ahead of its first call (train.loop.aot); ``lowered``: :meth:`lower_epoch`'s, if done."""
        lowered = self.lower_epoch(ts, env_state) if lowered is None else lowered
        self._compiled_epoch = lowered.compile()

    @property
    def epoch_compiled(self) -> bool:
        """Whether :meth:`compile_epoch` has compiled :meth:`epoch` (a learner that served
        an earlier run has)."""
        return self._compiled_epoch is not None

    def lower_epoch(self, ts: TrainingState, env_state: PackedEnv) -> Lowered:
        """:meth:`epoch` traced and lowered for these states, compiled by nothing yet."""
        if self.parallel == "split":
            raise ValueError("run.parallel = 'split' compiles its programs on first use")
        return self._parallel_epoch.lower(ts, env_state)

    @property
    def reset_program(self) -> Wrapped:
        """The jitted reset of every seed's robots, ``(S, E/D, 2)`` keys in."""
        return self._reset

    @property
    def env_template(self) -> State:
        """One device's environment state as the reset makes it, as shapes (E robots)."""
        return self._env_template

    @property
    def sharding(self) -> NamedSharding | None:
        """The device mesh's sharding of the ``sharded`` path (``None``: ``pmap``)."""
        return self._sharding

    def pack_env(self, env_state: State) -> PackedEnv:
        """The environment state as it crosses device programs and is checkpointed: its
        zero-size leaves (MJX has several) and batch-wide buffers (``leaves.batch_wide``)
        left out of a flat dict (:func:`train.store.leaves.prune`)."""
        return leaves.prune(env_state, self._shared_at)

    def unpack_env(self, packed: PackedEnv) -> State:
        """Inverse of :meth:`pack_env` for one seed's per-device batch (inside the program)."""
        fresh = {i: jnp.asarray(v) for i, v in self._shared.items()}
        return leaves.graft(self._env_template, packed, fresh)

    def place(self, ts: TrainingState, env_state: Mapping[str, ArrayLike]) -> Placed:
        """Put host ``(D, ...)`` states on the devices exactly as :meth:`epoch` returns them
        (same shardings, no weak types), so fresh and restored runs hit the compiled epoch."""
        ts, env_state = strip_weak_types(ts), strip_weak_types(env_state)
        if self._sharding is None:
            return self._identity(ts, env_state)
        sharding = self._sharding

        def put(x: ArrayLike) -> jax.Array:
            x = np.asarray(x)
            if self.n_processes == 1:
                return jax.device_put(x, sharding)
            shape = (x.shape[0] * self.n_processes, *x.shape[1:])
            return jax.make_array_from_process_local_data(sharding, x, shape)

        return jax.tree.map(put, ts), jax.tree.map(put, env_state)

    @allow_rank_promotion
    def _epoch(self, ts: TrainingState, packed: PackedEnv) -> Epoch:
        env_state = self.unpack_env(packed)
        (ts, env_state), metrics = jax.lax.scan(
            self._iteration, (ts, env_state), None, length=self.cfg.run.epoch_iterations
        )
        return ts, self.pack_env(env_state), epoch_metrics(ts, metrics, AXIS)

    # --- evaluation -------------------------------------------------------------------------

    def evaluate(self, ts: TrainingState) -> list[Result]:
        """Each seed's deterministic policy on the held-out episodes (``ts``: ``(S, ...)``)."""
        return self.evaluation.policies((ts.normalizer_params, ts.params.policy), self.n_seeds)

    def evaluate_baseline(self, ts: TrainingState) -> Result:
        """The analytic baseline on the same episodes, in the same compiled program (``ts``
        only gives the policy's parameter shapes)."""
        params = (ts.normalizer_params, ts.params.policy)
        return self.evaluation.play("analytic", jax.tree.map(lambda x: x[0], params))


__all__ = ["Learner", "all_finite"]
