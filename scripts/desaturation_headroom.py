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
budget (scripts/baseline_error_budget.py), before dynamics.

    .venv/bin/python scripts/desaturation_headroom.py [--samples 4000] [--seed 0]
        [--omega-weights 1 0.1 0.03 0.01]
"""

from __future__ import annotations

import argparse
import itertools

import jax
import numpy as np

from mecanum_jax import kinematics, limits
from mecanum_jax.env import EnvConfig, MecanumEnv


def nearest_feasible(J: np.ndarray, m: np.ndarray, c: np.ndarray) -> np.ndarray:
    """argmin_t |t - c|² subject to |J t| <= m (per wheel), exactly.

    The feasible set is a polytope in 3-D with the half-spaces ±J_i t <= m_i. The nearest
    point lies on a face, an edge or a vertex: every set of 1 to 3 active constraints is
    tried (projection onto their intersection) and the nearest feasible candidate kept.
    """
    A = np.concatenate([J, -J])
    b = np.concatenate([m, m])
    if np.all(A @ c <= b + 1e-12):
        return c
    best, best_d = None, np.inf
    for k in (1, 2, 3):
        for rows in itertools.combinations(range(len(A)), k):
            Ak, bk = A[list(rows)], b[list(rows)]
            gram = Ak @ Ak.T
            if np.linalg.matrix_rank(gram) < k:
                continue
            t = c - Ak.T @ np.linalg.solve(gram, Ak @ c - bk)
            d = float(np.sum((t - c) ** 2))
            if d < best_d and np.all(A @ t <= b + 1e-9):
                best, best_d = t, d
    if best is None:
        raise RuntimeError(f"no feasible projection for command {c}")
    return best


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
    J = np.asarray(kinematics.jacobian(env.geometry), np.float64)
    m = np.asarray(env.max_rates, np.float64) * np.ones(J.shape[0])
    scaled = np.asarray(limits.desaturate(env.geometry, out, env.max_rates)[0], np.float64)
    rows = []
    for lam in args.omega_weights:
        d = np.array([1.0, 1.0, np.sqrt(lam)])  # project u = d * t in the weighted metric
        nearest = np.stack([nearest_feasible(J / d, m, c * d) for c in out]) / d
        worst = float(np.max(np.abs(nearest @ J.T) / m))
        assert worst <= 1 + 1e-6, f"nearest twist infeasible: saturation {worst}"
        rows.append((lam, nearest))

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
    for lam, nearest in rows:
        nv, nw = rmse(nearest)
        print(f"| nearest, λ = {lam:g} | {nv:.3f} ({nv / sv:.2f}x) | {nw:.3f} ({nw / sw:.2f}x) |")


if __name__ == "__main__":
    main()
