"""Checkpoints (orbax): the full training state, saved and restored for resume.

A checkpoint at ``<run>/checkpoints/<epoch>/`` holds three items:

- ``train``: the :class:`~train.learner.state.TrainingState` of every seed and device (optimizer
  state, parameters, observation normalizer, rng keys);
- ``env``: the environment state of every robot (so resuming continues the same episodes);
- ``meta``: JSON — epoch, environment steps, wall time, the resolved config, the robot
  and the observation layout (so a checkpoint from another robot or layout is refused).

``train`` and ``env`` are stored as flat dicts of named leaves with checksums, and
restored by name (:mod:`train.store.leaves`); the leaf-index format of versions before
2026-11-25 is recognised and restored by index.

A newest checkpoint that does not read (corrupt, or cut short mid-write) is set aside as
``<epoch>.corrupt`` by :func:`restore`, or passed over with a warning by the readers.
One seed's policy is restored from ``train`` and ``meta`` by :mod:`train.learner.policy`.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypeVar

import jax

from mecanum_jax import atomic
from train.store.leaves import CheckpointError, corruption, pack, unpack

if TYPE_CHECKING:
    import orbax.checkpoint as ocp

Train = TypeVar("Train")
Env = TypeVar("Env")

CHECKPOINT_DIR = "checkpoints"


def quiet_closed_loop_noise() -> None:
    """Drop the "Event loop is closed" tracebacks that orbax's reader threads leave behind
    after a failed read (Python reports them as unraisable exceptions at exit); every other
    unraisable exception is reported as before. Called by the command lines."""
    if getattr(sys.unraisablehook, "_mecanum_quiet", False):
        return
    previous = sys.unraisablehook

    def hook(unraisable: sys.UnraisableHookArgs) -> None:
        exc = unraisable.exc_value
        if isinstance(exc, RuntimeError) and str(exc) == "Event loop is closed":
            return
        previous(unraisable)

    hook._mecanum_quiet = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


def _orbax() -> ModuleType:
    """orbax.checkpoint, imported on first use: about 0.6 s that a run's start need not
    wait for (its first checkpoint comes epochs later; docs/profiling.md)."""
    import orbax.checkpoint

    return orbax.checkpoint


def manager(run_dir: Path, max_to_keep: int = 3, create: bool = True) -> ocp.CheckpointManager:
    ocp = _orbax()
    root = (run_dir / CHECKPOINT_DIR).absolute()
    extra: dict[str, object] = {}  # more CheckpointManagerOptions
    if jax.process_count() > 1:
        # process-local: process 0 alone writes its host copies; orbax's default would
        # wait at barriers for every process of a jax.distributed run (and with a process
        # subset it leaves creating the root to the caller)
        me = jax.process_index()
        extra["multiprocessing_options"] = ocp.options.MultiprocessingOptions(
            primary_host=me, active_processes={me}
        )
        if create:
            root.mkdir(parents=True, exist_ok=True)
        create = False
    options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=create, **extra)
    return ocp.CheckpointManager(root, options=options)


def save(
    mgr: ocp.CheckpointManager,
    epoch: int,
    train: object,
    env: object,
    meta: Mapping[str, object],
) -> None:
    """Save host (numpy) trees; blocks until written so a crash cannot leave it half done.
    orbax writes ``<epoch>.orbax-checkpoint-tmp`` and renames it when complete; a save that
    fails (a full disk) removes it and raises :class:`mecanum_jax.atomic.DiskError` where
    the disk was at fault, the checkpoints before it untouched."""
    ocp = _orbax()
    try:
        mgr.save(
            epoch,
            args=ocp.args.Composite(
                train=ocp.args.StandardSave(pack(train)),
                env=ocp.args.StandardSave(pack(env)),
                meta=ocp.args.JsonSave(meta),
            ),
            force=True,
        )
        mgr.wait_until_finished()
    except Exception as err:
        root = Path(mgr.directory)
        with contextlib.suppress(OSError):
            remove_partial_saves(root.parent)
        disk = atomic.explain(err, root / str(epoch))
        if disk is err:
            raise
        raise disk from err


PARTIAL_SAVE = "*.orbax-checkpoint-tmp*"
"""orbax's name for a checkpoint being written (renamed to ``<epoch>`` when complete)."""


def remove_partial_saves(run_dir: Path) -> list[Path]:
    """Remove the checkpoints of ``run_dir`` that a failed or killed save left half written
    (``<epoch>.orbax-checkpoint-tmp``); returns them. Only the run's one writer calls it
    (train.store.lock)."""
    root = run_dir / CHECKPOINT_DIR
    found = sorted(root.glob(PARTIAL_SAVE)) if root.is_dir() else []
    for path in found:
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
    return found


def latest_epoch(run_dir: Path) -> int | None:
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        return None
    mgr = manager(run_dir, create=False)
    try:
        return mgr.latest_step()
    finally:
        mgr.close()


def checkpoint_path(run_dir: Path, epoch: int) -> Path:
    return run_dir / CHECKPOINT_DIR / str(epoch)


def _read_items(mgr: ocp.CheckpointManager, epoch: int, items: tuple[str, ...]) -> dict[str, Any]:
    """The named items of checkpoint ``epoch`` as they were saved (no template: a file that
    does not decode is corruption, not a shape mismatch); ``meta`` is JSON, others arrays."""
    ocp = _orbax()
    args = {k: ocp.args.JsonRestore() if k == "meta" else ocp.args.StandardRestore() for k in items}
    out = dict(mgr.restore(epoch, args=ocp.args.Composite(**args)))
    for k in items:
        damage = "" if k == "meta" else corruption(out[k])
        if damage:  # decoded, but not the bytes that were saved
            raise CheckpointError(f"{k}: {damage}")
    return out


class SkippedCheckpointWarning(UserWarning):
    """The newest checkpoint of a run did not read (empty, corrupt or cut short); an older
    one was used."""


def _newest_clean(
    run_dir: Path, epoch: int | None, items: tuple[str, ...], skip: Callable[[int, str], None]
) -> tuple[int, dict[str, Any]]:
    """``(epoch, items)`` of checkpoint ``epoch``, or without one of the newest checkpoint
    whose items read cleanly, calling ``skip(epoch, reason)`` for each newer one that did
    not (empty, corrupt or cut short). Raises :class:`CheckpointError` naming every failure."""
    mgr = manager(run_dir, create=False)
    try:
        saved = sorted(mgr.all_steps(), reverse=True)
        if epoch is not None and not checkpoint_path(run_dir, epoch).exists():
            raise CheckpointError(
                f"epoch = {epoch}: no such checkpoint in {str(run_dir / CHECKPOINT_DIR)!r}; "
                f"its epochs: {sorted(saved)}"
            )
        epochs = saved if epoch is None else [epoch]
        if not epochs:
            raise CheckpointError(f"{str(run_dir)!r}: no checkpoints in {CHECKPOINT_DIR}/")
        bad = []
        for ep in epochs:
            try:
                return ep, _read_items(mgr, ep, items)
            except Exception as err:  # orbax raises many types for unreadable files
                text = str(err) if epoch is not None else (str(err).splitlines() or [""])[0]
                reason = f"{type(err).__name__}: {text}"
                bad.append(f"{str(checkpoint_path(run_dir, ep))!r} ({reason})")
                if epoch is None:
                    skip(ep, reason)
        if epoch is not None:
            raise CheckpointError(f"checkpoint {bad[0]} is corrupt or incomplete")
        raise CheckpointError(
            f"{str(run_dir)!r}: no checkpoint reads cleanly; each is corrupt or incomplete: "
            + "; ".join(bad)
        )
    finally:
        mgr.close()


def read_checked(run_dir: Path, epoch: int | None, items: tuple[str, ...]) -> tuple[int, dict]:
    """:func:`_newest_clean`, with a :class:`SkippedCheckpointWarning` naming each newer
    checkpoint that did not read, once one did."""
    bad: list[str] = []

    def skip(ep: int, reason: str) -> None:
        bad.append(f"checkpoint {str(checkpoint_path(run_dir, ep))!r} ({reason})")

    ep, out = _newest_clean(run_dir, epoch, items, skip)
    if bad:
        warnings.warn(
            f"{'; '.join(bad)}: corrupt or incomplete; using epoch {ep}, the newest that "
            "reads cleanly",
            SkippedCheckpointWarning,
            stacklevel=3,
        )
    return ep, out


def restore(
    run_dir: Path,
    train_like: Train,
    env_like: Env,
    epoch: int | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[Train, Env, dict[str, Any]]:
    """Restore the full state of ``epoch`` into trees shaped like the given.

    Without ``epoch``: the newest checkpoint that reads cleanly. A newer one that is
    corrupt or was cut short mid-write is renamed ``<epoch>.corrupt`` (kept for inspection,
    out of the way of the next save) and reported through ``log``. A checkpoint that reads
    but has another shape (an older version's training state) is an error, not skipped.
    """
    say = log or (lambda _: None)
    moved: list[int] = []

    def set_aside(ep: int, reason: str) -> None:
        moved.append(ep)
        path = checkpoint_path(run_dir, ep)
        aside = path.with_name(f"{ep}.corrupt")
        path.rename(aside)
        say(
            f"checkpoint {str(path)!r} is corrupt or incomplete ({reason}); "
            f"moved to {str(aside)!r} for inspection; trying the previous one"
        )

    ep, out = _newest_clean(run_dir, epoch, ("train", "env", "meta"), set_aside)
    path = checkpoint_path(run_dir, ep)
    try:
        train = unpack(train_like, out["train"])
        env = unpack(env_like, out["env"])
    except (CheckpointError, KeyError) as err:
        raise CheckpointError(
            f"checkpoint {str(path)!r} reads, but does not fit this run's state: "
            f"{err}. A checkpoint written by an older version of mecanum_jax, whose "
            "training state had another shape, can still be evaluated (mecanum-eval) "
            "but not resumed"
        ) from err
    if moved:
        say(f"resuming from checkpoint {str(path)!r}, the newest that reads cleanly")
    return train, env, dict(out["meta"])


def read_meta(run_dir: Path, epoch: int | None = None) -> tuple[int, dict[str, Any]]:
    epoch, out = read_checked(run_dir, epoch, ("meta",))
    return epoch, dict(out["meta"])


def read_train(run_dir: Path, epoch: int, train_like: Train) -> Train:
    """The training state of checkpoint ``epoch``, shaped like ``train_like`` (matched by
    leaf name; by index in the leaf-index format); a mismatch names the checkpoint."""
    _, saved = read_checked(run_dir, epoch, ("train",))
    return unpack_train(run_dir, epoch, train_like, saved)


def unpack_train(run_dir: Path, epoch: int, train_like: Train, saved: Mapping[str, Any]) -> Train:
    try:
        return unpack(train_like, saved["train"])
    except CheckpointError as err:
        where = str(checkpoint_path(run_dir, epoch))
        raise CheckpointError(f"checkpoint {where!r}: {err}") from err


__all__ = [
    "CHECKPOINT_DIR",
    "CheckpointError",
    "SkippedCheckpointWarning",
    "checkpoint_path",
    "latest_epoch",
    "manager",
    "quiet_closed_loop_noise",
    "read_checked",
    "read_meta",
    "read_train",
    "remove_partial_saves",
    "restore",
    "save",
    "unpack_train",
]
