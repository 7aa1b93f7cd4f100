"""Input checks shared by the checked entry points.

Shape checks are static and always run, also under ``jit``. Value checks (finiteness)
need concrete values: they run when an entry point is called eagerly and are skipped when
the input is a tracer (inside ``jit``/``vmap``/``grad``), where raising is impossible.

Under ``jit`` the kinematics are pure arithmetic, on purpose (no check slows the hot path):
a NaN or infinite twist gives NaN or infinite wheel rates for that robot only (an infinity
times a zero Jacobian entry is NaN), never an error and never a change to other robots.
Check untrusted input eagerly (the same functions called outside ``jit`` raise, naming the
entry) or with ``jnp.isfinite`` before the call.

Numbers of the Python API (a radius, a gear ratio, a time step) are accepted as Python
numbers or as NumPy/JAX scalars (0-d arrays): :func:`real_number`.
"""

from __future__ import annotations

import importlib.util
import os
from typing import TYPE_CHECKING, SupportsFloat

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import ConfigError, python_number

if TYPE_CHECKING:
    import numpy.typing as npt


class InputError(ValueError):
    """User data (an array, a file, an argument) is invalid. The message names the field."""


def is_concrete(*xs: object) -> bool:
    """True when no leaf of ``xs`` is a JAX tracer, so its values can be inspected."""
    leaves = jax.tree_util.tree_leaves(xs)
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)


def as_float_array(x: npt.ArrayLike, name: str) -> jax.Array:
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


def real_number(value: object, name: str, error: type[InputError] = InputError) -> float:
    """A finite real number (a Python int or float, or a NumPy/JAX 0-d scalar of one) as a
    float; anything else (a bool, a string, an array, NaN, infinity) raises naming ``name``."""
    number = python_number(value)
    if isinstance(number, bool) or not isinstance(number, int | float):
        raise error(f"{name} = {value!r}: expected a finite number")
    if not np.isfinite(number):
        raise error(f"{name} = {value!r}: expected a finite number")
    return float(number)


def fmt(value: SupportsFloat) -> str:
    """A number for an error message: shortest readable form, no NumPy type prefix."""
    return f"{float(value):.7g}"


def check_last_axis(x: jax.Array, size: int, name: str, meaning: str) -> None:
    if x.ndim == 0 or x.shape[-1] != size:
        raise InputError(
            f"{name}: shape {tuple(x.shape)} is invalid; its last axis must have size "
            f"{size} ({meaning})"
        )


def checked_twist(twist: npt.ArrayLike, finite: bool = True) -> jax.Array:
    """Body twists (..., 3) as a float array; shape always checked, values when concrete."""
    t = as_float_array(twist, "twist")
    check_last_axis(t, 3, "twist", "vx, vy, wz")
    if finite:
        check_finite(t, "twist")
    return t


def check_finite(x: npt.ArrayLike, name: str, error: type[InputError] = InputError) -> None:
    """Raise naming the first non-finite entry of ``x`` (only for concrete values)."""
    if not is_concrete(x):
        return
    arr = np.asarray(x)
    bad = ~np.isfinite(arr)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"{name}[{', '.join(map(str, index))}]" if index else name
        raise error(f"{where} = {fmt(arr[index])}: must be finite (no NaN or infinity)")


_INSTALL = {
    "cuda": "pip install 'mecanum-jax[cuda]' (NVIDIA GPUs; needs an NVIDIA driver)",
    "gpu": "pip install 'mecanum-jax[cuda]' (NVIDIA GPUs; needs an NVIDIA driver)",
    "tpu": "pip install 'jax[tpu]' (on a Cloud TPU VM)",
    "rocm": "install JAX's ROCm plugin (AMD GPUs; see JAX's installation guide)",
}


def installed_platforms() -> list[str]:
    """The JAX platforms this environment could start: the CPU, plus CUDA or TPU where
    their plugin is installed (whether a device is present is not asked)."""
    found = ["cpu"]
    if any(_has(m) for m in ("jax_cuda12_plugin", "jax_cuda13_plugin")):
        found.append("cuda")
    if _has("libtpu"):
        found.append("tpu")
    return found


def _has(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:
        return False


def require_platform() -> None:
    """Raise :class:`ConfigError` in one line when the backend ``JAX_PLATFORMS`` asks for
    cannot start: what was asked, what this environment has and how to install it. Every
    command line calls it before it builds anything (after ``jax.distributed`` starts, if
    it does); with ``JAX_PLATFORMS`` unset JAX picks what exists and nothing is checked."""
    asked = os.environ.get("JAX_PLATFORMS", "").strip()
    if not asked:
        return
    try:
        jax.devices()
    except (RuntimeError, AssertionError) as err:  # a missing CUDA raises a bare assert
        wanted = [p.strip() for p in asked.split(",") if p.strip()]
        how = "; ".join(dict.fromkeys(_INSTALL[p] for p in wanted if p in _INSTALL))
        reason = str(err).split(" (set JAX_PLATFORMS")[0].strip() or "no such plugin or device"
        raise ConfigError(
            f"JAX_PLATFORMS = {asked!r}: that backend cannot start here ({reason}); this "
            f"environment has {', '.join(installed_platforms())}"
            + (f"; to install it: {how}" if how else "")
            + "; or unset JAX_PLATFORMS (JAX then uses what exists)"
        ) from None
