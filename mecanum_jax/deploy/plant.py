"""The robot a deployment rehearsal drives: plain C MuJoCo, no JAX or MJX in its loop.

:class:`Plant` steps one robot, built by :mod:`mecanum_jax.sim.mjcf` at either fidelity,
with the wheel servos modelled as :class:`mecanum_jax.sim.physics.Robot` models them
(docs/physics_model.md), so that a controller meets the physics the policy was trained
and evaluated on, through another engine:

- setpoints slewed at ``max_accel`` (0: none), a PI speed servo per wheel whose
  P part is MuJoCo's velocity actuator (``kv = kp``, implicit) and whose I part
  (``ki/kp · ∫(setpoint − ω) dt``, anti-windup clamped) is added to its setpoint;
- a saturated servo linearised by the chord of its torque curve each physics step
  (``Robot._chord_servo``); its force range is set beyond reach
  (:data:`CHORD_RANGE` × the limit), as under MuJoCo Warp, because the chord already
  keeps every force within the limit and C MuJoCo drops a clamped actuator's slope from
  the implicit integrator;
- the fast model's carrier hinges set back to zero before every physics step;
- sensors: encoder rates, gyro z, the accelerometer's specific force finite-differenced
  over the control period (body frame), and, for the metrics only, pose and true twist;
- per-robot parameters written into a copy of the model (``Robot.model_for``); where C
  MuJoCo differs from MJX in how it reads them, the plant follows MJX (a payload's centre
  of mass, the float32 start on smaller wheels: see :meth:`Plant.reset`).

:class:`SensorChannel` adds what a real robot's sensors add, as the training environment
does: Gaussian noise and a latency of whole control periods.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import TYPE_CHECKING, Any, NamedTuple

import mujoco
import numpy as np

from mecanum_jax.sim import mjcf
from mecanum_jax.sim.description import RobotDescription

if TYPE_CHECKING:
    import numpy.typing as npt

    from mecanum_jax.sim.state import RobotParams  # imports JAX: for type checking only

GRAVITY = 9.81  # as mecanum_jax.sim.state.GRAVITY (that module imports JAX)
CHORD_RANGE = 2.0  # as mecanum_jax.sim.servo.CHORD_WARP_RANGE
MAX_ABS_QVEL = 2.0e3  # as mecanum_jax.sim.physics: beyond this a state counts as unstable


@dataclasses.dataclass(frozen=True)
class PlantParams:
    """One robot's physical parameters, as :class:`mecanum_jax.sim.state.RobotParams`
    (NumPy arrays; per wheel where (n,))."""

    friction: np.ndarray
    payload_mass: float
    payload_com: np.ndarray
    radius_scale: np.ndarray
    torque_limit: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    max_accel: float

    @classmethod
    def nominal(cls, desc: RobotDescription, n: int) -> PlantParams:
        a = desc.actuators
        return cls(
            friction=np.full(n, desc.sim.floor_friction),
            payload_mass=0.0,
            payload_com=np.zeros(3),
            radius_scale=np.ones(n),
            torque_limit=np.full(n, a.max_torque),
            kp=np.full(n, a.kp),
            ki=np.full(n, a.ki),
            max_accel=float(a.max_accel),
        )

    @classmethod
    def of(cls, params: RobotParams, i: int) -> PlantParams:
        """Robot ``i`` of a batch of ``RobotParams`` (an evaluation scenario's)."""
        get: dict[str, np.ndarray] = {
            f.name: np.asarray(getattr(params, f.name))[i] for f in dataclasses.fields(cls)
        }
        values: dict[str, Any] = {
            k: float(v) if v.ndim == 0 else v.astype(float) for k, v in get.items()
        }
        return cls(**values)


class Measurement(NamedTuple):
    """The robot's sensors (first four) and, for evaluation only, the truth (last three)."""

    wheel_rate: np.ndarray  # (n,) rad/s
    gyro_z: float  # rad/s
    accel: np.ndarray  # (3,) m/s², body frame
    wheel_torque: np.ndarray  # (n,) N·m
    pose: np.ndarray  # (3,) x, y, yaw
    twist: np.ndarray  # (3,) vx, vy (body frame), ωz


class Plant:
    """One robot in C MuJoCo at ``fidelity``, its servos as the project models them."""

    def __init__(self, desc: RobotDescription, fidelity: mjcf.Fidelity = "fast"):
        self.desc = desc
        self.fidelity = fidelity
        self.nominal_model, self.index = mjcf.build_model(desc, fidelity, visual=False)
        self.n_wheels = len(self.index.wheel_names)
        self.dt = float(self.nominal_model.opt.timestep)
        self._inv_inertia = _axle_inverse_inertia(self.nominal_model, self.index.axle_dof)
        r = np.asarray(desc.build_geometry(warn_singular=False).radii, float)
        self._radii = r
        self.reset(PlantParams.nominal(desc, self.n_wheels))

    def reset(self, params: PlantParams) -> Measurement:
        """The robot at rest at the origin with ``params`` written into its model."""
        self.params = params
        self.model = _model_for(self.nominal_model, self.index, self.fidelity, params)
        self.data = mujoco.MjData(self.model)
        f = self.index.free_qpos
        # wheels with a radius error stand the chassis higher or lower (Robot.reset). In
        # float32, as MJX computes it: the wheels start exactly touching the floor, and
        # whether the first step's contact acts turns on the last bit of that distance
        f32 = np.float32
        r = np.max(f32(params.radius_scale) * f32(self._radii))
        self.data.qpos[f + 2] = f32(f32(self.data.qpos[f + 2]) + (r - f32(np.max(self._radii))))
        self.initial_qpos = self.data.qpos.copy()
        mujoco.mj_forward(self.model, self.data)
        self.setpoint = np.zeros(self.n_wheels)
        self.integral = np.zeros(self.n_wheels)
        self.accel = np.array([0.0, 0.0, GRAVITY])
        self.unstable = 0
        return self.measure()

    def step(self, setpoints: npt.ArrayLike, seconds: float) -> Measurement:
        """Hold wheel-rate setpoints (n,) rad/s for ``seconds`` (whole physics steps)."""
        substeps = max(1, round(seconds / self.dt))
        command = np.asarray(setpoints, float)
        d, free = self.data, self.index.free_dof
        v0 = d.qvel[free : free + 3].copy()
        for _ in range(substeps):
            self._physics_step(command)
        v1 = d.qvel[free : free + 3]
        accel_world = (v1 - v0) / (substeps * self.dt) + np.array([0.0, 0.0, GRAVITY])
        self.accel = self._rotation().T @ accel_world
        return self.measure()

    def _physics_step(self, command: np.ndarray) -> None:
        m, d, idx, p = self.model, self.data, self.index, self.params
        if self.fidelity == "fast":  # the axle never tilts (mjcf: the fast model)
            d.qpos[idx.carrier_qpos] = 0.0
        slew = p.max_accel * self.dt
        delta = command - self.setpoint
        self.setpoint = self.setpoint + np.clip(delta, -slew, slew) if slew > 0 else command
        rate = d.qvel[idx.axle_dof]
        has_i = p.ki > 0
        bound = np.where(has_i, p.torque_limit / np.where(has_i, p.ki, 1.0), 0.0)
        self.integral = np.clip(self.integral + (self.setpoint - rate) * self.dt, -bound, bound)
        ctrl = self.setpoint + np.where(has_i, p.ki / p.kp, 0.0) * self.integral
        self._chord_servo(ctrl - rate)
        d.ctrl[idx.actuators] = ctrl
        mujoco.mj_step(m, d)
        if not (np.all(np.isfinite(d.qvel)) and np.max(np.abs(d.qvel)) < MAX_ABS_QVEL):
            d.qpos[:] = self.initial_qpos  # as Robot: reset in place, and counted
            d.qvel[:] = 0.0
            d.qacc_warmstart[:] = 0.0
            self.setpoint[:] = 0.0
            self.integral[:] = 0.0
            self.unstable += 1

    def _chord_servo(self, error: np.ndarray) -> None:
        """``Robot._chord_servo``: a saturated servo gets the chord of its torque curve."""
        p, acts = self.params, self.index.actuators
        mag = np.abs(error)
        saturated = p.kp * mag > p.torque_limit
        reach = np.minimum(p.torque_limit * self.dt * self._inv_inertia, mag)
        reach = np.where(saturated, reach, 1.0)
        at_reach = np.minimum(p.torque_limit, p.kp * np.maximum(mag - reach, 0.0))
        slope = (p.torque_limit - at_reach) / reach
        gain = np.where(saturated, slope, p.kp)
        self.model.actuator_gainprm[acts, 0] = gain
        self.model.actuator_biasprm[acts, 0] = np.where(
            saturated, np.sign(error) * p.torque_limit - slope * error, 0.0
        )
        self.model.actuator_biasprm[acts, 2] = -gain

    def _rotation(self) -> np.ndarray:
        f = self.index.free_qpos
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, self.data.qpos[f + 3 : f + 7])
        return mat.reshape(3, 3)

    def measure(self) -> Measurement:
        d, idx = self.data, self.index
        f, v = idx.free_qpos, idx.free_dof
        R = self._rotation()
        w, x, y, z = d.qpos[f + 3 : f + 7]
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        v_body = R.T @ d.qvel[v : v + 3]
        return Measurement(
            wheel_rate=d.qvel[idx.axle_dof].copy(),
            gyro_z=float(d.qvel[v + 5]),  # a free joint's angular velocity is body-frame
            accel=self.accel.copy(),
            wheel_torque=d.actuator_force[idx.actuators].copy(),
            pose=np.array([d.qpos[f], d.qpos[f + 1], yaw]),
            twist=np.array([v_body[0], v_body[1], d.qvel[v + 5]]),
        )


class SensorChannel:
    """What the controller receives: the plant's sensors with Gaussian noise (standard
    deviations: wheel rate, gyro, accel) and ``latency`` control periods old, kept as the
    training environment keeps them (its reset fills the history with the first reading)."""

    def __init__(self, noise_std: npt.ArrayLike = (0.0, 0.0, 0.0), latency: int = 0, seed: int = 0):
        self.noise_std = np.asarray(noise_std, float)
        if self.noise_std.shape != (3,) or not np.all(self.noise_std >= 0):
            raise ValueError(f"noise_std = {noise_std!r}: three standard deviations >= 0")
        if int(latency) != latency or latency < 0:
            raise ValueError(f"latency = {latency!r}: whole control periods >= 0")
        self.latency = int(latency)
        self.rng = np.random.default_rng(seed)
        self.history: list[tuple[np.ndarray, float, np.ndarray]] = []

    def _noisy(self, m: Measurement) -> tuple[np.ndarray, float, np.ndarray]:
        s, r = self.noise_std, self.rng
        return (
            m.wheel_rate + s[0] * r.standard_normal(len(m.wheel_rate)),
            m.gyro_z + s[1] * float(r.standard_normal()),
            m.accel + s[2] * r.standard_normal(3),
        )

    def reset(self, m: Measurement) -> tuple[np.ndarray, float, np.ndarray]:
        self.history = [self._noisy(m)] * (self.latency + 1)
        return self.history[-1]

    def read(self, m: Measurement) -> tuple[np.ndarray, float, np.ndarray]:
        """The reading the controller sees after the plant measured ``m``."""
        self.history = [self._noisy(m), *self.history[:-1]]
        return self.history[-1]


def _model_for(
    nominal: mujoco.MjModel, idx: mjcf.ModelIndex, fidelity: str, p: PlantParams
) -> mujoco.MjModel:
    """A copy of the model with ``p`` written in (``Robot.model_for``, in NumPy)."""
    m = copy.copy(nominal)  # mj_copyModel
    g = idx.wheel_geoms
    m.geom_friction[g, 0] = np.broadcast_to(p.friction[:, None], g.shape)
    c = idx.chassis_body
    mb, mp = float(nominal.body_mass[c]), p.payload_mass
    ipos, inertia = nominal.body_ipos[c].copy(), nominal.body_inertia[c].copy()
    com = (mb * ipos + mp * p.payload_com) / (mb + mp)

    def point(mass: float, d: np.ndarray) -> np.ndarray:
        return mass * np.array(
            [d[1] ** 2 + d[2] ** 2, d[0] ** 2 + d[2] ** 2, d[0] ** 2 + d[1] ** 2]
        )

    m.body_mass[c] = mb + mp
    m.body_ipos[c] = com
    if not np.allclose(com, ipos):  # C MuJoCo takes a "same frame" body's xipos from xpos
        m.body_sameframe[c] = mujoco.mjtSameFrame.mjSAMEFRAME_NONE
    m.body_inertia[c] = inertia + point(mb, ipos - com) + point(mp, p.payload_com - com)
    acts = idx.actuators
    m.actuator_forcerange[acts] = np.stack([-p.torque_limit, p.torque_limit], -1) * CHORD_RANGE
    scale = p.radius_scale[:, None]
    m.geom_rbound[g] *= scale  # the broadphase's bound grows with the wheel
    m.geom_aabb[g] *= scale[..., None]
    if fidelity == "fast":
        m.geom_size[g[:, 0], 0] = np.float32(m.geom_size[g[:, 0], 0]) * np.float32(p.radius_scale)
    else:  # the whole roller ring scales about the axle
        m.geom_size[g, 0] *= scale
        m.geom_size[g, 1] *= scale
        m.geom_pos[g] *= scale[..., None]
        m.body_pos[idx.roller_bodies] *= scale[..., None]
    return m  # no mj_setConst: as in MJX, the constants stay the nominal model's


def _axle_inverse_inertia(m: mujoco.MjModel, axle_dof: np.ndarray) -> np.ndarray:
    """``(M⁻¹)[a, a]`` per axle at the reset pose (``servo.axle_inverse_inertia``)."""
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    return np.linalg.inv(full)[axle_dof, axle_dof]


__all__ = ["CHORD_RANGE", "Measurement", "Plant", "PlantParams", "SensorChannel"]
