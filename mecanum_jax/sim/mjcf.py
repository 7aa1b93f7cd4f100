"""MJCF generation: one robot description → a MuJoCo model, in two fidelities.

- ``"reference"``: each wheel is a hub on an actuated hinge carrying N passive rollers
  (barrel-shaped chains of spheres, ``sim.roller_spheres``; or straight capsules) on
  hinges along their own axes, mounted at the angle whose mean effective angle on the
  floor is the roller angle (:func:`mounted_roller_angle`). Rollers touch the floor only. Realistic and slow; it validates the fast model and shows real slip.
- ``"fast"``: each wheel is one sphere on two hinges (shared/design/mjx-model.md §2):
  chassis → *carrier* on a passive hinge about the floor roller's axis u_i (fixed in the
  chassis frame) → *hub* on the actuated axle hinge → a sphere of the wheel's radius.
  :mod:`mecanum_jax.sim.physics` sets the carrier angle back to zero before every physics
  step, so the axle never tilts while the carrier's *rate* (the roller's spin) is kept:
  at the contact the two hinges leave free exactly the roller's rolling direction, and the
  hub drives ``v · u_i = r ω cos γ_i``, the mecanum constraint.

Frames: the chassis body's origin is the geometric centre at wheel-axle height (one wheel
radius above the floor); its x axis points forward. Each wheel's hub frame has x along
the drive direction ψ_i, y along the axle, z up.

Collision filtering: floor (contype 1, conaffinity 2), tyres and rollers (contype 2,
conaffinity 1): wheels touch the floor and nothing else; the chassis touches nothing.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import mujoco
import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics.geometry import WheelGeometry
from mecanum_jax.kinematics.singularity import warn_unreachable
from mecanum_jax.sim.description import SOLVERS, RobotDescription

Fidelity = Literal["fast", "reference"]
FIDELITIES: tuple[Fidelity, ...] = ("fast", "reference")

_WHEEL_RGBA = "0.15 0.15 0.15 1"
_ROLLER_RGBA = "0.85 0.55 0.1 1"
_CHASSIS_RGBA = "0.2 0.4 0.8 1"


@dataclasses.dataclass(frozen=True)
class ModelIndex:
    """Where things are in the compiled model, looked up once by name (no magic indices).

    Attributes:
      wheel_names: the wheels, in the geometry's order.
      chassis_body: body id of the chassis.
      free_qpos, free_dof: first qpos / dof address of the chassis free joint.
      axle_qpos, axle_dof: (n,) addresses of each wheel's axle hinge.
      carrier_qpos, carrier_dof: (n,) addresses of the fast model's roller hinges (empty
        for the reference model).
      actuators: (n,) actuator ids: one velocity servo per axle (``kv`` = the servo's
        proportional gain, handled implicitly by the integrator so stiff gains stay stable;
        ``forcerange`` = the torque limit).
      floor_geom: the floor's geom id.
      wheel_geoms: (n, k) the geoms that touch the floor for each wheel (k = 1 tyre, or
        every roller geom: ``rollers × roller_spheres`` spheres, or ``rollers`` capsules).
      roller_bodies: (n, k) roller body ids (reference model; empty for the fast one).
    """

    wheel_names: tuple[str, ...]
    chassis_body: int
    free_qpos: int
    free_dof: int
    axle_qpos: np.ndarray
    axle_dof: np.ndarray
    carrier_qpos: np.ndarray
    carrier_dof: np.ndarray
    actuators: np.ndarray
    floor_geom: int
    wheel_geoms: np.ndarray
    roller_bodies: np.ndarray


def _fmt(*values: float) -> str:
    return " ".join(f"{v:.9g}" for v in values)


def _quat_z(angle: float) -> str:
    return _fmt(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))


def _rot_y(alpha: float, v: np.ndarray) -> np.ndarray:
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def chassis_half_size(desc: RobotDescription, geom: WheelGeometry) -> tuple[float, float, float]:
    """The chassis box: the description's, or the largest box that clears every wheel."""
    if desc.body.half_size is not None:
        return desc.body.half_size
    pos = np.asarray(geom.positions, dtype=float)
    radii = np.asarray(geom.radii, dtype=float)
    w = desc.body.wheel_width
    margin = 0.005
    # shrink a box until it clears every wheel's footprint (2r along the drive, w along the axle)
    hx = float(np.max(np.abs(pos[:, 0])))
    hy = float(np.max(np.abs(pos[:, 1])))
    for _ in range(200):
        if not any(_overlaps((hx, hy), geom, i, w, margin) for i in range(geom.n_wheels)):
            break
        hx, hy = hx * 0.97, hy * 0.97
    else:  # pragma: no cover - a wheel at the very centre
        raise ConfigError("body.half_size: no chassis box fits between the wheels; give one")
    return (hx, hy, 0.3 * float(np.min(radii)))


def _wheel_corners(geom: WheelGeometry, i: int, width: float) -> np.ndarray:
    p = np.asarray(geom.positions[i], dtype=float)
    r = float(geom.radii[i])
    psi = float(geom.drive_angles[i])
    d = np.array([math.cos(psi), math.sin(psi)])
    a = np.array([-d[1], d[0]])
    return np.array([p + sx * r * d + sy * width / 2 * a for sx in (-1, 1) for sy in (-1, 1)])


def _overlaps(
    half: tuple[float, float], geom: WheelGeometry, i: int, width: float, margin: float
) -> bool:
    """Separating-axis test of the chassis box (axis-aligned) against wheel i's footprint."""
    corners = _wheel_corners(geom, i, width)
    box = np.array([[sx * half[0], sy * half[1]] for sx in (-1, 1) for sy in (-1, 1)])
    psi = float(geom.drive_angles[i])
    axes = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([math.cos(psi), math.sin(psi)]),
            np.array([-math.sin(psi), math.cos(psi)])]  # fmt: skip
    for ax in axes:
        pa, pb = box @ ax, corners @ ax
        if pa.max() + margin <= pb.min() or pb.max() + margin <= pa.min():
            return False
    return True


def _validate(
    desc: RobotDescription, geom: WheelGeometry, half: tuple[float, float, float]
) -> None:
    for i, name in enumerate(geom.names):
        if _overlaps((half[0], half[1]), geom, i, desc.body.wheel_width, 0.0):
            raise ConfigError(
                f"body.half_size = {list(half)}: the chassis overlaps wheel {name!r} at "
                f"{np.round(np.asarray(geom.positions[i]), 4).tolist()} (radius "
                f"{float(geom.radii[i]):.4g} m, width {desc.body.wheel_width} m)"
            )
    warn_unreachable(geom, desc.robot.name, stacklevel=3)  # rank < 3: commands projected


def _hub_inertia(mass: float, r: float, width: float) -> str:
    axle = 0.5 * mass * r * r
    perp = mass * (3 * r * r + width * width) / 12
    return _fmt(perp, axle, perp)


def _wheel_fast(desc: RobotDescription, geom: WheelGeometry, i: int) -> str:
    name = geom.names[i]
    x, y = (float(v) for v in geom.positions[i])
    r = float(geom.radii[i])
    gamma = float(geom.roller_angles[i])
    w = desc.body.wheel_width
    m = desc.body.wheel_mass
    mu = desc.sim.floor_friction
    marks = []
    for k in range(6):  # visual roller marks, so a viewer sees the hub turn
        alpha = 2 * math.pi * k / 6
        centre = _rot_y(alpha, np.array([0.0, 0.0, -r * 0.98]))
        axis = _rot_y(alpha, np.array([math.cos(gamma), math.sin(gamma), 0.0]))
        half = 0.35 * r
        p1, p2 = centre - half * axis, centre + half * axis
        marks.append(
            f'<geom type="capsule" fromto="{_fmt(*p1, *p2)}" size="{0.12 * r:.6g}" '
            f'contype="0" conaffinity="0" mass="0" rgba="{_ROLLER_RGBA}" group="1"/>'
        )
    return f"""
    <body name="{name}_carrier" pos="{_fmt(x, y, 0.0)}" quat="{_quat_z(float(geom.drive_angles[i]))}">
      <joint name="{name}_roller" type="hinge" axis="{_fmt(math.cos(gamma), math.sin(gamma), 0.0)}"/>
      <inertial pos="0 0 0" mass="1e-3" diaginertia="1e-7 1e-7 1e-7"/>
      <body name="{name}_hub">
        <joint name="{name}_axle" type="hinge" axis="0 1 0"
               armature="{desc.motors.reflected_inertia:.6g}"/>
        <inertial pos="0 0 0" mass="{m:.6g}" diaginertia="{_hub_inertia(m, r, w)}"/>
        <geom name="{name}_tyre" type="sphere" size="{r:.6g}" contype="2" conaffinity="1"
              condim="3" friction="{_fmt(mu, 0.0, 0.0)}" solref="{desc.sim.contact_timeconst:.6g} 1" mass="0" rgba="0 0 0 0" group="3"/>
        <geom type="cylinder" size="{_fmt(0.9 * r, w / 2)}" zaxis="0 1 0" contype="0"
              conaffinity="0" mass="0" rgba="{_WHEEL_RGBA}" group="1"/>
        {"".join(marks)}
      </body>
    </body>"""


def mounted_roller_angle(gamma: float, rollers: int) -> float:
    """The angle γ₀ at which the reference wheel mounts its rollers (in the hub's tangent
    plane) so that its floor roller's *effective* angle is ``gamma`` on average.

    A roller turned by α about the axle has its axis tilted out of the floor plane, and a
    surface of revolution on the floor is free to roll only across its axis' floor
    projection: the driven direction's angle is ``tan γ(α) = tan γ₀ / cos α``, larger than
    γ₀ everywhere but at α = 0. The floor roller sweeps |α| ≤ π/n, over which 1/cos α
    averages ``ln(sec(π/n) + tan(π/n)) / (π/n)`` (1.0169 for 10 rollers: rollers mounted
    at 45° act as 45.48°, which gives an X-square a lever arm to spin on, and an O-robot
    1.7% less lateral speed). Mounting them at ``atan(tan γ / that mean)`` (44.52°) makes
    the mean effective angle the description's γ (docs/physics_validation.md).
    """
    a = math.pi / rollers
    mean_sec = math.log(1.0 / math.cos(a) + math.tan(a)) / a
    return math.atan2(math.sin(gamma), math.cos(gamma) * mean_sec)


def _wheel_reference(desc: RobotDescription, geom: WheelGeometry, i: int) -> str:
    name = geom.names[i]
    x, y = (float(v) for v in geom.positions[i])
    r = float(geom.radii[i])
    n_rollers = desc.sim.rollers
    gamma = mounted_roller_angle(float(geom.roller_angles[i]), n_rollers)
    n_spheres = desc.sim.roller_spheres
    rho = desc.sim.roller_radius_ratio * r
    rc = r - rho
    half = math.pi * rc / (n_rollers * math.cos(gamma))  # rollers tile the rim along the drive
    m_hub = 0.5 * desc.body.wheel_mass
    m_roller = 0.5 * desc.body.wheel_mass / n_rollers
    mu = desc.sim.floor_friction
    w = desc.body.wheel_width
    rollers = []
    u_local = np.array([math.cos(gamma), math.sin(gamma), 0.0])
    for k in range(n_rollers):
        alpha = 2 * math.pi * k / n_rollers
        centre = _rot_y(alpha, np.array([0.0, 0.0, -rc]))
        axis = _rot_y(alpha, u_local)
        p1, p2 = -half * axis, half * axis
        roller_i = (m_roller * rho * rho) / 2
        contact = (
            f'contype="2" conaffinity="1" condim="3" friction="{_fmt(mu, 0.0, 0.0)}" mass="0" '
            f'solref="{desc.sim.contact_timeconst:.6g} 1" rgba="{_ROLLER_RGBA}" group="1"'
        )
        if n_spheres:  # barrel profile: every sphere reaches exactly r below the axle
            offsets = np.linspace(-half, half, n_spheres)
            geoms = "".join(
                f"""
          <geom name="{name}_roller{k}_{j}" type="sphere" pos="{_fmt(*(s * axis))}"
                size="{r - math.hypot(rc, s * math.cos(gamma)):.6g}" {contact}/>"""
                for j, s in enumerate(offsets)
            )
        else:
            geoms = f"""
          <geom name="{name}_roller{k}" type="capsule" fromto="{_fmt(*p1, *p2)}"
                size="{rho:.6g}" {contact}/>"""
        rollers.append(f"""
        <body name="{name}_roller{k}" pos="{_fmt(*centre)}">
          <joint name="{name}_roller{k}" type="hinge" axis="{_fmt(*axis)}"/>
          <inertial pos="0 0 0" mass="{m_roller:.6g}" diaginertia="{_fmt(roller_i, roller_i, roller_i)}"/>{geoms}
        </body>""")
    return f"""
    <body name="{name}_hub" pos="{_fmt(x, y, 0.0)}" quat="{_quat_z(float(geom.drive_angles[i]))}">
      <joint name="{name}_axle" type="hinge" axis="0 1 0"
               armature="{desc.motors.reflected_inertia:.6g}"/>
      <inertial pos="0 0 0" mass="{m_hub:.6g}" diaginertia="{_hub_inertia(m_hub, rc, w)}"/>
      <geom type="cylinder" size="{_fmt(0.55 * r, w / 2)}" zaxis="0 1 0" contype="0" conaffinity="0"
            mass="0" rgba="{_WHEEL_RGBA}" group="1"/>
      {"".join(rollers)}
    </body>"""


def build_mjcf(desc: RobotDescription, fidelity: Fidelity = "fast") -> str:
    """The MJCF XML of ``desc`` at ``fidelity``. Raises :class:`ConfigError` if unbuildable."""
    if fidelity not in FIDELITIES:
        raise ConfigError(f"fidelity = {fidelity!r}: expected one of {list(FIDELITIES)}")
    geom = desc.build_geometry(warn_singular=False)
    half = chassis_half_size(desc, geom)
    _validate(desc, geom, half)
    body = desc.body
    r_max = float(np.max(np.asarray(geom.radii)))
    hx, hy, hz = half
    m = body.mass
    inertia = _fmt(m * (hy**2 + hz**2) / 3, m * (hx**2 + hz**2) / 3, m * (hx**2 + hy**2) / 3)
    wheel = _wheel_fast if fidelity == "fast" else _wheel_reference
    wheels = "".join(wheel(desc, geom, i) for i in range(geom.n_wheels))
    act = desc.actuators
    motors = "".join(
        f'<velocity name="{n}_motor" joint="{n}_axle" kv="{act.kp:.6g}" ctrllimited="false" '
        f'forcerange="{_fmt(-act.max_torque, act.max_torque)}"/>'
        for n in geom.names
    )
    sim = desc.sim
    step = sim.timestep if fidelity == "fast" else sim.reference_timestep
    return f"""<mujoco model="{desc.robot.name}_{fidelity}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{step:.6g}" integrator="implicitfast" solver="{SOLVERS[sim.solver]}"
          iterations="{sim.iterations}" ls_iterations="{sim.ls_iterations}" cone="pyramidal">
    <flag eulerdamp="disable"/>
  </option>
  <visual><global offwidth="1280" offheight="720"/></visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1=".85 .85 .85" rgb2=".7 .7 .7"
             width="512" height="512"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.1"/>
  </asset>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="0 0 0.05" material="grid" contype="1" conaffinity="2"
          condim="3" friction="{_fmt(1e-4, 0.0, 0.0)}" solref="{sim.contact_timeconst:.6g} 1"/>
    <body name="chassis" pos="0 0 {r_max:.6g}">
      <freejoint name="chassis"/>
      <inertial pos="{_fmt(*body.com_offset)}" mass="{m:.6g}" diaginertia="{inertia}"/>
      <geom name="chassis" type="box" size="{_fmt(hx, hy, hz)}" pos="0 0 {hz:.6g}" contype="0"
            conaffinity="0" mass="0" rgba="{_CHASSIS_RGBA}" group="1"/>
      <geom name="front_marker" type="box" size="{_fmt(0.15 * hx, 0.4 * hy, 0.2 * hz)}"
            pos="{_fmt(0.8 * hx, 0.0, 2.1 * hz)}" contype="0" conaffinity="0" mass="0"
            rgba="0.9 0.2 0.2 1" group="1"/>
      <site name="imu" pos="0 0 0"/>{wheels}
    </body>
  </worldbody>
  <actuator>{motors}</actuator>
</mujoco>
"""


def build_model(
    desc: RobotDescription, fidelity: Fidelity = "fast", visual: bool = True
) -> tuple[mujoco.MjModel, ModelIndex]:
    """Compile ``desc`` at ``fidelity``; returns the model and its :class:`ModelIndex`.

    ``visual = False`` drops the geoms that only draw (no contact, no mass: hub discs,
    roller marks, the chassis box). The dynamics are identical, and MJX no longer computes
    their poses every step; the simulation uses that model, rendering the full one.
    """
    xml = build_mjcf(desc, fidelity)
    try:
        spec = mujoco.MjSpec.from_string(xml)
        if not visual:
            for g in [g for g in spec.geoms if g.contype == 0 and g.conaffinity == 0]:
                spec.delete(g)
        model = spec.compile()
    except ValueError as err:  # pragma: no cover - the generator's own bug
        raise ConfigError(
            f"robot {desc.robot.name!r} ({fidelity}): MuJoCo rejected the model: {err}"
        ) from None
    names = desc.build_geometry(warn_singular=False).names

    def jid(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)

    def gid(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)

    def bid(name: str) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    axle = np.array([jid(f"{n}_axle") for n in names])
    free = jid("chassis")
    if fidelity == "fast":
        carrier = np.array([jid(f"{n}_roller") for n in names])
        wheel_geoms = np.array([[gid(f"{n}_tyre")] for n in names])
        roller_bodies = np.zeros((len(names), 0), dtype=int)
    else:
        carrier = np.zeros((0,), dtype=int)
        k, spheres = desc.sim.rollers, desc.sim.roller_spheres
        geoms = [f"{j}_{i}" for j in range(k) for i in range(spheres)] if spheres else range(k)
        wheel_geoms = np.array([[gid(f"{n}_roller{g}") for g in geoms] for n in names])
        roller_bodies = np.array([[bid(f"{n}_roller{j}") for j in range(k)] for n in names])
    index = ModelIndex(
        wheel_names=names,
        chassis_body=bid("chassis"),
        free_qpos=int(model.jnt_qposadr[free]),
        free_dof=int(model.jnt_dofadr[free]),
        axle_qpos=model.jnt_qposadr[axle].copy(),
        axle_dof=model.jnt_dofadr[axle].copy(),
        carrier_qpos=model.jnt_qposadr[carrier].copy() if carrier.size else carrier,
        carrier_dof=model.jnt_dofadr[carrier].copy() if carrier.size else carrier,
        actuators=np.array(
            [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{n}_motor") for n in names]
        ),
        floor_geom=gid("floor"),
        wheel_geoms=wheel_geoms,
        roller_bodies=roller_bodies,
    )
    return model, index
