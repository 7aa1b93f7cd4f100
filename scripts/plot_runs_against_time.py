"""Plot several runs' learning curves against wall time (PNG): training reward, and the
randomized evaluation's ss v and ss ωz ratios to ``analytic``
(:func:`train.loop.curve.plot_runs_against_time`). For variants that train at different speeds,
e.g. the two sides of an ``ab`` call, whose ``NAME_metrics.jsonl`` files it reads.

.venv/bin/python scripts/plot_runs_against_time.py OUT.png LABEL=RUN_DIR_OR_METRICS ...
"""

import sys
from pathlib import Path

from train.loop.curve import plot_runs_against_time


def main() -> None:
    if len(sys.argv) < 3 or not all("=" in a for a in sys.argv[2:]):
        raise SystemExit(__doc__)
    runs = dict(a.split("=", 1) for a in sys.argv[2:])
    missing = [p for p in runs.values() if not Path(p).exists()]
    if missing:
        raise SystemExit(f"{missing[0]}: no such run directory or metrics file")
    try:
        plot_runs_against_time({k: Path(v) for k, v in runs.items()}, Path(sys.argv[1]))
    except (ValueError, KeyError) as err:
        raise SystemExit(f"{err}") from None


if __name__ == "__main__":
    main()
