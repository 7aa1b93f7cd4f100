"""Training-throughput benchmark: PPO environment steps per second, variants side by side.

Each variant is a training config plus overrides; for each, the benchmark builds the
compiled training program, times the first epoch (compilation included) and then
``--epochs`` further epochs, and reports end-to-end training throughput (rollouts and PPO
updates; evaluation and checkpointing excluded), summed over vectorized seeds::

    python -m train.tools.bench --config gpu --epochs 3 \\
        --variant base \\
        --variant "tf32 --run.matmul-precision default" \\
        --variant "envs16k --ppo.num-envs 16384 --ppo.batch-size 2048"

A variant is a name followed by ``mecanum-train``'s flags over the config's fields.

Prints a table and writes JSON (``--json-out``).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from typing import Any

import jax
import numpy as np
from rich.table import Table

from mecanum_jax.config import ConfigError
from mecanum_jax.tracing import prepare_tracing
from train.config import TrainConfig
from train.config_loading import apply_flags, load_train_config
from train.learner.ppo import Learner
from train.learner.transfer import to_host
from train.loop import compilation_cache
from train.loop.distributed import init_distributed
from train.loop.progress import print_error, report_console


def measure(cfg: TrainConfig, epochs: int) -> dict[str, Any]:
    prepare_tracing(cfg.run.matmul_precision)
    t0 = time.perf_counter()
    learner = Learner(cfg)
    state, env_state = learner.init()
    state, env_state, metrics = learner.epoch(state, env_state)
    jax.block_until_ready(metrics)
    first = time.perf_counter() - t0
    steps = cfg.steps_per_iteration * cfg.run.epoch_iterations * len(cfg.run.seeds)
    times = []
    for _ in range(epochs):
        t = time.perf_counter()
        state, env_state, metrics = learner.epoch(state, env_state)
        jax.block_until_ready(metrics)
        times.append(time.perf_counter() - t)
    best = min(times)
    return {
        "num_envs": cfg.ppo.num_envs,
        "seeds": len(cfg.run.seeds),
        "batch_size": cfg.ppo.batch_size,
        "num_minibatches": cfg.ppo.num_minibatches,
        "substeps": learner.env.substeps,
        "matmul_precision": cfg.run.matmul_precision,
        "update_precision": cfg.ppo.update_precision,
        "devices": learner.n_devices * learner.n_processes,
        "first_epoch_s": first,
        "epoch_s": times,
        "steps_per_epoch": steps,
        "steps_per_s_median": steps / float(np.median(times)),
        "steps_per_s_best": steps / best,
        "physics_steps_per_s_median": steps * learner.env.substeps / float(np.median(times)),
        "processes": jax.process_count(),
        "finite": bool(np.all(to_host(metrics["finite"]) > 0)),
    }


def _precision(r: dict[str, Any]) -> str:
    """The run's matmul precision, and the update's where it differs (``highest/default``)."""
    update = r.get("update_precision", "run")
    run = r["matmul_precision"]
    return run if update in ("run", run) else f"{run}/{update}"


def _table(results: list[dict[str, Any]]) -> Table:
    table = Table(title=f"PPO training throughput ({jax.devices()[0].device_kind})")
    for col in (
        "variant",
        "envs",
        "devices",
        "seeds",
        "precision",
        "1st epoch s",
        "env steps/s",
        "phys steps/s",
    ):
        table.add_column(col)
    for r in results:
        table.add_row(
            r["variant"],
            str(r["num_envs"]),
            str(r["devices"]),
            str(r["seeds"]),
            _precision(r),
            f"{r['first_epoch_s']:.1f}",
            f"{r['steps_per_s_median']:,.0f}",
            f"{r['physics_steps_per_s_median']:,.0f}",
        )
    return table


def main(argv: list[str] | None = None) -> int:
    argv = compilation_cache.configure(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="python -m train.tools.bench", description=__doc__)
    parser.add_argument("--config", default="gpu")
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument(
        "--variant",
        action="append",
        default=None,
        help='"NAME [--field value ...]": a name and mecanum-train flags (default: "base")',
    )
    parser.add_argument("--json-out", default=None)
    parser.add_argument(
        "--distributed", action="store_true", help="join a jax.distributed run (process 0 reports)"
    )
    args = parser.parse_args(argv)
    console = report_console()
    try:
        init_distributed(args.distributed)
        if args.epochs < 1:
            raise ConfigError(f"--epochs = {args.epochs}: must be >= 1")
        base = load_train_config(args.config)
        variants = []
        for v in args.variant or ["base"]:
            name, *flags = shlex.split(v)
            variants.append((name, apply_flags(base, flags, f"--variant {name}")))
    except ConfigError as err:
        print_error(console, err)
        return 2
    results = []
    for name, cfg in variants:
        console.log(f"variant {name}")
        results.append({"variant": name, **measure(cfg, args.epochs)})
        console.log(json.dumps(results[-1]))
    table = _table(results)
    if jax.process_index() != 0:
        return 0
    console.print(table)
    if args.json_out:
        out = {
            "device": jax.devices()[0].device_kind,
            "jax": jax.__version__,
            "date": time.strftime("%Y-%m-%d"),
            "config": args.config,
            "results": results,
        }
        with open(args.json_out, "w") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "measure"]
