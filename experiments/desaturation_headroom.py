"""How much tracking error could a smarter answer to out-of-reach commands save?

The analytic baseline scales an out-of-reach twist uniformly into the feasible set
(``limits.desaturate``: its direction is kept). The tracking metric, though, is the RMSE of
(vx, vy) and of ωz against the *commanded* twist, and the feasible twist nearest the
command is not, in general, the scaled one. This samples the training task's commands
(``MecanumEnv.sample_command``: its beyond-reach kind and any other that falls outside),
keeps the out-of-reach ones, and compares, kinematically (no dynamics, no slip):

- **scaled:** the baseline's uniform scaling;
- **nearest, weight λ:** the feasible twist minimising (vx error)² + (vy error)² +
  λ (ωz error)² (the exact projection onto the feasible polytope, in metres and radians
  per second; λ trades the v metric against the ω one).

It prints the RMSE of v and ω over the out-of-reach commands for both. The difference is
an upper bound on what a policy could gain on the beyond-reach share of the error
budget (experiments/baseline_error_budget.py), before dynamics.

    .venv/bin/python experiments/desaturation_headroom.py [--samples 4000] [--seed 0]
        [--omega-weights 1 0.1 0.03 0.01]
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from mecanum_jax.kinematics import limits
from mecanum_jax.task import EnvConfig, MecanumEnv


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--omega-weights", type=float, nargs="+", default=[1.0, 0.1, 0.03, 0.01])
    args = ap.parse_args()
    if args.samples < 1:
        ap.error(f"--samples {args.samples}: must be >= 1")
    for lam in args.omega_weights:
        if not lam > 0:
            ap.error(f"--omega-weights {lam}: must be > 0")
    env = MecanumEnv(EnvConfig())
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.samples)
    cmds = np.asarray(jax.jit(jax.vmap(env.sample_command))(keys), np.float64)
    sat = np.asarray(limits.saturation(env.geometry, cmds, env.max_rates))
    out = cmds[sat > 1.0]
    scaled = np.asarray(limits.desaturate(env.geometry, out, env.max_rates)[0], np.float64)
    rows: list[tuple[float, np.ndarray]] = []
    for lam in args.omega_weights:
        nearest = limits.nearest_feasible(env.geometry, out.astype(np.float32), env.max_rates, lam)
        rows.append((lam, np.asarray(nearest, np.float64)))

    def rmse(t: np.ndarray) -> tuple[float, float]:
        e = t - out
        v = np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))
        return float(v), float(np.sqrt(np.mean(e[:, 2] ** 2)))

    sv, sw = rmse(scaled)
    print(
        f"{len(out)} of {args.samples} sampled commands are out of reach "
        f"(saturation median {np.median(sat[sat > 1]):.2f}, max {sat.max():.2f})"
    )
    print("| answer | RMSE v (m/s) | RMSE ω (rad/s) |")
    print("|---|---|---|")
    print(f"| scaled (baseline) | {sv:.3f} | {sw:.3f} |")
    for lam, near in rows:
        nv, nw = rmse(near)
        print(f"| nearest, λ = {lam:g} | {nv:.3f} ({nv / sv:.2f}x) | {nw:.3f} ({nw / sw:.2f}x) |")


if __name__ == "__main__":
    main()
