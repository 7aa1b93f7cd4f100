"""``mecanum-eval``: evaluate a trained policy against reference controllers on named scenarios.

Examples::

    mecanum-eval baseline                               # the reference controllers alone
    mecanum-eval models/o_rectangle                     # the shipped policy, its packaged epoch
    mecanum-eval runs/gpu-20261122-101500               # latest checkpoint, first seed
    mecanum-eval runs/gpu-.../checkpoints/40 --seed 1 --video
    mecanum-eval runs/gpu-... --only nominal slippery --episodes 8 --out runs/eval-a
    mecanum-eval runs/gpu-... --scenarios my_scenarios.toml

The reference controllers (``--references``, default all of ``env.REFERENCES``:
``analytic``, the baseline; ``analytic_nearest``; ``feedback``) always run on the same
episodes as the policy (same robots, command sequences and sensor noise), and the tables,
``report.json`` and the plots put them side by side. Every policy-vs-reference ratio comes
with a paired bootstrap 95% interval over the episodes; the policy is "better" only where
the whole interval lies below 1 (mecanum_jax/evaluation/metrics.py). Evaluation seeds come from the
scenario file, in an rng domain of their own: evaluation never replays a training stream.

Everything is written to a ``<out>.partial`` directory that is renamed to ``<out>`` only
when complete and removed on any error, so an interrupted evaluation never leaves a report
that looks finished; an existing ``<out>`` is never overwritten. Exit codes: 2 bad input
(arguments, scenario file, checkpoint) or a disk that is full or read-only (one line naming
the path), 130 interrupted.

The console tables and the plots are drawn by :mod:`train.cli.eval_output`; ``--export`` writes
the deployable policy as ``mecanum-export`` does (:mod:`mecanum_jax.deploy.write`).
"""

from __future__ import annotations

from mecanum_jax.sim.render import ensure_gl_backend

ensure_gl_backend()  # before MuJoCo is imported: OSMesa when there is no display

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402
import tyro  # noqa: E402
from rich.console import Console  # noqa: E402

from mecanum_jax import atomic, tracing  # noqa: E402
from mecanum_jax._checks import require_platform  # noqa: E402
from mecanum_jax.config import ConfigError  # noqa: E402
from mecanum_jax.deploy.write import export_policy  # noqa: E402
from mecanum_jax.evaluation import (  # noqa: E402
    compare,
    episodes,
    metrics,
    paired,
    plots,
    scenarios,
)
from mecanum_jax.evaluation.traces import (  # noqa: E402
    Trace,
    drift_parts,
    per_episode,
    summarize,
    trace_parts,
)
from mecanum_jax.kinematics import model as kinematics  # noqa: E402
from train.cli.eval_args import EvalArgs, check_args  # noqa: E402
from train.cli.eval_output import (  # noqa: E402
    comparison_table,
    results_table,
    scorecard_table,
    write_plots,
)
from train.cli.eval_target import Target, default_out  # noqa: E402
from train.cli.paths import check_output, resolve_model  # noqa: E402
from train.loop import compilation_cache  # noqa: E402
from train.loop.progress import print_error, report_console, rollout_progress  # noqa: E402
from train.loop.run_records import write_json  # noqa: E402
from train.store import checkpoint  # noqa: E402

console = Console(stderr=True)


def whos(target: Target, args: EvalArgs) -> list[str]:
    return (["policy"] if target.restored is not None else []) + list(args.references)


def evaluate(
    target: Target,
    scenario_set: scenarios.ScenarioSet,
    args: EvalArgs,
    parts_out: paired.Parts | None = None,
) -> tuple[dict[str, Any], dict[str, dict[str, Trace[np.ndarray]]], dict[str, float]]:
    """Every scenario with the policy (if any) and the references, all in as few compiled
    chunks as the batch limit allows: results, traces and timings; ``parts_out``, if
    given, also receives every controller's per-episode metric parts by scenario."""
    env = target.env
    dt = env.config.control_dt
    mcfg = metrics.MetricConfig(settle_s=args.settle_s)
    t0 = time.time()
    batches = [episodes.prepare(env, sc) for sc in scenario_set.scenarios]
    t_prepare = time.time() - t0
    players = whos(target, args)
    jobs = [(b, who) for b in batches for who in players]
    with rollout_progress(console, args.progress_every_s) as progress:
        out = target.evaluator.run_many(jobs, target.params, progress)
    t_rollout = time.time() - t0 - t_prepare
    results: dict[str, Any] = {}
    traces: dict[str, dict[str, Trace[np.ndarray]]] = {}
    jac = kinematics.jacobian(env.geometry)
    for k, sc in enumerate(scenario_set.scenarios):
        per = {who: out[k * len(players) + j] for j, who in enumerate(players)}
        traces[sc.name] = per
        parts = {who: trace_parts(tr, jac, dt, mcfg) for who, tr in per.items()}
        if sc.scripted:
            for who, tr in per.items():
                parts[who] |= drift_parts(tr, dt)
        if parts_out is not None:
            parts_out[sc.name] = parts
        first = players[0]
        refs = [r for r in players if r != first] if first == "policy" else players[1:]
        results[sc.name] = {
            "description": sc.description,
            "episodes": sc.episodes,
            "seconds": sc.seconds,
            "seed": sc.seed,
            "scripted": sc.scripted,
            "randomization": sc.randomization,  # the file's, over the nominal robot
            **{who: summarize(tr, dt, sc.scripted, jac, mcfg) for who, tr in per.items()},
            "compare": {
                f"{first}/{ref}": compare.ratios(parts[first], parts[ref], n_boot=args.bootstrap)
                for ref in refs
                if first != ref
            },
            "per_episode": {who: per_episode(tr, dt, sc.scripted, mcfg) for who, tr in per.items()},
        }
    steps = sum(int(np.prod(b.commands.shape[:2])) for b, _ in jobs)
    timing = {
        "prepare_s": round(t_prepare, 2),
        "rollout_s": round(t_rollout, 2),
        "env_steps": steps,
        "max_batch": target.evaluator.max_batch,
    }
    console.log(
        f"{len(jobs)} rollouts ({steps:,} control steps) in {t_rollout:.1f} s "
        f"(compilation included), scenarios prepared in {t_prepare:.1f} s"
    )
    return results, traces, timing


def write_videos(
    target: Target, traces: dict[str, dict[str, Trace[np.ndarray]]], args: EvalArgs, out: Path
) -> list[Path]:
    from mecanum_jax.sim.render import render_frames, write_video

    names = list(args.video_scenarios) or (
        ["six_modes"] if "six_modes" in traces else [next(iter(traces))]
    )
    unknown = [n for n in names if n not in traces]
    if unknown:
        raise ConfigError(
            f"--video-scenarios: {unknown[0]!r} was not evaluated; have {list(traces)}"
        )
    every = max(1, round(1 / (args.fps * target.env.config.control_dt)))
    fps = round(1 / (every * target.env.config.control_dt))
    w, h = args.video_size
    paths = []
    for name in names:
        clips, labels = [], []
        for who, tr in traces[name].items():
            qpos = tr.qpos[args.video_episode, ::every]
            clips.append(render_frames(target.env.robot.mj_model, qpos, w, h))
            labels.append(who)
        frames = plots.side_by_side(clips, labels)
        paths.append(write_video(frames, out / f"video_{name}.{args.video_format}", fps))
    return paths


def _error(err: BaseException) -> None:
    print_error(console, err)


def _parse(argv: list[str], prog: str, cls: type) -> Any:
    return tyro.cli(cls, args=argv, prog=prog)


def main(argv: list[str] | None = None) -> int:
    """``mecanum-eval``: see the module docstring."""
    checkpoint.quiet_closed_loop_noise()
    tracing.reproducible_gpu_ops()  # one GPU, the same figures in every process
    argv = compilation_cache.configure(sys.argv[1:] if argv is None else argv)
    args = _parse(argv, "mecanum-eval", EvalArgs)
    t_start = time.time()
    try:
        target, scenario_set, out = _prepare(args)
    except (ConfigError, checkpoint.CheckpointError, OSError) as err:
        _error(err)
        return 2
    try:  # built in <out>.partial, renamed when complete, removed on an error (atomic.py)
        with atomic.directory(out) as partial:
            console.log(
                f"evaluating {target.label} on {scenario_set.names} ({scenario_set.source})"
            )
            results = _evaluate_into(partial, target, scenario_set, args, t_start)
    except (ConfigError, OSError) as err:
        _error(atomic.explain(err, out))
        return 2
    except KeyboardInterrupt:
        console.print(f"[yellow]interrupted[/]: nothing written (no {out})")
        return 130
    title = (
        "the reference controllers"
        if target.restored is None
        else f"{target.label}: policy vs reference controllers"
    )
    out_console = report_console()
    out_console.print(results_table(results, title))
    first = whos(target, args)[0]
    for ref in args.references:
        if ref != first:
            out_console.print(comparison_table(results, f"{first}/{ref}"))
    judged = [r for r in ("analytic", "feedback") if r in args.references]
    if first == "policy" and judged:  # the scorecard: against the baseline and the PI loop
        out_console.print(scorecard_table(results, "policy", judged))
    console.log(f"report: {out / 'report.json'} ({time.time() - t_start:.0f} s)")
    return 0


def _prepare(args: EvalArgs) -> tuple[Target, scenarios.ScenarioSet, Path]:
    """Check everything that can be checked before a rollout: the arguments, the
    scenarios (scripted ones included), the target and the output directory."""
    require_platform()  # JAX_PLATFORMS names a backend that exists (mecanum_jax._checks)
    check_args(args)
    if args.out:  # before anything is built
        check_output(args.out, "--out")
    if args.target != "baseline":  # models/o_rectangle is found where the package is
        args.target = resolve_model(args.target)
    scenario_set = scenarios.load_scenarios(args.scenarios).select(
        args.only, args.episodes, args.seconds
    )
    target = Target(args, scenario_set)
    smallest = min(s.episodes for s in scenario_set.scenarios)
    if args.video and args.video_episode >= smallest:
        raise ConfigError(
            f"--video-episode = {args.video_episode}: scenarios have {smallest} episodes"
        )
    out = check_output(args.out or default_out(args, target), "--out")
    for sc in scenario_set.scenarios:  # fail on bad scenarios before any rollout
        if sc.scripted:
            episodes.scripted_commands(target.env, sc)
    return target, scenario_set, out


def _evaluate_into(
    partial: Path,
    target: Target,
    scenario_set: scenarios.ScenarioSet,
    args: EvalArgs,
    t_start: float,
) -> dict[str, Any]:
    """Run the evaluation and write its plots, videos, export, per-episode parts
    (``parts.npz``) and report.json into ``partial``; returns the results."""
    parts: paired.Parts = {}
    results, traces, timing = evaluate(target, scenario_set, args, parts)
    dt = target.env.config.control_dt
    paired.save_parts(partial / paired.PARTS_FILE, parts)  # for scripts/compare_policies.py
    files: list[Path] = [partial / paired.PARTS_FILE]
    if args.plots:
        files += write_plots(results, traces, dt, partial)
    if args.video:
        files += write_videos(target, traces, args, partial)
    if args.export and target.restored is not None:
        files.append(export_policy(*target.restored.export_arrays(), partial / "policy.npz"))
    report = {
        "target": args.target,
        "label": target.label,
        "epoch": None if target.restored is None else target.restored.epoch,
        "seed": None if target.restored is None else target.restored.seed,
        "robot": target.env.desc.robot.name,
        "scenario_file": scenario_set.source,
        "device": str(jax.devices()[0]),
        "matmul_precision": target.precision,
        "fidelity": target.env.robot.fidelity,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "wall_s": round(time.time() - t_start, 2),
        "timing": timing,
        "files": sorted(p.name for p in files),
        "scenarios": results,
    }
    write_json(partial / "report.json", report)
    return results


__all__ = [
    "EvalArgs",
    "comparison_table",
    "evaluate",
    "main",
    "results_table",
]


if __name__ == "__main__":
    sys.exit(main())
