"""The NaN guard of :meth:`train.loop.run.Run.train`: which epoch went non-finite, and the
first non-finite quantity in it (a loss, else a parameter or the observation
normalizer: a non-finite gradient shows in the parameters it updated)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import numpy as np

from train.learner.transfer import to_host

if TYPE_CHECKING:
    from train.learner.state import TrainingState

LOSS_FIRST = "loss/total_loss"


class TrainingDiverged(RuntimeError):  # noqa: N818 (reads as the event it reports)
    """Loss or parameters went non-finite; the last good checkpoint was kept."""


def _kind(x: np.ndarray) -> str:
    return "nan" if np.isnan(x).any() else "inf"


def _losses(metrics: dict[str, np.ndarray], i: int) -> list[str]:
    """Seed ``i``'s non-finite loss metrics, the total first."""
    keys = sorted((k for k in metrics if k.startswith("loss/")), key=lambda k: k != LOSS_FIRST)
    return [k for k in keys if not np.isfinite(metrics[k][i])]


def bad_seeds(seeds: Sequence[int], metrics: dict[str, np.ndarray]) -> list[int]:
    """The seeds (indices into ``seeds``) whose epoch went non-finite: parameters or
    normalizer (the epoch's ``finite`` flag) or a loss."""
    return [i for i in range(len(seeds)) if not metrics["finite"][i] > 0 or _losses(metrics, i)]


def first_non_finite(
    seeds: Sequence[int], metrics: dict[str, np.ndarray], state: TrainingState, i: int
) -> str:
    """The first non-finite quantity of seed ``seeds[i]``: ``"loss/total_loss is nan in
    seed 0"`` or ``"policy parameter params/hidden_0/kernel is nan in seed 0"``. ``state``:
    the epoch's training state, ``(D, S, ...)``; read (from the devices) only when no
    loss is non-finite."""
    seed = seeds[i]
    if losses := _losses(metrics, i):
        return f"{losses[0]} is {_kind(metrics[losses[0]][i : i + 1])} in seed {seed}"
    named = {
        "parameter": state.params,
        "observation normalizer": {
            "mean": state.normalizer_params.mean,
            "std": state.normalizer_params.std,
        },
    }
    for what, tree in named.items():
        for path, leaf in jax.tree_util.tree_leaves_with_path(to_host(tree)):
            x = np.asarray(leaf)
            if not np.issubdtype(x.dtype, np.floating):
                continue
            x = x[:, i]  # (D, S, ...): seed i on every device
            if not np.isfinite(x).all():
                name = jax.tree_util.keystr(path, simple=True, separator="/")
                network, _, rest = name.partition("/")
                label = f"{network} {what} {rest}" if what == "parameter" else f"{what} {name}"
                return f"{label} is {_kind(x)} in seed {seed}"
    return f"parameters or normalizer non-finite in seed {seed}"


def message(epoch: int, what: str, last_good: int, run_dir: Path, checkpoint: Path) -> str:
    """The error of a run that went non-finite in ``epoch`` (its first non-finite
    quantity ``what``) with ``last_good`` the last epoch saved."""
    kept = (
        f"last good checkpoint: epoch {last_good} ({checkpoint})"
        if last_good
        else "no checkpoint yet (its first epoch diverged)"
    )
    return (
        f"non-finite values in epoch {epoch} ({what}); stopped, {kept}; resume it with "
        f"--resume {run_dir} and a change, such as a lower --ppo.learning-rate"
    )


__all__ = ["TrainingDiverged", "bad_seeds", "first_non_finite", "message"]
