"""Type aliases of what the learner's programs take and return (:mod:`train.learner.ppo`)."""

from __future__ import annotations

import jax
import numpy as np

from train.learner.state import TrainingState

PackedEnv = dict[str, jax.Array]
"""The environment state as it crosses device programs and is checkpointed: its leaves
by ``jax.tree.leaves`` position (:meth:`~train.learner.ppo.Learner.pack_env`)."""
Metrics = dict[str, jax.Array]
"""Metrics by name, as a program returns them."""
Host = tuple[TrainingState, np.ndarray]
"""A fresh host training state ``(D, S, ...)`` and the environment keys ``(D, S, E/D, 2)``."""
Placed = tuple[TrainingState, PackedEnv]
"""The training and the packed environment state, on the devices."""
Epoch = tuple[TrainingState, PackedEnv, Metrics]
"""An epoch's ``(state, env_state, metrics)``."""
Updated = tuple[TrainingState, Metrics]
"""An update's ``(state, metrics)``."""

__all__ = ["Epoch", "Host", "Metrics", "PackedEnv", "Placed", "Updated"]
