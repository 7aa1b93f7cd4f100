"""``run.parallel = "split"``: each device rolls out its own robots in a program of its own,
and one program over the device mesh updates the policy.

Why: under MuJoCo Warp the physics step is an XLA FFI custom call, and the batch-wide
buffers it works in (its contact buffer and sizes) carry no robot axis. XLA's SPMD
partitioner cannot split such a call, so the ``"sharded"`` path gathers the whole batch
onto every GPU and each GPU simulates every robot (2 H200s: 1.01x one; docs/benchmarks.md),
and ``jax.shard_map`` of the step crashed. Here no program that holds the physics spans
more than one device: device ``d``'s rollout program takes that device's slice of the
states (``(1, S, ...)``, zero-copy from the mesh-sharded arrays) and returns its slice of
the transitions, which are put together, again without a copy, into mesh-sharded arrays
for the update, the same program :meth:`~train.learner.iteration.Iteration.update` is on the
``"sharded"`` path (gradients and normalizer statistics averaged across devices).

An epoch is then ``epoch_iterations`` x (one rollout per device, one update).
:meth:`SplitEpoch.__call__` takes and returns the states exactly as the other paths'
epoch does, so checkpoints, evaluation and resume are unchanged. The rollout program
compiles once per device. One process only: its devices are the mesh.

Each device's rollout is run from a host thread of its own (the first device's from the
caller's thread, every other device's always from the same worker thread): the rollout's
scans are loops the host drives on a GPU, so the thread that runs a program waits for it,
and one thread would run the devices' rollouts one after the other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol, TypeVar

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
from brax.envs.base import State
from brax.training.types import Transition
from jax.sharding import NamedSharding
from jax.stages import Wrapped

from mecanum_jax.task.controller import allow_rank_promotion
from train.config import TrainConfig
from train.learner.parallel import AXIS
from train.learner.shapes import Epoch, Metrics, PackedEnv, Updated
from train.learner.state import TrainingState, epoch_metrics

Tree = TypeVar("Tree")
Rollouts = tuple[PackedEnv, Transition, jax.Array, Metrics]
"""A device's rollout: ``(packed env state, data, keys, env metrics)``."""


class SplitLearner(Protocol):
    """What the split epoch uses of its :class:`train.learner.ppo.Learner` (which builds
    it, so it is not imported here)."""

    cfg: TrainConfig
    devices: list[jax.Device]
    n_processes: int

    @property
    def sharding(self) -> NamedSharding | None: ...
    def program(self, fn: Callable[..., object]) -> Wrapped: ...
    def pack_env(self, env_state: State) -> PackedEnv: ...
    def unpack_env(self, packed: PackedEnv) -> State: ...
    def iteration_rollouts(
        self, ts: TrainingState, env_state: State
    ) -> tuple[State, Transition, jax.Array, Metrics]: ...
    def iteration_update(
        self, ts: TrainingState, data: Transition, keys: jax.Array, env_metrics: Metrics
    ) -> Updated: ...


def slices(tree: Tree, devices: Sequence[jax.Device]) -> list[Tree]:
    """Device ``d``'s ``(1, ...)`` slice of each mesh-sharded leaf of ``tree``, for each of
    ``devices``: the arrays the device already holds, not copies."""

    def on(device: jax.Device) -> Tree:
        def part(x: jax.Array) -> jax.Array:
            for shard in x.addressable_shards:
                if shard.device == device:
                    return shard.data
            raise ValueError(f"split epoch: no slice of an array on {device}")

        return jax.tree.map(part, tree)

    return [on(d) for d in devices]


def joined(trees: Sequence[Tree], sharding: NamedSharding) -> Tree:
    """Inverse of :func:`slices`: one mesh-sharded array per leaf, from each device's
    ``(1, ...)`` slices (no copy)."""

    def join(*xs: jax.Array) -> jax.Array:
        shape = (sum(x.shape[0] for x in xs), *xs[0].shape[1:])
        return jax.make_array_from_single_device_arrays(shape, sharding, list(xs))

    return jax.tree.map(join, *trees)


class SplitEpoch:
    """The ``"split"`` epoch of ``learner`` (see the module): callable as
    ``(state, packed env state) -> (state, packed env state, metrics)``."""

    def __init__(self, learner: SplitLearner):
        if learner.n_processes > 1:
            raise ValueError(
                "run.parallel = 'split': one process only (its devices are the mesh); "
                "use 'sharded' with --distributed"
            )
        if learner.sharding is None:
            raise ValueError("split epoch: the learner has no device mesh (parallel='pmap')")
        self.learner = learner
        self.devices = list(learner.devices)
        self.sharding = learner.sharding
        self.iterations = learner.cfg.run.epoch_iterations
        # (1, S, ...) in: the device's slice, its seeds vmapped (no collectives)
        self._rollout = jax.jit(jax.vmap(jax.vmap(self._rollout_one)))
        self._update = learner.program(self._update_one)
        self._finish = learner.program(self._finish_one)
        # one worker thread per device but the first, always the same one for a device
        self._threads = [
            ThreadPoolExecutor(1, thread_name_prefix=f"rollout-{i}")
            for i in range(1, len(self.devices))
        ]
        self._loaded = False

    def _rollouts(self, states: list[TrainingState], env: list[PackedEnv]) -> list[Rollouts]:
        """Every device's rollout, each from its own thread; the first time one after the
        other: a GPU program's first run loads it and MuJoCo Warp captures its CUDA graphs,
        and a stream another thread synchronizes meanwhile fails
        (CUDA_ERROR_STREAM_CAPTURE_UNSUPPORTED, 2 H200s)."""
        jobs = []
        for pool, t, e in zip(self._threads, states[1:], env[1:], strict=True):
            jobs.append(pool.submit(self._rollout, t, e))
            if not self._loaded:
                jobs[-1].result()
        first = self._rollout(states[0], env[0])
        self._loaded = True
        return [first, *(job.result() for job in jobs)]

    @allow_rank_promotion
    def _rollout_one(self, ts: TrainingState, packed: PackedEnv) -> Rollouts:
        """One seed's rollouts of one iteration on one device: the one-program epoch's
        :meth:`~train.learner.iteration.Iteration.iteration_rollouts` (same keys)."""
        learner = self.learner
        env_state, *rest = learner.iteration_rollouts(ts, learner.unpack_env(packed))
        return learner.pack_env(env_state), *rest

    @allow_rank_promotion
    def _update_one(
        self, ts: TrainingState, data: Transition, keys: jax.Array, env_metrics: Metrics
    ) -> Updated:
        """One seed's update on one device, averaged across devices (``AXIS``)."""
        return self.learner.iteration_update(ts, data, keys, env_metrics)

    def _finish_one(self, ts: TrainingState, per_iteration: tuple[Metrics, ...]) -> Metrics:
        """The epoch's metrics as the one-program epoch reports them."""
        stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *per_iteration)
        return epoch_metrics(ts, stacked, AXIS)

    def __call__(self, ts: TrainingState, packed: PackedEnv) -> Epoch:
        env = slices(packed, self.devices)
        per_iteration = []
        for _ in range(self.iterations):
            parts = self._rollouts(slices(ts, self.devices), env)
            env = [p[0] for p in parts]
            data, keys, env_metrics = (
                joined([p[i] for p in parts], self.sharding) for i in (1, 2, 3)
            )
            ts, metrics = self._update(ts, data, keys, env_metrics)
            per_iteration.append(metrics)
        metrics = self._finish(ts, tuple(per_iteration))
        return ts, joined(env, self.sharding), metrics


__all__ = ["SplitEpoch", "joined", "slices"]
