"""One session of a training run (:class:`~train.loop.run.Run`): what it carries from
epoch to epoch, when it evaluates and checkpoints, the checkpoint it writes and the one it
resumes from."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING

import jax

from mecanum_jax.sim.description import fingerprint
from train.config import TrainConfig
from train.learner.periodic import Comparison, Result
from train.learner.policy import check_compatible
from train.learner.ppo import Learner
from train.learner.shapes import PackedEnv
from train.learner.state import TrainingState
from train.learner.transfer import to_host
from train.loop.distributed import restore_process, save_process
from train.store import checkpoint

if TYPE_CHECKING:
    import orbax.checkpoint as ocp


@dataclasses.dataclass
class Session:
    """What one call of :meth:`train.loop.run.Run.train` carries from epoch to epoch: the
    run's config and directory, the learner and its state, and the epoch's figures."""

    cfg: TrainConfig
    dir: Path
    is_writer: bool  # process 0: writes the checkpoints
    learner: Learner
    t_start: float
    state: TrainingState
    env_state: PackedEnv
    epoch: int = 0
    walltime_before: float = 0.0
    # per seed, the epoch, env steps and wall time it first beat the baseline at
    beat_at: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    saved_epoch: int = 0
    first_epoch: int = 1  # this session's
    mgr: ocp.CheckpointManager | None = None
    baseline_job: Future[Result] | None = None  # the baseline's evaluation, begun at set-up
    baseline: Result | None = None
    setup_s: float = 0.0
    results: list[Result] = dataclasses.field(default_factory=list)
    comparisons: list[Comparison] = dataclasses.field(default_factory=list)
    shown: str = ""  # the last evaluation's figures, kept on the progress line
    path_warned: bool = False  # divergence.path_outgrown said so once

    def steps(self, epochs: int) -> int:
        """Environment steps per seed in ``epochs`` epochs."""
        cfg = self.cfg
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
        due = self.epoch % self.cfg.run.eval_every == 0
        return due or self.epoch == self.first_epoch or final

    def checkpoint_due(self, final: bool) -> bool:
        """Checkpoint this epoch: on the period, and on the epoch a run ends or stops at."""
        return self.epoch % self.cfg.run.checkpoint_every == 0 or final

    def meta(self) -> dict[str, object]:
        env = self.learner.env
        return {
            "config": self.cfg.to_dict(),
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

    def restore(self, log: Callable[[str], None]) -> None:
        """Continue from the newest checkpoint: state, robots, epoch, wall time, "beat at"."""
        learner = self.learner
        host_state, host_env, meta = checkpoint.restore(
            self.dir, to_host(self.state), to_host(self.env_state), log=log
        )
        check_compatible(meta, learner.env, f"checkpoint in {str(self.dir)!r}")
        if jax.process_index() != 0:
            # the checkpoint holds process 0's robots and loop keys; the others saved
            # theirs beside it (train.loop.distributed.save_process)
            own = restore_process(self.dir, int(meta["epoch"]), host_state.key, host_env)
            if own is None:  # lost: this process's fresh robots and loop keys
                log(
                    f"[yellow]process {jax.process_index()}: no saved robots for epoch "
                    f"{meta['epoch']}; they restart from fresh resets[/]"
                )
                own = to_host(self.state.key), to_host(self.env_state)
            keys, host_env = own
            host_state = host_state.replace(key=keys)
        self.state, self.env_state = learner.place(host_state, host_env)
        self.epoch, self.walltime_before = int(meta["epoch"]), float(meta["walltime"])
        self.beat_at = meta.get("beat_baseline", {})
        log(f"resumed {self.dir} at epoch {self.epoch} ({meta['env_steps']:,} steps)")

    def status(self) -> dict[str, object]:
        """status.json's figures besides the state: the epoch reached, its env steps per
        seed, the run's length in epochs, and the last checkpoint (``None`` before one)."""
        last = None
        if self.saved_epoch > 0:  # restored or saved: a checkpoint of that epoch exists
            path = checkpoint.checkpoint_path(self.dir, self.saved_epoch)
            last = {
                "epoch": self.saved_epoch,
                "env_steps": self.steps(self.saved_epoch),
                "path": str(path),
            }
        return {
            "epoch": self.epoch,
            "env_steps": self.steps(self.epoch),
            "epochs": self.cfg.num_epochs,
            "last_checkpoint": last,
        }

    def save(self) -> None:
        """Checkpoint the current epoch, unless it is saved already."""
        if self.epoch != self.saved_epoch:
            ts, es = self.state, self.env_state
            if self.is_writer:  # the manager opened at the first save (after a restore)
                self.mgr = self.mgr or checkpoint.manager(self.dir, self.cfg.run.max_checkpoints)
                checkpoint.save(self.mgr, self.epoch, to_host(ts), to_host(es), self.meta())
            elif jax.process_count() > 1:  # only its keys and robots are its own
                keep = self.cfg.run.max_checkpoints
                save_process(self.dir, self.epoch, to_host(ts.key), to_host(es), keep)
        self.saved_epoch = self.epoch


__all__ = ["Session"]
