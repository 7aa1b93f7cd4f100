"""A run directory's one writer and its faults (:class:`train.loop.run.Run`).

- **One writer.** Process 0 of a run holds ``<run>/.lock`` (:mod:`train.store.lock`) from
  ``Run.create`` or ``Run.resume`` until its ``train`` ends (``mecanum-train``: until the
  process exits). A second writer, a second ``--resume`` of the same run or a train into
  it, is refused before it writes anything: :class:`RunDirError` ``run directory 'PATH' is
  in use by another process (pid N); ...`` (exit code 2).
- **A disk that cannot take the run** (full, over quota, read-only): a new run's own files
  are removed again; a run that trained stops with status.json's ``state`` set to
  :data:`NO_SPACE` (``"failed: no space"``) or :data:`NOT_WRITABLE` (``"failed: not
  writable"``) where the disk still takes that, the last good checkpoint kept and a
  checkpoint cut short removed (:func:`train.store.checkpoint.remove_partial_saves`);
  ``--resume`` continues from it once the disk is fixed. The error is a
  :class:`mecanum_jax.atomic.DiskError`, one line naming the path.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import jax

from mecanum_jax.atomic import DiskError, disk_errors
from mecanum_jax.config import ConfigError
from train.config import TrainConfig
from train.config_loading import config_diff, config_value
from train.loop.distributed import barrier
from train.loop.run_records import write_json
from train.store import checkpoint, inputs, lock

# Fields a resumed run may change: its length, logging and evaluation cadence.
RESUMABLE_CHANGES = {
    "ppo.num_timesteps",
    "run.eval_every",
    "run.checkpoint_every",
    "run.max_checkpoints",
    "run.wandb_project",
    "run.progress_every_s",
}
# ... and, resuming a run that diverged, the optimizer's and the loss's step sizes.
STEP_SIZES = ("learning_rate", "max_grad_norm", "entropy_cost", "clipping_epsilon")
AFTER_DIVERGENCE = {f"ppo.{name}" for name in STEP_SIZES}

NO_SPACE = "failed: no space"
NOT_WRITABLE = "failed: not writable"


class RunDirError(ValueError):
    """The run directory cannot be used as asked (exists, in use, or is not a run)."""


def has_content(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds anything besides the lock file."""
    return run_dir.is_dir() and any(p.name != lock.LOCK_FILE for p in run_dir.iterdir())


def take_lock(run_dir: Path, then: str) -> Callable[[], None]:
    """Hold ``run_dir``'s lock (:func:`train.store.lock.acquire`), or :class:`RunDirError`
    naming the process that does; returns its release."""
    try:
        lock.acquire(run_dir, then)
    except lock.RunInUse as err:
        raise RunDirError(str(err)) from None
    return lambda: lock.release(run_dir)


@contextlib.contextmanager
def undone_on_error(run_dir: Path, made: bool) -> Iterator[None]:
    """A new run's first files: on any error, the directory is removed again where this
    run ``made`` it, else emptied (it was empty: :func:`has_content`)."""
    try:
        yield
    except BaseException:
        if made:
            shutil.rmtree(run_dir, ignore_errors=True)
        else:
            for item in run_dir.iterdir():
                if item.is_dir():
                    shutil.rmtree(item, ignore_errors=True)
                else:
                    item.unlink(missing_ok=True)
        raise


def first_files(
    run_dir: Path, cfg: TrainConfig, config_file: Path | None, exists: str
) -> Callable[[], None]:
    """A new run's directory, locked, and its first files: config.json, inputs/ (with
    ``config_file``, where given) and status.json ``created``; returns the lock's release.
    Where any of them cannot be written, none stay (nor the directory, where it was made
    here). ``exists``: the error for a directory another process filled meanwhile."""
    made = not run_dir.exists()
    with disk_errors(run_dir):
        run_dir.mkdir(parents=True, exist_ok=True)
    unlock = take_lock(run_dir, "choose another --run-dir")
    try:
        if has_content(run_dir):  # another process created it meanwhile
            raise RunDirError(exists)
        with undone_on_error(run_dir, made):
            write_json(run_dir / "config.json", cfg.to_dict())
            inputs.save_inputs(run_dir, cfg)
            if config_file is not None:
                inputs.add_file(run_dir, "config", config_file)
            write_json(
                run_dir / "status.json", {"state": "created", "time": time.time(), "epoch": 0}
            )
    except BaseException:
        unlock()
        raise
    return unlock


def resumed_config(run_dir: Path, overrides: TrainConfig | None) -> TrainConfig:
    """The saved config of ``run_dir`` with ``overrides`` checked (only
    :data:`RESUMABLE_CHANGES`, after a divergence also :data:`AFTER_DIVERGENCE`) and
    applied: config.json rewritten by process 0."""
    path = run_dir / "config.json"
    # its robot: the run's copy, if it has one; its values checked where it is the config
    saved = inputs.load_saved_config(run_dir, validate=overrides is None)
    cfg = saved
    if overrides is not None:
        allowed = RESUMABLE_CHANGES | (
            AFTER_DIVERGENCE if saved_state(run_dir) == "diverged" else set()
        )
        changed = [f for f in config_diff(saved, overrides) if f not in allowed]
        if changed:
            was, given = config_value(saved, changed[0]), config_value(overrides, changed[0])
            raise ConfigError(
                f"{changed[0]}: cannot change when resuming {str(run_dir)!r} "
                f"(saved {was!r}, given {given!r}); "
                f"only {sorted(allowed)} may change"
            )
        cfg = overrides.validate()
    barrier("run-resume")  # every process has read it before process 0 rewrites it
    if cfg is not saved and jax.process_index() == 0:
        write_json(path, inputs.as_given(cfg.to_dict(), json.loads(path.read_text())))
    return cfg


def saved_state(run_dir: Path) -> str | None:
    """The state status.json gives (``None``: none)."""
    try:
        return str(json.loads((run_dir / "status.json").read_text()).get("state"))
    except (OSError, ValueError, AttributeError):
        return None


def failed_state(err: DiskError) -> str:
    """status.json's state for a run stopped by ``err``."""
    return NO_SPACE if err.no_space else NOT_WRITABLE


def clean_up_failed_save(run_dir: Path) -> None:
    """A checkpoint cut short by a full disk, removed (the last good one stays)."""
    with contextlib.suppress(OSError):
        checkpoint.remove_partial_saves(run_dir)


__all__ = [
    "AFTER_DIVERGENCE",
    "NOT_WRITABLE",
    "NO_SPACE",
    "RESUMABLE_CHANGES",
    "RunDirError",
    "clean_up_failed_save",
    "failed_state",
    "first_files",
    "has_content",
    "resumed_config",
    "saved_state",
    "take_lock",
    "undone_on_error",
]
