"""Is one policy better than another? Two ``mecanum-eval`` outputs of the same episodes,
compared episode by episode.

    python scripts/compare_policies.py NEW_EVAL_DIR OLD_EVAL_DIR [--reference analytic]
        [--who feedback] [--against feedback]

Each argument is a ``mecanum-eval`` output directory (or its ``parts.npz``): the same
scenario file, seeds and episode counts, any machine. For every scenario in both, prints
each metric of the first policy and of the second and their ratio with the paired 95%
bootstrap interval (✓: the first is better, the whole interval below 1; ✗: worse; else a
tie), as mecanum_jax/evaluation/paired.py computes it. Exit 2, naming the scenario and the
figure, when the reference controller (played in both) reads differently, that is when the
two did not play the same episodes. ``--against`` names the second's controller when it is
not ``--who``'s, e.g. the policy against `feedback` under another config (a `mecanum-eval
baseline --config C` output).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mecanum_jax.evaluation import metrics, paired

METRICS = (
    ("ss v", "ss_lin"),
    ("ss ωz", "ss_wz"),
    ("RMSE v", "rmse_lin"),
    ("RMSE ωz", "rmse_wz"),
    ("settle v", "settle_lin_s"),
    ("settle ωz", "settle_wz_s"),
    ("drift", "drift_m"),
    ("energy", "energy_j"),
    ("flicker", "flicker"),
)
MARK = {"better": " ✓", "worse": " ✗"}


def table(
    a: paired.Parts,
    b: paired.Parts,
    reference: str,
    tolerance: float,
    who: str = "policy",
    against: str | None = None,
) -> list[str]:
    """Markdown lines: per scenario, each metric's values and the first's ratio to the
    second with its paired interval (of the controller ``who`` in the first, ``against``
    in the second; None: ``who`` in both)."""
    against = against or who
    pairs = paired.pair(a, b, who, against, reference=reference, tolerance=tolerance)
    lines = ["| scenario | metric | first | second | first / second |", "|---|---|---|---|---|"]
    for scenario, row in pairs.items():
        name = scenario
        for label, key in METRICS:
            if key not in row:
                continue
            c = row[key]
            va, vb = a[scenario][who][key].value(), b[scenario][against][key].value()
            mark = MARK.get(metrics.verdict(c), "")
            lines.append(
                f"| {name} | {label} | {va:.4g} | {vb:.4g} | "
                f"{c.ratio:.2f} [{c.lo:.2f}, {c.hi:.2f}]{mark} |"
            )
            name = ""
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first", type=Path, help="mecanum-eval output directory (or parts.npz)")
    ap.add_argument("second", type=Path, help="the same, of the policy compared against")
    ap.add_argument("--reference", default="analytic", help="the controller both played")
    ap.add_argument("--tolerance", type=float, default=0.01, help="its figures' relative match")
    ap.add_argument(
        "--who",
        default="policy",
        help="the controller compared: the policy, or a reference such as feedback (two "
        "`mecanum-eval baseline --config C` outputs: a reference under two configs)",
    )
    ap.add_argument(
        "--against",
        default=None,
        help="the second's controller, when it is not --who's (e.g. --against feedback: the "
        "policy against `feedback` under another config)",
    )
    args = ap.parse_args(argv)
    if not 0 <= args.tolerance < 1:
        print(f"compare_policies: --tolerance {args.tolerance}: must be in [0, 1)", file=sys.stderr)
        return 2
    try:
        a, b = paired.load_parts(args.first), paired.load_parts(args.second)
        lines = table(a, b, args.reference, args.tolerance, args.who, args.against)
    except (FileNotFoundError, paired.EpisodesDifferError) as e:
        print(f"compare_policies: {e}", file=sys.stderr)
        return 2
    print(f"first: {args.first}\nsecond: {args.second}\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
