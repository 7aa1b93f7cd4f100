"""The command lines' paths: outputs checked before anything runs (never overwritten,
writable), and the shipped model found wherever the package is installed."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from mecanum_jax.config import ConfigError, package_data

SHIPPED = ("o_rectangle",)
"""The shipped models: ``models/<name>`` in a clone, ``mecanum_jax/shipped/<name>`` in a
wheel (pyproject.toml's force-include)."""


def check_output(path: str | Path, field: str, empty_dir_ok: bool = False) -> Path:
    """``path`` as an output that can be created: it does not exist (or, with
    ``empty_dir_ok``, is an empty directory) and its nearest existing parent is a
    directory this process can write in. Raises :class:`ConfigError` naming ``field``."""
    path = Path(path)
    text = f"{field} = {str(path)!r}"
    if path.exists() or path.is_symlink():
        if not (empty_dir_ok and path.is_dir()):
            what = " and is not a directory" if empty_dir_ok else ""
            raise ConfigError(f"{text}: already exists{what}; never overwritten")
        if any(path.iterdir()):
            raise ConfigError(f"{text}: already exists and is not empty; never overwritten")
        return path
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{text}: {str(parent)!r} is not a directory")
    try:  # writing tells what access() cannot: read-only mounts, /proc, ACLs
        os.rmdir(tempfile.mkdtemp(prefix=".mecanum-probe-", dir=parent))
    except OSError as err:
        raise ConfigError(f"{text}: cannot create it in {str(parent)!r} ({err.strerror})") from None
    return path


def check_input_dir(path: str | Path, field: str) -> Path:
    """``path`` as an existing directory to read, or :class:`ConfigError` naming ``field``."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{field} = {str(path)!r}: no such directory")
    if not path.is_dir():
        raise ConfigError(f"{field} = {str(path)!r}: not a directory")
    return path


def shipped_dir() -> Path:
    """Where the shipped models are: inside the installed package, else the clone's models/."""
    return package_data("shipped", "models")


def resolve_model(target: str) -> str:
    """A model or run directory as given, or, where ``target`` names no existing path,
    the shipped model it names: ``shipped``, ``o_rectangle`` or ``models/o_rectangle``."""
    if Path(target).exists():
        return target
    name = SHIPPED[0] if target.rstrip("/") == "shipped" else target.rstrip("/")
    name = name.removeprefix("models/")
    if name in SHIPPED and (shipped_dir() / name).is_dir():
        return str(shipped_dir() / name)
    return target


__all__ = ["SHIPPED", "check_input_dir", "check_output", "resolve_model", "shipped_dir"]
