"""Markdown tables of one or more ``mecanum-eval`` reports, as docs/evaluation.md shows them.

    python scripts/eval_tables.py RUN/eval/report.json [MORE_REPORT.json ...]

Prints the figures of every controller per scenario, then the policy's ratio to each
reference with its 95% paired interval (✓ better, ✗ worse, otherwise a tie).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

FIGURES = (
    ("ss v", "ss_lin", "{:.3f}"),
    ("ss ωz", "ss_wz", "{:.3f}"),
    ("RMSE v", "rmse_lin", "{:.3f}"),
    ("RMSE ωz", "rmse_wz", "{:.3f}"),
    ("settle v s", "settle_lin_s", "{:.2f}"),
    ("settle ωz s", "settle_wz_s", "{:.2f}"),
    ("drift m", "drift_m", "{:.3f}"),
    ("energy J", "energy_j", "{:.0f}"),
    ("J/m", "energy_per_m", "{:.1f}"),
    ("null J", "null_energy_j", "{:.0f}"),
    ("flicker", "flicker", "{:.4f}"),
)
RATIOS = (
    ("ss v", "ss_lin"),
    ("ss ωz", "ss_wz"),
    ("RMSE ωz", "rmse_wz"),
    ("settle v", "settle_lin_s"),
    ("settle ωz", "settle_wz_s"),
    ("drift", "drift_m"),
    ("energy", "energy_j"),
)
MARK = {"better": " ✓", "worse": " ✗"}


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def figures_table(scenarios: dict[str, Any]) -> list[str]:
    lines = [
        _row(["scenario", "controller", *(name for name, _, _ in FIGURES)]),
        _row(["---"] * (2 + len(FIGURES))),
    ]
    for name, sc in scenarios.items():
        players = [w for w in ("policy", "analytic", "analytic_nearest", "feedback") if w in sc]
        for i, who in enumerate(players):
            cells = []
            for _, key, fmt in FIGURES:
                value = sc[who].get(key)
                cells.append("–" if value is None else fmt.format(value))
            lines.append(_row([name if i == 0 else "", who, *cells]))
    return lines


def ratio_table(scenarios: dict[str, Any]) -> list[str]:
    lines = [
        _row(["scenario", "vs", *(name for name, _ in RATIOS)]),
        _row(["---"] * (2 + len(RATIOS))),
    ]
    for name, sc in scenarios.items():
        pairs = [p for p in sc.get("compare", {}) if p.startswith("policy/")]
        for i, pair in enumerate(pairs):
            cells = []
            for _, key in RATIOS:
                c = sc["compare"][pair].get(key)
                if c is None or c.get("ratio") is None:
                    cells.append("–")
                    continue
                mark = MARK.get(c["verdict"], "")
                cells.append(f"{c['ratio']:.2f} [{c['lo']:.2f}, {c['hi']:.2f}]{mark}")
            lines.append(_row([name if i == 0 else "", pair.split("/", 1)[1], *cells]))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", nargs="+", type=Path, help="report.json files of mecanum-eval")
    args = parser.parse_args(argv)
    scenarios: dict[str, Any] = {}
    for path in args.reports:
        try:
            report = json.loads(path.read_text())
            scenarios.update(report["scenarios"])
        except (OSError, ValueError, KeyError) as err:
            print(
                f"error: reports: {str(path)!r} is not a mecanum-eval report ({err})",
                file=sys.stderr,
            )
            return 2
    print("\n".join(figures_table(scenarios)))
    print()
    print("\n".join(ratio_table(scenarios)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
