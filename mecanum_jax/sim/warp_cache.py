"""MuJoCo Warp's programs and JAX's persistent compilation cache do not mix.

A program that calls MuJoCo Warp (an XLA FFI call into Warp's CUDA graphs or its CPU
kernels) broke in both directions of the cache:

- **Read back, on an H100** (jax 0.11.2): the second start of ``train.coldstart`` under
  Warp loaded the evaluation rollout from the cache, and its first call failed with
  ``FFI callback error: RuntimeError: Warp error: unknown stream``.
- **Written, on XLA:CPU** (jax 0.10.2): a long test process crashed twice in
  ``compilation_cache.put_executable_and_time`` while serializing a Warp rollout (abort,
  then a segmentation fault).

So a process that builds Warp physics stops using the persistent cache from then on
(:func:`leave_the_persistent_cache`): its programs compile anew at each start, which costs
a warm start its cache but never crashes. Programs compiled before stay where they are.
"""

from __future__ import annotations

import sys

import jax
from jax.experimental.compilation_cache import compilation_cache

_warned = False


def leave_the_persistent_cache() -> bool:
    """Turn JAX's persistent compilation cache off for the rest of this process (module
    docstring); says so once on stderr. Returns whether it was on."""
    global _warned
    config = jax.config
    if not (
        getattr(config, "jax_enable_compilation_cache", False)
        and getattr(config, "jax_compilation_cache_dir", None)
    ):
        return False
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()  # JAX decides once per process whether to use it
    if not _warned:
        _warned = True
        print(
            "note: JAX's persistent compilation cache is off in this process: MuJoCo Warp's "
            "programs fail when read back from it (docs/benchmarks.md)",
            file=sys.stderr,
        )
    return True


__all__ = ["leave_the_persistent_cache"]
