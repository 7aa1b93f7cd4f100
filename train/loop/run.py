"""One training run on disk: directory, logs, evaluation, checkpoints, resume, failures.

A run directory holds::

    config.json        the resolved configuration (written before anything compiles)
    status.json        running | finished | interrupted | diverged, with the epoch
    metrics.jsonl      one line per seed per epoch (training, evaluation, baseline)
    tb/seed_<k>/       TensorBoard event files
    checkpoints/<e>/   orbax checkpoints (full state; see train.store.checkpoint)
    summary.json       final figures per seed (when finished)
    learning_curve.png the learning curve (written by mecanum-train; train.loop.curve)

Rules: a run directory is never overwritten (an existing one is only *resumed*); a NaN
stops the run with a message and keeps the last good checkpoint; Ctrl-C writes a
checkpoint of the last completed epoch before exiting.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import jax
import numpy as np
from rich.console import Console

from mecanum_jax.config import ConfigError
from mecanum_jax.precision import set_matmul_precision
from train.config import TrainConfig, config_diff, load_train_config
from train.learner.periodic import Result, beats, compare
from train.learner.policy import check_compatible
from train.learner.ppo import Learner, first_device, to_host
from train.loop import aot
from train.loop import run_records as records
from train.loop.aot import first_runs_alone
from train.loop.distributed import barrier, restore_process
from train.loop.loggers import MetricLogger, TensorBoardLogger, WandbLogger
from train.loop.run_records import stacked, write_json
from train.loop.session import Session
from train.store import checkpoint, inputs

# Fields a resumed run may change: its length, logging and evaluation cadence.
RESUMABLE_CHANGES = {
    "ppo.num_timesteps",
    "run.eval_every",
    "run.checkpoint_every",
    "run.max_checkpoints",
    "run.wandb_project",
    "run.progress_every_s",
}
# Fields the compiled learner never reads: a learner built without them serves the run.
LOGGING_ONLY = {"run.wandb_project", "run.progress_every_s"}


class TrainingDiverged(RuntimeError):  # noqa: N818 (reads as the event it reports)
    """Loss or parameters went non-finite; the last good checkpoint was kept."""


class RunDirError(ValueError):
    """The run directory cannot be used as asked (exists, or is not a run)."""


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
        self._extra_loggers = list(loggers or [])
        self._writers: list[MetricLogger] = []

    # --- directories ------------------------------------------------------------------------

    @classmethod
    def create(cls, cfg: TrainConfig, run_dir: str | Path, **kw: Any) -> Run:
        """A new run; refuses a directory that already has content."""
        cfg.validate()
        run_dir = Path(run_dir)
        if run_dir.exists() and any(run_dir.iterdir()):
            raise RunDirError(
                f"run directory {str(run_dir)!r} already exists and is not empty; "
                f"resume it with --resume {run_dir} or choose another --run-dir"
            )
        barrier("run-create")  # every process checks before process 0 writes
        run = cls(cfg, run_dir, **kw)
        if run.is_writer:
            run_dir.mkdir(parents=True, exist_ok=True)
            write_json(run_dir / "config.json", cfg.to_dict())
            inputs.save_inputs(run_dir, cfg)
            run._status("created", epoch=0)
        return run

    @classmethod
    def resume(cls, run_dir: str | Path, overrides: TrainConfig | None = None, **kw: Any) -> Run:
        """Reopen a run directory; ``overrides`` may only lengthen it or change cadences."""
        run_dir = Path(run_dir)
        path = run_dir / "config.json"
        if not path.exists():
            raise RunDirError(f"--resume {str(run_dir)!r}: not a run directory (no config.json)")
        saved = load_train_config(path)
        cfg = saved
        if overrides is not None:
            changed = [f for f in config_diff(saved, overrides) if f not in RESUMABLE_CHANGES]
            if changed:
                raise ConfigError(
                    f"{changed[0]}: cannot change when resuming {str(run_dir)!r} "
                    f"(saved {_get(saved, changed[0])!r}, given {_get(overrides, changed[0])!r}); "
                    f"only {sorted(RESUMABLE_CHANGES)} may change"
                )
            cfg = overrides.validate()
        if checkpoint.latest_epoch(run_dir) is None:
            raise RunDirError(f"--resume {str(run_dir)!r}: no checkpoint to resume from")
        barrier("run-resume")  # every process has read it before process 0 rewrites it
        if cfg is not saved and jax.process_index() == 0:
            write_json(path, cfg.to_dict())
        return cls(cfg, run_dir, **kw)

    def _status(self, state: str, **extra: Any) -> None:
        if self.is_writer:
            write_json(self.dir / "status.json", {"state": state, "time": time.time(), **extra})

    # --- logging ----------------------------------------------------------------------------

    def _open_logs(self) -> None:
        if not self.is_writer:
            return
        self._writers = [TensorBoardLogger(self.dir, self.cfg.run.seeds), *self._extra_loggers]
        if self.cfg.run.wandb_project:
            self._writers.append(
                WandbLogger(self.cfg.run.wandb_project, self.dir, self.cfg.to_dict())
            )

    def _log(self, epoch: int, steps: int, walltime: float, rows: list[dict[str, Any]]) -> None:
        if not self.is_writer:
            return
        with (self.dir / "metrics.jsonl").open("a") as f:
            for row in rows:
                line = {"epoch": epoch, "env_steps": steps, "walltime": walltime, **row}
                f.write(json.dumps(records.jsonable(line)) + "\n")
        numbers = {
            seed: {
                k: v
                for k, v in records.flatten(row).items()
                if isinstance(v, int | float) and math.isfinite(v) and k != "seed"
            }
            for seed, row in zip(self.cfg.run.seeds, rows, strict=True)
        }
        for writer in self._writers:
            writer.log(steps, numbers)

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
        ends past that many seconds of this session.
        """
        loop = self._set_up(learner)
        total = self.cfg.num_epochs
        last = total if stop_after_epochs is None else min(total, loop.epoch + stop_after_epochs)
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
                    final = is_last or out_of_time  # evaluated, logged and saved like any other
                    results = self._evaluate(loop) if loop.eval_due(final) else []
                    self._log_epoch(loop, metrics, results, sps)
                    done = loop.steps(loop.epoch)
                    progress.update(loop.epoch, done, sps, results, loop.comparisons, loop.shown)
                    if loop.checkpoint_due(final):
                        loop.save()
                    if out_of_time and not is_last:
                        self.console.log(f"time limit reached after epoch {loop.epoch}")
                        break
        finally:
            for w in self._writers:
                w.close()
        return self._finish(loop)

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
        if checkpoint.latest_epoch(self.dir) is not None:
            self._restore(loop)
        loop.saved_epoch, loop.first_epoch = loop.epoch, loop.epoch + 1
        if jax.process_count() > 1:
            # compile before any process runs the epoch's collectives (see barrier)
            learner.compile_epoch(loop.state, loop.env_state)
            barrier("epoch-compiled")
        self._open_logs()
        self._status("running", epoch=loop.epoch)
        loop.baseline_job = _in_thread(learner.evaluate_baseline, first_device(loop.state))
        if first_runs_alone(learner):
            loop.baseline_job.result()
        loop.setup_s = time.time() - t_start
        return loop

    def _learner(self, learner: Learner | None) -> Learner:
        """``learner`` where it was built for this run's config, else a new one."""
        if learner is not None:
            differs = [f for f in config_diff(learner.cfg, self.cfg) if f not in LOGGING_ONLY]
            if differs:
                raise ValueError(f"learner was built for another config: {differs}")
        learner = learner or Learner(self.cfg)
        if learner.teacher is not None:
            self.console.log(f"imitating {learner.teacher.describe()} (ppo.distill)")
        return learner

    @staticmethod
    def _fresh(learner: Learner) -> tuple[Any, Any]:
        """The learner's fresh state; where the baseline runs first, its reset, epoch and
        evaluation compiled together before any of them runs
        (:func:`train.loop.aot.compile_together`)."""
        if first_runs_alone(learner) and aot.can_compile_together(learner):
            return learner.init(*aot.compile_together(learner))
        return learner.init()

    def _restore(self, loop: Session) -> None:
        """Continue from the newest checkpoint: state, robots, epoch, wall time, "beat at"."""
        learner = loop.learner
        host_state, host_env, meta = checkpoint.restore(
            self.dir, to_host(loop.state), to_host(loop.env_state), log=self.console.log
        )
        check_compatible(meta, learner.env, f"checkpoint in {str(self.dir)!r}")
        if jax.process_index() != 0:
            # the checkpoint holds process 0's robots and loop keys; the others saved
            # theirs beside it (train.loop.distributed.save_process)
            own = restore_process(self.dir, int(meta["epoch"]), host_state.key, host_env)
            if own is None:  # lost: this process's fresh robots and loop keys
                self.console.log(
                    f"[yellow]process {jax.process_index()}: no saved robots for epoch "
                    f"{meta['epoch']}; they restart from fresh resets[/]"
                )
                own = to_host(loop.state.key), to_host(loop.env_state)
            keys, host_env = own
            host_state = host_state.replace(key=keys)
        loop.state, loop.env_state = learner.place(host_state, host_env)
        loop.epoch, loop.walltime_before = int(meta["epoch"]), float(meta["walltime"])
        loop.beat_at = meta.get("beat_baseline", {})
        self.console.log(f"resumed {self.dir} at epoch {loop.epoch} ({meta['env_steps']:,} steps)")

    def _train_epoch(self, loop: Session) -> tuple[float, dict[str, np.ndarray]]:
        """One compiled epoch: ``(env steps/s, per-seed metrics)``. Ctrl-C saves the last
        completed epoch; a non-finite loss or parameter saves it and stops the run."""
        t_epoch = time.time()
        try:
            new_state, new_env, metrics = loop.learner.epoch(loop.state, loop.env_state)
            metrics = {k: v[0] for k, v in to_host(metrics).items()}  # (S,)
        except KeyboardInterrupt:
            self.console.log(f"interrupted: saving epoch {loop.epoch}")
            loop.save()
            self._status("interrupted", epoch=loop.epoch)
            raise
        if loop.baseline is None:
            loop.baseline = loop.baseline_job.result()
            beside = "" if first_runs_alone(loop.learner) else ", with the baseline's evaluation"
            epoch_s = time.time() - t_epoch
            self.console.log(f"set-up {loop.setup_s:.0f} s; first epoch{beside}: {epoch_s:.0f} s")
        if not np.all(metrics["finite"] > 0):
            seeds = self.cfg.run.seeds
            bad = [s for s, f in zip(seeds, metrics["finite"], strict=True) if not f]
            loop.save()
            rows = records.seed_rows(self.cfg.run.seeds, metrics, {}, loop.baseline.values)
            self._log(loop.epoch + 1, loop.steps(loop.epoch + 1), loop.walltime(), rows)
            self._status("diverged", epoch=loop.epoch, seeds=bad)
            raise TrainingDiverged(
                f"non-finite loss or parameters in epoch {loop.epoch + 1} for seeds {bad}; "
                f"stopped, last good checkpoint: epoch {loop.epoch} "
                f"in {self.dir / 'checkpoints'}"
            )
        loop.state, loop.env_state = new_state, new_env
        loop.epoch += 1
        sps = loop.steps(1) * len(self.cfg.run.seeds) / (time.time() - t_epoch)
        return sps, metrics

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
        self._log(loop.epoch, loop.steps(loop.epoch), loop.walltime(), rows)
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
        self._status("finished" if done else "stopped", epoch=loop.epoch)
        return summary


def _in_thread(fn: Callable[..., Result], *args: Any) -> Future[Result]:
    """``fn(*args)`` begun in a thread of its own."""
    pool = ThreadPoolExecutor(1, thread_name_prefix="baseline-eval")
    job = pool.submit(fn, *args)
    pool.shutdown(wait=False)
    return job


def _get(cfg: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


__all__ = ["Run", "RunDirError", "TrainingDiverged"]
