"""``mecanum-bench physics``: batched MJX physics steps per second, per fidelity, MJX
implementation and servo model, over batch sizes.

One jitted, vmapped call of ``steps`` physics steps per batch size (on the CPU in chunks,
:mod:`mecanum_jax.sim.batching`), the median of several repeats after a compiling call.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from mecanum_jax.bench_report import header, median_spread, warn_spread, write_json
from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import model as kinematics

if TYPE_CHECKING:
    from mecanum_jax.sim.physics import Robot  # MJX import is slow: for type checking only


@dataclasses.dataclass(frozen=True)
class PhysicsBench:
    """Time batched MJX physics steps per second for each fidelity over batch sizes."""

    sizes: tuple[int, ...] = (1, 16, 256, 4096, 16384, 65536)
    """Batch sizes (robots)."""
    fidelities: tuple[str, ...] = ("fast", "reference")
    """Which model fidelities to time."""
    robot: str = "o_rectangle"
    """Built-in robot description."""
    steps: int = 50
    """Physics steps per timed call (one jitted scan)."""
    repeats: int = 3
    """Timed repeats; the median is reported."""
    max_reference_size: int = 16384
    """Largest batch for the (slow) reference fidelity."""
    ls_iterations: int | None = None
    """Override the description's line-search iterations (to explore speed)."""
    servos: tuple[str, ...] = ("chord",)
    """Servo models to time side by side: chord (the default) and/or mjx (MJX's own)."""
    impls: tuple[str, ...] = ("jax",)
    """MJX implementations to time side by side: jax and/or warp (the warp extra)."""
    json_out: Path | None = None
    """Write the results as JSON here."""


def time_physics(
    robot: Robot, sizes: Sequence[int], steps: int, repeats: int
) -> list[dict[str, Any]]:
    """Time ``robot`` (a :class:`physics.Robot`): one jitted, vmapped call of ``steps``
    physics steps per batch size, median of ``repeats`` after a compiling call."""
    from mecanum_jax.sim.batching import chunked_vmap, cpu_chunk

    params1 = robot.nominal_params()
    cmd1 = kinematics.inverse(robot.geometry, jnp.array([0.3, 0.1, 0.5]))
    chunk = cpu_chunk(robot.fidelity, robot.impl)  # CPU: jaxlib's LAPACK deadlock
    run = jax.jit(chunked_vmap(functools.partial(robot.step, substeps=steps), chunk))
    reset = jax.jit(chunked_vmap(robot.reset, chunk))
    rows = []
    for size in sizes:
        p = jax.tree_util.tree_map(lambda x, n=size: jnp.broadcast_to(x, (n, *x.shape)), params1)
        cmd = jnp.broadcast_to(cmd1, (size, cmd1.shape[0]))
        state = reset(p, jnp.zeros((size, 3)))
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(state, cmd, p))
        compile_s = time.perf_counter() - t0
        samples = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            state = jax.block_until_ready(run(state, cmd, p))
            samples.append(time.perf_counter() - t0)
        t, spread = median_spread(samples)
        rows.append(
            {"size": size, "seconds_per_call": t, "spread": spread, "compile_s": compile_s,
             "steps_per_s": size * steps / t, "unstable": int(np.asarray(state.unstable).sum())}
        )  # fmt: skip
    return rows


def run_physics(args: PhysicsBench, console: Console | None = None) -> dict[str, Any]:
    """Physics steps per second (robots × steps / wall time) for each fidelity and batch."""
    from mecanum_jax.sim import physics  # MJX import is slow: only when asked
    from mecanum_jax.sim.description import IMPLS, builtin_description

    console = console or Console(width=max(Console().width, 110))
    _check_physics_args(args, IMPLS)
    desc = builtin_description(args.robot)
    if args.ls_iterations is not None:
        desc = dataclasses.replace(
            desc, sim=dataclasses.replace(desc.sim, ls_iterations=args.ls_iterations)
        )
    rows: list[dict[str, Any]] = []
    for fidelity, impl, servo in itertools.product(args.fidelities, args.impls, args.servos):
        sizes = [n for n in args.sizes if fidelity == "fast" or n <= args.max_reference_size]
        sim = dataclasses.replace(desc.sim, impl=impl)
        robot = physics.Robot(
            dataclasses.replace(desc, sim=sim),
            fidelity,  # type: ignore[arg-type]
            servo=servo,  # type: ignore[arg-type]
            robots=max(sizes, default=1),
        )
        for row in time_physics(robot, sizes, args.steps, args.repeats):
            rows.append({"fidelity": fidelity, "impl": impl, "servo": servo, **row})
            what = f"{fidelity:9s} {impl:4s} {servo:5s} batch {row['size']:6d}"
            console.print(f"{what}: {row['steps_per_s']:12.4g} steps/s")
            warn_spread(console, what.replace("  ", " ").strip(), row["spread"])
    result = {**header("physics", args), "results": rows}
    console.print(_physics_table(result, args.steps))
    write_json(result, args.json_out, console)
    return result


def _check_physics_args(args: PhysicsBench, impls: tuple[str, ...]) -> None:
    bad = sorted(set(args.fidelities) - {"fast", "reference"})
    if bad:
        raise ConfigError(f"--fidelities: unknown fidelity {bad[0]!r}; known: fast, reference")
    bad = sorted(set(args.servos) - {"chord", "mjx"})
    if bad or not args.servos:
        raise ConfigError(f"--servos: {list(args.servos)}: expected chord and/or mjx")
    bad = sorted(set(args.impls) - set(impls))
    if bad or not args.impls:
        raise ConfigError(f"--impls: {list(args.impls)}: expected {' and/or '.join(impls)}")
    for flag, value in (("steps", args.steps), ("repeats", args.repeats)):
        if value < 1:
            raise ConfigError(f"--{flag} = {value}: must be >= 1")
    if not args.sizes or any(n < 1 for n in args.sizes):
        raise ConfigError(f"--sizes = {list(args.sizes)}: must be >= 1")


def _physics_table(result: dict[str, Any], steps: int) -> Table:
    table = Table(title=f"MJX physics on {result['device']} (jax {result['jax']})")
    for col in (
        "fidelity",
        "impl",
        "servo",
        "batch",
        "physics steps/s",
        "ms per step",
        "compile s",
        "unstable",
        "spread",
    ):
        table.add_column(col, justify="right")
    for r in result["results"]:
        ms = 1e3 * r["seconds_per_call"] / steps
        cells = (r["fidelity"], r["impl"], r["servo"], str(r["size"]), f"{r['steps_per_s']:.4g}")
        spread = f"{100 * r['spread']:.0f}%"  # (max − min) / median over the repeats
        table.add_row(*cells, f"{ms:.3f}", f"{r['compile_s']:.1f}", str(r["unstable"]), spread)
    return table


__all__ = ["PhysicsBench", "run_physics", "time_physics"]
