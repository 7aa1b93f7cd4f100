"""Compiling a learner's programs ahead of their first runs.

Under MuJoCo Warp (:func:`first_runs_alone`) a start runs the robots' reset, the
baseline's evaluation and the first epoch one after the other, never side by side;
:func:`compile_together`, which ``mecanum-train`` uses there, compiles the three at the
same time before any of them runs.

The reset and the epoch are lowered from shapes (:func:`env_keys_shape`,
:func:`abstract_state`): the states :meth:`~train.learner.ppo.Learner.place` lays out (and
a restored checkpoint's, which it places the same way) carry exactly those shapes, dtypes
and shardings, so the compiled programs take them without recompiling. (Compiling the
epoch on a worker thread while the robots reset was tried and removed: a few seconds off
a tiny cold start on the 2-core CPU, and under Warp it broke a warm start on an H200;
docs/profiling.md.)"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import jax
from jax.stages import Compiled, Lowered

from train.learner.periodic import Result
from train.learner.ppo import Learner
from train.learner.shapes import Host
from train.learner.state import TrainingState, fresh_state
from train.learner.transfer import first_device


def abstract_state(learner: Learner) -> tuple[Any, Any]:
    """The training and environment state :meth:`Learner.init` returns, as
    ``jax.ShapeDtypeStruct`` leaves laid out as :meth:`Learner.place` lays them out
    (concrete dtypes; the device mesh's sharding on the ``sharded`` path), from shapes
    alone: one seed's fresh state (``jax.eval_shape`` of ``train.learner.state.fresh_state``) and
    the learner's environment template, each with the devices' and the seeds' axes in
    front. Runs nothing, the reset included."""
    if learner.n_processes > 1:
        raise ValueError("abstract_state: one process only (several compile from their states)")
    cfg = learner.cfg
    one_seed = jax.eval_shape(
        lambda: fresh_state(cfg, learner.env, learner.networks, learner.optimizer, 0)[0]
    )
    lead = (learner.n_devices, learner.n_seeds)
    sharding = learner.sharding

    def spec(x: jax.ShapeDtypeStruct) -> jax.ShapeDtypeStruct:
        dtype = jax.dtypes.canonicalize_dtype(x.dtype)  # (x64 off: float32)
        return jax.ShapeDtypeStruct((*lead, *x.shape), dtype, sharding=sharding)

    env_state = learner.pack_env(learner.env_template)
    return jax.tree.map(spec, one_seed), jax.tree.map(spec, env_state)


def first_runs_alone(learner: Learner) -> bool:
    """Whether the baseline's first evaluation must finish before the first epoch starts.
    Under MuJoCo Warp a GPU program's first run loads it and Warp captures its CUDA graphs,
    and GPU work from another thread meanwhile breaks the capture: on the ``split`` path
    (CUDA_ERROR_STREAM_CAPTURE_UNSUPPORTED, train/learner/split_epoch.py) and with the epoch loaded
    on another thread during the reset (Warp CUDA error 904, docs/profiling.md). With the
    persistent cache, programs load in a second, so the two first runs would overlap."""
    return learner.parallel == "split" or learner.env.robot.impl == "warp"


def can_compile_together(learner: Learner) -> bool:
    """Whether :func:`compile_together` serves this learner: one process, and not the
    ``split`` path (whose per-GPU programs compile on first use)."""
    return learner.parallel != "split" and learner.n_processes == 1


def compile_together(learner: Learner) -> tuple[Host, Compiled]:
    """Trace and lower the robots' reset, the epoch and the baseline's evaluation, in that
    order, on this thread, and compile them at the same time as far as XLA's autotuning
    allows; runs nothing of Warp's. The reset compiles on a worker thread while the epoch
    is traced, the epoch there next, not beside the reset (one of four starts that
    compiled the two at once got an epoch 14% slower, likely from their autotuning timing
    kernels on one GPU at once; none of seven that compiled it beside the evaluation
    alone did: docs/profiling.md), and the evaluation here meanwhile.
    Returns ``(host, reset)`` for :meth:`~train.learner.ppo.Learner.init`: the fresh host state
    and the compiled reset.

    For a start whose first runs go one after the other (``first_runs_alone``: under
    MuJoCo Warp no GPU work may run beside a program's first run, whose graph capture it
    breaks): the runs stay in order, their compilations overlap, since no Warp program
    runs while they do. The reset and the epoch are lowered from shapes
    (:func:`env_keys_shape`, :func:`abstract_state`; Warp's batch-wide buffers are zeros
    of known shape, ``train.store.leaves.fresh_batch_wide``); the fresh state is made and the
    evaluation's episodes drawn on the CPU (``mecanum_jax.host``) while the epoch
    compiles. The order of tracing is the one every such start keeps, cold or warm (Warp
    numbers its FFI calls in trace order, and the persistent cache's keys hold the
    numbers). The evaluation's later calls find their compiled programs in jit's cache;
    the epoch's is the learner's
    (:meth:`~train.learner.ppo.Learner.compile_epoch`)."""
    if not can_compile_together(learner):
        raise ValueError("compile_together: one process, and not run.parallel = 'split'")
    reset = learner.reset_program.lower(env_keys_shape(learner))
    with ThreadPoolExecutor(1, thread_name_prefix="compile") as pool:
        reset_job = pool.submit(reset.compile)
        ts, env_state = abstract_state(learner)
        epoch = learner.lower_epoch(ts, env_state)
        compiled_reset = reset_job.result()  # the two autotune on the GPU one at a time
        epoch_job = pool.submit(learner.compile_epoch, ts, env_state, epoch)
        host = learner.init_training()
        for lowered in trace_baseline(learner, first_device(host[0])):
            lowered.compile()
        epoch_job.result()
    return host, compiled_reset


def begin_baseline(learner: Learner, ts: TrainingState, env_state: Any) -> Future[Result]:
    """The baseline's first evaluation, begun in a thread of its own. Where it runs beside
    the first epoch (not :func:`first_runs_alone`) and :func:`can_compile_together`, the
    epoch is traced and lowered first, on this thread, and compiled here once the thread
    has begun: tracing holds Python's lock, so the two traces at once each waited on the
    other and the epoch's compilation, the start's longest step, began seconds later
    (docs/profiling.md). A learner whose epoch is compiled already (one that served an
    earlier run) is not traced again."""
    lowered = None
    if not (first_runs_alone(learner) or learner.epoch_compiled) and can_compile_together(learner):
        lowered = learner.lower_epoch(ts, env_state)
    pool = ThreadPoolExecutor(1, thread_name_prefix="baseline-eval")
    job = pool.submit(learner.evaluate_baseline, first_device(ts))
    pool.shutdown(wait=False)
    if lowered is not None:
        learner.compile_epoch(ts, env_state, lowered)
    return job


def trace_baseline(learner: Learner, ts_first_device: TrainingState) -> list[Lowered]:
    """Trace and lower the programs of the baseline's evaluation
    (:meth:`~train.learner.ppo.Learner.evaluate_baseline`), running nothing; the lowered
    programs (``PeriodicEvaluation.trace``)."""
    params = (ts_first_device.normalizer_params, ts_first_device.params.policy)
    return learner.evaluation.trace("analytic", jax.tree.map(lambda x: x[0], params))


def env_keys_shape(learner: Learner) -> jax.ShapeDtypeStruct:
    """The shape of :meth:`Learner.init_training`'s environment keys, ``(D, S, E/D, key)``."""
    key = jax.eval_shape(lambda: jax.random.split(jax.random.PRNGKey(0), 1)[0])
    lead = (learner.n_devices, learner.n_seeds, learner.envs_per_device)
    return jax.ShapeDtypeStruct((*lead, *key.shape), key.dtype)


__all__ = [
    "abstract_state",
    "begin_baseline",
    "can_compile_together",
    "compile_together",
    "env_keys_shape",
    "first_runs_alone",
    "trace_baseline",
]
