"""Compatibility with the JAX versions this project must run on (0.10 to the newest).

Brax 0.14.2 calls ``jax.device_put_replicated``, which JAX 0.10 removed (it now raises
``AttributeError`` through JAX's deprecation hook). :func:`install` supplies a drop-in
replacement, following JAX's own migration guide
(https://docs.jax.dev/en/latest/migrate_pmap.html#drop-in-replacements): the value is
stacked along a new leading axis of size ``len(devices)`` and placed with a
``NamedSharding`` over a 1-D mesh of those devices, so slice ``k`` lives on
``devices[k]`` exactly as before, and ``jax.pmap`` consumes it unchanged.

The replacement is installed only when JAX lacks the function; on a JAX that still has it
nothing is touched. Importing the trainer (:mod:`train`) calls :func:`install`;
importing :mod:`mecanum_jax` does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

_AXIS = "replica"


def device_put_replicated(x: Any, devices: Sequence[Any]) -> Any:
    """Replicate the pytree ``x`` onto ``devices`` along a new leading axis.

    Args:
      x: an array, scalar, or pytree of them.
      devices: a non-empty sequence of ``jax.Device``.

    Returns:
      The same pytree, each leaf of shape ``(len(devices), *leaf.shape)``, with slice ``k``
      backed by memory on ``devices[k]``.
    """
    if isinstance(devices, str | bytes) or not isinstance(devices, Sequence) or not devices:
        raise ValueError(
            f"devices = {devices!r}: device_put_replicated needs a non-empty sequence of devices"
        )
    sharding = NamedSharding(Mesh(np.asarray(list(devices)), (_AXIS,)), PartitionSpec(_AXIS))
    count = len(devices)

    def put(leaf: Any) -> jax.Array:
        leaf = jnp.asarray(leaf)
        stacked = jnp.broadcast_to(leaf[None], (count, *leaf.shape))
        return jax.device_put(stacked, sharding)

    return jax.tree_util.tree_map(put, x)


def has_native_device_put_replicated() -> bool:
    """Whether the running JAX still provides ``jax.device_put_replicated`` itself."""
    try:
        fn = jax.device_put_replicated
    except AttributeError:
        return False
    return fn is not device_put_replicated


def install() -> bool:
    """Give ``jax`` a ``device_put_replicated`` if it has none. Returns True if it installed."""
    if has_native_device_put_replicated() or "device_put_replicated" in vars(jax):
        return False
    jax.device_put_replicated = device_put_replicated
    return True
