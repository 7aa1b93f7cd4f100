"""Writing a policy export (the trainer's side; the robot reads it with :mod:`.policy`)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from mecanum_jax import atomic
from mecanum_jax.deploy.policy import FORMAT


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
