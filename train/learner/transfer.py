"""The learner's states between the host and the devices: concrete dtypes before they go
to the devices (:func:`strip_weak_types`), host NumPy copies of what comes back
(:func:`first_device`, :func:`to_host`).
"""

from __future__ import annotations

from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

Tree = TypeVar("Tree")


def strip_weak_types(tree: Tree) -> Tree:
    """Arrays with concrete (non-weak) dtypes, so jit signatures do not flip between calls."""

    def strip(x: ArrayLike) -> jax.Array:
        x = jnp.asarray(x)
        return jnp.astype(x, x.dtype) if x.weak_type else x

    return jax.tree.map(strip, tree)


def first_device(tree: object) -> Any:
    """The device-0 copy of a ``(D, ...)`` tree, as host numpy arrays."""

    def first(x: ArrayLike) -> np.ndarray:
        if isinstance(x, jax.Array):
            return np.asarray(x.addressable_shards[0].data)[0]
        return np.asarray(x)[0]

    return jax.tree.map(first, tree)


def to_host(tree: object) -> Any:
    """Host numpy copies; of an array spread over processes, this process's devices' part."""

    def host(x: ArrayLike) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            shards = sorted(x.addressable_shards, key=lambda s: s.index[0].start or 0)
            return np.concatenate([np.asarray(s.data) for s in shards])
        return np.asarray(x)

    return jax.tree.map(host, tree)


__all__ = ["first_device", "strip_weak_types", "to_host"]
