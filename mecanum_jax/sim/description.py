"""Robot descriptions: TOML files in ``configs/robots/`` → geometry and motor data.

One description drives both the analytic model and (later) the physics. A file has the
tables ``[robot]``, ``[geometry]`` and ``[motors]``; see ``configs/robots/*.toml`` for
commented examples. Unknown or missing keys, and keys that the chosen layout does not
use, are rejected with an error naming the key and the value; so are numbers no real
robot has (:mod:`mecanum_jax.sim.plausible`; ``allow_implausible = true`` in ``[robot]``
accepts them) and layouts that cannot drive every planar translation.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
import math
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp

from mecanum_jax.config import (
    CONFIG_DIR,
    ConfigError,
    find_config,
    from_mapping,
    parse_toml,
    read_config_bytes,
)
from mecanum_jax.kinematics import geometry as geo
from mecanum_jax.kinematics import motors, singularity
from mecanum_jax.sim import plausible
from mecanum_jax.sim.specs import (  # the tables, re-exported: callers import them from here
    ActuatorSpec as ActuatorSpec,
)
from mecanum_jax.sim.specs import (
    BodySpec as BodySpec,
)
from mecanum_jax.sim.specs import (
    GeometrySpec as GeometrySpec,
)
from mecanum_jax.sim.specs import (
    Layout as Layout,
)
from mecanum_jax.sim.specs import (
    MotorSpec as MotorSpec,
)
from mecanum_jax.sim.specs import (
    RobotSpec as RobotSpec,
)
from mecanum_jax.sim.specs import (
    SimSpec as SimSpec,
)
from mecanum_jax.sim.specs import (
    WheelSpec as WheelSpec,
)

_LAYOUT_KEYS: dict[str, tuple[str, ...]] = {
    "O-square": ("wheel_radius", "half_size"),
    "X-square": ("wheel_radius", "half_size"),
    "O-rectangle": ("wheel_radius", "half_wheelbase", "half_track"),
    "X-rectangle": ("wheel_radius", "half_wheelbase", "half_track"),
    "centripetal": ("wheel_radius", "centre_distance"),
    "custom": ("wheels",),
}
_OPTIONAL_KEYS: dict[str, tuple[str, ...]] = {
    "centripetal": ("n_wheels", "first_wheel_angle_deg", "roller_angle_deg"),
    "custom": (),
}
_ALL_GEOMETRY_KEYS = (
    "wheel_radius", "half_size", "half_wheelbase", "half_track", "centre_distance", "n_wheels",
    "first_wheel_angle_deg", "roller_angle_deg", "wheels",
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A validated robot description file."""

    robot: RobotSpec
    geometry: GeometrySpec
    motors: MotorSpec
    body: BodySpec = BodySpec()  # noqa: RUF009 (frozen)
    actuators: ActuatorSpec = ActuatorSpec()  # noqa: RUF009 (frozen)
    sim: SimSpec = SimSpec()  # noqa: RUF009 (frozen)

    def build_geometry(
        self, dtype: jax.typing.DTypeLike | None = None, warn_singular: bool = True
    ) -> geo.WheelGeometry:
        """The :class:`~mecanum_jax.kinematics.geometry.WheelGeometry` this description defines."""
        return build_geometry(self.geometry, dtype=dtype, warn_singular=warn_singular)

    def motor_signs(self, names: tuple[str, ...]) -> tuple[int, ...]:
        return self.motors.signs if self.motors.signs is not None else motors.mirrored_signs(names)

    def max_wheel_rates(self, geometry: geo.WheelGeometry) -> jax.Array:
        """Per-wheel rate limits (n,) rad/s from the motor rpm limit and the gear ratio."""
        limit = motors.max_wheel_rate(self.motors.max_motor_rpm, self.motors.gear_ratio)
        return jnp.full((geometry.n_wheels,), limit, geometry.dtype)


def _check_geometry_keys(spec: GeometrySpec) -> None:
    required = _LAYOUT_KEYS[spec.layout]
    allowed = set(required) | set(_OPTIONAL_KEYS.get(spec.layout, ("roller_angle_deg",)))
    for key in _ALL_GEOMETRY_KEYS:
        value = getattr(spec, key)
        if key in required and value is None:
            raise ConfigError(f"geometry.{key}: missing required key for layout {spec.layout!r}")
        if key not in allowed and value is not None:
            raise ConfigError(
                f"geometry.{key} = {value!r}: not used by layout {spec.layout!r}; "
                f"its keys are {sorted(allowed)}"
            )


def build_geometry(
    spec: GeometrySpec, dtype: jax.typing.DTypeLike | None = None, warn_singular: bool = True
) -> geo.WheelGeometry:
    """Build and validate the geometry of a ``[geometry]`` table."""
    _check_geometry_keys(spec)
    roller = (
        math.radians(spec.roller_angle_deg)
        if spec.roller_angle_deg is not None
        else geo.DEFAULT_ROLLER_ANGLE
    )
    try:
        if spec.layout in ("O-square", "X-square", "O-rectangle", "X-rectangle"):
            assert spec.wheel_radius is not None
            square = spec.layout.endswith("square")
            rx = spec.half_size if square else spec.half_wheelbase
            ry = spec.half_size if square else spec.half_track
            assert rx is not None
            assert ry is not None
            shape: Literal["O", "X"] = "O" if spec.layout.startswith("O") else "X"
            return geo.four_wheel(
                shape, spec.wheel_radius, rx, ry, roller, dtype=dtype, warn_singular=warn_singular
            )
        if spec.layout == "centripetal":
            assert spec.wheel_radius is not None
            assert spec.centre_distance is not None
            return geo.centripetal(
                spec.wheel_radius,
                spec.centre_distance,
                spec.n_wheels if spec.n_wheels is not None else 3,
                roller,
                math.radians(spec.first_wheel_angle_deg or 0.0),
                dtype=dtype,
                warn_singular=warn_singular,
            )
        assert spec.wheels is not None
        wheels = spec.wheels
        return geo.make_geometry(
            [[w.x, w.y] for w in wheels],
            [math.radians(w.drive_angle_deg) for w in wheels],
            [math.radians(w.roller_angle_deg) for w in wheels],
            [w.radius for w in wheels],
            [w.name for w in wheels],
            dtype=dtype,
            warn_singular=warn_singular,
        )
    except geo.GeometryError as err:
        raise ConfigError(f"geometry ({spec.layout}): {err}") from None


def parse_description(data: dict, source: str = "robot description") -> RobotDescription:
    """Validate a parsed description mapping (e.g. from TOML)."""
    if isinstance(data, dict) and "robot" not in data and "geometry" not in data:
        kind = "a training config" if "env" in data or "ppo" in data else "another kind of file"
        kind = "a scenario file" if "defaults" in data or "scenarios" in data else kind
        raise ConfigError(
            f"{source}: not a robot description (it has {sorted(data)}, not the tables "
            f"[robot], [geometry] and [motors]); it looks like {kind}"
        )
    try:
        desc = from_mapping(RobotDescription, data)
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    try:
        geometry = desc.build_geometry(warn_singular=False)
        plausible.check_plausible(desc.robot, desc.geometry, desc.body, geometry)
        singularity.require_usable(geometry, desc.robot.name)
    except (ConfigError, geo.SingularLayoutError) as err:
        raise ConfigError(f"{source}: {err}") from None
    check_physics(desc, source)
    m = desc.motors
    if m.max_motor_rpm <= 0:
        raise ConfigError(f"{source}: motors.max_motor_rpm = {m.max_motor_rpm!r}: must be > 0")
    if m.gear_ratio <= 0:
        raise ConfigError(f"{source}: motors.gear_ratio = {m.gear_ratio!r}: must be > 0")
    if not m.rotor_inertia >= 0:
        raise ConfigError(
            f"{source}: motors.rotor_inertia = {m.rotor_inertia!r}: must be >= 0 kg·m²"
        )
    if m.signs is not None:
        if len(m.signs) != geometry.n_wheels:
            raise ConfigError(
                f"{source}: motors.signs = {list(m.signs)}: expected {geometry.n_wheels} "
                f"signs, one per wheel {list(geometry.names)}"
            )
        for i, s in enumerate(m.signs):
            if s not in (-1, 1):
                raise ConfigError(f"{source}: motors.signs[{i}] = {s!r}: expected +1 or -1")
    try:
        plausible.check_motors_plausible(desc.robot, m, geometry)
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    return desc


# sim.solver values and their MJCF spellings
SOLVERS = {"newton": "Newton", "cg": "CG"}
IMPLS = ("jax", "warp")  # sim.impl values


def check_physics(desc: RobotDescription, source: str) -> None:
    positive = {
        "body.mass": desc.body.mass,
        "body.wheel_mass": desc.body.wheel_mass,
        "body.wheel_width": desc.body.wheel_width,
        "actuators.max_torque": desc.actuators.max_torque,
        "sim.timestep": desc.sim.timestep,
        "sim.reference_timestep": desc.sim.reference_timestep,
        "sim.floor_friction": desc.sim.floor_friction,
    }
    if desc.body.half_size is not None:
        positive.update({f"body.half_size[{i}]": v for i, v in enumerate(desc.body.half_size)})
    for key, value in positive.items():
        if value <= 0:
            raise ConfigError(f"{source}: {key} = {value!r}: must be > 0")
    for key, value in {
        "actuators.kp": desc.actuators.kp,
        "actuators.ki": desc.actuators.ki,
        "actuators.max_accel": desc.actuators.max_accel,
    }.items():
        if value < 0:
            raise ConfigError(f"{source}: {key} = {value!r}: must be >= 0")
    if desc.actuators.kp == 0 and desc.actuators.ki == 0:
        raise ConfigError(
            f"{source}: actuators.kp = 0 and actuators.ki = 0: the servo needs a gain"
        )
    if desc.sim.contact_timeconst < 2 * desc.sim.timestep:
        raise ConfigError(
            f"{source}: sim.contact_timeconst = {desc.sim.contact_timeconst}: must be at least "
            f"two time steps (2 × {desc.sim.timestep}) for a stable contact"
        )
    if desc.sim.rollers < 3:
        raise ConfigError(
            f"{source}: sim.rollers = {desc.sim.rollers}: a wheel needs at least 3 rollers"
        )
    if desc.sim.roller_spheres == 1 or not 0 <= desc.sim.roller_spheres <= 16:
        raise ConfigError(
            f"{source}: sim.roller_spheres = {desc.sim.roller_spheres}: expected 2 to 16 "
            "spheres per roller, or 0 for capsule rollers"
        )
    if desc.sim.solver not in SOLVERS:
        raise ConfigError(
            f"{source}: sim.solver = {desc.sim.solver!r}: expected one of {list(SOLVERS)}"
        )
    if desc.sim.impl not in IMPLS:
        raise ConfigError(f"{source}: sim.impl = {desc.sim.impl!r}: expected one of {list(IMPLS)}")
    require_impl(desc.sim.impl, f"{source}: sim.impl")
    if desc.sim.iterations < 1 or desc.sim.ls_iterations < 1:
        raise ConfigError(
            f"{source}: sim.iterations = {desc.sim.iterations}, sim.ls_iterations = "
            f"{desc.sim.ls_iterations}: both must be >= 1"
        )
    if not 0.05 <= desc.sim.roller_radius_ratio <= 0.6:
        raise ConfigError(
            f"{source}: sim.roller_radius_ratio = {desc.sim.roller_radius_ratio}: "
            "expected 0.05 to 0.6"
        )


def require_impl(impl: str, field: str = "sim.impl") -> None:
    """Raise :class:`ConfigError` naming ``field`` if ``impl`` needs a package that is not
    installed (``"warp"``: warp-lang, the project's ``warp`` extra)."""
    if impl == "warp" and importlib.util.find_spec("warp") is None:
        raise ConfigError(
            f"{field} = 'warp': MJX's Warp implementation needs warp-lang, the project's "
            "optional 'warp' extra (uv sync --extra warp)"
        )


_LOADED: dict[Path, tuple[bytes, RobotDescription]] = {}
"""The description files read in this process, by resolved path: each one's SHA-256 and
the (frozen) description parsed from it."""


def load_description(path: str | Path) -> RobotDescription:
    """Load and validate a robot description TOML file: parsed once per process while its
    bytes stay the same (the same frozen description comes back); an edited file is
    parsed again."""
    data = read_config_bytes(path)  # read once: what is hashed is what is parsed
    file, digest = Path(path).resolve(), hashlib.sha256(data).digest()
    known = _LOADED.get(file)
    if known is None or known[0] != digest:
        known = (digest, parse_description(parse_toml(data, path), source=str(path)))
        _LOADED[file] = known
    return known[1]


def builtin_description(name: str) -> RobotDescription:
    """A description shipped in ``configs/robots/`` by file stem, e.g. ``"o_rectangle"``."""
    if Path(name).suffix or "/" in name:
        raise ConfigError(f"robot = {name!r}: not a built-in description's name")
    return resolve_description(name)


def resolve_description(robot: str, where: str = "") -> RobotDescription:
    """A description file by path (``robot`` ends in ``.toml`` or holds a ``/``) or a
    built-in one by name; errors name the field ``<where>.robot`` and the value."""
    field = f"{where}.robot" if where else "robot"
    robots = CONFIG_DIR / "robots"
    return load_description(find_config(robot, robots, field, "built-in description"))


def fingerprint(desc: RobotDescription) -> str:
    """A short hash of everything in a description (geometry, motors, body, actuators,
    simulation): two descriptions with the same fingerprint build the same robot. The MJX
    implementation (``sim.impl``) and ``robot.allow_implausible`` are left out: they build
    the same robot."""
    fields = dataclasses.asdict(desc)
    del fields["sim"]["impl"]
    del fields["robot"]["allow_implausible"]  # accepts the numbers, changes no robot
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
