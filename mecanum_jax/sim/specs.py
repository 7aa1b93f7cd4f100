"""The tables of a robot description file (``configs/robots/*.toml``), as frozen dataclasses:
what :mod:`mecanum_jax.sim.description` parses each table into."""

from __future__ import annotations

import dataclasses
from typing import Literal

Layout = Literal["O-square", "O-rectangle", "X-square", "X-rectangle", "centripetal", "custom"]


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
    allow_implausible: bool = False
    """Accept numbers no real robot has (lengths outside 1 mm–5 m, a wheel larger than the
    base or wider than 4 radii; :mod:`mecanum_jax.sim.plausible`)."""
