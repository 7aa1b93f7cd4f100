"""The main job until training lands: wheel rates of seed 000's six motion modes.

Run: ``mecanum-demo [--robot o_rectangle] [--speed 0.5]``.
"""

from __future__ import annotations

import dataclasses
import sys

import jax.numpy as jnp
import tyro
from rich.console import Console
from rich.table import Table

from mecanum_jax._checks import require_platform
from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.kinematics import motors, singularity
from mecanum_jax.kinematics.modes import SIX_MODES
from mecanum_jax.sim.description import resolve_description
from mecanum_jax.tracing import prepare_tracing

MAX_SPEED = 100.0
"""The largest ``--speed`` accepted, m/s or rad/s: far beyond any wheel, well short of 1e9."""


@dataclasses.dataclass(frozen=True)
class DemoArgs:
    """Print the wheel and motor speeds of seed 000's six motion modes."""

    robot: str = "o_rectangle"
    """Built-in robot description name (configs/robots/NAME.toml) or a path to a .toml file."""
    speed: float = 0.5
    """Linear speed (m/s) of translations and spin rate (rad/s) of the spins."""


def main(argv: list[str] | None = None) -> int:
    """``mecanum-demo``: exit code 2 for a bad speed or robot description."""
    args = tyro.cli(DemoArgs, args=argv, prog="mecanum-demo")
    try:
        require_platform()  # JAX_PLATFORMS names a backend that exists
        prepare_tracing("highest")
        if not 0 < args.speed <= MAX_SPEED:
            raise ConfigError(
                f"--speed = {args.speed!r}: must be a number > 0 and at most {MAX_SPEED} "
                "(m/s or rad/s; a mecanum robot's motors reach a few)"
            )
        desc = resolve_description(args.robot)
        geom = desc.build_geometry(warn_singular=False)
    except (ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    singularity.warn_unreachable(geom, desc.robot.name)  # rank < 3: the modes are projected
    modes = jnp.asarray([t for _, t, _ in SIX_MODES.values()]) * args.speed
    twists = singularity.project_reachable(modes, singularity.reachable_projector(geom))
    rates = kinematics.inverse(geom, twists)
    signs = desc.motor_signs(geom.names)
    rpm = motors.wheel_rates_to_motor_rpm(rates, jnp.asarray(signs), desc.motors.gear_ratio)
    back = rates @ jnp.asarray(singularity.reachable_forward_matrix(geom), rates.dtype).T

    title = f"{desc.robot.name}: seed 000's six motion modes at speed {args.speed}"
    table = Table(title=title, caption="wheel rates, rad/s (+ rolls the robot forward)")
    rpm_table = Table(caption="motor shaft speeds, rpm (mirrored motors turn the other way)")
    for t in (table, rpm_table):
        t.add_column("mode", no_wrap=True)
    table.add_column("twist vx, vy, wz", no_wrap=True)
    for name in geom.names:
        table.add_column(_short(name), justify="right", no_wrap=True)
        rpm_table.add_column(_short(name), justify="right", no_wrap=True)
    table.add_column("forward(rates)", no_wrap=True)
    for (key, (label, _, _)), t, w, m, b in zip(
        SIX_MODES.items(), twists, rates, rpm, back, strict=True
    ):
        mode = f"{key[0]}) {label}"
        table.add_row(mode, _fmt(t), *(f"{float(x):+.2f}" for x in w), _fmt(b))
        rpm_table.add_row(mode, *(f"{float(x):+.0f}" for x in m))
    console = Console(width=max(Console().width, 120))
    console.print(table)
    console.print(rpm_table)
    console.print(
        f"Jacobian rank {kinematics.jacobian_rank(geom)}, condition number "
        f"{float(kinematics.condition_number(geom)):.3f}; motor signs {signs}"
    )
    return 0


def _fmt(v: jnp.ndarray) -> str:
    return ", ".join(f"{float(x):+.2f}" for x in v)


def _short(name: str) -> str:
    """left_front -> LF, wheel_2 -> W2: compact column headers."""
    return "".join(part[0].upper() if part.isalpha() else part for part in name.split("_"))


if __name__ == "__main__":
    sys.exit(main())
