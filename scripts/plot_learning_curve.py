"""Plot a run's learning curve against the baseline's line (PNG): the training reward, and
the steady-state error of v and ωz on the held-out evaluation episodes (raw RMSE for runs
logged before the steady-state metrics existed).

.venv/bin/python scripts/plot_learning_curve.py RUN_DIR OUT.png
"""

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def main() -> None:
    run, out = Path(sys.argv[1]), sys.argv[2]
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    steps = [r["env_steps"] / 1e6 for r in rows]
    axes[0].plot(steps, [r["train"]["reward"] for r in rows])
    axes[0].set(title="training reward per step", xlabel="env steps (M)")
    ev = [r for r in rows if "eval" in r]
    if not ev:
        raise SystemExit(f"{run / 'metrics.jsonl'}: no evaluation logged yet")
    prefix = "ss" if "ss_lin" in ev[0]["eval"]["randomized"] else "rmse"
    for ax, key, unit in ((axes[1], f"{prefix}_lin", "m/s"), (axes[2], f"{prefix}_wz", "rad/s")):
        for scen, style in (("randomized", "-"), ("nominal", "--")):
            x = [r["env_steps"] / 1e6 for r in ev]
            ax.plot(
                x, [r["eval"][scen][key] for r in ev], style, color="C0", label=f"policy, {scen}"
            )
            ax.axhline(
                ev[0]["baseline"][scen][key], ls=style, color="C3", label=f"baseline, {scen}"
            )
        ax.set(title=f"eval {key} ({unit})", xlabel="env steps (M)")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
