"""Plot a run's learning curve against the baseline's line (PNG): the training reward, and
the steady-state error of v and ωz on the held-out evaluation episodes
(:func:`train.loop.curve.plot_learning_curve`; ``mecanum-train`` writes it as
``<run>/learning_curve.png`` at the end of a run).

.venv/bin/python scripts/plot_learning_curve.py RUN_DIR OUT.png
"""

import sys
from pathlib import Path

from train.loop.curve import plot_learning_curve


def main() -> None:
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    try:
        plot_learning_curve(Path(sys.argv[1]), Path(sys.argv[2]))
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(str(err)) from None


if __name__ == "__main__":
    main()
