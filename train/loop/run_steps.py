"""The steps of a training run's :meth:`~train.loop.run.Run.train`: the set-up (the learner,
its state fresh or restored, the logs, the baseline's evaluation begun), one compiled
epoch with its NaN guard (train.loop.divergence), the epoch's evaluation and log rows,
the finish (the last checkpoint, summary.json), and status.json after each.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np
from rich.console import Console

from mecanum_jax.tracing import prepare_tracing
from train.config import TrainConfig
from train.config_loading import config_diff
from train.learner.periodic import Result, beats, compare
from train.learner.ppo import Learner
from train.learner.shapes import Placed
from train.learner.state import TrainingState
from train.learner.transfer import first_device, to_host
from train.loop import aot, divergence, warm_start
from train.loop import run_records as records
from train.loop.aot import first_runs_alone
from train.loop.distributed import barrier
from train.loop.divergence import TrainingDiverged
from train.loop.loggers import EpochLog
from train.loop.run_records import stacked, write_json
from train.loop.session import Session
from train.store import checkpoint

# Fields the compiled learner never reads: a learner built without them serves the run.
LOGGING_ONLY = {"run.wandb_project", "run.progress_every_s"}


class RunSteps:
    """The steps of :meth:`train.loop.run.Run.train` (a subclass), on the run's config,
    directory, console and logs."""

    cfg: TrainConfig
    dir: Path
    console: Console
    is_writer: bool
    learner: Learner | None
    _logs: EpochLog

    def _status(self, state: str, **extra: object) -> None:
        if self.is_writer:
            write_json(self.dir / "status.json", {"state": state, "time": time.time(), **extra})

    def _report(self, loop: Session, state: str, **extra: object) -> None:
        """status.json: ``state``, the epoch reached and the last checkpoint."""
        self._status(state, **loop.status(), **extra)

    # --- the steps of train ------------------------------------------------------------------

    def _set_up(self, learner: Learner | None) -> Session:
        """The learner; its state, fresh or restored; the logs; and the baseline's
        evaluation, begun in a thread beside the first epoch's compilation, which set-up
        does (:func:`train.loop.aot.begin_baseline`; where
        :func:`first_runs_alone`: finished first, and compiled together with the reset and
        the epoch, :func:`train.loop.aot.compile_together`). The checkpoint manager opens at
        the first save."""
        prepare_tracing(self.cfg.run.matmul_precision)  # before anything is traced
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
        loop.baseline_job = job = aot.begin_baseline(learner, loop.state, loop.env_state)
        if first_runs_alone(learner):
            job.result()
        loop.setup_s = time.time() - t_start
        return loop

    def _learner(self, learner: Learner | None) -> Learner:
        """``learner`` where it was built for this run's config, else a new one (its
        programs kept on disk for the next start: train/loop/warm_start.py)."""
        if learner is not None:
            differs = [f for f in config_diff(learner.cfg, self.cfg) if f not in LOGGING_ONLY]
            if differs:
                raise ValueError(f"learner was built for another config: {differs}")
            return learner
        ahead = warm_start.load_ahead(self.cfg)  # loads while the learner is built
        return warm_start.attach(Learner(self.cfg), self.console.log, ahead)

    @staticmethod
    def _fresh(learner: Learner) -> Placed:
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
            assert loop.baseline_job is not None  # begun at set-up
            loop.baseline = loop.baseline_job.result()
            beside = "" if first_runs_alone(loop.learner) else ", with the baseline's evaluation"
            epoch_s = time.time() - t_epoch
            self.console.log(f"set-up {loop.setup_s:.0f} s; first epoch{beside}: {epoch_s:.0f} s")
        if bad := divergence.bad_seeds(self.cfg.run.seeds, metrics):
            self._diverged(loop, metrics, new_state, bad)
        env = self.cfg.env
        if not loop.path_warned and (
            why := divergence.path_outgrown(
                metrics, env.path_tau, env.reward.path_lin, loop.learner.env.constants.command_scale
            )
        ):
            self.console.log(f"warning: epoch {loop.epoch + 1}: {why}")
            loop.path_warned = True
        loop.state, loop.env_state = new_state, new_env
        loop.epoch += 1
        sps = loop.steps(1) * len(self.cfg.run.seeds) / (time.time() - t_epoch)
        return sps, metrics

    def _diverged(
        self, loop: Session, metrics: dict[str, np.ndarray], state: TrainingState, bad: list[int]
    ) -> None:
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

    def _finish(self, loop: Session) -> records.Summary:
        """The last checkpoint, the summary and the final status."""
        loop.save()
        if loop.baseline is None:  # no epoch ran (a finished run resumed)
            assert loop.baseline_job is not None  # begun at set-up
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


__all__ = ["LOGGING_ONLY", "RunSteps", "TrainingDiverged"]
