"""``mecanum-bench``: benchmarks that are product features.

``mecanum-bench kinematics`` times inverse, forward and odometry over batch sizes, on
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
import datetime
import functools
import itertools
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import geometry, odometry
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.precision import set_matmul_precision

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
    robot: Any, sizes: Sequence[int], steps: int, repeats: int
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
        t = statistics.median(samples)
        rows.append(
            {"size": size, "seconds_per_call": t, "compile_s": compile_s,
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
            console.print(
                f"{fidelity:9s} {impl:4s} {servo:5s} batch {row['size']:6d}: "
                f"{row['steps_per_s']:12.4g} steps/s"
            )
    result = {**_header("physics", args), "results": rows}
    console.print(_physics_table(result, args.steps))
    _write_json(result, args.json_out, console)
    return result


def _header(benchmark: str, args: Any) -> dict[str, Any]:
    """What every benchmark's JSON starts with: the date, the device and the arguments."""
    device = jax.devices()[0]
    return {
        "benchmark": benchmark,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "device": f"{device.platform}: {device.device_kind}",
        "jax": jax.__version__,
        "config": {
            k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(args).items()
        },
    }


def _check_physics_args(args: PhysicsBench, impls: tuple[str, ...]) -> None:
    bad = sorted(set(args.fidelities) - {"fast", "reference"})
    if bad:
        raise SystemExit(f"--fidelities: unknown fidelity {bad[0]!r}; known: fast, reference")
    bad = sorted(set(args.servos) - {"chord", "mjx"})
    if bad or not args.servos:
        raise SystemExit(f"--servos: {list(args.servos)}: expected chord and/or mjx")
    bad = sorted(set(args.impls) - set(impls))
    if bad or not args.impls:
        raise SystemExit(f"--impls: {list(args.impls)}: expected {' and/or '.join(impls)}")
    if args.steps < 1 or args.repeats < 1 or any(n < 1 for n in args.sizes):
        raise SystemExit(
            f"--steps = {args.steps}, --repeats = {args.repeats}, "
            f"--sizes = {list(args.sizes)}: all must be >= 1"
        )


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
    ):
        table.add_column(col, justify="right")
    for r in result["results"]:
        ms = 1e3 * r["seconds_per_call"] / steps
        cells = (r["fidelity"], r["impl"], r["servo"], str(r["size"]), f"{r['steps_per_s']:.4g}")
        table.add_row(*cells, f"{ms:.3f}", f"{r['compile_s']:.1f}", str(r["unstable"]))
    return table


def _write_json(result: dict[str, Any], path: Path | None, console: Console) -> None:
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(path)  # never leaves a half-written file
    console.print(f"wrote {path}")


def _available_bytes() -> int:
    dev = jax.devices()[0]
    try:
        stats = dev.memory_stats()
    except Exception:
        stats = None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES"))


def _time(
    fn: Callable[[], Any], repeats: int, min_time: float, block: Callable[[Any], Any] | None = None
) -> float:
    """Median seconds per call of ``fn``.

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
    return statistics.median(samples)


def _block(x: Any) -> Any:
    return jax.block_until_ready(x)


def _call_and_block(call: Callable[[], Any]) -> Any:
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
) -> tuple[Callable[[], Any], Callable[[], Any]]:
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
            raise SystemExit(f"--{name.replace('_', '-')} = {value}: must be >= 1")
    bad = [s for s in args.sizes if s < 1]
    if bad:
        raise SystemExit(f"--sizes: {bad[0]} is not a positive batch size")
    unknown = sorted(set(args.ops) - {"inverse", "inverse_soa", "forward", "odometry"})
    if unknown:
        raise SystemExit(
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
        if need > args.memory_fraction * _available_bytes():
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
        **_header("kinematics", args),
        "devices": len(jax.devices()),
        "host": platform.node(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "results": rows,
    }
    _print_table(result, console)
    _write_json(result, args.json_out, console)
    return result


_copy = jax.jit(lambda x: x + jnp.float32(1))


def _time_op(
    args: KinematicsBench, op: str, size: int, call: Callable[[], Any], ref: Callable[[], Any]
) -> dict[str, Any]:
    """One row: the JAX call's throughput and latency, a copy of as many bytes (the
    bandwidth roofline) and, for small batches, NumPy."""
    moved = _bytes_moved(op, size, args.odometry_steps)
    t_jax = _time(call, args.repeats, args.min_time, _block)
    t_latency = _time(functools.partial(_call_and_block, call), args.repeats, args.min_time)
    del call
    half = jnp.zeros((max(moved // 8, 1),), jnp.float32)  # read + write = moved bytes
    t_copy = _time(functools.partial(_copy, half), args.repeats, args.min_time, _block)
    del half
    t_np = None
    if args.numpy and size <= args.numpy_max_size:
        t_np = _time(ref, max(3, args.repeats // 2), args.min_time)
    return {
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
        "blocking call; roofline: JAX GB/s over a device copy of the same bytes",
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
    ):
        table.add_column(col, justify="right")
    for r in result["results"]:
        if "skipped" in r:
            table.add_row("—", f"{r['size']:.0e}", "skipped (memory)", "", "", "", "", "", "")
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
        )
    console.print(table)


@dataclasses.dataclass(frozen=True)
class DrivesComparison:
    """Compare the mecanum robot's velocity space with the other drives' (seed 000 §4)."""

    robot: str = "o_rectangle"
    """The mecanum robot (built-in name or TOML path); its wheel-rate limit applies to all."""
    drives: tuple[str, ...] = ("differential", "tricycle", "synchronous", "ackermann")
    """The other drives (built-in names from configs/robots/drives or TOML paths)."""
    out: Path = Path("velocity_spaces")
    """Directory for velocity_spaces.json and velocity_spaces.png."""


def run_drives(args: DrivesComparison) -> list[dict[str, Any]]:
    """Print the table, write the JSON and the plot."""
    from mecanum_jax.evaluation import velocity_space

    console = Console()
    with jax.enable_x64(True):
        spaces, max_rate = velocity_space.compare(args.robot, args.drives)
    table = Table(title=f"Velocity spaces at equal wheel-rate limits ({max_rate:.2f} rad/s)")
    columns = {
        "drive": "drive",
        "max_vx": "vx m/s",
        "max_vy": "vy m/s",
        "max_wz": "ωz rad/s",
        "max_diagonal": "diag m/s",
        "area_v_wz": "(vx,ωz) area",
        "area_vx_vy": "(vx,vy) area",
        "volume": "volume",
        "force_efficiency_forward": "eff fwd",
        "force_efficiency_sideways": "eff side",
    }
    for title in ("robot", *columns.values()):
        table.add_column(title)
    rows = [dataclasses.asdict(sp) for sp in spaces]
    for row in rows:
        cells = [str(row[k]) if k == "drive" else f"{row[k]:.3g}" for k in columns]
        table.add_row(row["name"], *cells)
    console.print(table)
    result = {"max_wheel_rate": max_rate, "mecanum": args.robot, "spaces": rows}
    _write_json(result, args.out / "velocity_spaces.json", console)
    with jax.enable_x64(True):
        png = velocity_space.plot(args.robot, args.drives, args.out / "velocity_spaces.png")
    console.print(f"wrote {png}")
    return rows


def _ensure_malloc_tuning(argv: list[str] | None) -> None:
    """Re-exec once with glibc's malloc backing large buffers by transparent huge pages.

    XLA:CPU allocates a fresh output buffer per call; with 4 KiB pages the page faults on
    it cost more than the arithmetic (a copy runs at ~6 GB/s instead of ~28 GB/s on the
    CI machine, docs/benchmarks.md). ``GLIBC_TUNABLES=glibc.malloc.hugetlb=1`` fixes it for
    the whole process. Set ``MECANUM_NO_MALLOC_TUNING=1`` to measure without it.
    """
    if argv is not None:  # called from Python, not as the command: never replace the process
        return
    tunables = os.environ.get("GLIBC_TUNABLES", "")
    if (
        sys.platform != "linux"
        or "glibc.malloc.hugetlb" in tunables
        or os.environ.get("MECANUM_NO_MALLOC_TUNING")
    ):
        return
    env = dict(os.environ)
    env["GLIBC_TUNABLES"] = ":".join(t for t in (tunables, "glibc.malloc.hugetlb=1") if t)
    os.execve(sys.executable, [sys.executable, "-m", "mecanum_jax.bench", *sys.argv[1:]], env)


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``mecanum-bench``."""
    _ensure_malloc_tuning(argv)
    set_matmul_precision("highest")  # one number on every device (mecanum_jax.precision)
    cmd = tyro.extras.subcommand_cli_from_dict(
        {"kinematics": KinematicsBench, "physics": PhysicsBench, "drives": DrivesComparison},
        args=argv,
    )
    if isinstance(cmd, DrivesComparison):
        run_drives(cmd)
    elif isinstance(cmd, KinematicsBench):
        run_kinematics(cmd)
    elif isinstance(cmd, PhysicsBench):
        try:
            run_physics(cmd)
        except ConfigError as err:
            raise SystemExit(f"error: {err}") from None


if __name__ == "__main__":
    main()
