"""Do two ``mecanum-eval`` reports of the same episodes agree? (e.g. a GPU's and a CPU's)

    python scripts/eval_agreement.py GPU/report.json CPU/report.json [--tolerance 0.01]

For every scenario and controller in both reports, prints the steady-state figures (ss v,
ss ωz) of each and their relative difference, and exits 1 when any differs by more than
``--tolerance`` (relative, default 1%) beyond an absolute floor of 1 mm/s or 1 mrad/s: a
GPU table is trusted only when one of its scenarios, rerun on the CPU, agrees.

A few episodes are chaotic: a rounding difference grows until their trajectories part
(also between two CPUs on different jax versions; docs/evaluation.md, "One number on every
device: the agreement check").
Where the reports carry per-episode figures, a pooled figure that differs is still called
in agreement, and marked ``diverged``, only when

- at most ``--max-diverged`` of the episodes (default 15%) differ by more than the
  tolerance, while a device-wide fault such as TF32 shifts every episode;
- the other episodes' pooled figures agree within the tolerance; and
- the whole difference is inside the figure's own 95% bootstrap half-width (over A's
  episodes): smaller than what drawing other episodes would change.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from mecanum_jax.evaluation import metrics
from mecanum_jax.task.references import REFERENCES

FIGURES = (("ss v", "ss_lin", 0.001), ("ss ωz", "ss_wz", 0.001))
PLAYERS = ("policy", *REFERENCES)


def _differs(x: float, y: float, floor: float, tolerance: float) -> bool:
    return abs(x - y) > floor and abs(x - y) / max(abs(y), 1e-12) > tolerance


def _pooled(rms: np.ndarray, count: np.ndarray) -> metrics.Part:
    """The report's pooled steady-state figure from per-episode ones (RMS weighted by the
    steady steps), as the metric part that the report's own figure is."""
    return metrics.Part(count * rms**2, count, "rms")


def diverged(
    ea: dict[str, Any], eb: dict[str, Any], key: str, floor: float, tolerance: float,
    max_diverged: float,
) -> str | None:  # fmt: skip
    """Why a differing pooled figure still agrees (see the module's text), or ``None``."""
    if key not in ea or key not in eb or "steady_steps" not in ea:
        return None
    xa, xb = ea[key], eb[key]
    if len(xa) != len(xb):
        return None
    keep = [i for i, (u, v) in enumerate(zip(xa, xb, strict=True)) if None not in (u, v)]
    if not keep:
        return None
    ra, rb = np.asarray([xa[i] for i in keep]), np.asarray([xb[i] for i in keep])
    count = np.asarray([ea["steady_steps"][i] for i in keep])
    apart = np.asarray([_differs(u, v, floor, tolerance) for u, v in zip(ra, rb, strict=True)])
    if apart.mean() > max_diverged or apart.all():
        return None
    same = ~apart
    pa, pb = _pooled(ra[same], count[same]).value(), _pooled(rb[same], count[same]).value()
    if pa is None or pb is None or _differs(pa, pb, floor, tolerance):
        return None
    whole_a, whole_b = _pooled(ra, count).value(), _pooled(rb, count).value()
    interval = metrics.bootstrap_interval(_pooled(ra, count))
    if whole_a is None or whole_b is None or interval is None:
        return None
    lo, hi = interval
    if abs(whole_a - whole_b) > (hi - lo) / 2:
        return None
    return f"diverged: {int(apart.sum())} of {len(ra)} episodes, within ±{(hi - lo) / 2:.4f}"


def agreement(
    a: dict[str, Any], b: dict[str, Any], tolerance: float, max_diverged: float = 0.15
) -> tuple[list[str], bool]:
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
                bad = _differs(x, y, floor, tolerance)
                why = None
                if bad:
                    ea = ra.get("per_episode", {}).get(who, {})
                    eb = rb.get("per_episode", {}).get(who, {})
                    why = diverged(ea, eb, key, floor, tolerance, max_diverged)
                ok &= not bad or why is not None
                mark = f"  {why}" if why else "  DISAGREE" if bad else ""
                lines.append(f"{name:<14} {who:<17} {label:<6} {x:8.4f} {y:8.4f} {rel:9.2%}{mark}")
    return lines, ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("a", type=Path, help="a report.json (e.g. the GPU's)")
    parser.add_argument("b", type=Path, help="a report.json of the same episodes (the CPU's)")
    parser.add_argument("--tolerance", type=float, default=0.01, help="relative, default 0.01")
    parser.add_argument(
        "--max-diverged", type=float, default=0.15,
        help="the share of episodes that may part (chaotic ones), default 0.15",
    )  # fmt: skip
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
    for name, value in (("tolerance", args.tolerance), ("max-diverged", args.max_diverged)):
        if not 0 <= value < 1:
            print(f"error: --{name} must be in [0, 1), got {value}", file=sys.stderr)
            return 2
    lines, ok = agreement(a, b, args.tolerance, args.max_diverged)
    print("\n".join(lines))
    print("agree" if ok else f"DISAGREE beyond {args.tolerance:.0%}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
