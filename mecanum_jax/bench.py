"""``mecanum-bench``: benchmarks that are product features.

- ``mecanum-bench kinematics``: batched inverse, forward and odometry against NumPy and a
  device-copy roofline (:mod:`mecanum_jax.bench_kinematics`);
- ``mecanum-bench physics``: batched MJX physics steps per second
  (:mod:`mecanum_jax.bench_physics`);
- ``mecanum-bench drives``: the mecanum robot's velocity space against the other drives'
  (:class:`DrivesComparison`).

Each prints a table and writes JSON (:mod:`mecanum_jax.bench_report`).
"""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import jax
import tyro
from rich.console import Console
from rich.table import Table

from mecanum_jax._checks import require_platform
from mecanum_jax.bench_kinematics import KinematicsBench, run_kinematics
from mecanum_jax.bench_physics import PhysicsBench, run_physics
from mecanum_jax.bench_report import write_json
from mecanum_jax.config import ConfigError
from mecanum_jax.tracing import prepare_tracing


@dataclasses.dataclass(frozen=True)
class DrivesComparison:
    """Compare the mecanum robot's velocity space with the other drives' (seed 000 §4)."""

    robot: str = "o_rectangle"
    """The mecanum robot (built-in name or TOML path); its wheel-rate limit applies to all."""
    drives: tuple[str, ...] = ("differential", "tricycle", "synchronous", "ackermann")
    """The other drives (built-in names from configs/robots/drives or TOML paths)."""
    out: Path = Path("velocity_spaces")
    """Directory for velocity_spaces.json and velocity_spaces.png."""


def run_drives(args: DrivesComparison) -> list[dict[str, object]]:
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
    write_json(result, args.out / "velocity_spaces.json", console)
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


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mecanum-bench``: exit 2 with one ``error:`` line for a bad argument."""
    _ensure_malloc_tuning(argv)
    cmd = tyro.extras.subcommand_cli_from_dict(
        {"kinematics": KinematicsBench, "physics": PhysicsBench, "drives": DrivesComparison},
        args=argv,
    )
    try:
        require_platform()
        prepare_tracing("highest")  # one number on every device (mecanum_jax.tracing)
        if isinstance(cmd, DrivesComparison):
            run_drives(cmd)
        elif isinstance(cmd, KinematicsBench):
            run_kinematics(cmd)
        elif isinstance(cmd, PhysicsBench):
            run_physics(cmd)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
