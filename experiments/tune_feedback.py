"""Tune the ``feedback`` reference controller's gains on training-distribution episodes.

The episodes are configs/eval/randomized.toml's distribution (the training task's) on a
*tuning* seed of their own, never the evaluation seed. Every (kp, ki, i_max) of the grid
plays the same episodes, and one compiled rollout serves the whole grid (the gains are
traced). The rule: the lowest steady-state ωz error among the gains whose steady-state v
error and energy stay within 5% of ``analytic_nearest`` (feedback acts on yaw only, so it
must not buy ωz with v or energy).

    .venv/bin/python experiments/tune_feedback.py [--episodes 128] [--seconds 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time

import numpy as np

from mecanum_jax.evaluation import metrics, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import EnvConfig, MecanumEnv

TUNING_SEED = 101  # configs/eval/randomized.toml evaluates on seed 11


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--kp", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2])
    ap.add_argument("--ki", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--i-max", type=float, nargs="+", default=[1.0, 3.0])
    ap.add_argument("--max-batch", type=int, default=64)
    args = ap.parse_args()
    t0 = time.time()
    sset = scenarios.load_scenarios("randomized").select((), args.episodes, args.seconds)
    sc = dataclasses.replace(sset.scenarios[0], seed=TUNING_SEED, name="tuning")
    env = MecanumEnv(scenarios.eval_env_config(EnvConfig(), sset))
    batch = scenarios.prepare(env, sc)
    ev = evaluation.Evaluator(env, max_batch=args.max_batch)
    jac = kinematics.jacobian(env.geometry)
    dt = env.config.control_dt

    def parts(who: str, gains: object = None) -> dict[str, metrics.Part]:
        (trace,) = ev.run_many([(batch, who)], feedback_gains=gains)
        return evaluation.trace_parts(trace, jac, dt)

    def summary(p: dict[str, metrics.Part]) -> dict[str, float]:
        """The figures this sweep reads (none of them is undefined on these episodes)."""
        return {k: float(v) for k, v in metrics.summary(p).items() if v is not None}

    refs = {who: parts(who) for who in ("analytic", "analytic_nearest")}
    near = summary(refs["analytic_nearest"])
    print(f"{args.episodes} tuning episodes x {args.seconds:g} s (seed {TUNING_SEED})")
    print(f"{'controller':>28s}  ss v   ss ωz  rmse ωz  settle ω  energy J")
    for who, p in refs.items():
        m = summary(p)
        print(f"{who:>28s}  {m['ss_lin']:.4f} {m['ss_wz']:.4f} {m['rmse_wz']:.4f}"
              f"  {m['settle_wz_s']:.3f}    {m['energy_j']:.1f}")  # fmt: skip
    best = None
    for kp, ki, i_max in itertools.product(args.kp, args.ki, args.i_max):
        m = summary(parts("feedback", np.asarray([kp, ki, i_max])))
        ok = m["ss_lin"] <= 1.05 * near["ss_lin"] and m["energy_j"] <= 1.05 * near["energy_j"]
        if ok and (best is None or m["ss_wz"] < best[1]["ss_wz"]):
            best = ((kp, ki, i_max), m)
        print(f"feedback kp {kp:4.2f} ki {ki:4.1f} imax {i_max:3.1f}  {m['ss_lin']:.4f} "
              f"{m['ss_wz']:.4f} {m['rmse_wz']:.4f}  {m['settle_wz_s']:.3f}    "
              f"{m['energy_j']:.1f}{'' if ok else '  (v or energy > 1.05x nearest)'}")  # fmt: skip
    if best is not None:
        (kp, ki, i_max), m = best
        print(f"chosen: kp = {kp}, ki = {ki}, i_max = {i_max} (ss ωz {m['ss_wz']:.4f} against "
              f"analytic_nearest {near['ss_wz']:.4f}); {time.time() - t0:.0f} s")  # fmt: skip


if __name__ == "__main__":
    main()
