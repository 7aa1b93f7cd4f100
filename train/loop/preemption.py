"""Stopping a run cleanly on a cluster's stop signal (:meth:`train.loop.run.Run.train`).

SLURM and Kubernetes stop a job with SIGTERM, then SIGKILL after a grace period (SLURM's
``KillWait``, Kubernetes' ``terminationGracePeriodSeconds``: 30 s by default); SLURM's
``--signal=USR1@120`` sends SIGUSR1 that long before the time limit. While a run trains,
either signal only sets a flag: the epoch in progress (XLA cannot be interrupted) finishes,
is logged and checkpointed, status.json says ``interrupted``, and
:class:`Preempted` (a :class:`KeyboardInterrupt`, so whatever handles Ctrl-C handles it)
carries the exit code ``128 + signal``: 143 for SIGTERM, 138 for SIGUSR1.

In a multi-process run every process must stop after the same epoch: each writes its own
part of the checkpoint (train.loop.distributed), and one that trained on alone would wait
in the next epoch's collectives for peers that left. :func:`agree` makes the decision
common after every epoch, through the coordination service.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType

import jax

from train.loop.distributed import barrier, coordination_client

STOP_SIGNALS = (signal.SIGTERM, signal.SIGUSR1)


class Preempted(KeyboardInterrupt):
    """A stop signal arrived; the run checkpointed its last epoch and stopped, resumably."""

    def __init__(self, signum: int, epoch: int, where: str):
        self.signum = signum
        self.signal = signal.Signals(signum).name
        self.epoch = epoch
        self.exit_code = 128 + signum
        super().__init__(f"{self.signal} received: stopped after epoch {epoch}; {where}")


class StopSignals:
    """While entered, :data:`STOP_SIGNALS` set :attr:`signum` (the first one to arrive)
    instead of ending the process; the previous handlers come back on exit. Only the main
    thread may install handlers: entered from another thread it does nothing."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Callable[[int, FrameType | None], object] | int | None] = {}

    def __enter__(self) -> StopSignals:
        self.signum = None
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum
        # straight to the file descriptor: rich's console may be mid-write in this thread
        name = signal.Signals(signum).name
        note = f"{name} received: stopping after the epoch in progress, with a checkpoint\n"
        with contextlib.suppress(OSError):
            os.write(2, note.encode())


def agree(epoch: int, signum: int | None, out_of_time: bool) -> tuple[int | None, bool]:
    """``(signum, out_of_time)`` common to every process of a multi-process run after
    ``epoch``: a signal any process received (the smallest number where they differ) and
    whether any is out of time. Each process publishes its own, then all wait at a barrier
    and read them all; one process returns its own."""
    client = coordination_client() if jax.process_count() > 1 else None
    if client is None:
        return signum, out_of_time
    prefix = f"mecanum/stop/{epoch}/"
    client.key_value_set(f"{prefix}{jax.process_index()}", f"{signum or 0} {int(out_of_time)}")
    barrier(f"stop-{epoch}")
    said = [value.split() for _, value in client.key_value_dir_get(prefix)]
    # every process has read the previous epoch's (it passed this barrier)
    client.key_value_delete(f"mecanum/stop/{epoch - 1}/{jax.process_index()}")
    signums = sorted(int(s) for s, _ in said if int(s))
    return (signums[0] if signums else None), any(int(t) for _, t in said)


__all__ = ["STOP_SIGNALS", "Preempted", "StopSignals", "agree"]
