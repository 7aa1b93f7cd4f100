"""Robot descriptions: TOML files in ``configs/robots/`` → geometry and motor data.

One description drives both the analytic model and (later) the physics. A file has the
tables ``[robot]``, ``[geometry]`` and ``[motors]``; see ``configs/robots/*.toml`` for
commented examples. Unknown or missing keys, and keys that the chosen layout does not
use, are rejected with an error naming the key and the value.
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

from mecanum_jax.config import CONFIG_DIR, ConfigError, find_config, from_mapping, load_toml
from mecanum_jax.kinematics import geometry as geo
from mecanum_jax.kinematics import motors

Layout = Literal["O-square", "O-rectangle", "X-square", "X-rectangle", "centripetal", "custom"]

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
class WheelSpec:
    """One wheel of a ``custom`` layout (meanings as in :mod:`mecanum_jax.kinematics.geometry`)."""

    name: str
    x: float
    y: float
    radius: float
    roller_angle_deg: float
    drive_angle_deg: float = 0.0


@dataclasses.dataclass(frozen=True)
class GeometrySpec:
    """The ``[geometry]`` table. Which keys are required depends on ``layout``."""

    layout: Layout
    wheel_radius: float | None = None
    half_size: float | None = None
    half_wheelbase: float | None = None
    half_track: float | None = None
    centre_distance: float | None = None
    n_wheels: int | None = None
    first_wheel_angle_deg: float | None = None
    roller_angle_deg: float | None = None
    wheels: tuple[WheelSpec, ...] | None = None


@dataclasses.dataclass(frozen=True)
class MotorSpec:
    """The ``[motors]`` table.

    Attributes:
      max_motor_rpm: motor shaft speed limit, rpm.
      gear_ratio: motor turns per wheel turn.
      signs: ±1 per wheel in wheel order; default: right-side wheels mirrored (−1).
      rotor_inertia: the motor rotor's inertia about its shaft, kg·m². The physics model
        puts ``rotor_inertia · gear_ratio²`` (the inertia a geared motor reflects to its
        wheel) on each axle as MuJoCo ``armature``. 0: the wheel's own inertia only.
    """

    max_motor_rpm: float
    gear_ratio: float = 1.0
    signs: tuple[int, ...] | None = None
    rotor_inertia: float = 0.0

    @property
    def reflected_inertia(self) -> float:
        """The rotor's inertia seen at the wheel, kg·m²."""
        return self.rotor_inertia * self.gear_ratio**2


@dataclasses.dataclass(frozen=True)
class BodySpec:
    """The ``[body]`` table: masses and shape for the physics model.

    Attributes:
      mass: chassis mass, kg (without wheels).
      half_size: chassis box half-extents (x, y, z), m; default: fitted between the wheels.
      com_offset: chassis centre of mass relative to the geometric centre (x, y, z), m.
      wheel_mass: mass of one wheel (hub and rollers), kg.
      wheel_width: wheel width along its axle, m.
    """

    mass: float = 4.0
    half_size: tuple[float, float, float] | None = None
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wheel_mass: float = 0.3
    wheel_width: float = 0.04


@dataclasses.dataclass(frozen=True)
class ActuatorSpec:
    """The ``[actuators]`` table: each wheel's speed servo (a PI loop, as seed 004's C620).

    Attributes:
      max_torque: wheel torque limit, N·m.
      kp: proportional gain, N·m per rad/s of rate error.
      ki: integral gain, N·m per rad of accumulated rate error.
      max_accel: setpoint slew limit, rad/s² (0: none).
    """

    max_torque: float = 3.0
    kp: float = 2.0
    ki: float = 20.0
    max_accel: float = 0.0


@dataclasses.dataclass(frozen=True)
class SimSpec:
    """The ``[sim]`` table: physics settings.

    Attributes:
      timestep: physics step, s (the fast fidelity's; the environment sets its own).
      reference_timestep: the reference fidelity's physics step, s. Its 10 rollers per
        wheel (capsules, when measured) go unstable at 2 ms once a wheel spins up freely
        on a slippery floor (μ = 0.1, lateral 1 m/s: 333 resets in 2 s); 1 ms is stable.
      solver: the constraint solver, ``"newton"`` or ``"cg"`` (conjugate gradient: cheaper
        iterations, no factorisation; docs/physics_model.md compares them).
      iterations: constraint solver (Newton) iterations. 12: with fewer, the solve is not
        converged while wheels slip fast on a slippery floor, and the error feeds energy
        into the chassis. Robots tipped over in 4096 randomized baseline episodes × 10 s
        (H100): 509 with 4 iterations (some flew metres
        high), 25 with 8, none with 12 or 16 (whose statistics equal 12's).
      ls_iterations: line-search iterations.
      floor_friction: sliding friction coefficient of floor and wheels.
      rollers: passive rollers per wheel in the reference fidelity.
      roller_radius_ratio: roller radius (at its middle) as a fraction of the wheel radius.
      roller_spheres: spheres per roller in the reference fidelity, ≥ 2: each roller is a
        chain of spheres along its axis whose radii follow the barrel profile of a real
        mecanum roller, so every sphere reaches exactly the wheel radius below the axle and
        the rolling radius is constant (between spheres it dips by about
        ``(1 − cos(π / (rollers·(roller_spheres − 1))))·(1 − roller_radius_ratio)`` of
        the radius: 0.2% with 10 rollers of 5 spheres). ``0``: straight capsule rollers,
        whose ends reach up to 3.4% beyond the radius (a polygonal wheel; up to 6.9% twist
        error, docs/physics_model.md).
      contact_timeconst: contact stiffness as MuJoCo's solref time constant, s (≥ 2 steps);
        stiffer than MuJoCo's 0.02 s default, whose soft contacts let the wheels creep
        sideways under centripetal load (≈3% twist error at 2 rad/s with 0.02 s).
      impl: MJX implementation, ``"jax"`` (default) or ``"warp"`` (MuJoCo Warp through
        MJX: needs the ``warp`` extra, on a CUDA GPU or the CPU; docs/benchmarks.md
        compares them).
    """

    timestep: float = 0.002
    reference_timestep: float = 0.001
    solver: str = "newton"
    iterations: int = 12
    ls_iterations: int = 4
    floor_friction: float = 1.0
    rollers: int = 10
    roller_radius_ratio: float = 0.3
    roller_spheres: int = 5
    contact_timeconst: float = 0.005
    impl: str = "jax"


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """The ``[robot]`` table."""

    name: str
    description: str = ""


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A validated robot description file."""

    robot: RobotSpec
    geometry: GeometrySpec
    motors: MotorSpec
    body: BodySpec = BodySpec()
    actuators: ActuatorSpec = ActuatorSpec()
    sim: SimSpec = SimSpec()

    def build_geometry(self, dtype: object = None, warn_singular: bool = True) -> geo.WheelGeometry:
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
    spec: GeometrySpec, dtype: object = None, warn_singular: bool = True
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
    try:
        desc = from_mapping(RobotDescription, data)
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    try:
        geometry = desc.build_geometry(warn_singular=False)
    except ConfigError as err:
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
    file = Path(path).resolve()
    try:
        digest = hashlib.sha256(file.read_bytes()).digest()
    except OSError:  # unreadable: load_toml below says why
        digest = b""
    known = _LOADED.get(file)
    if not digest or known is None or known[0] != digest:
        known = (digest, parse_description(load_toml(path), source=str(path)))
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
    implementation (``sim.impl``) is left out: it simulates the same robot."""
    fields = dataclasses.asdict(desc)
    del fields["sim"]["impl"]
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]
