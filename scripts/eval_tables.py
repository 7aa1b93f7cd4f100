"""Markdown tables of one or more ``mecanum-eval`` reports, as docs/evaluation.md shows them.

    python scripts/eval_tables.py RUN/eval/report.json [MORE_REPORT.json ...]
        [--also candidate=CANDIDATE/report.json ...]

Prints the figures of every controller per scenario, then the policy's ratio to each
reference with its 95% paired interval (✓ better, ✗ worse, otherwise a tie). ``--also
NAME=REPORT`` adds the policy of another report on the same episodes (same scenarios,
episodes, length, seed and physics model) as rows named NAME, with its ratio to
``analytic`` (e.g. a candidate beside the shipped policy); one NAME may take several
reports of different scenarios.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from mecanum_jax.task.references import REFERENCES

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
SAME_EPISODES = ("episodes", "seconds", "seed")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def figures_table(scenarios: dict[str, Any], also: tuple[str, ...] = ()) -> list[str]:
    lines = [
        _row(["scenario", "controller", *(name for name, _, _ in FIGURES)]),
        _row(["---"] * (2 + len(FIGURES))),
    ]
    for name, sc in scenarios.items():
        players = [w for w in ("policy", *also, *REFERENCES) if w in sc]
        for i, who in enumerate(players):
            cells = []
            for _, key, fmt in FIGURES:
                value = sc[who].get(key)
                cells.append("–" if value is None else fmt.format(value))
            lines.append(_row([name if i == 0 else "", who, *cells]))
    return lines


def ratio_table(scenarios: dict[str, Any], also: tuple[str, ...] = ()) -> list[str]:
    lines = [
        _row(["scenario", "vs", *(name for name, _ in RATIOS)]),
        _row(["---"] * (2 + len(RATIOS))),
    ]
    for name, sc in scenarios.items():
        pairs = [p for p in sc.get("compare", {}) if p.split("/", 1)[0] in ("policy", *also)]
        for i, pair in enumerate(pairs):
            cells = []
            for _, key in RATIOS:
                c = sc["compare"][pair].get(key)
                if c is None or c.get("ratio") is None:
                    cells.append("–")
                    continue
                mark = MARK.get(c["verdict"], "")
                cells.append(f"{c['ratio']:.2f} [{c['lo']:.2f}, {c['hi']:.2f}]{mark}")
            who, ref = pair.split("/", 1)
            label = ref if who == "policy" else f"{ref} ({who})"
            lines.append(_row([name if i == 0 else "", label, *cells]))
    return lines


def add_also(scenarios: dict[str, Any], fidelity: str, name: str, report: dict) -> str | None:
    """Add ``report``'s policy to ``scenarios`` as ``name``; an error message if its episodes
    are not the same ones."""
    if report.get("fidelity", "fast") != fidelity:
        return f"its fidelity {report.get('fidelity')!r} is not the tables' {fidelity!r}"
    for scenario, other in report["scenarios"].items():
        if scenario not in scenarios:
            continue
        sc = scenarios[scenario]
        if name in sc:
            return f"scenario {scenario!r} has {name!r} already (from an earlier --also)"
        for key in SAME_EPISODES:
            mine, theirs = other.get(key), sc.get(key)
            if mine != theirs:
                return f"scenario {scenario!r}: {key} = {mine!r}, the tables' {theirs!r}"
        sc[name] = other["policy"]
        compare = other.get("compare", {}).get("policy/analytic")
        if compare is not None:
            sc.setdefault("compare", {})[f"{name}/analytic"] = compare
    return None


def _load(path: Path) -> dict[str, Any]:
    report: dict[str, Any] = json.loads(path.read_text())
    if "scenarios" not in report:  # a JSON file, but not a report
        raise KeyError("scenarios")
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", nargs="+", type=Path, help="report.json files of mecanum-eval")
    parser.add_argument(
        "--also",
        action="append",
        default=[],
        metavar="NAME=REPORT",
        help="another report's policy on the same episodes, shown as NAME (repeatable)",
    )
    args = parser.parse_args(argv)
    scenarios: dict[str, Any] = {}
    fidelity = "fast"
    for path in args.reports:
        try:
            report = _load(path)
        except (OSError, ValueError, KeyError) as err:
            return _error(f"reports: {str(path)!r} is not a mecanum-eval report ({err})")
        scenarios.update(report["scenarios"])
        fidelity = report.get("fidelity", "fast")
    names: list[str] = []
    for spec in args.also:
        name, sep, path_text = spec.partition("=")
        if not sep or not name or not path_text:
            return _error(f"--also: {spec!r} is not NAME=REPORT")
        if name in ("policy", *REFERENCES):
            return _error(f"--also: the name {name!r} is taken by a controller of the tables")
        try:
            report = _load(Path(path_text))
        except (OSError, ValueError, KeyError) as err:
            return _error(f"--also: {path_text!r} is not a mecanum-eval report ({err})")
        problem = add_also(scenarios, fidelity, name, report)
        if problem is not None:
            return _error(f"--also: {path_text!r} is not on the same episodes: {problem}")
        if name not in names:
            names.append(name)
    print("\n".join(figures_table(scenarios, tuple(names))))
    print()
    print("\n".join(ratio_table(scenarios, tuple(names))))
    return 0


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
