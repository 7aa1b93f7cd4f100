"""Command lines: ``mecanum-train`` (one run) and ``mecanum-train-batch`` (seeds × variants).

Examples::

    mecanum-train                    # the quick CPU default (configs/train/quick.toml)
    mecanum-train --config gpu --ppo.num-timesteps 50_000_000
    mecanum-train --resume runs/quick-20261122-101500
    mecanum-train-batch --configs quick tiny --seeds 0 1 2 --out runs/compare

Any config field can be overridden with a flag named by its dotted path
(``--ppo.learning-rate 1e-3``, ``--env.randomization.friction 0.3 1.0``); see
``mecanum-train --help``. Exit codes: 2 bad config or run directory (one in use by another
process included), or a disk that is full or read-only (one line naming the path; the last
good checkpoint is kept and status.json says ``failed: no space``: resume once freed), 3 diverged,
130 interrupted by Ctrl-C, 143 stopped by SIGTERM, 138 by SIGUSR1 (128 + the signal;
a checkpoint was written: resume with --resume; train/loop/preemption.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypedDict

import jax
from rich.console import Console
from rich.table import Table

from mecanum_jax import memory
from mecanum_jax._checks import require_platform
from mecanum_jax.config import ConfigError, find_config
from mecanum_jax.sim.description import require_impl
from train.cli.paths import check_input_dir, check_output
from train.config import TrainConfig
from train.config_loading import TRAIN_CONFIG_DIR, apply_flags, load_train_config
from train.loop import compilation_cache, curve, warm_start
from train.loop.distributed import init_distributed
from train.loop.divergence import TrainingDiverged
from train.loop.progress import print_error
from train.loop.run_dir import RunDirError
from train.loop.run_records import Summary, write_json
from train.store import checkpoint, inputs, lock

if TYPE_CHECKING:  # the trainer (the learner, MJX, Brax) is imported once the input passed
    from train.loop.run import Run

console = Console(stderr=True)


class Diverged(TypedDict):
    """A batch variant's entry in the batch's summary.json where it diverged."""

    name: str
    run_dir: str
    diverged: str


def _meta_parser(prog: str, batch: bool) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, add_help=False)
    if batch:
        p.add_argument("--configs", nargs="+", default=["quick"])
        p.add_argument("--seeds", nargs="+", type=int, default=None)
        p.add_argument("--out", default=None)
    else:
        p.add_argument("--config", default=None)
        p.add_argument("--run-dir", default=None)
        p.add_argument("--resume", default=None)
    p.add_argument("--max-minutes", type=float, default=None)
    p.add_argument("--distributed", action="store_true")
    return p


def _f(x: float | str | None) -> str:
    """A figure for a table: four decimals, "-" where undefined."""
    return "-" if x is None or not math.isfinite(float(x)) else f"{float(x):.4f}"


def results_table(summary: Summary, title: str) -> Table:
    """Policy against baseline per scenario and seed (final evaluation): steady-state error
    against the nearest feasible twist (train.learner.periodic)."""
    table = Table(title=title)
    for col in ("seed", "scenario", "ss v (m/s)", "base", "ss ω (rad/s)", "base", "beat at"):
        table.add_column(col)
    for entry in summary["seeds"]:
        beat = entry.get("beat_baseline")
        beat_s = f"{beat['walltime']:.0f} s / {beat['env_steps']:,}" if beat else "not yet"
        for name, ev in entry.get("eval", {}).items():
            b = summary["baseline"][name]
            table.add_row(
                str(entry["seed"]),
                name,
                _f(ev["ss_lin"]),
                _f(b["ss_lin"]),
                _f(ev["ss_wz"]),
                _f(b["ss_wz"]),
                beat_s if name == "randomized" else "",
            )
    return table


def _fail(err: BaseException, code: int) -> int:
    print_error(console, err)
    return code


def _check_meta(meta: argparse.Namespace) -> None:
    """The options outside the config: a time limit is a positive number of minutes."""
    m = meta.max_minutes
    if m is not None and not 0 < m < math.inf:
        raise ConfigError(f"--max-minutes = {m}: must be a positive number of minutes")


def _require_memory(cfg: TrainConfig) -> None:
    """Refuse a config whose estimated footprint (mecanum_jax.memory) exceeds the memory,
    naming the larger part: the training batch, or the periodic evaluation's traces (its
    two scenarios, each of run.num_eval_envs episodes a seed)."""
    p, r, seeds = cfg.ppo, cfg.run, len(cfg.run.seeds)
    train = memory.training_bytes(
        seeds * p.num_envs, seeds * p.batch_size * p.num_minibatches, p.unroll_length
    )
    evaluation = memory.evaluation_bytes(2 * seeds * r.num_eval_envs, r.eval_episode_length, 1)
    need = train + evaluation - memory.BASE_BYTES  # one process: its base counted once
    if evaluation > train:
        where = (
            f"run.num_eval_envs = {r.num_eval_envs}, run.eval_episode_length = "
            f"{r.eval_episode_length} ({seeds} seed(s))"
        )
        fix = "use fewer --run.num-eval-envs or a shorter --run.eval-episode-length"
    else:
        where = f"ppo.num_envs = {p.num_envs}, ppo.batch_size = {p.batch_size} ({seeds} seed(s))"
        fix = "use fewer --ppo.num-envs and --ppo.batch-size"
    memory.require_memory(need, where, fix)


def _config_file(name: str) -> Path:
    """The config file a run was given, copied into its inputs/ (train.store.inputs)."""
    return find_config(name, TRAIN_CONFIG_DIR, "config", "")


_HELD: list[Path] = []


def _hold(run: Run) -> Run:
    """The run directory's lock, held until the command ends (train.loop.run_dir): the
    learning curve written after training too."""
    if run.is_writer:
        lock.acquire(run.dir)
        _HELD.append(run.dir)
    return run


class Command(Protocol):
    """A command line's ``main``: its arguments (default: ``sys.argv``'s) to an exit code."""

    def __call__(self, argv: list[str] | None = None) -> int: ...


def _releasing(command: Command) -> Command:
    """``command`` giving back the locks :func:`_hold` took when it returns (an in-process
    caller, a test, may resume the run from another process next)."""

    @functools.wraps(command)
    def run(argv: list[str] | None = None) -> int:
        try:
            return int(command(argv))
        finally:
            while _HELD:
                lock.release(_HELD.pop())

    return run


@_releasing
def main(argv: list[str] | None = None) -> int:
    """``mecanum-train``: train one run (several seeds side by side), then evaluate it."""
    checkpoint.quiet_closed_loop_noise()
    argv = compilation_cache.configure(sys.argv[1:] if argv is None else argv)
    prog = "mecanum-train"
    meta, rest = _meta_parser(prog, batch=False).parse_known_args(argv)
    description = (
        "Train PPO on the mecanum tracking task. Options besides the config fields: "
        "--config PATH|NAME (default: quick), --run-dir DIR (default: runs/<name>-<time>), "
        "--resume DIR, --max-minutes M (stop resumably after M minutes), "
        "--distributed (multi-process through jax.distributed; see train/loop/distributed.py)."
    )
    try:
        # before anything touches JAX (loading a config may): jax.distributed requires it
        _check_meta(meta)
        init_distributed(meta.distributed)
        require_platform()  # after jax.distributed starts, before anything is built
        if meta.resume and (meta.config or meta.run_dir):
            raise ConfigError("--resume: give either --resume or --config/--run-dir, not both")
        if meta.resume:
            saved = check_input_dir(meta.resume, "--resume") / "config.json"
            if saved.exists():  # its values checked once, after the flags
                base = inputs.load_saved_config(saved.parent, validate=False)
                cfg = apply_flags(base, rest, prog, description, source=str(saved))
            else:  # Run.resume names the missing config.json
                cfg = apply_flags(TrainConfig(), rest, prog, description)
            require_impl(cfg.env.physics_impl, "env.physics_impl")
            warm_start.begin_loading(cfg)  # the stored programs, while the trainer imports
            from train.loop.run import Run

            run = _hold(Run.resume(meta.resume, overrides=cfg, console=console))
            done = checkpoint.latest_epoch(run.dir)
            if done is not None and done >= run.cfg.num_epochs:
                steps = done * run.cfg.steps_per_iteration * run.cfg.run.epoch_iterations
                console.print(
                    f"run {str(run.dir)!r} is already finished: epoch {done} of "
                    f"{run.cfg.num_epochs} ({steps:,} env steps per seed). Its results: "
                    f"{run.dir / 'summary.json'}; evaluate it with mecanum-eval {run.dir}; "
                    "train it further with --resume and a larger --ppo.num-timesteps"
                )
                return 0
        else:
            cfg = load_train_config(meta.config or "quick", rest, prog, description)
            if meta.distributed and not meta.run_dir:
                raise ConfigError(
                    "--distributed: give --run-dir (a default name from the clock could "
                    "differ between processes)"
                )
            require_impl(cfg.env.physics_impl, "env.physics_impl")  # before the run dir
            if Path(meta.config or "quick").stem == "gpu" and jax.default_backend() == "cpu":
                console.print(
                    "[yellow]warning[/]: --config gpu on a CPU: its first epoch alone takes "
                    "about 10 minutes here, and --max-minutes stops only between epochs; "
                    "on a CPU use --config quick"
                )
            _require_memory(cfg)  # before the run dir too: a refused run leaves none
            run_dir = meta.run_dir or f"runs/{cfg.name}-{time.strftime('%Y%m%d-%H%M%S')}"
            check_output(run_dir, "--run-dir", empty_dir_ok=True)
            config_file = _config_file(meta.config or "quick")
            warm_start.begin_loading(cfg)  # the stored programs, while the trainer imports
            from train.loop.run import Run

            run = _hold(Run.create(cfg, run_dir, config_file=config_file, console=console))
        console.log(f"run directory: {run.dir}")
        limit = None if meta.max_minutes is None else 60 * meta.max_minutes
        summary = run.train(time_limit_s=limit)
    except (ConfigError, RunDirError, checkpoint.CheckpointError, OSError) as err:
        return _fail(err, 2)
    except TrainingDiverged as err:
        return _fail(err, 3)
    except KeyboardInterrupt as err:  # Ctrl-C, or a stop signal (train.loop.preemption)
        console.print("[yellow]interrupted[/]: checkpoint written; resume with --resume")
        return getattr(err, "exit_code", 130)
    out = Console()
    out.print(results_table(summary, f"{summary['name']}: policy vs analytic baseline"))
    learned = curve.learned_table(run.dir, summary["name"])
    if learned is not None:
        out.print(learned)
    _plot(run)
    console.log(f"summary: {run.dir / 'summary.json'}")
    return 0


def _plot(run: Run) -> None:
    """Write the run's learning curve (process 0 only) and say where."""
    path = curve.write_plot(run.dir) if run.is_writer else None
    if path is not None:
        console.log(f"learning curve: {path}")


@_releasing
def batch_main(argv: list[str] | None = None) -> int:
    """``mecanum-train-batch``: several config variants, each with all seeds vectorized."""
    argv = compilation_cache.configure(sys.argv[1:] if argv is None else argv)
    prog = "mecanum-train-batch"
    meta, rest = _meta_parser(prog, batch=True).parse_known_args(argv)
    out = Path(meta.out or f"runs/batch-{time.strftime('%Y%m%d-%H%M%S')}")
    description = (
        "Train several config variants (--configs A B ...), each with --seeds trained side by "
        "side, each in its own run directory under --out; ends with a comparison table. "
        "Config-field flags apply to every variant."
    )
    try:
        _check_meta(meta)
        check_output(out, "--out", empty_dir_ok=True)  # never over an earlier batch
        init_distributed(meta.distributed)
        require_platform()
        if meta.distributed and not meta.out:
            raise ConfigError(
                "--distributed: give --out (a default name from the clock could differ "
                "between processes)"
            )
        variants = []
        for name in meta.configs:
            cfg = load_train_config(name, rest, prog, description)
            if meta.seeds:
                cfg = dataclasses.replace(
                    cfg, run=dataclasses.replace(cfg.run, seeds=tuple(meta.seeds))
                ).validate()
            variants.append((Path(name).stem, cfg))
        names = [n for n, _ in variants]
        if len(set(names)) != len(names):
            raise ConfigError(f"--configs = {meta.configs}: variant names must be distinct")
        from train.loop.run import Run

        runs = [
            _hold(Run.create(cfg, out / name, config_file=_config_file(c), console=console))
            for (name, cfg), c in zip(variants, meta.configs, strict=True)
        ]
    except (ConfigError, RunDirError, OSError) as err:
        return _fail(err, 2)
    summaries: list[Summary | Diverged] = []
    for run in runs:
        console.rule(f"variant {run.cfg.name} ({run.dir})")
        try:
            limit = None if meta.max_minutes is None else 60 * meta.max_minutes
            summaries.append(run.train(time_limit_s=limit))
            _plot(run)
        except TrainingDiverged as err:
            print_error(console, err, f"{run.dir}: diverged")
            summaries.append({"name": run.cfg.name, "run_dir": str(run.dir), "diverged": str(err)})
        except KeyboardInterrupt as err:
            console.print("[yellow]interrupted[/]: checkpoint written")
            return getattr(err, "exit_code", 130)
    table = batch_table(summaries)
    Console().print(table)
    if runs[0].is_writer:
        write_json(out / "summary.json", summaries)
        console.log(f"summary: {out / 'summary.json'}")
    return 0


def batch_table(summaries: list[Summary | Diverged]) -> Table:
    table = Table(title="batch: final steady-state error (randomized eval), time to beat baseline")
    for col in ("variant", "seed", "ss v", "base v", "ss ω", "base ω", "beat baseline at"):
        table.add_column(col)
    for s in summaries:
        if "diverged" in s:
            table.add_row(s["name"], "-", "diverged", "", "", "", "")
            continue
        b = s["baseline"]["randomized"]
        for entry in s["seeds"]:
            ev = entry.get("eval", {}).get("randomized")
            beat = entry.get("beat_baseline")
            table.add_row(
                s["name"],
                str(entry["seed"]),
                _f(ev["ss_lin"]) if ev else "-",
                _f(b["ss_lin"]),
                _f(ev["ss_wz"]) if ev else "-",
                _f(b["ss_wz"]),
                f"{beat['walltime']:.0f} s ({beat['env_steps']:,} steps)" if beat else "never",
            )
    return table


if __name__ == "__main__":
    sys.exit(main())
