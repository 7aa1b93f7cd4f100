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

from mecanum_jax.config import (
    CONFIG_DIR,
    ConfigError,
    find_config,
    from_mapping,
    invalid,
    load_toml,
)
from train.config import TrainConfig

TRAIN_CONFIG_DIR = CONFIG_DIR / "train"


SAVED_ABSENT: dict[str, Any] = {
    "env": {
        "residual_scale": 0.1, "residual_space": "wheel", "residual_base": "analytic",
        "action_filter": 0.0, "residual_deadband": 0.0, "residual_ramp_s": 0.0,
        "path_tau": 0.0, "path_integrator": "euler",
        "commands": {"p_zero": 0.1, "p_translation": 0.3, "resample_min_s": 1.0,
                     "resample_max_s": 4.0},
        "randomization": {"nominal_share": 0.0},
        "reward": {"sigma_ang": 1.0, "error_ang": 0.1, "path_ang": 0.0, "target": "command"},
        "feedback": {"hold_s": 0.0, "reset": False, "deadband": 0.0, "margin": 0.0},
    },
    "network": {"init_noise_std": 0.5},
    "ppo": {
        "num_timesteps": 400_000, "num_envs": 64, "batch_size": 64, "num_minibatches": 4,
        "learning_rate": 3e-4, "learning_rate_final": 1.0, "update_precision": "run",
        "smoothness": {"temporal": 0.0, "spatial": 0.0},
        "anchor": {"weight": 0.0, "spins": False, "translations": False},
    },
    "run": {"epoch_iterations": 10, "eval_every": 1, "checkpoint_every": 1,
            "num_eval_envs": 32, "eval_episode_length": 250},
}  # fmt: skip
"""What a saved config (a run's ``config.json``, a checkpoint's meta) that lacks a field ran
with, where the field's default has since become the shipped recipe's: each field was added
off (or small), and a file written before it existed means that value, not today's
default. Saved configs written since spell every field; TOML files mean today's defaults."""


SAVED_RETIRED: dict[str, Any] = {"env": {"commands": {"p_mirror": 0.0}}}
"""Fields a saved config may state that no longer exist, each at the value with which its
run ran as the code now runs (the option off): such a key is dropped; at another value the
run used an option that is gone (docs/controller.md, Levers tried), and loading refuses it.
TOML files get no such leave: there a retired key is an unknown key."""


def saved_config(data: Any, source: str) -> Any:
    """A saved config's mapping (a run's ``config.json``, a checkpoint's meta) in today's
    fields: retired ones stated off dropped (:data:`SAVED_RETIRED`; stated otherwise, a
    :class:`ConfigError` naming ``source`` and the field), absent ones filled
    (:func:`with_absent`)."""
    with _named(source):
        return with_absent(_without_retired(data, SAVED_RETIRED, ""))


def _without_retired(data: Any, retired: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        return data
    out = dict(data)
    for key, off in retired.items():
        if key not in out:
            continue
        name = f"{where}.{key}" if where else key
        if isinstance(off, dict):
            out[key] = _without_retired(out[key], off, name)
        elif out[key] == off:
            del out[key]
        else:
            why = f"this option was removed; a saved config loads only with it off ({off!r})"
            raise invalid(name, out[key], why)
    return out


def with_absent(data: Any, absent: Any = SAVED_ABSENT) -> Any:
    """``data`` (a saved config's mapping) with every field of ``absent`` it lacks filled in."""
    if not isinstance(data, dict):
        return data
    out = dict(data)
    for key, value in absent.items():
        if key not in out:
            out[key] = value
        elif isinstance(value, dict):
            out[key] = with_absent(out[key], value)
    return out


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
        data = (
            saved_config(json.loads(p.read_text()), str(p)) if p.suffix == ".json" else load_toml(p)
        )
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


def config_value(cfg: object, dotted: str) -> object:
    """The field of ``cfg`` at a dotted path (as :func:`config_diff` names it)."""
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


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
    "SAVED_ABSENT",
    "SAVED_RETIRED",
    "TRAIN_CONFIG_DIR",
    "apply_flags",
    "config_diff",
    "config_value",
    "load_train_config",
    "parse_train_config",
    "saved_config",
    "with_absent",
]
