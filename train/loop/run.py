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
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import jax
import numpy as np
from rich.console import Console

from mecanum_jax import atomic
from mecanum_jax.precision import set_matmul_precision
from train.config import TrainConfig
from train.config_loading import config_diff
from train.learner.periodic import Result, beats, compare
from train.learner.ppo import Learner
from train.learner.transfer import first_device, to_host
from train.loop import aot, divergence, warm_start
from train.loop import run_records as records
from train.loop.aot import first_runs_alone
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
from train.loop.run_records import stacked, write_json
from train.loop.session import Session
from train.store import checkpoint

# Fields the compiled learner never reads: a learner built without them serves the run.
LOGGING_ONLY = {"run.wandb_project", "run.progress_every_s"}


class TrainingDiverged(RuntimeError):  # noqa: N818 (reads as the event it reports)
    """Loss or parameters went non-finite; the last good checkpoint was kept."""


class Run:
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
        cls, cfg: TrainConfig, run_dir: str | Path, config_file: Path | None = None, **kw: Any
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
    def resume(cls, run_dir: str | Path, overrides: TrainConfig | None = None, **kw: Any) -> Run:
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

    def _status(self, state: str, **extra: Any) -> None:
        if self.is_writer:
            write_json(self.dir / "status.json", {"state": state, "time": time.time(), **extra})

    def _report(self, loop: Session, state: str, **extra: Any) -> None:
        """status.json: ``state``, the epoch reached and the last checkpoint."""
        self._status(state, **loop.status(), **extra)

    # --- training ---------------------------------------------------------------------------

    def train(
        self,
        stop_after_epochs: int | None = None,
        learner: Learner | None = None,
        time_limit_s: float | None = None,
    ) -> dict[str, Any]:
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

    # --- the steps of train ------------------------------------------------------------------

    def _set_up(self, learner: Learner | None) -> Session:
        """The learner; its state, fresh or restored; the logs; and the baseline's
        evaluation, begun in a thread beside the first epoch's compilation (where
        :func:`first_runs_alone`: finished first, and compiled together with the reset and
        the epoch, :func:`train.loop.aot.compile_together`). The checkpoint manager opens at
        the first save."""
        set_matmul_precision(self.cfg.run.matmul_precision)  # before anything is traced
        t_start = time.time()
        learner = self.learner = self._learner(learner)
        loop = Session(self.cfg, self.dir, self.is_writer, learner, t_start, *self._fresh(learner))
        if self.is_writer and (debris := checkpoint.remove_partial_saves(self.dir)):
            self.console.log(f"removed a checkpoint cut short: {', '.join(map(str, debris))}")
        if checkpoint.latest_epoch(self.dir) is not None:
            loop.restore(self.console.log)
        loop.saved_epoch, loop.first_epoch = loop.epoch, loop.epoch + 1
        if self.is_writer and (
            dropped := records.keep_rows(self.dir / "metrics.jsonl", loop.epoch)
        ):
            self.console.log(f"metrics.jsonl: {dropped} rows after epoch {loop.epoch} dropped")
        if jax.process_count() > 1:
            # compile before any process runs the epoch's collectives (see barrier)
            learner.compile_epoch(loop.state, loop.env_state)
            barrier("epoch-compiled")
        self._logs.open(loop.steps(loop.epoch) + 1 if (self.dir / "tb").exists() else None)
        self._report(loop, "running")
        loop.baseline_job = _in_thread(learner.evaluate_baseline, first_device(loop.state))
        if first_runs_alone(learner):
            loop.baseline_job.result()
        loop.setup_s = time.time() - t_start
        return loop

    def _learner(self, learner: Learner | None) -> Learner:
        """``learner`` where it was built for this run's config, else a new one (its
        programs kept on disk for the next start: train/loop/warm_start.py)."""
        if learner is not None:
            differs = [f for f in config_diff(learner.cfg, self.cfg) if f not in LOGGING_ONLY]
            if differs:
                raise ValueError(f"learner was built for another config: {differs}")
        return learner or warm_start.attach(Learner(self.cfg), self.console.log)

    @staticmethod
    def _fresh(learner: Learner) -> tuple[Any, Any]:
        """The learner's fresh state; where the baseline runs first, its reset, epoch and
        evaluation compiled together before any of them runs
        (:func:`train.loop.aot.compile_together`)."""
        if first_runs_alone(learner) and aot.can_compile_together(learner):
            return learner.init(*aot.compile_together(learner))
        return learner.init()

    def _train_epoch(self, loop: Session) -> tuple[float, dict[str, np.ndarray]]:
        """One compiled epoch: ``(env steps/s, per-seed metrics)``. Ctrl-C saves the last
        completed epoch; a non-finite loss or parameter saves it and stops the run."""
        t_epoch = time.time()
        try:
            new_state, new_env, on_devices = loop.learner.epoch(loop.state, loop.env_state)
            metrics: dict[str, np.ndarray] = {k: v[0] for k, v in to_host(on_devices).items()}
        except KeyboardInterrupt:
            self.console.log(f"interrupted: saving epoch {loop.epoch}")
            loop.save()
            self._report(loop, "interrupted", signal="SIGINT")
            raise
        if loop.baseline is None:
            loop.baseline = loop.baseline_job.result()
            beside = "" if first_runs_alone(loop.learner) else ", with the baseline's evaluation"
            epoch_s = time.time() - t_epoch
            self.console.log(f"set-up {loop.setup_s:.0f} s; first epoch{beside}: {epoch_s:.0f} s")
        if bad := divergence.bad_seeds(self.cfg.run.seeds, metrics):
            self._diverged(loop, metrics, new_state, bad)
        loop.state, loop.env_state = new_state, new_env
        loop.epoch += 1
        sps = loop.steps(1) * len(self.cfg.run.seeds) / (time.time() - t_epoch)
        return sps, metrics

    def _diverged(self, loop: Session, metrics: dict[str, Any], state: Any, bad: list[int]) -> None:
        """The epoch after ``loop.epoch`` went non-finite (seeds ``bad``, indices): the last
        good state saved (the bad one never is), the bad epoch's row logged, the status,
        and the error naming the first non-finite quantity."""
        seeds = self.cfg.run.seeds
        what = divergence.first_non_finite(seeds, metrics, state, bad[0])
        loop.save()
        assert loop.baseline is not None  # awaited after the first epoch
        rows = records.seed_rows(seeds, metrics, {}, loop.baseline.values)
        self._logs.log(loop.epoch + 1, loop.steps(loop.epoch + 1), loop.walltime(), rows)
        path = checkpoint.checkpoint_path(self.dir, loop.epoch)
        text = divergence.message(loop.epoch + 1, what, loop.saved_epoch, self.dir, path)
        seed_list = [seeds[i] for i in bad]
        self._report(loop, "diverged", diverged_epoch=loop.epoch + 1, seeds=seed_list, error=text)
        raise TrainingDiverged(text)

    def _evaluate(self, loop: Session) -> list[Result]:
        """Each seed's policy on the held-out episodes, compared with the baseline; records
        the first epoch each seed beats it."""
        assert loop.baseline is not None  # awaited after the first epoch
        results = loop.learner.evaluate(first_device(loop.state))
        loop.results = results
        loop.comparisons = [compare(r, loop.baseline) for r in results]
        for seed, comp in zip(self.cfg.run.seeds, loop.comparisons, strict=True):
            if str(seed) not in loop.beat_at and beats(comp):
                loop.beat_at[str(seed)] = {
                    "epoch": loop.epoch,
                    "env_steps": loop.steps(loop.epoch),
                    "walltime": loop.walltime(),
                }
        return results

    def _log_epoch(
        self, loop: Session, metrics: dict[str, np.ndarray], results: list[Result], sps: float
    ) -> None:
        assert loop.baseline is not None
        evals = stacked(results) if results else {}
        comps = loop.comparisons if results else []
        rows = records.seed_rows(
            self.cfg.run.seeds, metrics, evals, loop.baseline.values, sps, comps
        )
        self._logs.log(loop.epoch, loop.steps(loop.epoch), loop.walltime(), rows)
        if evals:
            loop.shown = records.shown(evals["randomized"], loop.baseline.values["randomized"])

    def _finish(self, loop: Session) -> dict[str, Any]:
        """The last checkpoint, the summary and the final status."""
        loop.save()
        if loop.baseline is None:  # no epoch ran (a finished run resumed)
            loop.baseline = loop.baseline_job.result()
        evals = stacked(loop.results) if loop.results else {}
        devices = self.learner.n_devices * self.learner.n_processes if self.learner else None
        summary = records.summary(
            self.cfg,
            self.dir,
            loop.epoch,
            loop.walltime(),
            evals,
            loop.comparisons,
            loop.baseline.values,
            loop.beat_at,
            loop.t_start,
            devices,
        )
        if self.is_writer:
            write_json(self.dir / "summary.json", summary)
        done = loop.epoch >= self.cfg.num_epochs
        self._report(loop, "finished" if done else "stopped")
        return summary


def _in_thread(fn: Callable[..., Result], *args: Any) -> Future[Result]:
    """``fn(*args)`` begun in a thread of its own."""
    pool = ThreadPoolExecutor(1, thread_name_prefix="baseline-eval")
    job = pool.submit(fn, *args)
    pool.shutdown(wait=False)
    return job


__all__ = ["Preempted", "Run", "RunDirError", "TrainingDiverged"]
