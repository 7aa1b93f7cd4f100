"""Plain progress lines for log files, where the live display cannot be drawn.

``mecanum-train``, ``mecanum-train-batch`` and ``mecanum-eval`` draw a rich live display on
their log stream (stderr). Where that stream is not a terminal (``> log 2>&1``, nohup,
SLURM), a live display shows nothing until it ends; these lines stand in for it, on the
same stream: one every ``every_s`` seconds, and one at each event (a finished rollout
chunk; the trainer's first and last epoch, and an evaluation, unless it comes less than
``every_s`` after the last line: the timer's next line carries it). So a log grows at a
human rate whatever the epoch's length. On a terminal the live display is drawn and no
line is printed.
What counts as a terminal is rich's decision (``Console.is_terminal``), so its overrides
hold: ``TTY_COMPATIBLE=1`` forces the live display, ``TTY_COMPATIBLE=0`` the lines.

The timer is a thread of its own that prints the latest known figures, so a line comes
every ``every_s`` seconds even inside a long compiled epoch or rollout chunk (or while
one compiles): its elapsed time is current, its step count that of the last finished
epoch. A line at an event restarts the timer.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

SCENARIO = "randomized"
"""The periodic evaluation's scenario the lines quote (the training distribution)."""


def print_error(console: Console, err: BaseException | str, label: str = "error") -> None:
    """``label: err`` in red on ``console``; the message is printed as it is, brackets and
    all (a leaf name such as ``['params']`` is not rich markup)."""
    text = f"[bold red]{escape(label)}:[/] {escape(str(err))}"
    console.print(text, soft_wrap=True, markup=True, highlight=False)


def report_console(width: int = 140) -> Console:
    """A console for a printed report: the terminal's width on a terminal, else ``width``
    columns, so that a log or a pipe keeps whole figures rather than rich's 80."""
    return Console(width=None if sys.stdout.isatty() else width)


def wants_lines(console: Console) -> bool:
    """Whether ``console`` gets plain lines (it is not a terminal) rather than a display."""
    return not console.is_terminal


def duration(s: float) -> str:
    """Seconds as ``45s``, ``3m05s`` or ``1h02m``."""
    s = max(0, round(s))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


def count(x: float) -> str:
    """A count in three significant figures: 614k, 1.19M."""
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= div:
            return f"{x / div:.3g}{unit}"
    return f"{x:.0f}"


class Ticker:
    """Prints ``describe()`` as one plain line every ``every_s`` seconds (from a thread) and
    at each :meth:`now`, while entered as a context manager; does nothing when disabled."""

    def __init__(
        self, console: Console, every_s: float, describe: Callable[[], str], enabled: bool
    ):
        if not every_s > 0:
            raise ValueError(f"every_s = {every_s}: must be > 0")
        self.console = console
        self.every_s = every_s
        self.enabled = enabled
        self._describe = describe
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last = time.monotonic()
        self._waiting = False  # (TrainLines) an evaluation no line has shown yet

    def __enter__(self) -> Ticker:
        if self.enabled:
            self._stop.clear()
            self._last = time.monotonic()
            self._thread = threading.Thread(target=self._run, name="progress-lines", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def now(self) -> None:
        """Print a line now (an event) and restart the timer."""
        if self.enabled:
            with self._lock:
                self._print()

    def _print(self) -> None:
        self.console.out(self._describe(), highlight=False)
        self._last = time.monotonic()
        self._waiting = False

    def _run(self) -> None:
        wait = self.every_s
        while not self._stop.wait(wait):
            with self._lock:
                due = self._last + self.every_s - time.monotonic()
                if due <= 0:
                    self._print()
                    due = self.every_s
            wait = max(0.05, due)


class TrainLines(Ticker):
    """The trainer's line: elapsed time of this session, env steps per seed, env steps/s,
    ETA, and the last periodic evaluation's figures. ``update`` at each epoch's end."""

    def __init__(
        self,
        console: Console,
        every_s: float,
        enabled: bool,
        *,
        label: str,
        total_steps: int,
        t_start: float,
        time_limit_s: float | None,
        done_steps: int = 0,
    ):
        super().__init__(console, every_s, self.text, enabled)
        self.label = label
        self.total = total_steps
        self.t_start = t_start
        self.time_limit_s = time_limit_s
        self.done = done_steps
        self.epoch: int | None = None
        self.sps: float | None = None
        self.evaluation = ""
        self._first: tuple[float, int] | None = None  # time, steps after this session's first
        self._latest: tuple[float, int] | None = None  # ... and latest epoch

    def update(
        self,
        epoch: int,
        done_steps: int,
        sps: float,
        evaluation: str | None,
        final: bool = False,
    ) -> None:
        """An epoch ended; ``evaluation``: its evaluation's figures (``None``: none ran).
        A line at once for the first epoch, the ``final`` one (after the line of an
        evaluation still waiting), and an evaluation ``every_s`` or more after the last
        line; an earlier evaluation waits for the timer's next line (a newer one replaces
        its figures)."""
        if final and self._waiting:
            self.now()  # the waiting evaluation, with its own epoch's figures
        now = time.time()
        with self._lock:
            first = self._first is None
            self.epoch, self.done, self.sps = epoch, done_steps, sps
            self._latest = (now, done_steps)
            if self._first is None:
                self._first = self._latest
            if evaluation is not None:
                self.evaluation = evaluation
                self._waiting = True
            spaced = time.monotonic() - self._last >= self.every_s
        if first or final or (evaluation is not None and spaced):
            self.now()

    def eta_s(self, now: float) -> tuple[float | None, str]:
        """Seconds left and what bounds them: the step budget at the rate measured since
        the end of this session's first epoch (evaluations included; none before a second
        epoch ends, as the first one includes compilation), or the time limit, whichever
        comes first."""
        rate = None
        if self._first and self._latest and self._latest[1] > self._first[1]:
            rate = (self._latest[1] - self._first[1]) / max(self._latest[0] - self._first[0], 1e-9)
        by_steps = max(0, self.total - self.done) / rate if rate else None
        if self.time_limit_s is not None:
            by_limit = max(0.0, self.t_start + self.time_limit_s - now)
            if by_steps is None or by_limit < by_steps:
                return by_limit, " (time limit)"
        return by_steps, ""

    def text(self) -> str:
        now = time.time()
        parts = [f"[{self.label}] {duration(now - self.t_start)}"]
        parts.append(f"env steps {count(self.done)}/{count(self.total)}")
        if self.sps is None:
            parts.append("compiling the first epoch")
        else:
            parts.append(f"{count(self.sps)} env steps/s")
        eta, bound = self.eta_s(now)
        parts.append("ETA -" if eta is None else f"ETA {duration(eta)}{bound}")
        if self.evaluation:
            parts.append(self.evaluation)
        return " | ".join(parts)


def evaluation_text(
    steps: int,
    evals: dict[str, dict[str, np.ndarray]],
    comparisons: list[dict[str, Any]],
) -> str:
    """The last evaluation on :data:`SCENARIO`: the steady-state errors (mean over seeds)
    and their policy/analytic ratios on the same episodes (mean over seeds)."""
    policy = evals.get(SCENARIO, {})

    def figure(key: str, name: str, unit: str) -> str:
        values = policy.get(key)
        if values is None or not np.isfinite(values).any():
            return f"{name} -"
        text = f"{name} {float(np.nanmean(values)):.3f} {unit}"
        ratios = [c.get(SCENARIO, {}).get(key, {}).get("ratio") for c in comparisons]
        ratios = [r for r in ratios if r is not None]
        return text + (f" ({np.mean(ratios):.2f}× analytic)" if ratios else "")

    lin = figure("ss_lin", "ss v", "m/s")
    wz = figure("ss_wz", "ss ωz", "rad/s")
    return f"eval at {count(steps)} steps ({SCENARIO}): {lin}, {wz}"


@contextlib.contextmanager
def rollout_progress(console: Console, every_s: float) -> Iterator[Callable[[int, int], None]]:
    """``mecanum-eval``'s rollouts: yields the ``progress(done, total)`` callback of
    :meth:`mecanum_jax.evaluation.rollout.Evaluator.run_many`. On a terminal, rich's
    transient bar; elsewhere a line per finished chunk and every ``every_s`` seconds
    (chunks done/total, elapsed)."""
    if not wants_lines(console):
        columns = (TextColumn("rollouts"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task("rollouts", total=None)
            yield lambda done, total: bar.update(task, completed=done, total=total)
        return
    t0 = time.time()
    state = {"chunks": (0, 0)}  # replaced whole: the timer's thread reads it

    def text() -> str:
        done, total = state["chunks"]
        chunks = f"{done}/{total} chunks done" if total else "0 chunks done (compiling)"
        return f"[rollouts] {chunks}, {duration(time.time() - t0)} elapsed"

    with Ticker(console, every_s, text, enabled=True) as lines:

        def chunk_done(done: int, total: int) -> None:
            state["chunks"] = (done, total)
            lines.now()

        yield chunk_done


__all__ = [
    "SCENARIO",
    "Ticker",
    "TrainLines",
    "count",
    "duration",
    "evaluation_text",
    "report_console",
    "rollout_progress",
    "wants_lines",
]
