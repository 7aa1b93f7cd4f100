"""Matmul precision: one number on every device.

On A100 and H100 GPUs, JAX runs float32 matrix products in TF32 (10 mantissa bits) unless
told otherwise (jax-ml/jax issues 12008 and 18934); on the CPU it runs them in float32.
An evaluation left at JAX's default therefore reads differently on a GPU: the analytic
baseline's nominal steady-state ωz error read 0.50 rad/s on an H100 against 0.19 on the
CPU. Two guards keep figures device-independent:

- every entry point (``mecanum-train``, ``mecanum-eval``, ``mecanum-bench``, the physics
  validation) calls :func:`set_matmul_precision` with its config's precision (``highest``
  by default) before anything is traced, through :func:`mecanum_jax.tracing.prepare_tracing`;
- the kinematics' solves and projections pass ``precision=HIGHEST`` themselves
  (:data:`HIGHEST`), so their answers do not depend on the global setting at all.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import jax

from mecanum_jax.config import ConfigError

HIGHEST = jax.lax.Precision.HIGHEST
"""Full float32 products (six bf16 passes on TPUs, no TF32 on GPUs)."""

PRECISIONS = ("default", "high", "highest")
"""``default``: JAX's own (TF32 on recent NVIDIA GPUs); ``high``: bf16_3x / TF32;
``highest``: full float32."""


def _check(name: str, where: str) -> None:
    if name not in PRECISIONS:
        raise ConfigError(f"{where} = {name!r}: expected one of {list(PRECISIONS)}")


def set_matmul_precision(name: str, where: str = "run.matmul_precision") -> None:
    """Set JAX's default matmul precision for everything traced afterwards.

    ``default`` restores JAX's own default (which is TF32 on A100/H100 GPUs).
    """
    _check(name, where)
    jax.config.update("jax_default_matmul_precision", None if name == "default" else name)


@contextlib.contextmanager
def matmul_precision_scope(name: str, where: str = "precision") -> Iterator[None]:
    """Trace the block's matrix products at precision ``name`` (one of :data:`PRECISIONS`),
    whatever the global setting. JAX writes the precision into each product when it is
    traced; ``default`` is written as ``Precision.DEFAULT``, not left unset, because a
    transformation that re-traces the block later (``vmap`` of a ``scan`` body) would
    resolve an unset one against the global setting. The kinematics pass :data:`HIGHEST`
    themselves and are not affected."""
    _check(name, where)
    with jax.default_matmul_precision(name):
        yield


def matmul_precision() -> str:
    """The precision now in force (``default`` when JAX's own)."""
    value = getattr(jax.config, "jax_default_matmul_precision", None)
    return "default" if value is None else str(value)


__all__ = [
    "HIGHEST",
    "PRECISIONS",
    "matmul_precision",
    "matmul_precision_scope",
    "set_matmul_precision",
]
