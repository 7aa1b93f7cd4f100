"""Why does nearest-feasible desaturation track v worse than uniform scaling on a loaded robot?

On the held-out payload and weak_motors scenarios `analytic_nearest` and `feedback` (which
desaturate an out-of-reach twist to the nearest feasible one) lose RMSE v to `analytic`
(which scales it uniformly), and the shipped policy, a residual on `feedback`, with them
(docs/evaluation.md). The guess: the nearest feasible twist puts more wheels at their rate
limit, and a loaded motor does not hold them there. This plays a scenario of
configs/eval/default.toml (diagnosis only: nothing is chosen on it) with `analytic` and
`analytic_nearest` on the same episodes and, on the steady steps (the ss metrics' steps)
whose command is beyond the wheels' reach, prints per controller: the share of wheels
whose setpoint is at its rate limit, the share of steps with a wheel at its torque limit,
the wheels' mean shortfall |setpoint| − |rate| (rad/s), and the steady v error against the
target (RMS, m/s). The setpoints are recomputed from the command as each controller does
(nominal geometry), since a reference's trace holds no action.

    .venv/bin/python experiments/desaturation_under_load.py [--only payload] [--episodes 16]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mecanum_jax.evaluation import metrics
from mecanum_jax.task import references
from train import evaluate as train_eval

WHO = ("analytic", "analytic_nearest")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="payload")
    ap.add_argument("--episodes", type=int, default=16)
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    out = Path(tempfile.mkdtemp(prefix="desaturation_under_load-"))
    argv = ["baseline", "--config", "gpu", "--only", args.only, "--episodes", str(args.episodes)]
    argv += ["--no-plots", "--physics-impl", "jax", "--references", *WHO]
    argv += ["--out", str(out / "report")]
    target, _, played = train_eval.play_traces(argv, "desaturation_under_load")
    env = target.env
    traces = played[args.only]
    dt = env.config.control_dt
    command = np.asarray(traces["analytic"].command)
    steady = metrics.steady_mask(command, dt, metrics.MetricConfig()) > 0
    beyond = np.linalg.norm(np.asarray(traces["analytic"].target) - command, axis=-1) > 1e-4
    mask = steady & beyond
    max_rates = np.asarray(env.max_rates)
    setpoints = {
        "analytic": np.asarray(references.baseline_rates(env, jnp.asarray(command))),
        "analytic_nearest": np.asarray(references.nearest_rates(env, jnp.asarray(command))),
    }
    print(f"{args.only}: {command.shape[0]} episodes; {int(mask.sum())} steady steps beyond "
          f"reach of {int(steady.sum())} steady steps")  # fmt: skip
    print("controller | wheels at the rate limit | steps with a wheel at its torque limit"
          " | mean shortfall rad/s | ss v RMS m/s (these steps) | (all steady)")  # fmt: skip
    for who in WHO:
        t = traces[who]
        sp = setpoints[who]
        at_limit = np.abs(sp) >= 0.999 * max_rates
        shortfall = np.abs(sp) - np.abs(np.asarray(t.wheel_rate))
        err = np.asarray(t.twist)[..., :2] - np.asarray(t.target)[..., :2]
        err2 = np.sum(err**2, axis=-1)
        torque_bound = np.mean(np.asarray(t.saturated)[mask] > 0)
        print(
            f"{who} | {np.mean(at_limit[mask]):.3f} | {torque_bound:.3f}"
            f" | {np.mean(shortfall[mask]):.3f} | {np.sqrt(np.mean(err2[mask])):.4f}"
            f" | {np.sqrt(np.mean(err2[steady])):.4f}"
        )


if __name__ == "__main__":
    main()
