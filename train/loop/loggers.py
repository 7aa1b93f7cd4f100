"""Where a run's per-epoch metrics go besides ``metrics.jsonl``: TensorBoard always, and
Weights & Biases when ``run.wandb_project`` names a project (optional; ``pip install
wandb``). Each sink takes one flat ``{name: number}`` row per training seed, at the run's
env-step count; a user can add their own through ``Run(..., loggers=[...])``.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from mecanum_jax import atomic
from train.loop import run_records as records

if TYPE_CHECKING:
    from train.config import TrainConfig


class MetricLogger(Protocol):
    """A metrics sink: ``log`` once per epoch, ``close`` at the end of training."""

    def log(self, steps: int, rows: dict[int, dict[str, float]]) -> None: ...

    def close(self) -> None: ...


class TensorBoardLogger:
    """TensorBoard event files, one folder per seed: ``<run>/tb/seed_<s>``.

    tensorboardX's own thread writes them and flushes every :attr:`FLUSH_S` seconds and at
    :meth:`close`; :meth:`log` only queues, so the training loop never waits on it. (A
    flush after each epoch's ~140 scalars waited for that thread through a queue of 10:
    0.13–0.25 s on the 2-core CPU while another Python thread ran, 3.7 s a call in a
    profiled GPU run; docs/profiling.md.)"""

    FLUSH_S = 10.0
    QUEUE = 4096  # events waiting for the writer thread before add_scalar would block

    def __init__(self, run_dir: Path, seeds: tuple[int, ...], purge_step: int | None = None):
        """``purge_step``: a resumed run's first step; TensorBoard hides the events of
        earlier sessions from that step on (those of epochs after the checkpoint)."""
        from tensorboardX import SummaryWriter

        self._writers = {
            s: SummaryWriter(
                str(run_dir / "tb" / f"seed_{s}"),
                purge_step=purge_step,
                max_queue=self.QUEUE,
                flush_secs=self.FLUSH_S,
            )
            for s in seeds
        }

    def log(self, steps: int, rows: dict[int, dict[str, float]]) -> None:
        for seed, row in rows.items():
            writer = self._writers[seed]
            for key, value in row.items():
                writer.add_scalar(key, value, steps)

    def close(self) -> None:
        for writer in self._writers.values():
            writer.close()


class WandbLogger:
    """One W&B run per run directory (its id derived from the directory, so a resumed run
    continues the same W&B run); each seed's metrics under ``seed_<s>/``."""

    def __init__(self, project: str, run_dir: Path, config: Mapping[str, object]):
        import wandb

        run_id = hashlib.sha1(str(run_dir.resolve()).encode()).hexdigest()[:16]
        self._run = wandb.init(
            project=project,
            name=run_dir.name,
            id=run_id,
            resume="allow",
            dir=str(run_dir),
            config=config,
        )

    def log(self, steps: int, rows: dict[int, dict[str, float]]) -> None:
        flat = {f"seed_{seed}/{k}": v for seed, row in rows.items() for k, v in row.items()}
        self._run.log(flat, step=steps)

    def close(self) -> None:
        self._run.finish()


class EpochLog:
    """A run's per-epoch log, written by process 0 alone (``enabled``): metrics.jsonl, one
    line per seed, and the sinks: TensorBoard, W&B where ``run.wandb_project`` names a
    project, and the user's ``extra`` loggers."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, extra: list[MetricLogger], enabled: bool):
        self.cfg, self.dir, self.enabled = cfg, run_dir, enabled
        self._extra = list(extra)
        self.sinks: list[MetricLogger] = []

    def open(self, purge_step: int | None) -> None:
        """Open the sinks; ``purge_step``: a resumed run's (:class:`TensorBoardLogger`)."""
        if not self.enabled:
            return
        self.sinks = [TensorBoardLogger(self.dir, self.cfg.run.seeds, purge_step), *self._extra]
        if self.cfg.run.wandb_project:
            self.sinks.append(WandbLogger(self.cfg.run.wandb_project, self.dir, self.cfg.to_dict()))

    def log(
        self, epoch: int, steps: int, walltime: float, rows: Sequence[Mapping[str, object]]
    ) -> None:
        if not self.enabled:
            return
        lines = [{"epoch": epoch, "env_steps": steps, "walltime": walltime, **r} for r in rows]
        text = "".join(json.dumps(records.jsonable(line)) + "\n" for line in lines)
        atomic.append_text(self.dir / "metrics.jsonl", text)  # the epoch's rows whole, or none
        numbers = {
            seed: {
                k: v
                for k, v in records.flatten(row).items()
                if isinstance(v, int | float) and math.isfinite(v) and k != "seed"
            }
            for seed, row in zip(self.cfg.run.seeds, rows, strict=True)
        }
        for sink in self.sinks:
            sink.log(steps, numbers)

    def close(self) -> None:
        for sink in self.sinks:
            sink.close()


__all__ = ["EpochLog", "MetricLogger", "TensorBoardLogger", "WandbLogger"]
