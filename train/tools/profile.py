"""Where a training epoch's time goes, part by part, on one device.

Each part of the epoch is compiled as a program of its own on the learner's shapes
(:mod:`train.tools.profile_parts`) and warmed up; then ``--repeats`` rounds call each program
once, blocking, in turn (so that all see the same load), and each part is the median of
its calls, less that of an empty program's call with the same arguments. One measured
epoch is set against their sum. The periodic evaluation and the run loop's host
transfers are timed in the same rounds and spread over the epochs between them
(``run.eval_every``, ``run.checkpoint_every``)::

    python -m train.tools.profile --config gpu --json-out profile.json [mecanum-train flags]
    python -m train.tools.profile --config tiny --ppo.num-envs 8 --trace-dir /tmp/trace

Some parts are differences of nested programs (environment step ⊂ training environment ⊂
rollout, each with the physics replaced), so a part smaller than the timing noise can read
slightly negative; "rest of the epoch" is what the parts do not account for (negative:
the epoch overlaps or fuses work that the parts run apart). ``--trace-dir`` also
records one epoch with ``jax.profiler.trace`` (TensorBoard's profile plugin or Perfetto
reads it; tens of MB for the tiny config on a CPU: ``--run.epoch-iterations 1`` makes a
shorter epoch). Always one device (the first), whatever ``run.max_devices`` says.

Prints a table and writes JSON (``--json-out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NotRequired, TypedDict, TypeVar, TypeVarTuple

import jax
import numpy as np
from rich.table import Table

from mecanum_jax.config import ConfigError
from mecanum_jax.tracing import prepare_tracing
from train.config import TrainConfig
from train.config_loading import apply_flags, load_train_config
from train.learner.ppo import Learner
from train.learner.transfer import first_device, to_host
from train.loop import compilation_cache
from train.loop.progress import print_error, report_console
from train.loop.run_records import machine_record, write_json
from train.tools.profile_parts import EpochParts

R = TypeVar("R")
Args = TypeVarTuple("Args")


class Timing(TypedDict):
    """One program's times (s): its compilation, first call, and the timed rounds."""

    aot: NotRequired[bool]  # compiled ahead of time (dropped once the median is in)
    compile_s: float
    first_call_s: float
    times_s: list[float]
    median_s: NotRequired[float]


class Timer:
    """Programs compiled and warmed up one by one, then timed in turns: each round calls
    every program once (blocking), so that all of them see the same machine load."""

    def __init__(self, log: Callable[[str], None]):
        self.log = log
        self.calls: dict[str, tuple[Callable[..., object], tuple[object, ...]]] = {}
        self.programs: dict[str, Timing] = {}

    def add(self, name: str, fn: Callable[[*Args], R], *args: *Args) -> R:
        """Compile ``fn`` for ``args`` (ahead of time where it is jitted; else its first
        call, less a timed one, is taken as its compilation) and run it once; returns its
        output."""
        self.log(f"compiling {name}")
        t = time.perf_counter()
        compiled = fn.lower(*args).compile() if hasattr(fn, "lower") else fn
        compile_s = time.perf_counter() - t
        t = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        self.calls[name] = (compiled, args)
        self.programs[name] = {
            "aot": hasattr(fn, "lower"),
            "compile_s": compile_s,
            "first_call_s": time.perf_counter() - t,
            "times_s": [],
        }
        return out

    def run(self, repeats: int) -> dict[str, Timing]:
        """``repeats`` rounds; each program's median, and its compile time."""
        self.log(f"timing {len(self.calls)} programs, {repeats} rounds")
        for _ in range(repeats):
            for name, (fn, args) in self.calls.items():
                t = time.perf_counter()
                jax.block_until_ready(fn(*args))
                self.programs[name]["times_s"].append(time.perf_counter() - t)
        for p in self.programs.values():
            p["median_s"] = float(np.median(p["times_s"]))
            if not p.pop("aot"):  # compiled by its first call, if at all
                p["compile_s"] = max(p["first_call_s"] - p["median_s"], 0.0)
        return self.programs


def measure(
    cfg: TrainConfig,
    repeats: int = 5,
    trace_dir: str | None = None,
    log: Callable[[str], None] = print,
    learner: Learner | None = None,
) -> dict[str, Any]:
    """Time the parts, the epoch, the evaluation and the transfers; return the report.
    ``learner``: one built for ``cfg`` already (default: a new one on the first device)."""
    prepare_tracing(cfg.run.matmul_precision)
    learner = learner or Learner(cfg, devices=jax.local_devices()[:1])
    timer = Timer(log)
    ts, env = learner.init()
    # the epoch first: its first call compiles it and moves the robots on from their
    # resets, so that every part runs on robots in motion
    ts, env, metrics = timer.add("epoch", learner.epoch, ts, env)
    parts = EpochParts(learner)
    for name in ("call", "physics", "task", "env"):
        timer.add(name, parts.programs[name], ts, env)
    _, data, _ = timer.add("rollout", parts.programs["rollout"], ts, env)
    data = jax.tree.map(lambda x: x[:, :, -1], data)  # (devices, seeds, iteration, ...)
    timer.add("call (data)", parts.programs["call"], ts, data)
    for name in ("update", "normalizer", "gae"):
        timer.add(name, parts.programs[name], ts, data)
    host_ts = first_device(ts)
    timer.add("evaluation", learner.evaluate, host_ts)
    timer.add("metrics to host", to_host, metrics)
    timer.add("state to host (evaluation)", first_device, ts)
    timer.add("state to host (checkpoint)", lambda *x: to_host(x), ts, env)
    programs = timer.run(repeats)
    if trace_dir:
        log(f"tracing one epoch into {trace_dir}")
        with jax.profiler.trace(trace_dir):
            jax.block_until_ready(learner.epoch(ts, env))
    return report(cfg, learner, programs)


def report(cfg: TrainConfig, learner: Learner, programs: dict[str, Timing]) -> dict[str, Any]:
    """The table's rows (seconds per epoch of the run loop) from the programs' medians."""
    t = {name: p["median_s"] for name, p in programs.items()}
    for name in ("physics", "task", "env", "rollout"):  # a call's own cost is not the part's
        t[name] -= t["call"]
    for name in ("update", "normalizer", "gae"):  # one iteration's
        t[name] = (t[name] - t["call (data)"]) * cfg.run.epoch_iterations
    r = cfg.run
    iters = r.epoch_iterations
    rows = [
        ("physics (MJX step)", t["physics"], "physics"),
        ("observation, reward, commands", t["task"], "task"),
        ("automatic resets, transitions", t["env"] - t["task"], "env - task"),
        ("policy inference (rollout)", t["rollout"] - t["env"], "rollout - env"),
        ("observation normalizer", t["normalizer"], "normalizer"),
        ("GAE", t["gae"], "gae"),
        (
            "update: forward, backward, optimizer",
            t["update"] - t["normalizer"] - t["gae"],
            "update - normalizer - gae",
        ),
    ]
    parts_sum = sum(s for _, s, _ in rows)
    rows.append(("rest of the epoch (not in a part)", t["epoch"] - parts_sum, "epoch - parts"))
    host = (
        t["metrics to host"]
        + t["state to host (evaluation)"] / r.eval_every
        + t["state to host (checkpoint)"] / r.checkpoint_every
    )
    rows.append((f"periodic evaluation (1 in {r.eval_every})", t["evaluation"] / r.eval_every, ""))
    rows.append(("host syncs and transfers", host, "metrics; state for evaluation, checkpoint"))
    loop_s = t["epoch"] + rows[-2][1] + host
    steps = cfg.steps_per_iteration * iters * len(r.seeds)
    env = learner.env
    return {
        **machine_record(cfg, env.robot.impl),
        "shapes": {
            "devices": learner.n_devices,
            "seeds": len(r.seeds),
            "robots_per_seed_and_device": learner.envs_per_device,
            "unroll_length": cfg.ppo.unroll_length,
            "unrolls_per_iteration": learner.unrolls_per_iteration,
            "iterations_per_epoch": iters,
            "minibatches": cfg.ppo.num_minibatches,
            "updates_per_batch": cfg.ppo.num_updates_per_batch,
            "substeps": env.substeps,
            "eval_every": r.eval_every,
            "checkpoint_every": r.checkpoint_every,
        },
        "parts": [
            {"part": name, "s_per_epoch": s, "share": s / loop_s, "from": how}
            for name, s, how in rows
        ],
        "epoch_s": t["epoch"],
        "sum_of_parts_s": parts_sum,
        "loop_epoch_s": loop_s,
        "env_steps_per_epoch": steps,
        "env_steps_per_s": steps / t["epoch"],
        "env_steps_per_s_loop": steps / loop_s,
        "physics_env_steps_per_s": steps / t["physics"],
        "programs": programs,
    }


def table(result: dict[str, Any]) -> Table:
    s = result["shapes"]
    title = (
        f"One training epoch of {result['config']} on {result['device']} "
        f"({result['physics_impl']} physics, {s['devices']} device(s) × {s['seeds']} seed(s) × "
        f"{s['robots_per_seed_and_device']} robots)"
    )
    out = Table(title=title)
    for col in ("part", "s / epoch", "share", "from programs"):
        out.add_column(col, justify="left" if col in ("part", "from programs") else "right")
    for p in result["parts"]:
        out.add_row(p["part"], f"{p['s_per_epoch']:.4f}", f"{100 * p['share']:.1f}%", p["from"])
    out.add_section()
    out.add_row("one epoch of the run loop", f"{result['loop_epoch_s']:.4f}", "100.0%", "")
    return out


def summary(result: dict[str, Any]) -> str:
    ratio = result["sum_of_parts_s"] / result["epoch_s"]
    return (
        f"sum of the epoch's parts {result['sum_of_parts_s']:.4f} s against one measured "
        f"epoch {result['epoch_s']:.4f} s ({100 * ratio:.0f}%); env steps/s: "
        f"{result['env_steps_per_s']:,.0f} in the epoch, {result['env_steps_per_s_loop']:,.0f} "
        f"in the run loop, {result['physics_env_steps_per_s']:,.0f} for the physics alone"
    )


def check_out_path(flag: str, value: str | None, directory: bool) -> None:
    """Fail before compiling where a ``--json-out``/``--trace-dir`` could not be written."""
    if value is None:
        return
    path = Path(value)
    if directory:
        if path.exists() and not path.is_dir():
            raise ConfigError(f"{flag} = {value!r}: exists and is not a directory")
    elif path.is_dir() or not path.absolute().parent.is_dir():
        raise ConfigError(f"{flag} = {value!r}: not a file in an existing directory")


def main(argv: list[str] | None = None) -> int:
    argv = compilation_cache.configure(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog="python -m train.tools.profile",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", default="gpu")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds (median)")
    parser.add_argument("--json-out", default=None)
    parser.add_argument("--trace-dir", default=None, help="also trace one epoch (jax.profiler)")
    args, flags = parser.parse_known_args(argv)
    console = report_console()
    try:
        if args.repeats < 1:
            raise ConfigError(f"--repeats = {args.repeats}: must be >= 1")
        check_out_path("--json-out", args.json_out, directory=False)
        check_out_path("--trace-dir", args.trace_dir, directory=True)
        cfg = apply_flags(load_train_config(args.config), flags, parser.prog)
    except ConfigError as err:
        print_error(console, err)
        return 2
    result = measure(cfg, args.repeats, args.trace_dir, console.log)
    console.print(table(result))
    console.print(summary(result))
    if args.json_out:
        write_json(Path(args.json_out), result)
        console.log(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "measure", "report", "table"]
