"""What a run learned, read from its ``metrics.jsonl``: the first and the last periodic
evaluation side by side (:func:`learned_table`), and the learning-curve plot
(:func:`plot_learning_curve`, also ``scripts/plot_learning_curve.py``). ``mecanum-train``
prints the one and writes the other (``learning_curve.png``) at the end of a run.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path
from typing import Any

from rich import box
from rich.table import Table

from train.loop.progress import SCENARIO, count

PLOT_NAME = "learning_curve.png"


def evaluations(run_dir: Path) -> list[dict[str, Any]]:
    """The rows of ``metrics.jsonl`` that hold a periodic evaluation (one per seed each)."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.exists():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in rows if "eval" in r]


def _num(x: object, fmt: str) -> str:
    """A figure, "-" where missing or not finite (metrics.jsonl writes NaN as a string)."""
    if not isinstance(x, int | float) or not math.isfinite(x):
        return "-"
    return fmt.format(x)


def _float(x: object) -> float:
    """A logged figure as a float (NaN where metrics.jsonl holds none or ``"nan"``)."""
    return float(x) if isinstance(x, int | float) else math.nan


def _ratio(row: dict[str, Any], key: str) -> str:
    c = row.get("compare", {}).get(SCENARIO, {}).get(key)
    return "-" if c is None else _num(c.get("ratio"), "{:.2f}×")


def learned_table(run_dir: Path, name: str) -> Table | None:
    """Per seed, the first and the last periodic evaluation on held-out :data:`SCENARIO`
    episodes: epoch, env steps, wall time, training reward, steady-state error of v and
    ωz and their ratio to ``analytic``'s on the same episodes; then ``analytic``'s own
    errors. ``None`` when the run logged no evaluation."""
    rows = evaluations(run_dir)
    if not rows:
        return None
    seeds = list(dict.fromkeys(r.get("seed") for r in rows))
    table = Table(
        title=f"{name}: what it learned (held-out {SCENARIO} episodes)",
        caption="ratio: to analytic's error on the same episodes",
        box=box.SIMPLE_HEAD,
    )
    columns = ["seed"] if len(seeds) > 1 else []
    columns += ["eval", "epoch", "steps", "wall s", "reward"]
    columns += ["ss v m/s", "ratio", "ss ωz rad/s", "ratio"]
    for col in columns:
        left = col in ("seed", "eval")
        table.add_column(col, justify="left" if left else "right", no_wrap=left)
    for seed in seeds:
        mine = [r for r in rows if r.get("seed") == seed]
        shown = [("first", mine[0]), ("last", mine[-1])] if len(mine) > 1 else [("only", mine[0])]
        for label, r in shown:
            ev = r["eval"].get(SCENARIO, {})
            table.add_row(
                *([str(seed)] if len(seeds) > 1 else []),
                label,
                str(r["epoch"]),
                count(r["env_steps"]),
                _num(r.get("walltime"), "{:.0f}"),
                _num(r.get("train", {}).get("reward"), "{:.3f}"),
                _num(ev.get("ss_lin"), "{:.3f}"),
                _ratio(r, "ss_lin"),
                _num(ev.get("ss_wz"), "{:.3f}"),
                _ratio(r, "ss_wz"),
            )
    base = rows[-1].get("baseline", {}).get(SCENARIO, {})
    ss_v, ss_w = _num(base.get("ss_lin"), "{:.3f}"), _num(base.get("ss_wz"), "{:.3f}")
    lead = ["analytic", ""] if len(seeds) > 1 else ["analytic"]
    table.add_row(*lead, "", "", "", "", ss_v, "", ss_w, "")
    return table


def plot_learning_curve(run_dir: Path, out: Path) -> Path:
    """Plot a run's learning curve against the baseline's line (PNG), a line per seed:
    the training reward, and the steady-state error of v and ωz on the held-out evaluation
    episodes (raw RMSE for runs logged before the steady-state metrics existed). Raises
    ``ValueError`` when the run logged no evaluation yet."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir, out = Path(run_dir), Path(out)
    rows = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    ev = [r for r in rows if "eval" in r]
    if not ev:
        raise ValueError(f"{run_dir / 'metrics.jsonl'}: no evaluation logged yet")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    prefix = "ss" if "ss_lin" in ev[0]["eval"]["randomized"] else "rmse"
    for i, seed in enumerate(dict.fromkeys(r.get("seed") for r in rows)):  # a line per seed
        mine = [r for r in rows if r.get("seed") == seed]
        steps = [r["env_steps"] / 1e6 for r in mine]
        axes[0].plot(steps, [_float(r["train"]["reward"]) for r in mine], color="C0")
        x = [r["env_steps"] / 1e6 for r in mine if "eval" in r]
        for ax, key in ((axes[1], f"{prefix}_lin"), (axes[2], f"{prefix}_wz")):
            for scen, style in (("randomized", "-"), ("nominal", "--")):
                y = [_float(r["eval"][scen].get(key)) for r in mine if "eval" in r]
                ax.plot(x, y, style, color="C0", label=f"policy, {scen}" if i == 0 else None)
    axes[0].set(title="training reward per step", xlabel="env steps (M)")
    for ax, key, unit in ((axes[1], f"{prefix}_lin", "m/s"), (axes[2], f"{prefix}_wz", "rad/s")):
        for scen, style in (("randomized", "-"), ("nominal", "--")):
            base = _float(ev[0]["baseline"][scen][key])
            ax.axhline(base, ls=style, color="C3", label=f"baseline, {scen}")
        ax.set(title=f"eval {key} ({unit})", xlabel="env steps (M)")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_runs_against_time(runs: dict[str, Path], out: Path) -> Path:
    """Several runs' learning curves against wall time (PNG), a colour per run and a line
    per seed: the training reward, and the randomized evaluation's steady-state error of
    v and ωz as ratios to ``analytic``'s on the same episodes. For variants that run at
    different speeds: learning is compared at equal wall time (docs/benchmarks.md).
    ``runs`` maps a label to a run directory or its ``metrics.jsonl``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for colour, (label, path) in enumerate(runs.items()):
        path = Path(path)
        path = path / "metrics.jsonl" if path.is_dir() else path
        rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
        if not any("eval" in r for r in rows):
            raise ValueError(f"{path}: no evaluation logged")
        for i, seed in enumerate(dict.fromkeys(r.get("seed") for r in rows)):
            mine = [r for r in rows if r.get("seed") == seed]
            first = label if i == 0 else None
            t = [r["walltime"] for r in mine]
            axes[0].plot(t, [_float(r["train"]["reward"]) for r in mine], f"C{colour}", label=first)
            ev = [r for r in mine if "eval" in r]
            for ax, key in ((axes[1], "ss_lin"), (axes[2], "ss_wz")):
                y = [_float(r["compare"][SCENARIO][key]["ratio"]) for r in ev]
                ax.plot([r["walltime"] for r in ev], y, f"C{colour}o-", label=first)
    axes[0].set(title="training reward per step", xlabel="wall time (s)")
    for ax, key in ((axes[1], "ss v"), (axes[2], "ss ωz")):
        ax.axhline(1.0, color="C3", ls=":", label="analytic")
        ax.set(title=f"{SCENARIO} {key} / analytic", xlabel="wall time (s)")
    axes[0].legend(fontsize=7)
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def write_plot(run_dir: Path) -> Path | None:
    """``<run>/learning_curve.png``, when the run logged an evaluation and matplotlib is
    installed; else ``None``."""
    if not evaluations(run_dir) or importlib.util.find_spec("matplotlib") is None:
        return None
    return plot_learning_curve(run_dir, Path(run_dir) / PLOT_NAME)


__all__ = [
    "PLOT_NAME",
    "evaluations",
    "learned_table",
    "plot_learning_curve",
    "plot_runs_against_time",
    "write_plot",
]
