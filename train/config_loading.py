"""Reading a training config: from ``configs/train/*.toml`` or a run directory's
``config.json``, with command-line flags over it, and the fields where two configs differ.

Command-line overrides are tyro flags over the config's dataclasses
(``--ppo.learning-rate``), applied before the values are checked
(:func:`load_train_config`); an error in a value names the file it came from.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mecanum_jax.config import CONFIG_DIR, ConfigError, find_config, from_mapping, load_toml
from train.config import TrainConfig

TRAIN_CONFIG_DIR = CONFIG_DIR / "train"


def parse_train_config(data: Any, source: str, validate: bool = True) -> TrainConfig:
    """The config of the mapping ``data``; errors name ``source``. ``validate=False``: the
    types checked, the values left to :func:`apply_flags` (given ``source``)."""
    with _named(source):
        cfg = from_mapping(TrainConfig, data)
        return cfg.validate() if validate else cfg


@contextlib.contextmanager
def _named(source: str) -> Iterator[None]:
    """A :class:`ConfigError` raised inside, named with ``source``, the values' file."""
    try:
        yield
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None


def load_train_config(
    path: str | Path,
    flags: list[str] | None = None,
    prog: str = "mecanum-train",
    description: str = "",
) -> TrainConfig:
    """Load a training config from TOML, or from a run directory's ``config.json``.

    A bare name (``quick``) means ``configs/train/<name>.toml``. ``flags``: command-line
    flags over its fields (:func:`apply_flags`), its values checked once, after them.
    """
    p = find_config(path, TRAIN_CONFIG_DIR, "config", "built-in config")
    try:
        data = json.loads(p.read_text()) if p.suffix == ".json" else load_toml(p)
    except json.JSONDecodeError as err:
        raise ConfigError(f"config file {str(p)!r}: invalid JSON: {err}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"config file {str(p)!r}: not a text file (UTF-8)") from None
    except OSError as err:
        raise ConfigError(f"config file {str(p)!r}: unreadable: {err.strerror}") from None
    if flags is None:
        return parse_train_config(data, str(p))
    base = parse_train_config(data, str(p), validate=False)
    return apply_flags(base, flags, prog, description, source=str(p))


def apply_flags(
    base: TrainConfig,
    flags: list[str],
    prog: str = "mecanum-train",
    description: str = "",
    source: str = "",
) -> TrainConfig:
    """``base`` with command-line flags over its fields (``--ppo.learning-rate 1e-3``),
    parsed by tyro as ``mecanum-train`` parses them, then validated (``base`` itself where
    they change nothing). ``source``: the file of a ``base`` not yet validated; an error
    in a value of its own names the file, as :func:`parse_train_config` does."""
    import tyro

    cfg = tyro.cli(
        TrainConfig,
        default=base,
        args=flags,
        prog=prog,
        description=description,
        config=(tyro.conf.FlagConversionOff,),
    )
    if cfg == base:
        cfg = base  # checked once, whichever layer asks first
    try:
        return cfg.validate()
    except ConfigError:
        if source:  # the file's own error first, named with the file
            with _named(source):
                base.validate()
        raise


def config_diff(a: Any, b: Any, where: str = "") -> list[str]:
    """Dotted paths of the fields that differ between two configs."""
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        out = []
        for f in dataclasses.fields(a):
            path = f"{where}.{f.name}" if where else f.name
            out += config_diff(getattr(a, f.name), getattr(b, f.name), path)
        return out
    return [] if a == b else [where]


__all__ = [
    "TRAIN_CONFIG_DIR",
    "apply_flags",
    "config_diff",
    "load_train_config",
    "parse_train_config",
]
