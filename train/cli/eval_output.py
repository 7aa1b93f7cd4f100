"""What ``mecanum-eval`` shows and draws: its console tables and its plots.

``results`` is the report's ``scenarios`` mapping (:func:`train.cli.evaluate.evaluate`): per
scenario, each controller's summary and the paired comparisons. The comparisons and the
scorecard's wins, ties and losses are computed by :mod:`mecanum_jax.evaluation.compare`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.table import Table

from mecanum_jax.evaluation import plots
from mecanum_jax.evaluation.compare import score
from mecanum_jax.evaluation.traces import Trace
from mecanum_jax.task import REFERENCES

if TYPE_CHECKING:
    import numpy as np

TABLE = (
    ("RMSE v", "rmse_lin", "{:.3f}"),
    ("RMSE ωz", "rmse_wz", "{:.3f}"),
    ("ss v", "ss_lin", "{:.3f}"),
    ("ss ωz", "ss_wz", "{:.3f}"),
    ("settle v s", "settle_lin_s", "{:.2f}"),
    ("settle ω s", "settle_wz_s", "{:.2f}"),
    ("drift m", "drift_m", "{:.3f}"),
    ("energy J", "energy_j", "{:.0f}"),
    ("null J", "null_energy_j", "{:.1f}"),
    ("flicker", "flicker", "{:.4f}"),
)


def results_table(results: dict[str, Any], title: str) -> Table:
    """Every controller per scenario; the best tracking figure of each scenario in green.

    v in m/s, ωz in rad/s; ``ss``: steady-state error against the nearest feasible twist.
    """
    table = Table(title=title)
    for c in ("scenario", "who", *(c for c, _, _ in TABLE)):
        table.add_column(c, justify="left" if c in ("scenario", "who") else "right")
    for name, r in results.items():
        players = [w for w in ("policy", *REFERENCES) if w in r]
        for i, who in enumerate(players):
            cells = []
            for _, key, fmt in TABLE:
                v = r[who].get(key)
                text = "-" if v is None else fmt.format(v)
                values = [r[w].get(key) for w in players if r[w].get(key) is not None]
                if (
                    v is not None
                    and len(values) > 1
                    and key not in ("null_energy_j", "flicker")
                    and v == min(values)
                ):
                    text = f"[green]{text}[/]"
                cells.append(text)
            table.add_row(name if i == 0 else "", who, *cells)
    return table


def comparison_table(results: dict[str, Any], pair: str) -> Table:
    """``pair`` (e.g. ``policy/analytic``) ratios with 95% intervals per scenario; green
    where the interval lies wholly below 1 (better), red wholly above (worse)."""
    keys = ("ss_lin", "ss_wz", "rmse_lin", "rmse_wz", "settle_wz_s", "drift_m", "energy_j")
    table = Table(title=f"{pair}: ratio [95% paired bootstrap interval]")
    table.add_column("scenario")
    for k in keys:
        table.add_column(k, justify="right")
    for name, r in results.items():
        cmp = r.get("compare", {}).get(pair)
        if cmp is None:
            continue
        cells = []
        for k in keys:
            c = cmp.get(k)
            if c is None:
                cells.append("-")
                continue
            text = f"{c['ratio']:.2f} [{c['lo']:.2f},{c['hi']:.2f}]"
            color = {"better": "green", "worse": "red"}.get(str(c["verdict"]))
            cells.append(f"[{color}]{text}[/]" if color else text)
        table.add_row(name, *cells)
    return table


def scorecard_table(results: dict[str, Any], who: str, refs: Sequence[str]) -> Table:
    """:func:`~mecanum_jax.evaluation.compare.score` of ``who`` against each of ``refs``
    as one table: per scenario, the wins/ties/losses against each reference, and the
    metrics lost (``ref:metric``)."""
    refs = [r for r in refs if r != who]
    title = f"{who} against {' and '.join(refs)}: wins/ties/losses of the tracking metrics"
    table = Table(title=title)
    table.add_column("scenario")
    for ref in refs:
        table.add_column(f"vs {ref}", justify="right")
    table.add_column("lost")
    cards = {ref: score(results, f"{who}/{ref}") for ref in refs}
    for name in results:
        row, lost = [name], []
        for ref in refs:
            card = cards[ref].get(name)
            if card is None:
                row.append("-")
                continue
            n = len(card["losses"])
            counts = f"{len(card['wins'])}/{len(card['ties'])}/"
            row.append(counts + (f"[red]{n}[/]" if n else "0"))
            lost += [f"{ref}:{key}" for key in card["losses"]]
        table.add_row(*row, ", ".join(lost) or "-")
    few = [f"{n} ({r['episodes']})" for n, r in results.items() if r.get("episodes", 8) < 8]
    if few:  # a paired interval over so few episodes says little
        table.caption = (
            f"not significant: {', '.join(few)} had fewer than 8 episodes, so their "
            "verdicts are not significant (--episodes 8 or more)"
        )
    return table


def write_plots(
    results: dict[str, Any],
    traces: dict[str, dict[str, Trace[np.ndarray]]],
    dt: float,
    out: Path,
) -> list[Path]:
    paths = [
        plots.plot_errors(
            {n: {w: r[w] for w in ("policy", *REFERENCES) if w in r} for n, r in results.items()},
            out / "errors.png",
        ),
        plots.plot_trajectories(
            traces, dt, {n: r["scripted"] for n, r in results.items()}, out / "trajectories.png"
        ),
    ]
    for name, per in traces.items():
        paths.append(
            plots.plot_twist(
                per, dt, f"{name}: {results[name]['description']}", out / f"twist_{name}.png"
            )
        )
    return paths


__all__ = ["comparison_table", "results_table", "scorecard_table", "write_plots"]
