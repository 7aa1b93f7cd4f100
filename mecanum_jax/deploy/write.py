"""Writing a policy export (the trainer's side; the robot reads it with :mod:`.policy`):
``policy.npz`` with the robot-side code beside it as one archive, ``mecanum_robot.zip``
(:func:`export_policy`), or one ONNX graph (:func:`export_onnx`), from a policy's arrays and
its task's :func:`task_meta`."""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from mecanum_jax import atomic
from mecanum_jax.deploy.policy import FORMAT, NumpyPolicy

if TYPE_CHECKING:  # the task's modules load MJX: imported where an export is written
    from mecanum_jax.sim.description import RobotDescription
    from mecanum_jax.task.config import EnvConfig
    from mecanum_jax.task.constants import RobotConstants

Layers = list[tuple[np.ndarray, np.ndarray]]


class Task(Protocol):
    """What an export reads of a task: a ``MecanumEnv`` or its ``TaskShapes`` (which builds
    no MJX model)."""

    @property
    def config(self) -> EnvConfig: ...
    @property
    def desc(self) -> RobotDescription: ...
    @property
    def constants(self) -> RobotConstants: ...


def task_meta(task: Task) -> dict[str, object]:
    """What an exported policy's control loop needs of ``task``
    (:func:`mecanum_jax.task.controller.controller_meta`)."""
    from mecanum_jax.task.controller import controller_meta

    return controller_meta(task.config, task.desc, task.constants)


def save(
    path: str | Path,
    layers: list[tuple[np.ndarray, np.ndarray]],
    mean: np.ndarray,
    std: np.ndarray,
    meta: Mapping[str, object],
) -> Path:
    """Write an export (atomically: a crash or a full disk leaves no half-written file)."""
    path = Path(path)
    arrays = {f"w{i}": np.asarray(w, np.float32) for i, (w, _) in enumerate(layers)}
    arrays |= {f"b{i}": np.asarray(b, np.float32) for i, (_, b) in enumerate(layers)}
    arrays |= {"obs_mean": np.asarray(mean, np.float32), "obs_std": np.asarray(std, np.float32)}
    arrays["meta"] = np.asarray(json.dumps(dict(meta, format=FORMAT, layers=len(layers))))
    with atomic.open_atomic(path, "wb") as f:
        np.savez(f, allow_pickle=True, **arrays)  # numpy's default, named: all else is arrays
    return path


ARCHIVE = "mecanum_robot.zip"
"""The robot-side code's file beside ``policy.npz``: put it on ``sys.path`` and import
``mecanum_loop`` (or ``mecanum_policy``) from it."""


def robot_side_files() -> dict[str, Path]:
    """What the robot needs beside ``policy.npz``, by its name in :data:`ARCHIVE`: the NumPy
    policy, the control loop, the controller package (``mecanum_control/``) and the
    self-check the archive runs as a program (:mod:`.selfcheck`), from the library."""
    from mecanum_jax import control
    from mecanum_jax.deploy import policy

    source = Path(policy.__file__)
    files = {
        "__main__.py": source.with_name("selfcheck.py"),  # python mecanum_robot.zip
        "mecanum_policy.py": source,
        "mecanum_loop.py": source.with_name("loop.py"),
    }
    package = Path(control.__file__).parent
    for src in sorted(package.glob("*.py")):
        files[f"mecanum_control/{src.name}"] = src
    return files


def robot_archive() -> bytes:
    """:func:`robot_side_files` as one zip, the same bytes for the same sources: stored
    uncompressed (no zlib version enters), in name order, every date 1980-01-01."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, src in sorted(robot_side_files().items()):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            archive.writestr(info, src.read_bytes())
    return buffer.getvalue()


def export_policy(
    layers: Layers, mean: np.ndarray, std: np.ndarray, meta: Mapping[str, object], path: Path
) -> Path:
    """Write ``policy.npz`` (weights, normalizer, control-loop constants) and the robot-side
    code beside it as :data:`ARCHIVE` (:func:`robot_archive`). Each file atomically; on an
    error, those it had written are removed again."""
    new = [p for p in (path, path.with_name(ARCHIVE)) if not p.exists()]
    try:
        save(path, layers, mean, std, meta)
        atomic.write_bytes(path.with_name(ARCHIVE), robot_archive())
    except BaseException:
        for p in new:
            p.unlink(missing_ok=True)
        raise
    return path


def export_onnx(
    layers: Layers, mean: np.ndarray, std: np.ndarray, meta: Mapping[str, object], path: Path
) -> Path:
    """Write the policy and its control loop as one ONNX graph (:mod:`.onnx`)."""
    from mecanum_jax.deploy import onnx as onnx_export

    return onnx_export.write_onnx(NumpyPolicy(layers, mean, std, dict(meta)), path)


__all__ = [
    "ARCHIVE",
    "Task",
    "export_onnx",
    "export_policy",
    "robot_archive",
    "robot_side_files",
    "save",
    "task_meta",
]
