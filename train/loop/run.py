"""One training run on disk: directory, logs, evaluation, checkpoints, resume, failures.

A run directory holds::

    config.json        the resolved configuration (written before anything compiles)
    .lock              held by the run's one writer (train.loop.run_dir)
    status.json        created | running | finished | stopped | interrupted | diverged |
                       failed: no space | failed: not writable, the epoch and its env
                       steps, the last checkpoint (rewritten every epoch)
    metrics.jsonl      one line per seed per epoch (training, evaluation, baseline)
    tb/seed_<k>/       TensorBoard event files
    checkpoints/<e>/   orbax checkpoints (full state; see train.store.checkpoint)
    summary.json       final figures per seed (when finished)
    learning_curve.png the learning curve (written by mecanum-train; train.loop.curve)

Rules: a run directory is never overwritten (an existing one is only *resumed*, its logs
cut back to the checkpoint's epoch); a NaN stops the run with a message naming the first
non-finite quantity and keeps the last good checkpoint (train.loop.divergence); Ctrl-C
writes a checkpoint of the last completed epoch before exiting, SIGTERM and SIGUSR1 one of
the epoch in progress, once it ends (train.loop.preemption); a second writer is refused,
and a full or read-only disk stops the run resumably (train.loop.run_dir). Every file is
written atomically (mecanum_jax.atomic).

:class:`Run` binds a run to its directory and drives its epochs; what each step of them
does (set-up, an epoch, its evaluation and log rows, the finish) is
:class:`~train.loop.run_steps.RunSteps`'s, which it extends.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict, Unpack

import jax
from rich.console import Console

from mecanum_jax import atomic
from train.config import TrainConfig
from train.learner.ppo import Learner
from train.loop import run_records as records
from train.loop.distributed import barrier
from train.loop.loggers import EpochLog, MetricLogger
from train.loop.preemption import Preempted, StopSignals, agree
from train.loop.run_dir import (
    RunDirError,
    clean_up_failed_save,
    failed_state,
    first_files,
    has_content,
    resumed_config,
    take_lock,
)
from train.loop.run_steps import RunSteps
from train.loop.session import Session
from train.store import checkpoint


class RunOptions(TypedDict, total=False):
    """What :meth:`Run.create` and :meth:`Run.resume` pass on to :class:`Run`."""

    console: Console | None
    loggers: list[MetricLogger] | None


class Run(RunSteps):
    """A training run bound to its directory. ``Run.create`` or ``Run.resume``, then ``train``."""

    def __init__(
        self,
        cfg: TrainConfig,
        run_dir: Path,
        console: Console | None = None,
        loggers: list[MetricLogger] | None = None,
    ):
        """``loggers``: extra metric sinks (:class:`train.loop.loggers.MetricLogger`), called with
        every epoch's flat rows beside metrics.jsonl, TensorBoard and W&B."""
        self.cfg = cfg
        self.dir = run_dir
        self.console = console or Console(stderr=True)
        self.is_writer = jax.process_index() == 0
        self.learner: Learner | None = None
        self._logs = EpochLog(cfg, run_dir, loggers or [], self.is_writer)
        self._unlock: Callable[[], None] | None = None

    def close(self) -> None:
        """Give back the run directory's lock (:meth:`train` does when it ends)."""
        unlock = self._unlock
        self._unlock = None
        if unlock is not None:
            unlock()

    # --- directories ------------------------------------------------------------------------

    @classmethod
    def create(
        cls,
        cfg: TrainConfig,
        run_dir: str | Path,
        config_file: Path | None = None,
        **kw: Unpack[RunOptions],
    ) -> Run:
        """A new run; refuses a directory that already has content, or that another
        process writes. ``config_file``: the config file it was given, copied into its
        inputs/. Where its first files cannot be written, none stay."""
        cfg.validate()
        run_dir = Path(run_dir)
        exists = (
            f"run directory {str(run_dir)!r} already exists and is not empty; "
            f"resume it with --resume {run_dir} or choose another --run-dir"
        )
        if has_content(run_dir):
            raise RunDirError(exists)
        barrier("run-create")  # every process checks before process 0 writes
        run = cls(cfg, run_dir, **kw)
        if run.is_writer:
            run._unlock = first_files(run_dir, cfg, config_file, exists)
        return run

    @classmethod
    def resume(
        cls, run_dir: str | Path, overrides: TrainConfig | None = None, **kw: Unpack[RunOptions]
    ) -> Run:
        """Reopen a run directory; ``overrides`` may only lengthen it or change cadences
        (after a divergence, also :data:`AFTER_DIVERGENCE`). A run stopped before its first
        checkpoint starts again from epoch 0."""
        run_dir = Path(run_dir)
        path = run_dir / "config.json"
        if not path.exists():
            raise RunDirError(f"--resume {str(run_dir)!r}: not a run directory (no config.json)")
        # the lock first: a second writer is refused before it reads or writes anything
        unlock = (
            take_lock(run_dir, f"resume with --resume {run_dir}")
            if jax.process_index() == 0
            else None
        )
        try:
            run = cls(resumed_config(run_dir, overrides), run_dir, **kw)
        except BaseException:
            if unlock is not None:
                unlock()
            raise
        run._unlock = unlock
        return run

    # --- training ---------------------------------------------------------------------------

    def train(
        self,
        stop_after_epochs: int | None = None,
        learner: Learner | None = None,
        time_limit_s: float | None = None,
    ) -> records.Summary:
        """Train to ``ppo.num_timesteps`` (or ``stop_after_epochs`` more epochs).

        Returns the summary (also written to ``summary.json``).

        ``learner`` reuses already compiled programs of a run with the same config.
        ``time_limit_s`` stops (resumably, with a checkpoint) after the first epoch that
        ends past that many seconds of this session. SIGTERM or SIGUSR1 (where called from
        the main thread) stops it after the epoch in progress, with a checkpoint, raising
        :class:`~train.loop.preemption.Preempted` (train.loop.preemption).
        """
        if self.is_writer and self._unlock is None:  # the run's one writer (run_dir.py)
            self._unlock = take_lock(self.dir, f"resume with --resume {self.dir}")
        loop: Session | None = None
        try:
            with StopSignals() as signals:
                loop = self._set_up(learner)
                self._epochs(loop, stop_after_epochs, time_limit_s, signals)
                return self._finish(loop)
        except Exception as err:
            disk = atomic.explain(err, self.dir)
            if not isinstance(disk, atomic.DiskError):
                raise
            clean_up_failed_save(self.dir)  # the last good checkpoint stays
            with contextlib.suppress(OSError):  # where the disk still takes it
                self._status(failed_state(disk), **(loop.status() if loop else {}), error=str(disk))
            raise disk from err
        finally:
            self.close()

    def _epochs(
        self,
        loop: Session,
        stop_after: int | None,
        time_limit_s: float | None,
        signals: StopSignals,
    ) -> None:
        """The epochs of :meth:`train`, each evaluated, logged and saved when due."""
        total = self.cfg.num_epochs
        last = total if stop_after is None else min(total, loop.epoch + stop_after)
        progress = records.TrainProgress(
            self.console,
            self.cfg.name,
            self.cfg.run.progress_every_s,
            self.is_writer,
            loop.steps(total),
            loop.steps(loop.epoch),
            loop.t_start,
            time_limit_s,
        )
        try:
            with progress.bar, progress.lines:
                while loop.epoch < last:
                    sps, metrics = self._train_epoch(loop)
                    is_last = loop.epoch == total
                    out_of_time = time_limit_s is not None and loop.session_s() > time_limit_s
                    signum, out_of_time = agree(loop.epoch, signals.signum, out_of_time)
                    final = is_last or out_of_time or signum is not None
                    # evaluated, logged and saved like any other; not evaluated when stopped
                    # by a signal (its grace period is short)
                    due = loop.eval_due(final) and (signum is None or is_last)
                    results = self._evaluate(loop) if due else []
                    self._log_epoch(loop, metrics, results, sps)
                    done = loop.steps(loop.epoch)
                    info = loop.shown
                    progress.update(loop.epoch, done, sps, results, loop.comparisons, info, final)
                    if loop.checkpoint_due(final):
                        loop.save()
                    if signum is not None and not is_last:
                        raise self._preempted(loop, signum)
                    self._report(loop, "running")
                    if out_of_time and not is_last:
                        self.console.log(f"time limit reached after epoch {loop.epoch}")
                        break
        finally:
            self._logs.close()

    def _preempted(self, loop: Session, signum: int) -> Preempted:
        """Stopped by a signal after the epoch it saved: the status and the error."""
        where = f"checkpoint {checkpoint.checkpoint_path(self.dir, loop.epoch)}"
        err = Preempted(signum, loop.epoch, f"{where}; resume with --resume {self.dir}")
        self.console.log(str(err))
        self._report(loop, "interrupted", signal=err.signal)
        return err


__all__ = ["Preempted", "Run", "RunDirError"]
