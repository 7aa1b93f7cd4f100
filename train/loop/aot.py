"""Compiling a learner's programs ahead of their first runs.

Under MuJoCo Warp (:func:`first_runs_alone`) a start runs the robots' reset, the
baseline's evaluation and the first epoch one after the other, never side by side;
:func:`compile_together`, which ``mecanum-train`` uses there, compiles the three at the
same time before any of them runs.

Compiling the epoch from shapes, while the robots reset:

A cold start compiles three large programs before its first evaluation: the robots'
reset, the training epoch and the evaluation rollout (docs/benchmarks.md). The epoch
needs only the *shapes* of the states it will be given, and those follow from the
config, so its compilation can start before the reset has run:
:func:`compile_epoch_ahead` lowers and compiles it on a worker thread (XLA compiles with
Python's lock released) while the caller resets the robots, and the caller waits on the
returned future before the first epoch. ``python -m train.tools.coldstart --ahead`` measures
it; ``mecanum-train`` does not use it yet: on the 2-core CPU it saved a few seconds of a
tiny cold start, and a run that also started the baseline's evaluation before the reset
(three compilations on two cores) took 8% longer (docs/benchmarks.md); on an H200 under
Warp it saved about 5 s of a cold start but broke a warm one (:func:`compile_epoch_ahead`),
and under MJX's JAX physics on a GPU it has not been measured. The states
:meth:`~train.learner.ppo.Learner.place` lays out (and a restored checkpoint's, which it places the
same way) carry exactly those shapes, dtypes and shardings, so the compiled program takes
them without recompiling."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import jax

from train.learner.ppo import Learner, first_device
from train.learner.state import fresh_state


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

    def spec(x: Any) -> jax.ShapeDtypeStruct:
        dtype = jax.dtypes.canonicalize_dtype(x.dtype)  # (x64 off: float32)
        return jax.ShapeDtypeStruct((*lead, *x.shape), dtype, sharding=sharding)

    env_state = learner.pack_env(learner.env_template)
    return jax.tree.map(spec, one_seed), jax.tree.map(spec, env_state)


def compile_epoch_ahead(learner: Learner) -> Future[None]:
    """Start compiling ``learner``'s epoch for the states of :func:`abstract_state` on a
    worker thread; the future's ``result()`` returns once :meth:`Learner.epoch` runs the
    compiled program (and raises what the compilation raised).

    Refused under MJX's Warp implementation. With Warp's stream table pinned
    (:mod:`mecanum_jax.sim.warp_streams`) two cold starts of ``train.tools.coldstart --ahead``
    ran, but ``mecanum-train`` compiling ahead from a warm compilation cache failed in the
    robots' reset with ``Warp CUDA error 904: capturing stream has unjoined work`` (H200,
    2026-11-27): the worker's tracing of Warp's calls overlapped a graph capture on the
    main thread."""
    if learner.env.robot.impl == "warp":
        raise ValueError(
            "env.physics_impl = 'warp': the epoch cannot be compiled ahead on a worker "
            "thread under MJX's Warp implementation (Warp CUDA error 904 in the reset's "
            "graph capture); drop --ahead or use --env.physics-impl jax"
        )
    state, env_state = abstract_state(learner)  # traced here: cheap, and errors surface now
    pool = ThreadPoolExecutor(1, thread_name_prefix="epoch-compile")
    job = pool.submit(learner.compile_epoch, state, env_state)
    pool.shutdown(wait=False)
    return job


def first_runs_alone(learner: Learner) -> bool:
    """Whether the baseline's first evaluation must finish before the first epoch starts.
    Under MuJoCo Warp a GPU program's first run loads it and Warp captures its CUDA graphs,
    and GPU work from another thread meanwhile breaks the capture: on the ``split`` path
    (CUDA_ERROR_STREAM_CAPTURE_UNSUPPORTED, train/learner/split_epoch.py) and with the epoch loaded
    on another thread during the reset (Warp CUDA error 904, docs/benchmarks.md). With the
    persistent cache, programs load in a second, so the two first runs would overlap."""
    return learner.parallel == "split" or learner.env.robot.impl == "warp"


def can_compile_together(learner: Learner) -> bool:
    """Whether :func:`compile_together` serves this learner: one process, and not the
    ``split`` path (whose per-GPU programs compile on first use)."""
    return learner.parallel != "split" and learner.n_processes == 1


def compile_together(learner: Learner) -> tuple[tuple[Any, Any], Any]:
    """Trace and lower the robots' reset, the epoch and the baseline's evaluation, in that
    order, on this thread, and compile them at the same time as far as XLA's autotuning
    allows; runs nothing of Warp's. The reset compiles on a worker thread while the epoch
    is traced, the epoch there next, not beside the reset (one of four starts that
    compiled the two at once got an epoch 14% slower, likely from their autotuning timing
    kernels on one GPU at once; none of seven that compiled it beside the evaluation
    alone did: docs/benchmarks.md), and the evaluation here meanwhile.
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


def trace_baseline(learner: Learner, ts_first_device: Any) -> list[Any]:
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
    "can_compile_together",
    "compile_epoch_ahead",
    "compile_together",
    "env_keys_shape",
    "first_runs_alone",
    "trace_baseline",
]
