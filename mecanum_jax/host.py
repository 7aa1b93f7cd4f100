"""Small set-up computations on the host's CPU, whatever the accelerator.

Building a robot, its environment, a training state or an evaluation's episodes runs a few
hundred small JAX operations eagerly (constants of the geometry and the limits, network
initializers, samplers). On a GPU each distinct one is an XLA program of its own, compiled
for the GPU at 50 to 200 ms each: about 8 s of a cold start of ``mecanum-train`` on an
H200 went to compiling them (docs/profiling.md). On the CPU backend the same operations
compile in some 20 ms each, and they give the same numbers on a GPU machine as on a CPU
one: the episodes and the initial parameters no longer depend on the accelerator.

:func:`on_host` runs a block with the CPU as JAX's default device; :func:`host_side`
runs a function so. Arrays made there are *uncommitted*: a jitted program on the
accelerator takes them as it takes NumPy arrays. Arrays placed on a device explicitly
(``device=``, ``jax.device_put(x, device)``) stay where they were put. Where JAX has no
CPU backend (``JAX_PLATFORMS=cuda``), both leave the default device alone.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator
from typing import ParamSpec, TypeVar

import jax

P = ParamSpec("P")
R = TypeVar("R")


def host_device() -> jax.Device | None:
    """This process's first CPU device, or ``None`` where JAX has no CPU backend."""
    try:
        return jax.local_devices(backend="cpu")[0]
    except RuntimeError:
        return None


@contextlib.contextmanager
def on_host() -> Iterator[None]:
    """Make the host's CPU JAX's default device inside the block (this thread only)."""
    cpu = host_device()
    if cpu is None:
        yield
        return
    with jax.default_device(cpu):
        yield


def host_side(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` run under :func:`on_host`."""

    @functools.wraps(fn)
    def wrapped(*args: P.args, **kwargs: P.kwargs) -> R:
        with on_host():
            return fn(*args, **kwargs)

    return wrapped


__all__ = ["host_device", "host_side", "on_host"]
