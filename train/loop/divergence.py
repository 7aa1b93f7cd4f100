"""The NaN guard of :meth:`train.loop.run.Run.train`: which epoch went non-finite, and the
first non-finite quantity in it (a loss, else a parameter or the observation
normalizer: a non-finite gradient shows in the parameters it updated); and the warning of
a path error that outgrows its leak, which stays finite while it ruins the value loss."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import numpy as np
from numpy.typing import ArrayLike

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


def path_outgrown(
    metrics: dict[str, np.ndarray], path_tau: float, path_lin: float, command_scale: ArrayLike
) -> str | None:
    """Why the true path error has outgrown what a leak of ``path_tau`` s holds, or None: a
    leaky integral of speed errors stays within τ times the largest, 2.5 times the reach
    (the robot at most at it, a command beyond it at most 1.5 of it). The error is a seed's
    root mean square over the epoch, from the path reward (``path_lin`` per m²), else its
    mean (``path_m``): a few robots far off show in the first. The first-order integrator
    outgrows the bound on fast spins; its reward and value loss grow with it while every
    figure stays finite (docs/controller.md, What limits it)."""
    if path_tau <= 0:
        return None
    if path_lin > 0 and "reward/path_lin" in metrics:
        what, size = "root mean square", np.sqrt(np.max(-metrics["reward/path_lin"]) / path_lin)
    elif "path_m" in metrics:
        what, size = "mean", np.max(metrics["path_m"])
    else:
        return None
    bound = 2.5 * path_tau * float(np.hypot(*np.asarray(command_scale)[:2]))
    if not size > bound:  # a NaN is the NaN guard's
        return None
    return (
        f"the true path error's {what} is {size:.3g} m, beyond the {bound:.3g} m a "
        f"{path_tau} s leak holds: the first-order path error (env.path_integrator = "
        "'euler') outgrows its leak on fast spins, and the path reward and value loss with "
        "it; 'exact' stays bounded"
    )


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


__all__ = ["TrainingDiverged", "bad_seeds", "first_non_finite", "message", "path_outgrown"]
