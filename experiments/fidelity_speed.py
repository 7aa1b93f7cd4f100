"""How long an evaluation rollout takes in the reference roller model against the fast one
(docs/evaluation.md).

Both fidelities play the same episodes (the ``nominal`` scenario of configs/eval/default.toml,
the analytic baseline) in one process, through ``mecanum_jax.evaluation.rollout.Evaluator``
with the CPU's default batch (64 fast, 4 reference robots per compiled call). The first
call includes XLA's compilation; the later ones are the rollout alone (best of ``--repeat``).

Run: ``GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python experiments/fidelity_speed.py``
(a few minutes on 2 CPU cores).
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from mecanum_jax.evaluation import scenarios
from mecanum_jax.evaluation.rollout import Evaluator
from mecanum_jax.precision import set_matmul_precision
from mecanum_jax.task import MecanumEnv
from mecanum_jax.task import fidelity as fid
from train.config import load_train_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    set_matmul_precision("highest")
    chosen = scenarios.load_scenarios("default").select(["nominal"], args.episodes, args.seconds)
    cfg = scenarios.eval_env_config(load_train_config("quick").env, chosen)
    print(f"{jax.devices()[0]}; nominal, {args.episodes} episodes x {args.seconds:g} s, analytic")
    print("| fidelity | physics step | substeps | batch | first call (with compilation) | "
          "rollout | robot-seconds simulated per wall second |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for fidelity in fid.FIDELITIES:
        batch = fid.cpu_batch(fidelity)
        env = MecanumEnv(cfg, robots=batch, fidelity=fidelity)
        evaluator = Evaluator(env, None, batch)
        episodes = scenarios.prepare(env, chosen.scenarios[0])
        times = []
        for _ in range(1 + args.repeat):
            t0 = time.perf_counter()
            trace = evaluator.run(episodes, who="analytic")
            np.asarray(trace.twist)
            times.append(time.perf_counter() - t0)
        best = min(times[1:])
        print(
            f"| {fidelity} | {env.robot.dt * 1000:g} ms | {env.substeps} | {batch} | "
            f"{times[0]:.1f} s | {best:.1f} s | {args.episodes * args.seconds / best:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
