"""Domain randomization: the per-robot physical parameters drawn at every reset.

Floor friction and its per-wheel spread, payload mass and position, wheel-radius error
(the baseline keeps the nominal geometry), torque limit, servo gains and observation
latency, each uniform in the ranges of :class:`RandomizationConfig`; a share of the robots
can be the nominal robot instead.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mecanum_jax.config import invalid, require
from mecanum_jax.sim.state import RobotParams
from mecanum_jax.task.constants import RobotConstants


@dataclasses.dataclass(frozen=True)
class RandomizationConfig:
    """Per-robot domain randomization, drawn uniformly at each reset (enabled = false:
    the nominal robot on the description's floor friction, no payload, no latency).

    The payload's centre of mass is payload_com_offset plus a uniform draw in
    ±payload_com_xy (x, y) and payload_com_z (z), in the body frame.
    """

    enabled: bool = True
    """Randomize at all (false: the nominal robot, no payload, no latency)."""
    friction: tuple[float, float] = (0.1, 1.5)
    """Floor friction coefficient range [lo, hi] (> 0)."""
    wheel_friction_spread: float = 0.1
    """Per-wheel relative friction spread around the floor's, ± fraction in [0, 1)."""
    payload_mass: tuple[float, float] = (0.0, 3.0)
    """Payload mass range, kg (>= 0)."""
    payload_com_xy: float = 0.08
    """Payload centre of mass: uniform ± this in x and y, m, in [0, 1)."""
    payload_com_z: tuple[float, float] = (0.0, 0.06)
    """Payload centre of mass z range in the body frame, m."""
    payload_com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Fixed payload centre-of-mass offset (x, y, z) added to the draw, m (|x| < 1)."""
    radius_scale: tuple[float, float] = (0.95, 1.05)
    """True wheel radius / nominal radius, range (> 0); the controller keeps the nominal."""
    wheel_radius_spread: float = 0.01
    """Per-wheel relative radius spread around the draw, ± fraction in [0, 1)."""
    torque_scale: tuple[float, float] = (0.5, 1.0)
    """Motor torque limit / nominal limit, range (> 0)."""
    gain_scale: tuple[float, float] = (0.7, 1.3)
    """Wheel servo gain / nominal gain, range (> 0)."""
    latency_steps: tuple[int, int] = (0, 2)
    """Observation latency in whole control steps, range (0 <= lo <= hi <= 10)."""
    nominal_share: float = 0.25
    """Share of robots that are the nominal robot instead (the description's friction, no
    payload, nominal radii, motors and gains, no latency), in [0, 1]."""

    def validate(self, where: str = "env.randomization") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        for name in (
            "friction",
            "payload_mass",
            "payload_com_z",
            "radius_scale",
            "torque_scale",
            "gain_scale",
            "latency_steps",
        ):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise invalid(f"{where}.{name}", [lo, hi], "lower bound above upper bound")
        for name in ("friction", "radius_scale", "torque_scale", "gain_scale"):
            if getattr(self, name)[0] <= 0:
                raise invalid(f"{where}.{name}", list(getattr(self, name)), "must be > 0")
        if self.payload_mass[0] < 0:
            raise invalid(f"{where}.payload_mass", list(self.payload_mass), "must be >= 0")
        if any(abs(x) >= 1 for x in self.payload_com_offset):
            raise invalid(
                f"{where}.payload_com_offset", list(self.payload_com_offset), "need |x| < 1 m"
            )
        if self.latency_steps[0] < 0 or self.latency_steps[1] > 10:
            raise invalid(
                f"{where}.latency_steps", list(self.latency_steps), "need 0 <= lo <= hi <= 10"
            )
        require(self, where, ("nominal_share",), lambda v: 0 <= v <= 1, "must be in [0, 1]")
        require(
            self,
            where,
            ("wheel_friction_spread", "wheel_radius_spread", "payload_com_xy"),
            lambda v: 0 <= v < 1,
            "must be in [0, 1)",
        )


# A pytree (like CommandConfig), so evaluation can pass their values as traced arrays (one
# compiled sampler for every scenario); ``enabled`` stays static.
jax.tree_util.register_dataclass(
    RandomizationConfig,
    data_fields=[f.name for f in dataclasses.fields(RandomizationConfig) if f.name != "enabled"],
    meta_fields=["enabled"],
)


def sample_params(
    robot: RobotConstants, key: jax.Array, r: RandomizationConfig
) -> tuple[RobotParams, jax.Array]:
    """Physical parameters around ``robot``'s nominal ones, and observation latency
    (steps), drawn from ``r``."""
    nom = robot.nominal_params
    if not r.enabled:
        return nom, jnp.asarray(0, jnp.int32)
    n = robot.n_wheels
    ks = jax.random.split(key, 10)

    def u(k: jax.Array, lo: float, hi: float, shape: tuple[int, ...] = ()) -> jax.Array:
        return jax.random.uniform(k, shape, minval=lo, maxval=hi)

    spread = r.wheel_friction_spread
    friction = u(ks[0], *r.friction) * u(ks[1], 1 - spread, 1 + spread, (n,))
    xy = u(ks[2], -r.payload_com_xy, r.payload_com_xy, (2,))
    com = jnp.concatenate([xy, u(ks[3], *r.payload_com_z, (1,))]) + jnp.asarray(
        r.payload_com_offset, jnp.float32
    )
    rs = r.wheel_radius_spread
    radius = u(ks[4], *r.radius_scale) * u(ks[5], 1 - rs, 1 + rs, (n,))
    gain = u(ks[7], *r.gain_scale)
    params = nom._replace(
        friction=friction,
        payload_mass=u(ks[6], *r.payload_mass),
        payload_com=com,
        radius_scale=radius,
        torque_limit=nom.torque_limit * u(ks[8], *r.torque_scale),
        kp=nom.kp * gain,
        ki=nom.ki * gain,
    )
    lo, hi = r.latency_steps
    latency = jax.random.randint(ks[9], (), lo, hi + 1)
    # a key of its own, so the other draws are those of a config without nominal robots
    nominal = jax.random.uniform(jax.random.fold_in(key, 1)) < r.nominal_share
    params = jax.tree.map(lambda a, b: jnp.where(nominal, a, b), nom, params)
    return params, jnp.where(nominal, 0, latency)


__all__ = ["RandomizationConfig", "sample_params"]
