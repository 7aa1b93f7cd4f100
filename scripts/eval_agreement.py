"""Do two ``mecanum-eval`` reports of the same episodes agree? (e.g. a GPU's and a CPU's)

    python scripts/eval_agreement.py GPU/report.json CPU/report.json [--tolerance 0.01]

For every scenario and controller in both reports, prints the steady-state figures (ss v,
ss ωz) of each and their relative difference, and exits 1 when any differs by more than
``--tolerance`` (relative, default 1%) beyond an absolute floor of 1 mm/s or 1 mrad/s: a
GPU table is trusted only when one of its scenarios, rerun on the CPU, agrees.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

FIGURES = (("ss v", "ss_lin", 0.001), ("ss ωz", "ss_wz", 0.001))
PLAYERS = ("policy", "analytic", "analytic_nearest", "feedback")


def agreement(a: dict[str, Any], b: dict[str, Any], tolerance: float) -> tuple[list[str], bool]:
    """Lines of the comparison, and whether every figure agrees."""
    lines = [f"{'scenario':<14} {'who':<17} {'figure':<6} {'A':>8} {'B':>8} {'rel diff':>9}"]
    ok = True
    shared = [n for n in a["scenarios"] if n in b["scenarios"]]
    if not shared:
        return ["no scenario in both reports"], False
    for name in shared:
        ra, rb = a["scenarios"][name], b["scenarios"][name]
        for who in (w for w in PLAYERS if w in ra and w in rb):
            for label, key, floor in FIGURES:
                x, y = ra[who].get(key), rb[who].get(key)
                if x is None or y is None:
                    continue
                rel = abs(x - y) / max(abs(y), 1e-12)
                bad = abs(x - y) > floor and rel > tolerance
                ok &= not bad
                mark = "  DISAGREE" if bad else ""
                lines.append(f"{name:<14} {who:<17} {label:<6} {x:8.4f} {y:8.4f} {rel:9.2%}{mark}")
    return lines, ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("a", type=Path, help="a report.json (e.g. the GPU's)")
    parser.add_argument("b", type=Path, help="a report.json of the same episodes (the CPU's)")
    parser.add_argument("--tolerance", type=float, default=0.01, help="relative, default 0.01")
    args = parser.parse_args(argv)
    reports = []
    for path in (args.a, args.b):
        try:
            reports.append(json.loads(path.read_text()))
        except (OSError, ValueError) as err:
            print(f"error: {path}: {err}", file=sys.stderr)
            return 2
    a, b = reports
    print(f"A: {a.get('device')} ({a.get('matmul_precision', 'precision not recorded')})")
    print(f"B: {b.get('device')} ({b.get('matmul_precision', 'precision not recorded')})")
    lines, ok = agreement(a, b, args.tolerance)
    print("\n".join(lines))
    print("agree" if ok else f"DISAGREE beyond {args.tolerance:.0%}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
