"""Plain progress lines where the log stream is not a terminal (train.loop.progress), and what a
run learned at its end (train.loop.curve).

The fast tests drive the trainer in-process on a console writing to a string (not a
terminal) or forced to be a terminal; the ``full`` ones run ``mecanum-train`` and
``mecanum-eval`` as subprocesses with their output redirected to a file.
"""

import dataclasses
import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from train.loop import curve, progress
from train.loop.run import Run

ROOT = Path(__file__).resolve().parent.parent
LINE = re.compile(r"^\[tiny\] \S+ \| env steps \S+/960 \| .* \| ETA ", re.M)


def _console(terminal: bool) -> tuple[Console, io.StringIO]:
    buf = io.StringIO()
    return Console(file=buf, force_terminal=terminal, width=200), buf


def _wait_for(predicate, what: str, limit_s: float = 60.0) -> None:
    """Poll until ``predicate()``; a generous limit only to fail instead of hanging."""
    end = time.monotonic() + limit_s
    while not predicate():
        assert time.monotonic() < end, f"never happened: {what}"
        time.sleep(0.01)


def test_lines_only_where_the_stream_is_no_terminal(monkeypatch):
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    assert progress.wants_lines(_console(False)[0])
    assert not progress.wants_lines(_console(True)[0])
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # rich's override: draw the live display
    assert not progress.wants_lines(Console(file=io.StringIO()))


@pytest.mark.parametrize("enabled", [True, False])
def test_ticker_prints_on_its_timer_and_at_events(enabled):
    console, buf = _console(False)
    said = iter(range(1000))
    with progress.Ticker(console, 0.05, lambda: f"line {next(said)}", enabled) as ticker:
        ticker.now()
        if enabled:  # the timer's thread adds lines without being asked
            _wait_for(lambda: buf.getvalue().count("\n") >= 3, "timer lines")
    lines = buf.getvalue().splitlines()
    if enabled:
        assert lines[:3] == ["line 0", "line 1", "line 2"]
    else:
        assert lines == []


class _Clock:
    def __init__(self, t: float):
        self.t = t

    def time(self) -> float:
        return self.t

    def monotonic(self) -> float:
        return self.t


def test_train_line_fields_and_eta(monkeypatch):
    clock = _Clock(1000.0)
    monkeypatch.setattr(progress, "time", clock)
    console, _ = _console(False)
    kw = {"label": "q", "total_steps": 10_000, "t_start": 1000.0}
    lines = progress.TrainLines(console, 30, True, time_limit_s=None, **kw)
    clock.t = 1035.0
    assert lines.text() == "[q] 35s | env steps 0/10k | compiling the first epoch | ETA -"
    lines.update(1, 1000, 400.0, None)  # the first epoch includes compilation: no rate
    assert lines.text() == "[q] 35s | env steps 1k/10k | 400 env steps/s | ETA -"
    clock.t = 1045.0
    lines.update(2, 2000, 500.0, "eval ...")  # the rate since the first epoch: 100 steps/s
    assert lines.text() == "[q] 45s | env steps 2k/10k | 500 env steps/s | ETA 1m20s | eval ..."
    limited = progress.TrainLines(console, 30, True, time_limit_s=60.0, **kw)
    loose = progress.TrainLines(console, 30, True, time_limit_s=600.0, **kw)
    clock.t = 1045.0
    for x in (limited, loose):
        x.update(1, 1000, 400.0, None)
    assert limited.text().endswith("| ETA 15s (time limit)")  # no rate yet: the limit
    clock.t = 1055.0
    for x in (limited, loose):
        x.update(3, 3000, 500.0, None)  # 200 steps/s: 35 s for the steps
    assert limited.text().endswith("| ETA 5s (time limit)")
    assert loose.text().endswith("| ETA 35s")  # the step budget, sooner than the limit


def test_evaluation_text_quotes_errors_and_ratios():
    evals = {"randomized": {"ss_lin": np.array([0.3, 0.5]), "ss_wz": np.array([np.nan, 0.8])}}
    comps = [{"randomized": {"ss_lin": {"ratio": 0.9}}}, {"randomized": {"ss_lin": {"ratio": 1.1}}}]
    text = progress.evaluation_text(51_200, evals, comps)
    assert text == (
        "eval at 51.2k steps (randomized): ss v 0.400 m/s (1.00× analytic), ss ωz 0.800 rad/s"
    )


def test_rollout_progress_lines_and_bar():
    console, buf = _console(False)
    with progress.rollout_progress(console, 0.05) as chunk_done:
        _wait_for(lambda: "compiling" in buf.getvalue(), "a timer line before any chunk")
        chunk_done(1, 3)
        chunk_done(3, 3)
    text = buf.getvalue()
    assert "[rollouts] 0 chunks done (compiling), " in text
    assert "[rollouts] 1/3 chunks done, " in text
    assert "[rollouts] 3/3 chunks done, " in text
    console, buf = _console(True)
    with progress.rollout_progress(console, 0.05) as chunk_done:
        chunk_done(3, 3)
    assert "[rollouts]" not in buf.getvalue()


def _train(tiny, learner, run_dir, console, every_s=0.2):
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, progress_every_s=every_s))
    Run.create(cfg, run_dir, console=console).train(learner=learner)


def test_training_prints_lines_into_a_log_even_inside_an_epoch(
    tiny, learner, tmp_path, monkeypatch
):
    """Not a terminal: a line at each evaluation and on the timer, inside an epoch too;
    the shared learner serves (the interval is a logging-only field)."""
    console, buf = _console(False)
    real_epoch, calls, seen = learner.epoch, [], {}

    def slow_second_epoch(*args):
        calls.append(1)
        if len(calls) == 2:  # epoch 2 runs until the timer has printed a line
            before = buf.getvalue().count("\n")
            _wait_for(lambda: buf.getvalue().count("\n") > before, "a line inside an epoch")
            seen["inside"] = buf.getvalue().splitlines()[before:]
        return real_epoch(*args)

    monkeypatch.setattr(learner, "epoch", slow_second_epoch)
    _train(tiny, learner, tmp_path / "log", console)
    text = buf.getvalue()
    lines = LINE.findall(text)
    assert len(lines) >= 4, text  # 3 evaluations and the timer's line inside epoch 2
    assert any(re.match(r"\[tiny\] .* env steps 320/960 .* env steps/s", x) for x in seen["inside"])
    for steps in ("320", "640", "960"):
        assert f"eval at {steps} steps (randomized): ss v 0." in text
    assert "m/s (" in text
    assert "× analytic), ss ωz " in text
    assert "━" not in text  # no live display in a log


def test_training_on_a_terminal_draws_the_display_instead(tiny, learner, tmp_path):
    console, buf = _console(True)
    _train(tiny, learner, tmp_path / "tty", console)
    text = buf.getvalue()
    assert not LINE.search(text)
    assert "━" in text  # rich's bar was drawn


def _rows(tmp_path, rows):
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return tmp_path


def _row(seed, epoch, ss_lin, ratio, evaluated=True):
    row = {"epoch": epoch, "env_steps": 1000 * epoch, "walltime": 10.0 * epoch, "seed": seed}
    row["train"] = {"reward": -0.5 + 0.1 * epoch}
    if evaluated:
        row["eval"] = {"randomized": {"ss_lin": ss_lin, "ss_wz": 1.0}}
        row["baseline"] = {"randomized": {"ss_lin": 0.4, "ss_wz": 0.9}}
        row["compare"] = {"randomized": {"ss_lin": {"ratio": ratio}}}
    return row


def _render(table) -> str:
    console, buf = _console(False)
    console.print(table)
    return buf.getvalue()


def test_learned_table_puts_first_and_last_evaluation_side_by_side(tmp_path):
    rows = [_row(s, e, 0.8 - 0.1 * e, 2.0 - 0.2 * e, e != 2) for e in (1, 2, 3) for s in (0, 5)]
    rows[-1]["eval"]["randomized"]["ss_lin"] = "nan"  # as metrics.jsonl writes NaN
    text = _render(curve.learned_table(_rows(tmp_path, rows), "q"))
    assert "q: what it learned (held-out randomized episodes)" in text
    first = re.search(r"^ +0 +first +1 +1k +10 +-0\.400 +0\.700 +1\.80× +1\.000 +- *$", text, re.M)
    last = re.search(r"^ +5 +last +3 +3k +30 +-0\.200 +- +1\.40× +1\.000 +- *$", text, re.M)
    assert first, text
    assert last, text
    assert re.search(r"^ +analytic +0\.400 +0\.900 *$", text, re.M), text
    assert curve.learned_table(_rows(tmp_path, [_row(0, 1, 0, 0, False)]), "q") is None
    assert curve.write_plot(tmp_path) is None  # no evaluation: no plot


def test_learning_curve_is_plotted_from_the_run(full_run, tmp_path):
    run, _ = full_run
    path = curve.plot_learning_curve(run.dir, tmp_path / "curve.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 10_000
    text = _render(curve.learned_table(run.dir, "tiny"))
    assert re.search(r"^ +first +1 +320 ", text, re.M)
    assert re.search(r"^ +last +3 +960 ", text, re.M)


def _redirected(args, log: Path, **env):
    """Run ``python -m args`` in the repository with stdout and stderr into ``log``."""
    with log.open("w") as f:
        code = subprocess.run(
            [sys.executable, "-m", *args], cwd=ROOT, stdout=f, stderr=f, env={**os.environ, **env}
        ).returncode
    return code, log.read_text()


@pytest.mark.full  # compiles a fresh learner and the rollouts: minutes on 2 cores
def test_redirected_train_and_eval_print_progress_lines(tmp_path):
    run = tmp_path / "run"
    argv = [
        "train.cli.train",
        "--config",
        "tiny",
        "--run-dir",
        str(run),
        "--run.progress-every-s",
        "0.5",
    ]
    code, text = _redirected(argv, tmp_path / "train.log", TTY_COMPATIBLE="0")
    assert code == 0, text
    assert len(LINE.findall(text)) >= 4, text  # the first compilation alone takes seconds
    assert "compiling the first epoch" in text
    assert "eval at 960 steps (randomized): ss v " in text
    assert "tiny: what it learned" in text
    assert re.search(r"^ +last +3 +960 ", text, re.M)
    assert (run / curve.PLOT_NAME).stat().st_size > 10_000
    assert "learning curve: " in text
    argv = [
        "train.cli.evaluate",
        "baseline",
        "--only",
        "nominal",
        "--episodes",
        "2",
        "--seconds",
        "1",
    ]
    argv += ["--progress-every-s", "0.5", "--no-plots", "--out", str(tmp_path / "ev")]
    code, text = _redirected(argv, tmp_path / "eval.log", TTY_COMPATIBLE="0")
    assert code == 0, text
    assert "[rollouts] 0 chunks done (compiling), " in text
    assert re.search(r"^\[rollouts\] 1/1 chunks done, \S+ elapsed$", text, re.M), text
    # forced to count as a terminal: the live display, no lines
    argv[-1] = str(tmp_path / "ev2")
    code, text = _redirected(argv, tmp_path / "eval2.log", TTY_COMPATIBLE="1")
    assert code == 0, text
    assert "[rollouts]" not in text
