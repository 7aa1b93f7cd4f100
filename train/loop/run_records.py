"""What a training run writes and shows: atomic JSON, the per-seed rows of metrics.jsonl,
summary.json, and the progress display's figures (train.loop.run drives them)."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NotRequired, TypedDict

import jax
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from mecanum_jax import atomic
from train.loop.progress import TrainLines, evaluation_text, wants_lines
from train.loop.progress import count as _si

if TYPE_CHECKING:  # (the learner's evaluation imports the physics: a command line that
    # refuses its input before training need not)
    from train.config import TrainConfig
    from train.learner.periodic import Comparison, Result

Evals = Mapping[str, Mapping[str, np.ndarray]]
"""Per scenario and metric, the seeds' values (:func:`stacked`)."""
Values = Mapping[str, Mapping[str, float | None]]
"""Per scenario, one controller's metrics (``Result.values``)."""


class SeedSummary(TypedDict):
    """One seed's entry in summary.json: the epoch, env steps and wall time it first beat
    the baseline at (``None``: not yet), its last evaluation and comparison, if any."""

    seed: int
    beat_baseline: Mapping[str, float] | None
    eval: NotRequired[dict[str, dict[str, float]]]
    compare: NotRequired[Comparison]


class Summary(TypedDict):
    """summary.json (:func:`summary`)."""

    name: str
    run_dir: str
    epochs: int
    env_steps_per_seed: int
    walltime_s: float
    session_s: float
    devices: int | None
    processes: int
    device_kind: str
    baseline: Values
    seeds: list[SeedSummary]


def jsonable(x: object) -> object:
    """``x`` with numpy values as Python ones and non-finite floats as strings."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.generic | np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def write_json(path: Path, data: object) -> None:
    """Write atomically (:mod:`mecanum_jax.atomic`): a crash or a full disk never leaves a
    half-written file that looks complete, nor a temporary one."""
    atomic.write_json(path, jsonable(data))


def keep_rows(path: Path, epoch: int) -> int:
    """Cut ``path`` (metrics.jsonl) back to its rows of epochs up to ``epoch``, the
    checkpoint a run resumes from, so the epochs it trains again are not logged twice;
    a line cut short by a killed process goes too. Atomic; returns how many lines went."""
    if not path.exists():
        return 0
    lines = path.read_text().splitlines(keepends=True)
    kept = []
    for line in lines:
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if line.endswith("\n") and isinstance(row, dict) and row.get("epoch", 0) <= epoch:
            kept.append(line)
    if len(kept) < len(lines):
        atomic.write_text(path, "".join(kept))
    return len(lines) - len(kept)


def machine_record(cfg: TrainConfig, physics_impl: str) -> dict[str, str]:
    """Where and when a benchmark ran: device, platform, jax, date, config, physics, and the
    ``XLA_FLAGS`` it compiled with (the command lines add theirs: ``mecanum_jax.tracing``)."""
    return {
        "device": jax.devices()[0].device_kind,
        "platform": jax.default_backend(),
        "jax": jax.__version__,
        "date": time.strftime("%Y-%m-%d"),
        "config": cfg.name,
        "physics_impl": physics_impl,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def stacked(results: list[Result]) -> dict[str, dict[str, np.ndarray]]:
    """Per scenario and metric, the seeds' values ``(S,)`` (NaN where undefined)."""
    first = results[0].values

    def value(r: Result, name: str, k: str) -> float:
        v = r.values[name][k]
        return np.nan if v is None else v

    return {  # metrics undefined for every seed (drift, on unscripted episodes) are left out
        name: {
            k: np.array([value(r, name, k) for r in results])
            for k in first[name]
            if any(r.values[name][k] is not None for r in results)
        }
        for name in first
    }


def _per_seed(evals: Evals, i: int) -> dict[str, dict[str, float]]:
    return {name: {k: float(v[i]) for k, v in res.items()} for name, res in evals.items()}


def seed_rows(
    seeds: Sequence[int],
    metrics: dict[str, np.ndarray],
    evals: Evals,
    baseline: Values,
    sps: float | None = None,
    comps: list[Comparison] | None = None,
) -> list[dict[str, object]]:
    """One metrics.jsonl row per seed: training metrics, and the evaluation if one ran."""
    rows = []
    for i, seed in enumerate(seeds):
        train = {k: float(v[i]) for k, v in metrics.items()}
        if sps is not None:
            train["steps_per_s"] = sps
        row: dict[str, object] = {"seed": seed, "train": train}
        if evals:
            row["eval"] = _per_seed(evals, i)
            row["baseline"] = baseline
        if comps:
            row["compare"] = comps[i]
        rows.append(row)
    return rows


def summary(
    cfg: TrainConfig,
    run_dir: Path,
    epoch: int,
    walltime: float,
    evals: Evals,
    comps: list[Comparison],
    baseline: Values,
    beat_at: Mapping[str, Mapping[str, float]],
    t_start: float,
    devices: int | None,
) -> Summary:
    """summary.json: the run's length and time, and each seed's last evaluation."""
    per_seed = []
    for i, seed in enumerate(cfg.run.seeds):
        entry: SeedSummary = {"seed": seed, "beat_baseline": beat_at.get(str(seed))}
        if evals:
            entry["eval"] = _per_seed(evals, i)
        if comps:
            entry["compare"] = comps[i]
        per_seed.append(entry)
    return {
        "name": cfg.name,
        "run_dir": str(run_dir),
        "epochs": epoch,
        "env_steps_per_seed": epoch * cfg.steps_per_iteration * cfg.run.epoch_iterations,
        "walltime_s": walltime,
        "session_s": time.time() - t_start,
        "devices": devices,
        "processes": jax.process_count(),
        "device_kind": jax.devices()[0].device_kind,
        "baseline": baseline,
        "seeds": per_seed,
    }


def shown(policy: Mapping[str, np.ndarray], baseline: Mapping[str, float | None]) -> str:
    """The progress line's figures: steady-state error of the policy / the baseline."""

    def pair(key: str) -> str:
        if key not in policy or baseline.get(key) is None:
            return "-"
        return f"{float(np.nanmean(policy[key])):.2f}/{baseline[key]:.2f}"

    return f"ss v {pair('ss_lin')} ω {pair('ss_wz')}"


def flatten(d: Mapping[str, object], prefix: str = "") -> dict[str, object]:
    """A nested dict as ``{"a/b/c": value}``."""
    out: dict[str, object] = {}
    for k, v in d.items():
        key = f"{prefix}/{k}" if prefix else k
        if isinstance(v, dict):
            out |= flatten(v, key)
        else:
            out[key] = v
    return out


class TrainProgress:
    """The progress line: steps, env steps/s, time left, the last evaluation's figures; on
    a terminal rich's live display, elsewhere plain lines (train.loop.progress)."""

    def __init__(
        self,
        console: Console,
        name: str,
        every_s: float,
        writer: bool,
        total_steps: int,
        done_steps: int,
        t_start: float,
        time_limit_s: float | None = None,
    ):
        self.total = total_steps
        self.lines = TrainLines(
            console,
            every_s,
            writer and wants_lines(console),
            label=name,
            total_steps=total_steps,
            t_start=t_start,
            time_limit_s=time_limit_s,
            done_steps=done_steps,
        )
        self.bar = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(bar_width=8),
            TextColumn("{task.fields[steps]}"),
            TextColumn("{task.fields[sps]}/s"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[info]}"),
            console=console,
            disable=not writer or self.lines.enabled,
        )
        self.task = self.bar.add_task(
            name[:12],
            total=total_steps,
            completed=done_steps,
            steps=f"{_si(done_steps)}/{_si(total_steps)}",
            sps="-",
            info="compiling",
        )
        if writer and not self.lines.enabled:
            console.log(
                "progress: steps, env steps/s, time left | steady-state error of v (m/s) and "
                "ω (rad/s), policy/baseline, on held-out randomized episodes"
            )

    def update(
        self,
        epoch: int,
        done: int,
        sps: float,
        results: list[Result],
        comparisons: list[Comparison],
        info: str,
        final: bool = False,
    ) -> None:
        steps = f"{_si(done)}/{_si(self.total)}"
        self.bar.update(self.task, completed=done, steps=steps, sps=_si(sps), info=info)
        figures = evaluation_text(done, stacked(results), comparisons) if results else None
        self.lines.update(epoch, done, sps, figures, final)
