"""Cold start of training: from process start to the first evaluation, phase by phase.

Runs what ``mecanum-train`` runs before its first evaluation, in its order: the config,
the trainer's imports (the stored programs loading meanwhile), the model and environment
build (:class:`train.learner.ppo.Learner`); where the baseline runs first
(``train.loop.aot.first_runs_alone``, as under Warp) the reset, the epoch and the
evaluation compiled together before any of them runs (``train.loop.aot.compile_together``,
unless ``--compile-together off``); the robots' reset; the evaluation of the analytic
baseline (first where the baseline runs first; elsewhere begun beside the first epoch, as
``mecanum-train`` does, and its phase is the wait for it after that epoch); the first
epoch; the policy's evaluation (``mecanum-train`` evaluates each session's first epoch);
and then a second epoch (compiled already: the first one's compilation shows as the
difference). With
``--to-end``, the rest of the run's epochs and the trained policy's evaluation follow: the
time from a fresh process to a trained, evaluated policy.

The programs come from the warm-start store as in ``mecanum-train``
(``train.loop.warm_start``; ``--warm-start off``: traced and compiled as before it).

Every program JAX compiles is listed from ``jax.monitoring``'s events: its tracing,
lowering and XLA compilation times, whether the persistent compilation cache served it
(``train.loop.compilation_cache``; a second start reads from a warm cache), and the phase it
compiled in. A name compiled more than once is a recompilation (or another program from
the same function)::

    python -m train.tools.coldstart --config gpu --json-out coldstart.json [mecanum-train flags]

Times are measured from process start (Linux ``/proc``; elsewhere from this module's
import). Prints two tables and writes JSON (``--json-out``).
"""

from __future__ import annotations

import time

T_MODULE = time.perf_counter()  # before anything heavy is imported here
CPU_AT_MODULE = time.process_time()  # the process's CPU seconds so far (all threads)

import argparse  # noqa: E402
import contextlib  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
from collections import Counter  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING, Any, cast  # noqa: E402

from train.tools.compile_log import CompileLog, Program  # noqa: E402

if TYPE_CHECKING:
    from concurrent.futures import Future

    from jax.stages import Compiled
    from rich.table import Table

    from train.learner.periodic import Result
    from train.learner.shapes import Host


def process_age_s() -> float | None:
    """Seconds since this process started (Linux), or ``None`` where unknown."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22: starttime
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


AGE_AT_MODULE = process_age_s()


class Clock:
    """Phases that tile the time from process start: each runs from the end of the one
    before to its own end (name, seconds, seconds since process start)."""

    def __init__(self, log: CompileLog):
        self.offset = (AGE_AT_MODULE or 0.0) - T_MODULE
        self.log = log
        self.phases: list[dict[str, object]] = []
        self._t, self._cpu = T_MODULE, CPU_AT_MODULE
        if AGE_AT_MODULE is not None:
            name = "interpreter, import train (jax, mecanum_jax)"
            first = {"phase": name, "s": AGE_AT_MODULE, "at_s": AGE_AT_MODULE}
            self.phases.append({**first, "cpu_s": CPU_AT_MODULE})

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[dict[str, object]]:
        """Time the block as phase ``name``; programs compiled in it are attributed to it.
        The block may add entries to the dict it gets."""
        self.log.phase = name
        extra: dict[str, object] = {}
        yield extra
        now, cpu = time.perf_counter(), time.process_time()
        at = now + self.offset
        self.phases.append(
            {"phase": name, "s": now - self._t, "at_s": at, "cpu_s": cpu - self._cpu, **extra}
        )
        self._t, self._cpu = now, cpu


def cold_start(argv: list[str], clock: Clock) -> dict[str, Any]:
    """The phases (see the module docstring); returns the report's head."""
    # as mecanum-train: the config before the trainer's modules, so that the stored
    # programs load on a thread while those import (train.loop.warm_start.begin_loading)
    with clock.phase("imports: jax, the config's modules"):
        import jax

        from train.loop import compilation_cache

        argv = compilation_cache.configure(argv)
        from mecanum_jax.config import ConfigError
        from mecanum_jax.tracing import prepare_tracing
        from train.config_loading import apply_flags, load_train_config
        from train.loop import warm_start
    cache_dir = compilation_cache.in_force()
    with clock.phase("config (load, flags, validation)"):
        parser = argparse.ArgumentParser(
            prog="python -m train.tools.coldstart", description=__doc__
        )
        parser.add_argument("--config", default="gpu")
        parser.add_argument("--json-out", default=None)
        parser.add_argument(
            "--warm-start",
            choices=("on", "off"),
            default="on",
            help="keep the compiled programs on disk for the next start, as mecanum-train "
            "does (train.loop.warm_start)",
        )
        parser.add_argument(
            "--to-end",
            action="store_true",
            help="train to ppo.num_timesteps and evaluate the trained policy",
        )
        parser.add_argument(
            "--compile-together",
            choices=("on", "off"),
            default="on",
            help="where the baseline runs first: compile the reset, the epoch and the "
            "evaluation at once before any runs, as mecanum-train does "
            "(train.loop.aot.compile_together)",
        )
        parser.add_argument(
            "--import-floor",
            action="store_true",
            help='then time `python -c "import jax, mujoco, brax"` in a fresh interpreter '
            "and print the first policy evaluation's time as a multiple of it",
        )
        args, flags = parser.parse_known_args(argv)
        try:
            if args.json_out and not Path(args.json_out).absolute().parent.is_dir():
                raise ConfigError(f"--json-out = {args.json_out!r}: its directory does not exist")
            cfg = apply_flags(load_train_config(args.config), flags, parser.prog)
        except ConfigError as err:
            print(f"error: {err}", file=sys.stderr)
            raise SystemExit(2) from None
        prepare_tracing(cfg.run.matmul_precision)
        if args.warm_start == "on":
            warm_start.begin_loading(cfg)
    with clock.phase("imports: trainer (MJX, Brax, Flax, optax)"):
        import numpy as np

        from train.learner.ppo import Learner
        from train.learner.transfer import first_device
    with clock.phase("model and environment build"):
        if args.warm_start == "on":
            ahead = warm_start.load_ahead(cfg)  # loading since the config
            learner = Learner(cfg)
            warm_start.attach(learner, lambda line: print(line, file=sys.stderr), ahead)
        else:
            learner = Learner(cfg)
    from train.loop.aot import (
        begin_baseline,
        can_compile_together,
        compile_together,
        first_runs_alone,
    )

    baseline_first = first_runs_alone(learner)  # as mecanum-train orders them
    on = args.compile_together == "on"
    together = baseline_first and on and can_compile_together(learner)
    prepared: tuple[Host | None, Compiled | None] = (None, None)
    if together:
        with clock.phase("compiling together: the reset, the epoch and the evaluation"):
            prepared = compile_together(learner)
    with clock.phase("robots' reset"):
        ts, env = jax.block_until_ready(learner.init(*prepared))

    def epoch(name: str) -> None:
        nonlocal ts, env
        with clock.phase(name) as extra:
            ts, env, metrics = learner.epoch(ts, env)
            metrics = jax.device_get(metrics)
            extra["finite"] = bool(np.all(np.asarray(metrics["finite"]) > 0))
            extra["metrics"] = {k: np.asarray(v).tolist() for k, v in metrics.items()}

    def baseline(job: Future[Result]) -> None:
        with clock.phase("first evaluation: baseline") as extra:
            extra["values"] = job.result().values

    # as mecanum-train: first and alone, or begun beside the first epoch and awaited after it
    with clock.phase("the epoch compiled, the baseline's evaluation begun"):
        job = begin_baseline(learner, ts, env)
    if baseline_first:
        baseline(job)
    epoch("first epoch")
    if not baseline_first:
        baseline(job)
    with clock.phase("first evaluation: policy") as extra:
        extra["values"] = [r.values for r in learner.evaluate(first_device(ts))]
    epoch("second epoch")
    if args.to_end:
        with clock.phase(f"the run's other {max(cfg.num_epochs - 2, 0)} epochs"):
            for _ in range(2, cfg.num_epochs):
                ts, env, _ = learner.epoch(ts, env)
            jax.block_until_ready(ts)
        with clock.phase("trained policy's evaluation") as extra:
            extra["values"] = [r.values for r in learner.evaluate(first_device(ts))]
    from train.loop.run_records import machine_record
    from train.loop.warm_start import store_of

    store = store_of(learner)

    return {
        **machine_record(cfg, learner.env.robot.impl),
        "robots": cfg.ppo.num_envs,
        "seeds": len(cfg.run.seeds),
        "devices": learner.n_devices,
        "cache": {
            "on": cache_dir is not None,
            "dir": None if cache_dir is None else str(cache_dir),
        },
        "from_process_start": AGE_AT_MODULE is not None,
        "json_out": args.json_out,
        "warm_start": None
        if store is None
        else {
            "loaded": store.loaded,
            "loaded_ahead": store.loaded_ahead,
            "written": store.written,
            "load_s": store.load_s,
            "dir": str(store.directory),
        },
        "compiled_together": together,
        "import_floor": args.import_floor,
    }


def import_floor_s() -> float:
    """Wall seconds of ``python -c "import jax, mujoco, brax"`` in a fresh interpreter."""
    import subprocess

    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import jax, mujoco, brax"], check=True)
    return time.perf_counter() - t


def summarize(result: dict[str, Any], programs: list[Program]) -> dict[str, Any]:
    """The report: the programs, slowest first, and their totals. ``recompiled``: each
    name compiled more than once, with its count and total compile time, slowest first
    (eager operations on arrays of new shapes count too)."""
    count = Counter(p["name"] for p in programs)
    seconds: dict[str, float] = {}
    for p in programs:
        seconds[p["name"]] = seconds.get(p["name"], 0.0) + p["compile_s"]
    cache = Counter(str(p["cache"]) for p in programs)
    slowest = sorted(seconds.items(), key=lambda item: -item[1])
    recompiled = {n: {"count": count[n], "compile_s": s} for n, s in slowest if count[n] > 1}
    return {
        **result,
        "programs": sorted(programs, key=lambda p: -p["compile_s"]),
        "totals": {
            "programs": len(programs),
            "compile_s": sum(p["compile_s"] for p in programs),
            "trace_s": sum(p["trace_s"] or 0.0 for p in programs),
            "lower_s": sum(p["lower_s"] or 0.0 for p in programs),
            "cache_hits": cache["hit"],
            "cache_misses": cache["miss"],
            "recompiled": recompiled,
        },
    }


def _tables(report: dict[str, Any], top: int) -> list[Table]:
    from rich.table import Table

    phases = Table(
        title=f"Cold start of {report['config']} on {report['device']} "
        f"({report['physics_impl']} physics, {report['robots']} robots, "
        f"cache {report['cache']['dir'] or 'off'})"
    )
    for col in ("phase", "s", "CPU s", "at s (from process start)"):
        phases.add_column(col, justify="left" if col == "phase" else "right")
    for p in report["phases"]:
        phases.add_row(p["phase"], f"{p['s']:.2f}", f"{p['cpu_s']:.2f}", f"{p['at_s']:.2f}")
    progs = Table(title=f"Compiled programs (the {top} slowest of {len(report['programs'])})")
    for col in ("program", "phase", "trace s", "lower s", "compile s", "cache"):
        progs.add_column(col, justify="left" if col in ("program", "phase", "cache") else "right")

    def f(x: float | None) -> str:
        return "-" if x is None else f"{x:.2f}"

    for p in report["programs"][:top]:
        progs.add_row(
            p["name"], p["phase"], f(p["trace_s"]), f(p["lower_s"]), f(p["compile_s"]),
            p["cache"] or "-",
        )  # fmt: skip
    return [phases, progs]


def main(argv: list[str] | None = None, top: int = 15) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with CompileLog() as log:
        clock = Clock(log)
        result = cold_start(argv, clock)
    result["phases"] = clock.phases
    report = summarize(result, log.programs())
    from train.loop.progress import report_console
    from train.loop.run_records import write_json

    console = report_console()
    for t in _tables(report, top):
        console.print(t)
    totals = report["totals"]
    again = totals["recompiled"]
    shown = ", ".join(
        f"{n} ×{r['count']} ({r['compile_s']:.2f} s)" for n, r in list(again.items())[:6]
    )
    console.print(
        f"{totals['programs']} programs compiled: {totals['compile_s']:.1f} s in XLA, "
        f"{totals['trace_s']:.1f} s tracing, {totals['lower_s']:.1f} s lowering; persistent "
        f"cache hits {totals['cache_hits']}, misses {totals['cache_misses']}; {len(again)} "
        f"names compiled more than once{': ' + shown if again else ''}"
        f"{' ...' if len(again) > 6 else ''}"
    )
    if loads := (report["warm_start"] or {}).get("load_s"):
        console.print(
            "warm start, loaded (read / Warp targets / onto the devices, s): "
            + "; ".join(
                f"{n} {t['read']:.2f} / {t['targets']:.2f} / {t['deserialize']:.2f}"
                for n, t in loads.items()
            )
        )
    if report.pop("import_floor"):
        floor = report["import_floor_s"] = import_floor_s()
        at = [p["at_s"] for p in clock.phases if p["phase"] == "first evaluation: policy"]
        first = cast(float, at[0])
        console.print(
            f"first policy evaluation at {first:.2f} s = {first / floor:.2f}x "
            f'`python -c "import jax, mujoco, brax"` ({floor:.2f} s)'
        )
    if report["json_out"]:
        write_json(Path(report["json_out"]), report)
        console.log(f"wrote {report['json_out']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["main", "process_age_s"]
