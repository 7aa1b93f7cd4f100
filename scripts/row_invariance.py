"""Does a CPU evaluation read an episode the same in any row of its chunk?

    python scripts/row_invariance.py [--scenario nominal] [--rolls 8 16 32] [--guard 8 0]

Plays one default scenario's episodes (a chunk's worth, 64) with `feedback` in one chunk,
then the same episodes rolled by each of ``--rolls`` rows, and prints how many episodes'
traces part, once for each ``--guard`` (``batching.CPU_GUARD_ROWS``: the rows a chunk plays
past its episodes and drops). With the command line's XLA flags (XLA:CPU's older emitters,
as ``mecanum-eval`` sets them), at the ``highest`` matmul precision (docs/evaluation.md,
How it runs). About 15 s per guard on 2 cores.
"""

from __future__ import annotations

import argparse
import dataclasses

from train.loop import compilation_cache

compilation_cache.configure([])  # the command line's XLA flags, before JAX starts

import jax  # noqa: E402
import numpy as np  # noqa: E402

import mecanum_jax.evaluation as ev  # noqa: E402
from mecanum_jax.evaluation import episodes, scenarios  # noqa: E402
from mecanum_jax.sim import batching  # noqa: E402
from mecanum_jax.task import MecanumEnv  # noqa: E402
from mecanum_jax.tracing import prepare_tracing  # noqa: E402
from train.config_loading import load_train_config  # noqa: E402


def parted(base: ev.Trace, other: ev.Trace, order: np.ndarray) -> np.ndarray:
    """Per episode of ``base``: whether any of its trace's values differs in ``other``,
    whose rows hold the episodes ``order``."""
    back = np.argsort(order)
    n = len(order)
    out = np.zeros(n, bool)
    for x, y in zip(jax.tree.leaves(base), jax.tree.leaves(other), strict=True):
        x, y = np.asarray(x).reshape(n, -1), np.asarray(y)[back].reshape(n, -1)
        out |= ~np.all(x == y, axis=1)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="nominal", help="a scenario of configs/eval/default.toml")
    p.add_argument("--rolls", type=int, nargs="+", default=[8, 16, 32])
    p.add_argument("--guard", type=int, nargs="+", default=[batching.CPU_GUARD_ROWS, 0])
    args = p.parse_args()
    prepare_tracing("highest")
    chunk = batching.CPU_CHUNK["fast"]
    default = scenarios.load_scenarios("default")
    sc = dataclasses.replace(default.select([args.scenario]).scenarios[0], episodes=chunk)
    cfg = episodes.eval_env_config(load_train_config("quick").env.validate("env"), default)
    env = MecanumEnv(cfg, robots=chunk)
    batch = episodes.prepare(env, sc)
    for guard in args.guard:
        evaluator = ev.Evaluator(env, None, chunk)
        evaluator.guard = guard
        base = evaluator.run(batch, who="feedback")
        for roll in args.rolls:
            order = np.roll(np.arange(chunk), roll)
            rolled = jax.tree.map(lambda x, o=order: np.asarray(x)[o], batch)
            n = int(parted(base, evaluator.run(rolled, who="feedback"), order).sum())
            print(f"{args.scenario}, guard rows {guard}, rolled by {roll}: {n} of {chunk} part")


if __name__ == "__main__":
    main()
