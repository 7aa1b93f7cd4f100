"""Vmapped physics on the CPU in chunks: jaxlib's batched LAPACK deadlocks above a batch
size, so a large batch runs as a ``lax.map`` over vmapped chunks (:func:`chunked_vmap`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import ParamSpec, TypeVar

import jax

P = ParamSpec("P")
R = TypeVar("R")

CPU_CHUNK = {"fast": 64, "reference": 16}
"""Robots per vmapped physics call on CPU, per fidelity: jaxlib 0.10's batched LAPACK (the
Cholesky of MJX's Newton solver) deadlocks the 2-core CPU's thread pool from a batch of
256 fast robots on (34 reference ones): its batch tasks wait for pool threads that the
batch itself holds. 64 fast robots run, and are the fastest chunk measured
(docs/benchmarks.md)."""


CPU_HANG_ROWS = 256
"""Fast robots from which one vmapped MJX batch hangs jaxlib 0.10's CPU backend (the 2-core
CPU: :data:`CPU_CHUNK`; an evaluation of 248 episodes and its guard rows hung, 2026-12-08)."""

CPU_GUARD_ROWS = 8
"""Rows a CPU evaluation chunk of fast robots plays past its episodes and drops. XLA:CPU's
vectorized loops run a batch's last 8 rows in their epilogue, rounded another way, so
without them an episode's figures moved with its row in the chunk, and a scenario read
differently alone and in a set (2-core AVX-512 CPU, jaxlib 0.10.2: every chunk size tried,
16 to 64); with them every episode is computed by the vector loop, for 12.5% more rows in a
chunk of 64 (docs/evaluation.md). None for the reference model, whose closed-loop rollout
hangs from 6 robots (:data:`~mecanum_jax.task.fidelity.CPU_EVAL_BATCH`)."""


def guard_rows(fidelity: str, impl: str) -> int:
    """:data:`CPU_GUARD_ROWS` for fast ``jax`` physics on the CPU backend, else 0."""
    return CPU_GUARD_ROWS if cpu_chunk(fidelity, impl) and fidelity == "fast" else 0


def cpu_chunk(fidelity: str = "fast", impl: str = "jax") -> int:
    """:data:`CPU_CHUNK` for the ``jax`` implementation on the CPU backend; 0 (no chunking)
    on accelerators and for ``warp`` (whose batch shares one contact buffer, and which does
    not use LAPACK)."""
    return CPU_CHUNK[fidelity] if jax.default_backend() == "cpu" and impl == "jax" else 0


def chunked_vmap(fn: Callable[P, R], chunk: int) -> Callable[P, R]:
    """``jax.vmap(fn)``, but over at most ``chunk`` items at a time (a ``lax.map`` over
    chunks; 0: one vmap). The chunk is the largest divisor of the batch up to ``chunk``."""

    def mapped(*xs: P.args, **kw: P.kwargs) -> R:
        n = jax.tree.leaves((xs, kw))[0].shape[0]
        c = max(d for d in range(1, min(chunk, n) + 1) if n % d == 0) if chunk else n
        if c == n:
            return jax.vmap(fn)(*xs, **kw)
        split = jax.tree.map(lambda x: x.reshape((n // c, c, *x.shape[1:])), (xs, kw))
        out = jax.lax.map(lambda ys: jax.vmap(fn)(*ys[0], **ys[1]), split)
        return jax.tree.map(lambda x: x.reshape((n, *x.shape[2:])), out)

    return mapped


__all__ = [
    "CPU_CHUNK",
    "CPU_GUARD_ROWS",
    "CPU_HANG_ROWS",
    "chunked_vmap",
    "cpu_chunk",
    "guard_rows",
]
