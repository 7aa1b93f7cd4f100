"""MuJoCo Warp's programs and JAX's persistent compilation cache: on XLA:CPU they do not mix.

- **On CUDA GPUs they do**, since :mod:`mecanum_jax.sim.warp_streams`. A second start
  under Warp used to fail in the first evaluation with ``FFI callback error:
  RuntimeError: Warp error: unknown stream`` when its programs came from the cache (an
  H100, jax 0.11.2, 2026-11-25). The cause was not the cache but Warp's stream table: the
  garbage collector, which runs at other moments when programs are read back, freed a
  stale wrapper of XLA's stream between a call's registration of that stream and its
  graph capture (logged on an H200, 2026-11-27). With the streams pinned, two starts in a
  row, one filling the cache and one reading it, both ran, and the second reached its first
  evaluation in 47 s instead of 94-103 s (docs/profiling.md).
- **Written, on XLA:CPU** (jax 0.10.2): a long test process crashed twice in
  ``compilation_cache.put_executable_and_time`` while serializing a Warp rollout (abort,
  then a segmentation fault). No stream is involved there.

So a process that builds Warp physics on a CPU device stops using the persistent cache
from then on (:func:`leave_the_persistent_cache`): its programs compile anew at each
start, which costs a warm start its cache but never crashes. Programs compiled before
stay where they are.
"""

from __future__ import annotations

import sys

import jax
from jax.experimental.compilation_cache import compilation_cache

_warned = False


def leave_the_persistent_cache(platform: str | None = None) -> bool:
    """Turn JAX's persistent compilation cache off for the rest of this process where Warp
    runs on ``platform`` (default: this process's first device's) ``"cpu"`` (module
    docstring); says so once on stderr. Returns whether it turned the cache off."""
    global _warned
    platform = platform or jax.local_devices()[0].platform
    config = jax.config
    if platform != "cpu" or not (
        getattr(config, "jax_enable_compilation_cache", False)
        and getattr(config, "jax_compilation_cache_dir", None)
    ):
        return False
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()  # JAX decides once per process whether to use it
    if not _warned:
        _warned = True
        print(
            "note: JAX's persistent compilation cache is off in this process: XLA:CPU "
            "crashed writing MuJoCo Warp's programs to it (docs/profiling.md)",
            file=sys.stderr,
        )
    return True


__all__ = ["leave_the_persistent_cache"]
