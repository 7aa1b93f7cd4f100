"""Training's plain progress lines (train/loop/progress.py) come at a human rate whatever the
epoch's length: one at the first and the last epoch, and an evaluation's at most every
``every_s`` seconds (the timer's line carries the others). A fake clock drives them."""

import io

from rich.console import Console

from train.loop import progress


class _Clock:
    def __init__(self, t: float):
        self.t = t

    def time(self) -> float:
        return self.t

    monotonic = time


def _lines(monkeypatch, every_s: float = 30.0) -> tuple[progress.TrainLines, io.StringIO, _Clock]:
    clock = _Clock(1000.0)
    monkeypatch.setattr(progress, "time", clock)
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=False, width=300)
    kw = {"label": "q", "total_steps": 10**6, "t_start": 1000.0, "time_limit_s": None}
    return progress.TrainLines(console, every_s, True, **kw), buf, clock


def test_one_second_epochs_each_evaluated_print_a_line_per_30_s(monkeypatch):
    lines, buf, clock = _lines(monkeypatch)
    for epoch in range(1, 601):  # ten minutes of one-second epochs, each evaluated
        clock.t += 1.0
        lines.update(epoch, 1000 * epoch, 1000.0, f"eval {epoch}", final=epoch == 600)
    printed = buf.getvalue().splitlines()
    assert len(printed) <= 600 / 30 + 2  # (the timer's thread, not running here, adds none)
    assert printed[0].endswith("| eval 1")  # the first epoch's at once
    assert printed[1].endswith("| eval 31")  # then every 30 s
    assert printed[-1].endswith("| eval 600")  # and the last


def test_epochs_without_evaluation_leave_the_lines_to_the_timer(monkeypatch):
    lines, buf, clock = _lines(monkeypatch)
    for epoch in range(1, 101):
        clock.t += 0.1
        lines.update(epoch, 1000 * epoch, 1000.0, None, final=epoch == 100)
    printed = buf.getvalue().splitlines()
    assert len(printed) == 2  # the first epoch and the last
    assert "env steps 100k/1M" in printed[-1]


def test_an_evaluation_waiting_for_the_timer_is_printed_before_the_last_line(monkeypatch):
    lines, buf, clock = _lines(monkeypatch)
    lines.update(1, 1000, 100.0, "eval a")
    clock.t += 5.0
    lines.update(2, 2000, 100.0, "eval b")  # 5 s after the last line: waits
    assert buf.getvalue().count("\n") == 1
    clock.t += 5.0
    lines.update(3, 3000, 100.0, "eval c", final=True)
    printed = buf.getvalue().splitlines()
    assert len(printed) == 3
    assert "env steps 2k/1M" in printed[1]
    assert printed[1].endswith("| eval b")
    assert printed[2].endswith("| eval c")
    clock.t += 60.0
    lines.update(4, 4000, 100.0, "eval d")  # a minute later: at once
    assert buf.getvalue().splitlines()[-1].endswith("| eval d")
