"""One training run on disk: directory, logs, evaluation, checkpoints, resume, failures.

A run directory holds::

    config.json        the resolved configuration (written before anything compiles)
    status.json        running | finished | interrupted | diverged, with the epoch
    metrics.jsonl      one line per seed per epoch (training, evaluation, baseline)
    tb/seed_<k>/       TensorBoard event files
    checkpoints/<e>/   orbax checkpoints (full state; see train.checkpoint)
    summary.json       final figures per seed (when finished)
    learning_curve.png the learning curve (written by mecanum-train; train.curve)

Rules: a run directory is never overwritten (an existing one is only *resumed*); a NaN
stops the run with a message and keeps the last good checkpoint; Ctrl-C writes a
checkpoint of the last completed epoch before exiting.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from rich.console import Console

from mecanum_jax.config import ConfigError
from mecanum_jax.precision import set_matmul_precision
from mecanum_jax.sim.description import fingerprint
from train import aot, baseline_cache, checkpoint
from train import run_records as records
from train.aot import first_runs_alone
from train.config import TrainConfig, config_diff, load_train_config
from train.distributed import barrier, restore_process, save_process
from train.loggers import MetricLogger, TensorBoardLogger, WandbLogger
from train.periodic import Result, beats, compare
from train.ppo import Learner, first_device, to_host
from train.run_records import stacked, write_json

# Fields a resumed run may change: its length, logging/evaluation cadence, baseline cache.
RESUMABLE_CHANGES = {
    "ppo.num_timesteps",
    "run.eval_every",
    "run.checkpoint_every",
    "run.max_checkpoints",
    "run.wandb_project",
    "run.progress_every_s",
    "run.baseline_cache",
}
# Fields the compiled learner never reads: a learner built without them serves the run.
LOGGING_ONLY = {"run.wandb_project", "run.progress_every_s", "run.baseline_cache"}


class TrainingDiverged(RuntimeError):  # noqa: N818 (reads as the event it reports)
    """Loss or parameters went non-finite; the last good checkpoint was kept."""


class RunDirError(ValueError):
    """The run directory cannot be used as asked (exists, or is not a run)."""


@dataclasses.dataclass
class _Loop:
    """What one call of :meth:`Run.train` carries from epoch to epoch."""

    run: Run
    learner: Learner
    t_start: float
    state: Any
    env_state: Any
    epoch: int = 0
    walltime_before: float = 0.0
    beat_at: dict[str, Any] = dataclasses.field(default_factory=dict)
    saved_epoch: int = 0
    first_epoch: int = 1  # this session's
    mgr: Any = None
    baseline_job: Any = None
    baseline_from: str = ""  # "cache", "computed" or "off" (train.baseline_cache)
    baseline: Result | None = None
    setup_s: float = 0.0
    results: list[Result] = dataclasses.field(default_factory=list)
    comparisons: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    shown: str = ""  # the last evaluation's figures, kept on the progress line

    def steps(self, epochs: int) -> int:
        """Environment steps per seed in ``epochs`` epochs."""
        cfg = self.run.cfg
        return epochs * cfg.steps_per_iteration * cfg.run.epoch_iterations

    def session_s(self) -> float:
        return time.time() - self.t_start

    def walltime(self) -> float:
        """Wall time of the run: this session (model, compilation, the baseline's
        evaluation included) plus the sessions before a resume."""
        return self.walltime_before + self.session_s()

    def eval_due(self, final: bool) -> bool:
        """Evaluate this epoch: on the period, on this session's first (a first figure soon
        after the start), and on the epoch a run ends or stops at."""
        due = self.epoch % self.run.cfg.run.eval_every == 0
        return due or self.epoch == self.first_epoch or final

    def checkpoint_due(self, final: bool) -> bool:
        """Checkpoint this epoch: on the period, and on the epoch a run ends or stops at."""
        return self.epoch % self.run.cfg.run.checkpoint_every == 0 or final

    def meta(self) -> dict[str, Any]:
        env = self.learner.env
        return {
            "config": self.run.cfg.to_dict(),
            "robot": env.desc.robot.name,
            "robot_fingerprint": fingerprint(env.desc),
            "observation_layout": [list(x) for x in env.layout],
            "privileged_layout": [list(x) for x in env.privileged_layout],
            "action_size": env.action_size,
            "devices": self.learner.n_devices,
            "epoch": self.epoch,
            "env_steps": self.steps(self.epoch),
            "walltime": self.walltime(),
            "beat_baseline": self.beat_at,
        }

    def save(self) -> None:
        """Checkpoint the current epoch, unless it is saved already."""
        if self.epoch != self.saved_epoch:
            ts, es = self.state, self.env_state
            if self.run.is_writer:  # the manager opened at the first save (after a restore)
                self.mgr = self.mgr or checkpoint.manager(
                    self.run.dir, self.run.cfg.run.max_checkpoints
                )
                checkpoint.save(self.mgr, self.epoch, to_host(ts), to_host(es), self.meta())
            elif jax.process_count() > 1:  # only its keys and robots are its own
                keep = self.run.cfg.run.max_checkpoints
                save_process(self.run.dir, self.epoch, to_host(ts.key), to_host(es), keep)
        self.saved_epoch = self.epoch


class Run:
    """A training run bound to its directory. ``Run.create`` or ``Run.resume``, then ``train``."""

    def __init__(
        self,
        cfg: TrainConfig,
        run_dir: Path,
        console: Console | None = None,
        loggers: list[MetricLogger] | None = None,
    ):
        """``loggers``: extra metric sinks (:class:`train.loggers.MetricLogger`), called with
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

    def _set_up(self, learner: Learner | None) -> _Loop:
        """The learner, fresh or restored state, logs, and the baseline's evaluation: read
        back (train.baseline_cache) or begun in a thread, beside the first epoch's
        compilation (where :func:`first_runs_alone`: finished first, compiled together with
        the reset and the epoch, ``train.aot.compile_together``). The checkpoint manager
        opens at the first save."""
        cfg = self.cfg
        set_matmul_precision(cfg.run.matmul_precision)  # before anything is traced
        t_start = time.time()
        if learner is not None:
            differs = [f for f in config_diff(learner.cfg, cfg) if f not in LOGGING_ONLY]
            if differs:
                raise ValueError(f"learner was built for another config: {differs}")
        learner = self.learner = learner or Learner(cfg)
        if learner.teacher is not None:
            self.console.log(f"imitating {learner.teacher.describe()} (ppo.distill)")
        alone = first_runs_alone(learner)
        together = alone and aot.can_compile_together(learner)
        state, env_state = (
            learner.init(*aot.compile_together(learner)) if together else learner.init()
        )
        loop = _Loop(self, learner, t_start, state, env_state)
        if checkpoint.latest_epoch(self.dir) is not None:
            self._restore(loop)
        loop.saved_epoch, loop.first_epoch = loop.epoch, loop.epoch + 1
        if jax.process_count() > 1:
            # compile before any process runs the epoch's collectives (see barrier)
            learner.compile_epoch(loop.state, loop.env_state)
            barrier("epoch-compiled")
        self._open_logs()
        self._status("running", epoch=loop.epoch)
        in_place = alone and not together  # on a hit, its program traced all the same
        loop.baseline_job, loop.baseline_from = baseline_cache.start(
            learner, first_device(loop.state), cfg.run.baseline_cache, self.console.log, in_place
        )
        if alone:
            loop.baseline_job.result()
        loop.setup_s = time.time() - t_start
        return loop

    def _restore(self, loop: _Loop) -> None:
        """Continue from the newest checkpoint: state, robots, epoch, wall time, "beat at"."""
        learner = loop.learner
        host_state, host_env, meta = checkpoint.restore(
            self.dir, to_host(loop.state), to_host(loop.env_state), log=self.console.log
        )
        checkpoint.check_compatible(meta, learner.env, f"checkpoint in {str(self.dir)!r}")
        if jax.process_index() != 0:
            # the checkpoint holds process 0's robots and loop keys; the others saved
            # theirs beside it (train.distributed.save_process)
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

    def _train_epoch(self, loop: _Loop) -> tuple[float, dict[str, np.ndarray]]:
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
            alone = first_runs_alone(loop.learner) or loop.baseline_from == "cache"
            beside = "" if alone else ", with the baseline's evaluation"
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

    def _evaluate(self, loop: _Loop) -> list[Result]:
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
        self, loop: _Loop, metrics: dict[str, np.ndarray], results: list[Result], sps: float
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

    def _finish(self, loop: _Loop) -> dict[str, Any]:
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


def _get(cfg: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


__all__ = ["Run", "RunDirError", "TrainingDiverged"]
