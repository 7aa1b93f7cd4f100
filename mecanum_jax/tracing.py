"""What every entry point sets before anything is traced.

:func:`prepare_tracing` sets the matmul precision (:mod:`mecanum_jax.precision`: one number
on every device), lowers JAX's threefry hash unrolled on the CPU (:func:`unroll_threefry`)
and as JAX's CUDA kernel on GPUs (:func:`threefry_kernel_on_gpus`).

JAX lowers threefry on the CPU as a loop of five rounds (``jax/_src/random/threefry2x32.py``,
``use_rolled_loops``) and XLA:CPU compiles each such loop as a call of its own, apart from
its neighbours. Every random draw is one: in the `tiny` config's epoch they were 248 of
1,083 kernels and 8.8 of 18.5 MB of LLVM IR, and 10.1 of the robots' reset's 10.6 MB. The
unrolled form, JAX's own lowering on every other platform, fuses with the code around it:
the same random bits, and a cold ``tiny`` start compiles in 43 s instead of 53. Other float
results can move by an ulp where XLA fuses their neighbours differently (docs/profiling.md).
JAX's own main branch has since dropped the CPU's loop (jax-ml/jax, commit 1935c5f of
``threefry2x32.py`` registers no CPU rule): :func:`unroll_threefry` can go once the lock's
JAX lowers so itself.

On GPUs JAX lowers the hash unrolled too, and XLA fuses its rounds into the code around
every draw; with ``jax_threefry_gpu_kernel_lowering`` (:func:`threefry_kernel_on_gpus`) each
draw is one call of JAX's CUDA kernel instead: the same bits, the `gpu` config's cold start
16-17 s sooner on one H100 (its epoch compiles in 23-25 s against 37-39 s), for epochs 2.3%
slower (docs/profiling.md). ``JAX_THREEFRY_GPU_KERNEL_LOWERING=0`` in the environment keeps
JAX's unrolled hash, for a long run from a warm cache; a learner whose programs span several
devices turns the kernel off (XLA's partitioner cannot split its custom call).

:func:`older_cpu_emitters`, which the trainer's and evaluator's command lines call before
JAX starts its backend, has XLA:CPU compile with its older emitters
(``--xla_cpu_use_fusion_emitters=false``): a cold ``tiny`` start's epoch and evaluation
rollout compile in about two thirds of the time and run no slower (the figures:
docs/profiling.md). Float results move where the emitters round differently.
:func:`reproducible_gpu_ops`, which the evaluator's command line calls, has XLA:GPU run
only deterministic ops: the same episodes give the same figures in every process.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable, MutableMapping
from functools import partial
from typing import Any

from mecanum_jax.precision import set_matmul_precision

_installed: list[bool] = []  # once per process


def threefry_rule(rolled: bool) -> Callable[..., Any]:
    """JAX's own lowering rule for ``threefry2x32``, rolled (its CPU loop) or unrolled;
    ``TypeError`` where this JAX's private lowering lacks the ``use_rolled_loops`` switch
    (checked now, not at a lowering)."""
    from jax._src.interpreters import mlir
    from jax._src.random import threefry2x32 as tf

    lowering = tf._threefry2x32_lowering
    if "use_rolled_loops" not in inspect.signature(lowering).parameters:
        raise TypeError("another threefry lowering")
    return mlir.lower_fun(partial(lowering, use_rolled_loops=rolled), multiple_results=True)


def unroll_threefry() -> bool:
    """Lower ``threefry2x32`` unrolled on the CPU, as JAX does on GPUs; idempotent.

    The hash's arithmetic is the same, so the bits are (tests/test_tracing.py). Returns
    whether the lowering is installed: ``False`` where this JAX lacks the private
    lowering it reuses, or its ``use_rolled_loops`` switch, which then keeps its own
    (slower to compile on the CPU, equal bits).
    """
    if not _installed:
        try:
            from jax._src.interpreters import mlir
            from jax._src.random import threefry2x32 as tf

            mlir.register_lowering(tf.threefry2x32_p, threefry_rule(False), platform="cpu")
            _installed.append(True)
        except (ImportError, AttributeError, TypeError, ValueError):
            _installed.append(False)
    return _installed[0]


OLDER_CPU_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
"""The ``XLA_FLAGS`` entry :func:`older_cpu_emitters` adds."""
KNOWN_JAXLIBS = ("0.10.",)
"""The jaxlib releases whose XLA has that flag (XLA aborts a process over an unknown one:
the GPU image's jaxlib 0.11.2 does, "Unknown flag in XLA_FLAGS")."""


def older_cpu_emitters(
    environ: MutableMapping[str, str] = os.environ, jaxlib_version: str | None = None
) -> bool:
    """Add :data:`OLDER_CPU_EMITTERS` to ``XLA_FLAGS`` for this process's CPU programs and
    the processes it starts; returns whether it is in force. XLA reads ``XLA_FLAGS`` once,
    when JAX starts its backend, so call it before (loading a config starts it).

    Left alone where ``XLA_FLAGS`` names the flag already (the caller's choice stands:
    ``=true`` keeps XLA's default) and under a jaxlib not in :data:`KNOWN_JAXLIBS`. JAX's
    persistent cache and the warm-start store key their programs by ``XLA_FLAGS``."""
    return _add_xla_flag(environ, OLDER_CPU_EMITTERS, _known(jaxlib_version, KNOWN_JAXLIBS))


def _known(jaxlib_version: str | None, releases: tuple[str, ...]) -> bool:
    if jaxlib_version is None:
        from jaxlib.version import __version__

        jaxlib_version = __version__
    return jaxlib_version.startswith(releases)


def _add_xla_flag(environ: MutableMapping[str, str], flag: str, allowed: bool) -> bool:
    """Add ``flag`` (``--name=value``) to ``XLA_FLAGS`` where ``allowed`` and the variable
    does not name it already; returns whether ``flag`` is in force."""
    flags = environ.get("XLA_FLAGS", "")
    if allowed and flag.split("=")[0] not in flags:
        environ["XLA_FLAGS"] = f"{flags} {flag}".strip()
    return flag in environ.get("XLA_FLAGS", "").split()


REPRODUCIBLE_GPU_OPS = "--xla_gpu_exclude_nondeterministic_ops=true"
"""The ``XLA_FLAGS`` entry :func:`reproducible_gpu_ops` adds."""
REPRODUCIBLE_JAXLIBS = ("0.10.", "0.11.")
"""The jaxlib releases whose XLA has that flag (the lock's 0.10.2, the GPU image's 0.11.2)."""


def reproducible_gpu_ops(
    environ: MutableMapping[str, str] = os.environ,
    jaxlib_version: str | None = None,
    started: bool | None = None,
) -> bool:
    """Have XLA:GPU run only deterministic ops (no scatter-adds by atomics, for instance),
    so that two processes playing the same episodes on one GPU give the same figures bit for
    bit; ``mecanum-eval`` calls it. Without it one H100 parted 252 of 320 per-episode figures
    between two runs; with it none, for a rollout about 18% slower (docs/evaluation.md). No
    effect on the CPU, which is deterministic anyway.

    Left alone where ``XLA_FLAGS`` names the flag already (``=false`` keeps XLA's faster
    default), under a jaxlib not in :data:`REPRODUCIBLE_JAXLIBS`, and once JAX has started
    its backend (``started``; XLA read ``XLA_FLAGS`` then, and a changed variable would
    change only the persistent cache's keys). Returns whether the flag is in force."""
    if started is None:
        started = _backend_started()
    allowed = not started and _known(jaxlib_version, REPRODUCIBLE_JAXLIBS)
    return _add_xla_flag(environ, REPRODUCIBLE_GPU_OPS, allowed)


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # another JAX: leave XLA_FLAGS as it is
        return True


GPU_THREEFRY_FLAG = "jax_threefry_gpu_kernel_lowering"
"""The JAX flag :func:`threefry_kernel_on_gpus` sets."""
GPU_THREEFRY_VAR = GPU_THREEFRY_FLAG.upper()
"""JAX's own environment variable for it."""


def threefry_kernel_on_gpus(
    environ: MutableMapping[str, str] = os.environ, on: bool = True
) -> bool:
    """Lower ``threefry2x32`` on GPUs as JAX's CUDA kernel, one call a draw (``on``; no
    effect on the CPU), else as JAX's unrolled hash, unless the environment's
    :data:`GPU_THREEFRY_VAR` has chosen; returns the setting. JAX's caches and the
    warm-start store key programs by it."""
    import jax

    if GPU_THREEFRY_VAR not in environ:
        jax.config.update(GPU_THREEFRY_FLAG, on)
    return bool(getattr(jax.config, GPU_THREEFRY_FLAG))


def prepare_tracing(precision: str, where: str = "run.matmul_precision") -> None:
    """Before anything is traced: the matmul ``precision`` (``where`` names its field in
    an error) and the threefry lowerings (the CPU's unrolled, the GPUs' kernel)."""
    set_matmul_precision(precision, where)
    unroll_threefry()
    threefry_kernel_on_gpus()
