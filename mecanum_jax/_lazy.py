"""Lazy re-exports for sub-packages whose modules import MJX (slow) or optional extras.

``from mecanum_jax.sim import Robot`` imports :mod:`mecanum_jax.sim.physics` when the name
is first asked for, so ``import mecanum_jax`` and the kinematics stay free of MJX.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def exports(
    package: str, names: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package``: ``names`` maps each exported name to
    the sub-module (relative, e.g. ``".physics"``) that defines it."""

    def getattr_(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module, package), name)

    def dir_() -> list[str]:
        return sorted(names)

    return getattr_, dir_
