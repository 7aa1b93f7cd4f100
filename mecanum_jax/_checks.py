"""Input checks shared by the checked entry points.

Shape checks are static and always run, also under ``jit``. Value checks (finiteness)
need concrete values: they run when an entry point is called eagerly and are skipped when
the input is a tracer (inside ``jit``/``vmap``/``grad``), where raising is impossible.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


class InputError(ValueError):
    """User data (an array, a file, an argument) is invalid. The message names the field."""


def is_concrete(*xs: Any) -> bool:
    """True when no leaf of ``xs`` is a JAX tracer, so its values can be inspected."""
    leaves = jax.tree_util.tree_leaves(xs)
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)


def as_float_array(x: Any, name: str) -> jax.Array:
    """Convert to a floating JAX array; integers and bools become the default float."""
    try:
        arr = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} = {x!r}: not convertible to an array ({err})") from None
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        if jnp.issubdtype(arr.dtype, jnp.complexfloating):
            raise InputError(f"{name}: complex dtype {arr.dtype} is not supported")
        arr = arr.astype(jnp.result_type(float))
    return arr


def fmt(value: Any) -> str:
    """A number for an error message: shortest readable form, no NumPy type prefix."""
    return f"{float(value):.7g}"


def check_last_axis(x: jax.Array, size: int, name: str, meaning: str) -> None:
    if x.ndim == 0 or x.shape[-1] != size:
        raise InputError(
            f"{name}: shape {tuple(x.shape)} is invalid; its last axis must have size "
            f"{size} ({meaning})"
        )


def checked_twist(twist: Any, finite: bool = True) -> jax.Array:
    """Body twists (..., 3) as a float array; shape always checked, values when concrete."""
    t = as_float_array(twist, "twist")
    check_last_axis(t, 3, "twist", "vx, vy, wz")
    if finite:
        check_finite(t, "twist")
    return t


def check_finite(x: Any, name: str, error: type[InputError] = InputError) -> None:
    """Raise naming the first non-finite entry of ``x`` (only for concrete values)."""
    if not is_concrete(x):
        return
    arr = np.asarray(x)
    bad = ~np.isfinite(arr)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"{name}[{', '.join(map(str, index))}]" if index else name
        raise error(f"{where} = {fmt(arr[index])}: must be finite (no NaN or infinity)")
