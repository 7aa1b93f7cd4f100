"""Velocity commands: how they are drawn (:class:`CommandConfig`) and when they change.

Commands are sampled per robot and resampled at random times: zeros, pure translations in
every direction, pure spins, combinations, and commands beyond reach (more than the
wheels' rate limits allow), each a fraction of the feasible set's radius in its direction
(from the description's motor limits). A layout that cannot drive some twist (an
X-square cannot spin) gets commands projected onto the twists it can reach.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mecanum_jax.config import invalid, require
from mecanum_jax.kinematics import limits, singularity
from mecanum_jax.task.constants import RobotConstants

COMMAND_KINDS = ("zero", "translation", "spin", "combined", "beyond")
"""The kinds of command, in the order of :class:`CommandConfig`'s ``p_*`` weights."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CommandConfig:
    """How commands are drawn. Fractions are of the feasible set's radius in the direction.

    The kind of each command is drawn with the relative weights p_*.
    """

    p_zero: float = 0.15
    """Relative weight of the zero command (standing still) (>= 0)."""
    p_translation: float = 0.5
    """Relative weight of pure translations in a uniform direction (>= 0)."""
    p_spin: float = 0.15
    """Relative weight of pure spins (>= 0)."""
    p_combined: float = 0.35
    """Relative weight of translation and spin together (>= 0)."""
    p_beyond: float = 0.1
    """Relative weight of commands beyond the wheels' reach (>= 0)."""
    min_fraction: float = 0.1
    """Smallest reachable command, as a fraction of the feasible radius (0 <= min <= max)."""
    max_fraction: float = 0.8
    """Largest reachable command, as a fraction of the feasible radius."""
    beyond_min_fraction: float = 1.1
    """Smallest out-of-reach command, as a fraction of the feasible radius (>= 1)."""
    beyond_max_fraction: float = 1.5
    """Largest out-of-reach command, as a fraction of the feasible radius."""
    resample_min_s: float = 0.5
    """Shortest time a command is held before a new one is drawn, s (> 0)."""
    resample_max_s: float = 2.5
    """Longest time a command is held, s (>= resample_min_s)."""

    def validate(self, where: str = "env.commands") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        kinds = tuple(f"p_{kind}" for kind in COMMAND_KINDS)
        require(self, where, kinds, lambda v: v >= 0, "must be >= 0")
        weights = [getattr(self, k) for k in kinds]
        if sum(weights) <= 0:
            raise invalid(f"{where}.p_*", weights, "at least one kind must have weight > 0")
        if not 0 <= self.min_fraction <= self.max_fraction:
            raise invalid(
                f"{where}.min_fraction", self.min_fraction, "need 0 <= min <= max_fraction"
            )
        if not 1 <= self.beyond_min_fraction <= self.beyond_max_fraction:
            raise invalid(
                f"{where}.beyond_min_fraction",
                self.beyond_min_fraction,
                "need 1 <= beyond_min_fraction <= beyond_max_fraction",
            )
        if not 0 < self.resample_min_s <= self.resample_max_s:
            raise invalid(f"{where}.resample_min_s", self.resample_min_s, "need 0 < min <= max")


def sample_command(robot: RobotConstants, key: jax.Array, c: CommandConfig) -> jax.Array:
    """One command (vx, vy, ωz) for ``robot`` from the mix of kinds of ``c``."""
    k_kind, k_angle, k_dir, k_sign, k_frac, k_beyond = jax.random.split(key, 6)
    weights = jnp.array([c.p_zero, c.p_translation, c.p_spin, c.p_combined, c.p_beyond])
    kind = jax.random.categorical(k_kind, jnp.log(weights))
    angle = jax.random.uniform(k_angle, (), minval=-jnp.pi, maxval=jnp.pi)
    translation = jnp.stack([jnp.cos(angle), jnp.sin(angle), jnp.asarray(0.0)])
    spin = jnp.array([0.0, 0.0, 1.0]) * jnp.where(jax.random.bernoulli(k_sign), 1.0, -1.0)
    # combined: a random direction in command space, each axis scaled to its reach
    combined = jax.random.normal(k_dir, (3,)) * robot.command_scale
    direction = jnp.select(
        [kind == 1, kind == 2], [translation, spin], jnp.where(kind == 0, 0.0, combined)
    )
    direction = singularity.project_reachable(direction, robot.reachable)
    norm = jnp.linalg.norm(direction)
    unit = direction / jnp.where(norm > 0, norm, 1.0)
    reach = limits.max_speed(robot.geometry, jnp.where(norm > 0, unit, 1.0), robot.max_rates)
    frac = jax.random.uniform(k_frac, (), minval=c.min_fraction, maxval=c.max_fraction)
    beyond = jax.random.uniform(
        k_beyond, (), minval=c.beyond_min_fraction, maxval=c.beyond_max_fraction
    )
    frac = jnp.where(kind == 4, beyond, frac)
    return jnp.where(kind == 0, 0.0, unit * reach * frac)


def resample_time(key: jax.Array, now: jax.Array, c: CommandConfig, dt: float) -> jax.Array:
    """The control step (of ``dt`` s) at which the command drawn at step ``now`` is replaced."""
    # jnp (not Python) arithmetic: evaluation passes the config's values as traced arrays
    lo = jnp.maximum(1, jnp.round(jnp.asarray(c.resample_min_s) / dt)).astype(jnp.int32)
    hi = jnp.maximum(lo, jnp.round(jnp.asarray(c.resample_max_s) / dt).astype(jnp.int32))
    return now + jax.random.randint(key, (), lo, hi + 1)


def command_schedule(
    robot: RobotConstants, key: jax.Array, steps: int, c: CommandConfig, dt: float
) -> jax.Array:
    """``(steps, 3)`` commands as an episode (control period ``dt`` s) would draw them: a
    first command, then a new one at random times (the training task's process, from ``c``)."""
    k0, k1, key = jax.random.split(key, 3)
    first = sample_command(robot, k0, c)
    start = resample_time(k1, jnp.asarray(0, jnp.int32), c, dt)

    def step(carry: tuple, t: jax.Array) -> tuple[tuple, jax.Array]:
        cmd, due, k = carry
        k, k_cmd, k_time = jax.random.split(k, 3)
        now = t >= due
        cmd = jnp.where(now, sample_command(robot, k_cmd, c), cmd)
        due = jnp.where(now, resample_time(k_time, t, c, dt), due)
        return (cmd, due, k), cmd

    _, out = jax.lax.scan(step, (first, start, key), jnp.arange(steps, dtype=jnp.int32))
    return out


__all__ = [
    "COMMAND_KINDS",
    "CommandConfig",
    "command_schedule",
    "resample_time",
    "sample_command",
]
