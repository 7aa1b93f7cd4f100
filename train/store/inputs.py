"""A run's inputs, copied into it: the robot description and the config file it was given.

A run directory (and a model directory that ``mecanum-export --model`` packs from it)
holds::

    inputs/robot.toml     the robot description TOML the run trained on (built-in or not)
    inputs/config.toml    the train config file it was given (when it was a file)
    inputs/inputs.json    where each came from, and its SHA-256

so that it evaluates, exports and resumes after the user's TOML is moved, edited or
deleted: :func:`use_copies` points a saved config's ``env.robot`` at the copy where the
name no longer gives the bytes the run trained on (and leaves it alone where it does, so
configs compare equal). An original that still exists but whose bytes changed is named in
a warning beside the copy (the copy is used: it is what the run trained on); a deleted one
is not mentioned.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mecanum_jax import atomic
from mecanum_jax.config import CONFIG_DIR, ConfigError, find_config

if TYPE_CHECKING:
    from train.config import TrainConfig

INPUTS_DIR = "inputs"
INDEX = "inputs.json"


class EditedInputWarning(UserWarning):
    """An input a run was trained with has been edited since; the run's copy is used."""


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def robot_file(robot: str) -> Path:
    """The description file ``env.robot`` names (a path, or a built-in name)."""
    return find_config(robot, CONFIG_DIR / "robots", "env.robot", "built-in description")


def read_index(run_dir: Path) -> dict[str, object]:
    """``inputs/inputs.json`` of ``run_dir`` (empty when the run predates copied inputs)."""
    path = run_dir / INPUTS_DIR / INDEX
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ConfigError(f"{str(path)!r}: unreadable: {err}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{str(path)!r}: expected a JSON object")
    return data


def add_file(run_dir: Path, key: str, source: Path) -> None:
    """Copy ``source`` into ``run_dir/inputs/<key><suffix>`` and record it in the index."""
    folder = run_dir / INPUTS_DIR
    copy = f"{key}{source.suffix or '.toml'}"
    atomic.copy_file(source, folder / copy)
    index = read_index(run_dir)
    index[key] = {"source": str(source.resolve()), "copy": copy, "sha256": sha256(source)}
    atomic.write_json(folder / INDEX, index)


def save_inputs(run_dir: str | Path, cfg: TrainConfig) -> None:
    """Copy the robot description of ``cfg`` (a TrainConfig) into ``run_dir/inputs/``."""
    add_file(Path(run_dir), "robot", robot_file(cfg.env.robot))


def copy_inputs(src_dir: Path, dst_dir: Path) -> None:
    """Carry a run's ``inputs/`` into a directory packed from it (a model directory, built
    under its ``.partial`` name: :func:`mecanum_jax.atomic.directory`)."""
    if (src_dir / INPUTS_DIR / INDEX).is_file():
        atomic.copy_tree(src_dir / INPUTS_DIR, dst_dir / INPUTS_DIR)


def robot_copy(run_dir: Path, given: str) -> Path | None:
    """The run's copy of its robot description where the saved config's ``given`` no longer
    names the bytes it trained on (moved, deleted or edited; an edited original, or one
    still at the recorded source, is named in an :class:`EditedInputWarning`); ``None`` for
    a run without a copy, or where ``given`` still names the very file."""
    entry = read_index(run_dir).get("robot")
    if not isinstance(entry, dict):
        return None
    copy = run_dir / INPUTS_DIR / str(entry.get("copy", "robot.toml"))
    if not copy.is_file():
        raise ConfigError(f"{str(run_dir / INPUTS_DIR / INDEX)!r}: names {copy.name}, missing")
    if entry.get("sha256") != sha256(copy):
        raise ConfigError(f"{str(copy)!r}: does not match its SHA-256 in {INDEX}")
    try:
        named: Path | None = robot_file(given)
    except ConfigError:
        named = None
    if named is not None and sha256(named) == entry["sha256"]:
        return None
    # an original still there differs from the copy: the one named, else the recorded one
    recorded = Path(str(entry.get("source", "")))
    original = named
    if original is None and recorded.is_file() and sha256(recorded) != entry["sha256"]:
        original = recorded
    if original is not None:
        warnings.warn(
            f"robot description {str(original)!r} has been edited since training; "
            f"using the run's copy {str(copy)!r}",
            EditedInputWarning,
            stacklevel=2,
        )
    return copy


def use_copies(data: object, run_dir: Path, warn: bool = True) -> object:
    """A saved config mapping of ``run_dir`` (config.json's, or a checkpoint's) with
    ``env.robot`` the run's copy, where it has one; parse it after this, since parsing
    loads the description."""
    if not isinstance(data, dict):
        return data
    env = data.get("env")
    if not (isinstance(env, dict) and isinstance(env.get("robot"), str)):
        return data
    with warnings.catch_warnings():
        if not warn:
            warnings.simplefilter("ignore", EditedInputWarning)
        copy = robot_copy(run_dir, env["robot"])
    if copy is None:
        return data
    return {**data, "env": {**env, "robot": str(copy.resolve())}}


def as_given(data: dict[str, Any], saved: dict[str, Any]) -> dict[str, Any]:
    """A config mapping to write back as ``config.json``, its ``env.robot`` as ``saved``
    (the config.json it replaces) named it, not the run's copy that :func:`use_copies`
    substituted."""
    robot = saved.get("env", {}).get("robot") if isinstance(saved, dict) else None
    if not isinstance(robot, str) or not isinstance(data.get("env"), dict):
        return data
    return {**data, "env": {**data["env"], "robot": robot}}


def load_saved_config(run_dir: Path, warn: bool = True, validate: bool = True) -> TrainConfig:
    """``run_dir/config.json`` as a TrainConfig whose ``env.robot`` is the run's copy (if
    it has one), so that it loads after the original is gone. Errors name the file.
    ``validate=False``: its types checked, its values left to the caller
    (``train.config_loading.parse_train_config``)."""
    from train.config_loading import parse_train_config, saved_config

    path = run_dir / "config.json"
    try:
        data = json.loads(path.read_text())
    except ValueError as err:  # JSON, or not UTF-8 text
        raise ConfigError(f"config file {str(path)!r}: invalid JSON: {err}") from None
    except OSError as err:
        raise ConfigError(f"config file {str(path)!r}: unreadable: {err.strerror}") from None
    data = use_copies(saved_config(data, str(path)), run_dir, warn)
    return parse_train_config(data, str(path), validate)


__all__ = [
    "INPUTS_DIR",
    "EditedInputWarning",
    "add_file",
    "as_given",
    "copy_inputs",
    "load_saved_config",
    "read_index",
    "robot_copy",
    "save_inputs",
    "use_copies",
]
