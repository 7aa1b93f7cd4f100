"""``mecanum-bench kinematics``: batched kinematics against NumPy and the memory roofline.

It times inverse, forward and odometry over batch sizes, on
whatever device JAX has, side by side with a NumPy implementation of the same maths in
the same run. It reports throughput (robots/s) and, against a device copy of the same
number of bytes measured in the same run, the fraction of the memory-bandwidth roofline.
It warms up first, blocks on results before reading clocks, and reports the median of
several repeats; it prints a table and writes JSON.

Variants timed:

- ``inverse``: the API, ``kinematics.inverse`` on twists (B, 3) → rates (B, 4).
- ``inverse_soa``: the same maths on component-major arrays (3, B) → (4, B)
  (``kinematics.inverse_soa``), the layout GPUs read fastest.
- ``forward``: rates (B, 4) → twists (B, 3).
- ``odometry``: ``odometry.integrate_increments`` of T body increments (T, B, 3) to
  the final pose (B, 3).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from mecanum_jax.bench_report import header, median_spread, warn_spread, write_json
from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import geometry, odometry
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.memory import available_bytes

DEFAULT_SIZES = (1_000, 10_000, 100_000, 1_000_000, 10_000_000, 100_000_000)


@dataclasses.dataclass(frozen=True)
class KinematicsBench:
    """Time batched inverse/forward/odometry against NumPy and a device-copy roofline."""

    sizes: tuple[int, ...] = DEFAULT_SIZES
    """Batch sizes (robots)."""
    repeats: int = 7
    """Timed repeats per measurement; the median is reported."""
    min_time: float = 0.02
    """Each repeat calls the function enough times to last at least this many seconds."""
    odometry_steps: int = 8
    """Time steps T integrated per robot in the odometry benchmark."""
    ops: tuple[str, ...] = ("inverse", "inverse_soa", "forward", "odometry")
    """Which operations to time."""
    numpy: bool = True
    """Also time the NumPy reference (skipped automatically above numpy_max_size)."""
    numpy_max_size: int = 100_000_000
    """Largest batch for which the NumPy reference is timed."""
    memory_fraction: float = 0.6
    """Skip a size whose buffers would exceed this fraction of the device's (or host's) memory."""
    json_out: Path | None = None
    """Write the results as JSON here."""


def _time(
    fn: Callable[[], object],
    repeats: int,
    min_time: float,
    block: Callable[[object], object] | None = None,
) -> tuple[float, float]:
    """Median seconds per call of ``fn``, and the repeats' spread (bench_report.median_spread).

    Without ``block`` each call is synchronous (NumPy, or a blocking JAX call: latency).
    With ``block``, calls are dispatched back to back and only the last result is waited
    for, as a pipeline of batches runs (throughput); ``block`` waits for one result.
    """
    wait = block or (lambda _: None)
    wait(fn())  # warm up (compiles on first use)
    start = time.perf_counter()
    wait(fn())
    once = max(time.perf_counter() - start, 1e-7)
    inner = max(1, int(min_time / once))
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = None
        for _ in range(inner):
            out = fn()
        wait(out)
        samples.append((time.perf_counter() - start) / inner)
    return median_spread(samples)


def _block(x: object) -> object:
    return jax.block_until_ready(x)


def _call_and_block(call: Callable[[], object]) -> object:
    return _block(call())


# --- NumPy reference: the same maths, written for NumPy ------------------------------------


def numpy_inverse(J: np.ndarray, twist: np.ndarray) -> np.ndarray:
    return twist @ J.T


def numpy_forward(F: np.ndarray, rates: np.ndarray) -> np.ndarray:
    return rates @ F.T


def numpy_integrate(pose: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Exact SE(2) integration (series below |φ| < 1e-3), vectorised over robots."""
    pose = pose.copy()
    for inc in increments:
        phi = inc[:, 2]
        small = np.abs(phi) < 1e-3
        safe = np.where(small, 1.0, phi)
        p2 = phi * phi
        a = np.where(small, 1 - p2 / 6 * (1 - p2 / 20), np.sin(safe) / safe)
        b = np.where(small, phi / 2 * (1 - p2 / 12 * (1 - p2 / 30)), (1 - np.cos(safe)) / safe)
        dx = a * inc[:, 0] - b * inc[:, 1]
        dy = b * inc[:, 0] + a * inc[:, 1]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        pose[:, 0] += c * dx - s * dy
        pose[:, 1] += s * dx + c * dy
        pose[:, 2] += phi
    return pose


# --- the benchmark -------------------------------------------------------------------------


def _bytes_moved(op: str, size: int, steps: int) -> int:
    per_robot = {
        "inverse": 3 + 4,
        "inverse_soa": 3 + 4,
        "forward": 4 + 3,
        "odometry": steps * 3 + 3 + 3,
    }
    return per_robot[op] * 4 * size


def _make_calls(
    op: str,
    size: int,
    key: jax.Array,
    steps: int,
    geom: geometry.WheelGeometry,
    jit_ops: dict[str, Callable[..., jax.Array]],
    J_np: np.ndarray,
    F_np: np.ndarray,
) -> tuple[Callable[[], object], Callable[[], object]]:
    """The JAX call and the NumPy reference call of one operation on fresh random data."""
    fn = jit_ops[op]
    if op == "odometry":
        inc = jax.random.normal(key, (steps, size, 3), jnp.float32) * 0.01
        pose = jnp.zeros((size, 3), jnp.float32)
        inc_np, pose_np = np.asarray(inc), np.asarray(pose)
        return (lambda: fn(pose, inc)), (lambda: numpy_integrate(pose_np, inc_np))
    cols = 4 if op == "forward" else 3
    x = jax.random.normal(key, (cols, size) if op == "inverse_soa" else (size, cols), jnp.float32)
    x_np = np.asarray(x)
    if op == "forward":
        return (lambda: fn(geom, x)), (lambda: numpy_forward(F_np, x_np))
    if op == "inverse":
        return (lambda: fn(geom, x)), (lambda: numpy_inverse(J_np, x_np))
    return (lambda: fn(geom, x)), (lambda: J_np @ x_np)


def _check_kinematics_args(args: KinematicsBench) -> None:
    for name, value in (("repeats", args.repeats), ("odometry_steps", args.odometry_steps)):
        if value < 1:
            raise ConfigError(f"--{name.replace('_', '-')} = {value}: must be >= 1")
    bad = [s for s in args.sizes if s < 1]
    if bad or not args.sizes:
        raise ConfigError(
            f"--sizes = {list(args.sizes)}: "
            f"{bad[0] if bad else 'none'} is not a positive batch size"
        )
    unknown = sorted(set(args.ops) - {"inverse", "inverse_soa", "forward", "odometry"})
    if unknown:
        raise ConfigError(
            f"--ops: unknown operation {unknown[0]!r}; "
            "known: inverse, inverse_soa, forward, odometry"
        )


def run_kinematics(args: KinematicsBench, console: Console | None = None) -> dict[str, Any]:
    """Run the kinematics benchmark; returns the JSON-able results."""
    console = console or Console(width=max(Console().width, 130))
    _check_kinematics_args(args)
    geom = geometry.o_rectangle(0.05, 0.10, 0.125)
    J_np = np.asarray(kinematics.jacobian(geom))
    F_np = np.asarray(kinematics.forward_matrix(geom))
    jit_ops: dict[str, Callable[..., jax.Array]] = {
        "inverse": jax.jit(kinematics.inverse),
        "inverse_soa": jax.jit(kinematics.inverse_soa),
        "forward": jax.jit(kinematics.forward),
        "odometry": jax.jit(lambda p, d: odometry.integrate_increments(p, d, return_path=False)),
    }
    rows: list[dict[str, Any]] = []
    for size in args.sizes:
        need = max(_bytes_moved(op, size, args.odometry_steps) for op in args.ops) * 3
        if need > args.memory_fraction * available_bytes():
            console.print(
                f"[yellow]batch {size:.0e}: skipped, needs ~{need / 2**30:.1f} GiB[/yellow]"
            )
            rows.append({"size": size, "skipped": "memory"})
            continue
        key = jax.random.PRNGKey(size % (2**31))
        for op in args.ops:
            calls = _make_calls(op, size, key, args.odometry_steps, geom, jit_ops, J_np, F_np)
            rows.append(_time_op(args, op, size, *calls))
    result = {
        **header("kinematics", args),
        "devices": len(jax.devices()),
        "host": platform.node(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "results": rows,
    }
    _print_table(result, console)
    write_json(result, args.json_out, console)
    return result


_copy = jax.jit(lambda x: x + jnp.float32(1))


def _time_op(
    args: KinematicsBench, op: str, size: int, call: Callable[[], object], ref: Callable[[], object]
) -> dict[str, Any]:
    """One row: the JAX call's throughput and latency, a copy of as many bytes (the
    bandwidth roofline) and, for small batches, NumPy."""
    moved = _bytes_moved(op, size, args.odometry_steps)
    t_jax, s_jax = _time(call, args.repeats, args.min_time, _block)
    t_latency, s_latency = _time(
        functools.partial(_call_and_block, call), args.repeats, args.min_time
    )
    del call
    half = jnp.zeros((max(moved // 8, 1),), jnp.float32)  # read + write = moved bytes
    t_copy, s_copy = _time(functools.partial(_copy, half), args.repeats, args.min_time, _block)
    del half
    t_np, s_np = None, None
    if args.numpy and size <= args.numpy_max_size:
        t_np, s_np = _time(ref, max(3, args.repeats // 2), args.min_time)
    spread = {"jax": s_jax, "latency": s_latency, "copy": s_copy, "numpy": s_np}
    return {
        "spread": {k: v for k, v in spread.items() if v is not None},
        "op": op,
        "size": size,
        "jax_s": t_jax,
        "jax_latency_s": t_latency,
        "numpy_s": t_np,
        "copy_s": t_copy,
        "bytes": moved,
        "jax_robots_per_s": size / t_jax,
        "numpy_robots_per_s": size / t_np if t_np else None,
        "jax_over_numpy": t_np / t_jax if t_np else None,
        "jax_GBps": moved / t_jax / 1e9,
        "copy_GBps": moved / t_copy / 1e9,
        "roofline_fraction": t_copy / t_jax,
    }


def _print_table(result: dict[str, Any], console: Console) -> None:
    table = Table(
        title=f"kinematics on {result['device']} (jax {result['jax']}), median of repeats",
        caption="JAX robots/s: calls dispatched back to back (throughput); latency: one "
        "blocking call; roofline: JAX GB/s over a device copy of the same bytes; spread: "
        "the row's largest (max − min)/median over repeats",
    )
    for col in (
        "op",
        "batch",
        "JAX robots/s",
        "NumPy robots/s",
        "JAX/NumPy",
        "latency µs",
        "JAX GB/s",
        "copy GB/s",
        "roofline",
        "spread",
    ):
        table.add_column(col, justify="right")
    for r in result["results"]:
        if "skipped" in r:
            table.add_row("—", f"{r['size']:.0e}", "skipped (memory)", *[""] * 7)
            continue
        np_rate = f"{r['numpy_robots_per_s']:.3g}" if r["numpy_robots_per_s"] else "—"
        ratio = f"{r['jax_over_numpy']:.2f}×" if r["jax_over_numpy"] else "—"
        table.add_row(
            r["op"],
            f"{r['size']:.0e}",
            f"{r['jax_robots_per_s']:.3g}",
            np_rate,
            ratio,
            f"{1e6 * r['jax_latency_s']:.1f}",
            f"{r['jax_GBps']:.1f}",
            f"{r['copy_GBps']:.1f}",
            f"{100 * r['roofline_fraction']:.0f}%",
            f"{100 * max(r['spread'].values()):.0f}%",
        )
    console.print(table)
    for r in result["results"]:
        for figure, spread in r.get("spread", {}).items():
            warn_spread(console, f"{r['op']} batch {r['size']:.0e}, {figure} time", spread)


__all__ = ["KinematicsBench", "numpy_forward", "numpy_integrate", "numpy_inverse", "run_kinematics"]
