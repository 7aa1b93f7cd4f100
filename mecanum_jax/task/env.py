"""The velocity-tracking task: a Brax environment on the fast MJX robot, and its baseline.

A robot is commanded a body twist ``(vx, vy, ωz)`` and must achieve it. The environment
follows Brax's interface (``reset(rng) -> State``, ``step(State, action) -> State`` for one
robot; :class:`TrainingEnv` batches it with automatic resets), so Brax's PPO components
drive it unchanged.

- **Control:** 50 Hz (``control_dt``) with ``control_dt / physics_timestep`` physics
  substeps. The default 5 ms physics step (contact time constant 10 ms) tracks steady
  twists within 0.5% like the 2 ms step, at 4 instead of 10 substeps; with the 12 Newton
  iterations no robot tips over, under the baseline or random actions (docs/training.md,
  experiments/physics_step_candidates.py).
- **Actions** in [-1, 1] per wheel. ``residual = true``: wheel-rate setpoints are the
  analytic baseline's plus ``action · residual_scale · max_rate``, so the zero action *is*
  the baseline. ``residual = false``: setpoints are ``action · max_rate``.
- **Commands** are sampled per robot and resampled at random times: zeros, pure
  translations in every direction, pure spins, combinations, and commands beyond reach
  (more than the wheels' rate limits allow), each a fraction of the feasible set's radius
  in its direction (from the description's motor limits).
- **Observations** (``obs["state"]``): the command, encoder rates, IMU gyro z and
  accelerometer, the wheel-odometry body twist, and the last action, with sensor noise
  and an observation latency of whole control steps. The critic's
  ``obs["privileged_state"]`` adds the true twist and the randomized physical parameters.
- **Reward:** ``Σ scale · term`` over named terms (:func:`reward_terms`): exp tracking
  kernels of the linear and yaw-rate errors, quadratic error penalties, and small
  action-rate and energy penalties; the scaled terms are reported in ``state.metrics``.
- **Domain randomization** per robot at every reset (ranges in the config): floor friction
  and per-wheel spread, payload mass and position, wheel-radius error (the baseline keeps
  the nominal geometry), torque limit, servo gains, sensor noise and latency.

:func:`baseline_policy` is the analytic inverse model of the nominal geometry, desaturated
to the motor limits, behind the same ``policy(obs, key) -> (action, extras)`` interface as
a learned policy.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State, Wrapper

from mecanum_jax.config import from_mapping, invalid, load_toml, require
from mecanum_jax.kinematics import limits
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.description import IMPLS, RobotDescription, resolve_description
from mecanum_jax.sim.physics import (
    GRAVITY,
    Robot,
    RobotParams,
    Sensors,
    chunked_vmap,
    cpu_chunk,
    select,
)

Policy = Callable[[Any, jax.Array], tuple[jax.Array, dict[str, Any]]]


# --- configuration -------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CommandConfig:
    """How commands are drawn. Fractions are of the feasible set's radius in the direction.

    The kind of each command is drawn with the relative weights ``p_*``.
    """

    p_zero: float = 0.1
    """Relative weight of the zero command (standing still) (>= 0)."""
    p_translation: float = 0.3
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
    resample_min_s: float = 1.0
    """Shortest time a command is held before a new one is drawn, s (> 0)."""
    resample_max_s: float = 4.0
    """Longest time a command is held, s (>= resample_min_s)."""


@dataclasses.dataclass(frozen=True)
class RandomizationConfig:
    """Per-robot domain randomization, drawn uniformly at each reset (``enabled = false``:
    the nominal robot on the description's floor friction, no payload, no latency).

    The payload's centre of mass is ``payload_com_offset`` plus a uniform draw in
    ``±payload_com_xy`` (x, y) and ``payload_com_z`` (z), in the body frame.
    """

    enabled: bool = True
    """Randomize at all (false: the nominal robot, no payload, no latency)."""
    friction: tuple[float, float] = (0.1, 1.2)
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


# Both configs are pytrees, so evaluation can pass their values as traced arrays (one
# compiled sampler for every scenario); ``enabled`` stays static.
jax.tree_util.register_dataclass(
    RandomizationConfig,
    data_fields=[f.name for f in dataclasses.fields(RandomizationConfig) if f.name != "enabled"],
    meta_fields=["enabled"],
)


@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    """Gaussian sensor noise (standard deviations); ``scale = 0`` turns it off."""

    scale: float = 1.0
    """Multiplies every standard deviation below (>= 0; 0: noise off)."""
    wheel_rate: float = 0.3
    """Encoder wheel-rate noise, rad/s (>= 0)."""
    gyro: float = 0.02
    """Gyro z noise, rad/s (>= 0)."""
    accel: float = 0.3
    """Accelerometer noise, m/s² (>= 0)."""


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    """The reward's scales: it is ``Σ scale · term`` over :data:`REWARD_TERMS`
    (:func:`reward_terms`), and each scaled term is logged as ``reward/<term>``."""

    tracking_lin: float = 1.0
    """Scale of ``exp(−|v_err|²/sigma_lin)`` (>= 0)."""
    tracking_ang: float = 0.5
    """Scale of ``exp(−ω_err²/sigma_ang)`` (>= 0)."""
    sigma_lin: float = 0.25
    """Width of the linear tracking kernel, (m/s)² (> 0)."""
    sigma_ang: float = 1.0
    """Width of the yaw-rate tracking kernel, (rad/s)² (> 0)."""
    error_lin: float = 1.0
    """Scale of the quadratic penalty ``−|v_err|²``, per (m/s)² (>= 0; 0: off)."""
    error_ang: float = 0.1
    """Scale of the quadratic penalty ``−ω_err²``, per (rad/s)² (>= 0; 0: off)."""
    action_rate: float = 0.01
    """Scale of ``−|a_t − a_(t−1)|²``, actions in [-1, 1] (>= 0)."""
    energy: float = 0.0005
    """Scale of ``−Σ|τ·ω|``, the wheels' mechanical power in W (>= 0)."""


REWARD_TERMS = (
    "tracking_lin",
    "tracking_ang",
    "error_lin",
    "error_ang",
    "action_rate",
    "energy",
)
"""The reward's terms, each scaled by the :class:`RewardConfig` field of the same name."""


def reward_terms(
    twist_error: jax.Array,
    action: jax.Array,
    last_action: jax.Array,
    power: jax.Array,
    cfg: RewardConfig,
) -> dict[str, jax.Array]:
    """The unscaled reward terms of one step (:data:`REWARD_TERMS`).

    ``twist_error`` is the true twist minus the command (vx, vy, ωz); ``power`` the wheels'
    mechanical power Σ|τ·ω| in W. Tracking terms are in (0, 1], penalties are <= 0.
    """
    lin2 = twist_error[..., 0] ** 2 + twist_error[..., 1] ** 2
    ang2 = twist_error[..., 2] ** 2
    return {
        "tracking_lin": jnp.exp(-lin2 / cfg.sigma_lin),
        "tracking_ang": jnp.exp(-ang2 / cfg.sigma_ang),
        "error_lin": -lin2,
        "error_ang": -ang2,
        "action_rate": -jnp.sum((action - last_action) ** 2, axis=-1),
        "energy": -power,
    }


def scaled_reward_terms(terms: dict[str, jax.Array], cfg: RewardConfig) -> dict[str, jax.Array]:
    """Each term times its scale; the reward is their sum."""
    return {name: getattr(cfg, name) * terms[name] for name in REWARD_TERMS}


@dataclasses.dataclass(frozen=True)
class FeedbackConfig:
    """The ``feedback`` reference controller: inverse-model feedforward, a yaw-rate PI loop
    on the (noisy, delayed) gyro, and nearest-feasible desaturation.

    Yaw-rate correction ``u = kp·e + I`` with ``e = ωz_cmd − gyro`` and
    ``I ← clip(I + ki·e·dt, ±i_max)``; the integrator holds while the corrected twist is out
    of the wheels' reach and ``e`` would drive it further (conditional-integration
    anti-windup). The gains come from a sweep on training-distribution episodes
    (experiments/tune_feedback.py; docs/evaluation.md): any proportional gain (even 0.02)
    raised the steady-state ωz error there, since the servos' own step response overshoots
    within one control step and the gyro arrives noisy and up to 2 steps late; integral
    gains above about 0.8/s oscillate.
    """

    kp: float = 0.0
    """Proportional gain, rad/s of yaw-rate correction per rad/s of error (>= 0)."""
    ki: float = 0.5
    """Integral gain, 1/s (>= 0)."""
    i_max: float = 1.5
    """Integrator clamp, rad/s (>= 0)."""
    omega_weight: float = 0.1
    """Nearest-feasible metric: (m/s)² per (rad/s)² of yaw-rate error (> 0)."""


REFERENCES = ("analytic", "analytic_nearest", "feedback")
"""The reference controllers, by index: the analytic inverse model with uniform
desaturation (the baseline), the same with nearest-feasible desaturation, and
:class:`FeedbackConfig`'s closed loop."""

RESIDUAL_SPACES = ("wheel", "twist")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The task. ``robot`` is a built-in description name or a path to a TOML file.

    ``residual_space`` (with ``residual = true``): ``"wheel"``, one correction per wheel
    (``± residual_scale · max_rate``); or ``"twist"``, a correction of the body twist
    (``± residual_scale`` of the largest feasible vx, vy, ωz) mapped through the nominal
    inverse model, so the policy cannot drive the wheels against each other (the
    inverse model's null space, which squeezes the rollers and only costs energy).

    ``solver_iterations`` > 0 overrides the description's Newton iterations (``0``: keep
    them); fewer than 12 let robots on slippery floors tip over (SimSpec.iterations).

    ``yaw_integral_tau`` > 0 adds an observation a real controller can compute: the leaky
    integral of the yaw-rate error the robot *measures*, ``I ← e^(−dt/τ)·I + (ω_cmd −
    gyro)·dt`` (gyro as observed: noisy, delayed), in units of ``τ`` times the largest
    feasible ωz. It gives a feedforward policy the memory an integral controller needs
    (experiments/feedback_headroom.py); ``0`` leaves it out.
    """

    robot: str = "o_rectangle"
    """A built-in robot description (configs/robots) or a path to a description TOML."""
    control_dt: float = 0.02
    """Control period, s (> 0, a whole multiple of physics_timestep)."""
    physics_timestep: float = 0.005
    """MJX physics step, s (> 0)."""
    contact_timeconst: float = 0.01
    """Contact solver time constant, s (> 0; about 2 physics steps or more)."""
    solver_iterations: int = 0
    """Newton iterations of the physics solver (>= 0; 0: the description's)."""
    physics_impl: str = ""
    """MJX implementation: "jax", "warp" (needs the warp extra), or "" (the robot's sim.impl)."""
    episode_length: int = 500
    """Control steps per training episode (>= 1)."""
    residual: bool = True
    """Actions correct the analytic baseline's setpoints (false: actions are setpoints)."""
    residual_scale: float = 0.1
    """Largest residual correction, as a fraction of the largest wheel rate or twist (> 0)."""
    residual_space: str = "wheel"
    """Where the residual acts: "wheel" (one per wheel) or "twist" (vx, vy, ωz)."""
    yaw_integral_tau: float = 0.0
    """Time constant of the observed leaky yaw-rate error integral, s (>= 0; 0: off)."""
    commands: CommandConfig = CommandConfig()
    """How commands are drawn."""
    randomization: RandomizationConfig = RandomizationConfig()
    """Per-robot domain randomization."""
    noise: NoiseConfig = NoiseConfig()
    """Sensor noise."""
    reward: RewardConfig = RewardConfig()
    """Reward scales."""
    feedback: FeedbackConfig = FeedbackConfig()
    """The feedback reference controller's gains."""

    def validate(self, where: str = "env") -> EnvConfig:
        """Check values (not only types); raise :class:`ConfigError` naming the field."""
        require(
            self,
            where,
            ("control_dt", "physics_timestep", "contact_timeconst", "residual_scale"),
            lambda v: v > 0,
            "must be > 0",
        )
        ratio = self.control_dt / self.physics_timestep
        if abs(ratio - round(ratio)) > 1e-6:
            raise invalid(
                f"{where}.control_dt",
                self.control_dt,
                f"must be a whole multiple of physics_timestep = {self.physics_timestep}",
            )
        require(self, where, ("episode_length",), lambda v: v >= 1, "must be >= 1")
        require(
            self,
            where,
            ("solver_iterations",),
            lambda v: v >= 0,
            "must be >= 0 (0: the robot description's sim.iterations)",
        )
        require(self, where, ("yaw_integral_tau",), lambda v: v >= 0, "must be >= 0 (0: off)")
        if self.physics_impl not in ("", *IMPLS):
            raise invalid(
                f"{where}.physics_impl", self.physics_impl, f"expected one of {['', *IMPLS]}"
            )
        if self.residual_space not in RESIDUAL_SPACES:
            raise invalid(
                f"{where}.residual_space", self.residual_space, f"expected one of {RESIDUAL_SPACES}"
            )
        if self.residual_space == "twist" and not self.residual:
            raise invalid(f"{where}.residual_space", self.residual_space, "needs residual = true")
        c = self.commands
        kinds = ("p_zero", "p_translation", "p_spin", "p_combined", "p_beyond")
        require(c, f"{where}.commands", kinds, lambda v: v >= 0, "must be >= 0")
        weights = [getattr(c, k) for k in kinds]
        if sum(weights) <= 0:
            raise invalid(
                f"{where}.commands.p_*", weights, "at least one kind must have weight > 0"
            )
        if not 0 <= c.min_fraction <= c.max_fraction:
            raise invalid(
                f"{where}.commands.min_fraction", c.min_fraction, "need 0 <= min <= max_fraction"
            )
        if not 1 <= c.beyond_min_fraction <= c.beyond_max_fraction:
            raise invalid(
                f"{where}.commands.beyond_min_fraction",
                c.beyond_min_fraction,
                "need 1 <= beyond_min_fraction <= beyond_max_fraction",
            )
        if not 0 < c.resample_min_s <= c.resample_max_s:
            raise invalid(
                f"{where}.commands.resample_min_s", c.resample_min_s, "need 0 < min <= max"
            )
        r = self.randomization
        rw = f"{where}.randomization"
        for name in (
            "friction",
            "payload_mass",
            "payload_com_z",
            "radius_scale",
            "torque_scale",
            "gain_scale",
            "latency_steps",
        ):
            lo, hi = getattr(r, name)
            if lo > hi:
                raise invalid(f"{rw}.{name}", [lo, hi], "lower bound above upper bound")
        for name in ("friction", "radius_scale", "torque_scale", "gain_scale"):
            if getattr(r, name)[0] <= 0:
                raise invalid(f"{rw}.{name}", list(getattr(r, name)), "must be > 0")
        if r.payload_mass[0] < 0:
            raise invalid(f"{rw}.payload_mass", list(r.payload_mass), "must be >= 0")
        if any(abs(x) >= 1 for x in r.payload_com_offset):
            raise invalid(f"{rw}.payload_com_offset", list(r.payload_com_offset), "need |x| < 1 m")
        if r.latency_steps[0] < 0 or r.latency_steps[1] > 10:
            raise invalid(f"{rw}.latency_steps", list(r.latency_steps), "need 0 <= lo <= hi <= 10")
        require(
            r,
            rw,
            ("wheel_friction_spread", "wheel_radius_spread", "payload_com_xy"),
            lambda v: 0 <= v < 1,
            "must be in [0, 1)",
        )
        require(
            self.noise,
            f"{where}.noise",
            ("scale", "wheel_rate", "gyro", "accel"),
            lambda v: v >= 0,
            "must be >= 0",
        )
        w, ww = self.reward, f"{where}.reward"
        require(w, ww, ("sigma_lin", "sigma_ang"), lambda v: v > 0, "must be > 0")
        require(w, ww, REWARD_TERMS, lambda v: v >= 0, "must be >= 0 (a weight)")
        fb = self.feedback
        require(fb, f"{where}.feedback", ("kp", "ki", "i_max"), lambda v: v >= 0, "must be >= 0")
        require(fb, f"{where}.feedback", ("omega_weight",), lambda v: v > 0, "must be > 0")
        self.description(where)  # the robot must load
        return self

    def description(self, where: str = "env") -> RobotDescription:
        """The robot description, with this task's physics timestep and contact time constant."""
        desc = resolve_description(self.robot, where)
        sim = dataclasses.replace(
            desc.sim,
            timestep=self.physics_timestep,
            contact_timeconst=self.contact_timeconst,
            iterations=self.solver_iterations or desc.sim.iterations,
            impl=self.physics_impl or desc.sim.impl,
        )
        return dataclasses.replace(desc, sim=sim)

    def nominal(self) -> EnvConfig:
        """The nominal scenario: no randomization, no sensor noise, no latency."""
        return dataclasses.replace(
            self,
            randomization=dataclasses.replace(self.randomization, enabled=False),
            noise=dataclasses.replace(self.noise, scale=0.0),
        )


def load_env_config(path: str | Path) -> EnvConfig:
    """An :class:`EnvConfig` from a TOML file (all keys optional, unknown keys rejected)."""
    return from_mapping(EnvConfig, load_toml(path), "env").validate()


# --- the environment -----------------------------------------------------------------------

_COMMAND_KINDS = ("zero", "translation", "spin", "combined", "beyond")


class MecanumEnv(Env):
    """One robot tracking body-twist commands (Brax ``Env``); batch with :class:`TrainingEnv`."""

    def __init__(self, config: EnvConfig | None = None, robots: int = 1):
        """``robots``: the most robots one batched call simulates (all vmapped axes
        together), for MuJoCo Warp's shared contact buffer (:class:`Robot`)."""
        self.config = config = (config or EnvConfig()).validate()
        self.desc = config.description()
        self.robot = Robot(self.desc, "fast", robots=robots)
        self.geometry = self.robot.geometry
        self.n_wheels = n = self.geometry.n_wheels
        self.substeps = round(config.control_dt / config.physics_timestep)
        self.max_rates = self.desc.max_wheel_rates(self.geometry).astype(jnp.float32)
        self.max_rate = float(np.max(np.asarray(self.max_rates)))
        axes = np.eye(3, dtype=np.float32)
        # scale of each command axis: the largest feasible pure vx, vy, ωz
        self.command_scale = jnp.asarray(
            np.asarray(limits.max_speed(self.geometry, axes, self.max_rates)), jnp.float32
        )
        self._nominal = self.robot.nominal_params()
        self._jacobian = jnp.asarray(kinematics.jacobian(self.geometry), jnp.float32)
        kinematics.require_full_rank(self.geometry)
        self._forward = jnp.asarray(kinematics.forward_matrix(self.geometry), jnp.float32)
        self.max_latency = config.randomization.latency_steps[1]
        self.twist_residual = config.residual and config.residual_space == "twist"
        self._action_size = 3 if self.twist_residual else n
        self._sensor_size = n + 1 + 3 + 3
        self.layout: tuple[tuple[str, int], ...] = (
            ("command", 3),
            ("wheel_rate", n),
            ("gyro_z", 1),
            ("accel", 3),
            ("odometry_twist", 3),
            ("last_action", self._action_size),
        )
        tau = config.yaw_integral_tau
        self._yaw_decay = float(np.exp(-config.control_dt / tau)) if tau > 0 else 0.0
        if tau > 0:
            self.layout += (("yaw_error_integral", 1),)
        self.privileged_layout: tuple[tuple[str, int], ...] = (
            *self.layout,
            ("true_twist", 3),
            ("friction", n),
            ("payload_mass", 1),
            ("payload_com", 3),
            ("radius_scale", n),
            ("torque_scale", n),
            ("gain_scale", n),
            ("latency", 1),
        )

    # --- Brax interface ---------------------------------------------------------------------

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        return {
            "state": (sum(s for _, s in self.layout),),
            "privileged_state": (sum(s for _, s in self.privileged_layout),),
        }

    @property
    def action_size(self) -> int:
        return self._action_size

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        k_params, rng = jax.random.split(rng)
        params, latency = self.sample_params(k_params)
        return self.reset_to(rng, params, latency, self.noise_std())

    def reset_to(
        self, rng: jax.Array, params: RobotParams, latency: jax.Array, noise_std: jax.Array
    ) -> State:
        """Reset with given physics ``params``, ``latency`` (control steps, at most the
        config's ``latency_steps[1]``) and sensor ``noise_std`` (wheel rate, gyro, accel).

        Evaluation uses this to run scenarios whose parameters are data, so that one
        compiled program serves them all.
        """
        k_cmd, k_time, k_noise, rng = jax.random.split(rng, 4)
        sim = self.robot.reset(params)
        command = self.sample_command(k_cmd)
        zeros = jnp.zeros(self.action_size)
        sens = self.robot.sensors(sim)
        noise_std = jnp.asarray(noise_std, jnp.float32)
        sensors = self._sensor_vector(sens, k_noise, noise_std)
        history = jnp.broadcast_to(sensors, (self.max_latency + 1, self._sensor_size))
        info = {
            "rng": rng,
            "params": params,
            "latency": jnp.asarray(latency, jnp.int32),
            "noise_std": noise_std,
            "command": command,
            "next_resample": self._resample_time(k_time, jnp.asarray(0, jnp.int32)),
            "step": jnp.asarray(0, jnp.int32),
            "last_action": zeros,
            "history": history,
            "yaw_integral": jnp.asarray(0.0),
            "feedback_integral": jnp.asarray(0.0),
            "feedback_gains": self.feedback_gains(),
            "truncation": jnp.asarray(0.0),
        }
        obs = self._observe(sens, info)
        metrics = {k: jnp.asarray(0.0) for k in self.metric_names}
        return State(sim, obs, jnp.asarray(0.0), jnp.asarray(0.0), metrics, info)

    def noise_std(self, noise: NoiseConfig | None = None) -> jax.Array:
        """Sensor noise standard deviations (wheel rate, gyro, accel) of a noise config."""
        nc = noise or self.config.noise
        return jnp.asarray(
            [nc.scale * nc.wheel_rate, nc.scale * nc.gyro, nc.scale * nc.accel], jnp.float32
        )

    def set_command(self, state: State, command: jax.Array) -> State:
        """Impose ``command`` from now on (scripted sequences): it replaces the current
        command, in the observations too, and the environment stops resampling."""
        info = dict(state.info)
        info["command"] = command
        info["next_resample"] = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)
        scaled = command / self.command_scale
        obs = {k: v.at[:3].set(scaled) for k, v in state.obs.items()}  # command comes first
        return state.replace(obs=obs, info=info)

    def step(self, state: State, action: jax.Array, reference: jax.Array | None = None) -> State:
        """One control step under ``action``; with ``reference`` (an index into
        :data:`REFERENCES`, may be traced; negative: none) that reference controller's
        setpoints replace the action's. The feedback controller's integrator is updated only
        when ``reference`` is given."""
        info = dict(state.info)
        action = jnp.clip(action, -1.0, 1.0)
        params: RobotParams = info["params"]
        command = info["command"]
        rates = self.wheel_setpoints(command, action)
        if reference is not None:
            rates = jnp.where(reference >= 0, self.reference_rates(reference, state.info), rates)
        # the feedback reference's integrator runs only where a reference may act (evaluation),
        # not in training, whose actions never use it
        feedback_integral = (
            state.info["feedback_integral"]
            if reference is None
            else self._feedback_integral(state.info)
        )
        sim = self.robot.step(state.pipeline_state, rates, params, self.substeps)
        sens = self.robot.sensors(sim)
        rng, k_noise, k_cmd, k_time = jax.random.split(info["rng"], 4)

        err = sens.twist - command
        power = jnp.sum(jnp.abs(sens.wheel_torque * sens.wheel_rate))
        scaled = scaled_reward_terms(
            reward_terms(err, action, info["last_action"], power, self.config.reward),
            self.config.reward,
        )
        reward = sum(scaled.values(), jnp.asarray(0.0))
        saturated = jnp.mean(
            (jnp.abs(sens.wheel_torque) >= 0.99 * params.torque_limit).astype(jnp.float32)
        )
        metrics = {
            **{f"reward/{name}": value for name, value in scaled.items()},
            "error/vx2": err[0] ** 2,
            "error/vy2": err[1] ** 2,
            "error/wz2": err[2] ** 2,
            "energy_j": power * self.config.control_dt,
            "saturated": saturated,
            "unstable": sim.unstable.astype(jnp.float32),
        }

        step = info["step"] + 1
        resample = step >= info["next_resample"]
        info["command"] = jnp.where(resample, self.sample_command(k_cmd), command)
        info["next_resample"] = jnp.where(
            resample, self._resample_time(k_time, step), info["next_resample"]
        )
        info["step"] = step
        info["rng"] = rng
        info["last_action"] = action
        info["feedback_integral"] = feedback_integral
        sensors = self._sensor_vector(sens, k_noise, info["noise_std"])
        info["history"] = jnp.concatenate([sensors[None], info["history"][:-1]], axis=0)
        if self.config.yaw_integral_tau > 0:  # against the command tracked in this step
            gyro = self._delayed(info)[self.n_wheels]
            err = command[2] - gyro * self.command_scale[2]
            info["yaw_integral"] = (
                self._yaw_decay * info["yaw_integral"] + err * self.config.control_dt
            )
        obs = self._observe(sens, info)
        return state.replace(pipeline_state=sim, obs=obs, reward=reward, metrics=metrics, info=info)

    metric_names = (
        *(f"reward/{name}" for name in REWARD_TERMS),
        "error/vx2",
        "error/vy2",
        "error/wz2",
        "energy_j",
        "saturated",
        "unstable",
    )

    # --- pieces -----------------------------------------------------------------------------

    def baseline_rates(self, command: jax.Array) -> jax.Array:
        """The analytic baseline: the nominal inverse model, desaturated to the rate limits."""
        twist, _ = limits.desaturate(self.geometry, command, self.max_rates)
        return kinematics.apply_rows(self._jacobian, twist)

    def feasible_target(self, command: jax.Array, radius_scale: jax.Array) -> jax.Array:
        """The nearest feasible twist to ``command`` (..., 3) for the robot as it really is
        (wheel radii scaled by ``radius_scale`` (n,), the rate limits), in the reference
        controllers' metric: the target of the steady-state error."""
        geom = self.geometry.replace(radii=self.geometry.radii * radius_scale)
        w = self.config.feedback.omega_weight
        return limits.nearest_feasible(geom, command, self.max_rates, w)

    def measured_yaw_rate(self, info: dict[str, Any]) -> jax.Array:
        """The gyro's yaw rate as the controller sees it now (noisy, ``latency`` steps old)."""
        return self._delayed(info)[self.n_wheels] * self.command_scale[2]

    def _rates(self, twist: jax.Array) -> jax.Array:
        return kinematics.apply_rows(self._jacobian, twist)

    def feedback_gains(self, feedback: FeedbackConfig | None = None) -> jax.Array:
        """``(kp, ki, i_max)`` of a feedback config (default: this task's), as the array the
        state carries in ``info["feedback_gains"]`` (so a gain sweep compiles once)."""
        fb = feedback or self.config.feedback
        return jnp.asarray([fb.kp, fb.ki, fb.i_max], jnp.float32)

    def _feedback_twist(self, info: dict[str, Any]) -> tuple[jax.Array, jax.Array]:
        """The PI-corrected twist command, and the yaw-rate error it corrects."""
        kp = info["feedback_gains"][0]
        command = info["command"]
        err = command[2] - self.measured_yaw_rate(info)
        u = kp * err + info["feedback_integral"]
        return command + jnp.asarray([0.0, 0.0, 1.0]) * u, err

    def _feedback_integral(self, info: dict[str, Any]) -> jax.Array:
        """The feedback controller's integrator after this step (see :class:`FeedbackConfig`)."""
        _, ki, i_max = info["feedback_gains"]
        twist, err = self._feedback_twist(info)
        saturated = jnp.max(jnp.abs(self._rates(twist)) / self.max_rates) > 1.0
        u = twist[2] - info["command"][2]
        hold = saturated & (err * u > 0)  # the error would wind it up further
        grown = jnp.clip(info["feedback_integral"] + ki * err * self.config.control_dt,
                         -i_max, i_max)  # fmt: skip
        return jnp.where(hold, info["feedback_integral"], grown)

    def nearest_rates(self, twist: jax.Array) -> jax.Array:
        """Wheel rates of the feasible twist nearest ``twist`` (nominal geometry)."""
        w = self.config.feedback.omega_weight
        return self._rates(limits.nearest_feasible(self.geometry, twist, self.max_rates, w))

    def reference_rates(self, reference: int | jax.Array, info: dict[str, Any]) -> jax.Array:
        """Wheel-rate setpoints of reference controller ``reference`` (an index into
        :data:`REFERENCES`; a Python int computes only that one) for the state's ``info``."""
        candidates = (
            lambda: self.baseline_rates(info["command"]),
            lambda: self.nearest_rates(info["command"]),
            lambda: self.nearest_rates(self._feedback_twist(info)[0]),
        )
        if isinstance(reference, int):
            return candidates[reference]()
        index = jnp.clip(jnp.asarray(reference), 0, len(candidates) - 1)
        return jnp.select([index == i for i in range(len(candidates))], [c() for c in candidates])

    def wheel_setpoints(self, command: jax.Array, action: jax.Array) -> jax.Array:
        """Wheel-rate setpoints (rad/s) for an action in [-1, 1]^action_size under ``command``."""
        if self.twist_residual:
            correction = action * (self.config.residual_scale * self.command_scale)
            rates = self.baseline_rates(command) + kinematics.apply_rows(self._jacobian, correction)
        elif self.config.residual:
            rates = self.baseline_rates(command) + action * (
                self.config.residual_scale * self.max_rates
            )
        else:
            rates = action * self.max_rates
        return jnp.clip(rates, -self.max_rates, self.max_rates)

    def sample_params(
        self, key: jax.Array, randomization: RandomizationConfig | None = None
    ) -> tuple[RobotParams, jax.Array]:
        """Per-robot physical parameters and observation latency (steps), drawn from
        ``randomization`` (default: the config's)."""
        r = randomization or self.config.randomization
        nom = self._nominal
        if not r.enabled:
            return nom, jnp.asarray(0, jnp.int32)
        n = self.n_wheels
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
        return params, latency

    def sample_command(self, key: jax.Array, commands: CommandConfig | None = None) -> jax.Array:
        """One command (vx, vy, ωz) from the mix of kinds of ``commands`` (default: the
        config's :class:`CommandConfig`)."""
        c = commands or self.config.commands
        k_kind, k_angle, k_dir, k_sign, k_frac, k_beyond = jax.random.split(key, 6)
        weights = jnp.array([c.p_zero, c.p_translation, c.p_spin, c.p_combined, c.p_beyond])
        kind = jax.random.categorical(k_kind, jnp.log(weights))
        angle = jax.random.uniform(k_angle, (), minval=-jnp.pi, maxval=jnp.pi)
        translation = jnp.stack([jnp.cos(angle), jnp.sin(angle), jnp.asarray(0.0)])
        spin = jnp.array([0.0, 0.0, 1.0]) * jnp.where(jax.random.bernoulli(k_sign), 1.0, -1.0)
        # combined: a random direction in command space, each axis scaled to its reach
        combined = jax.random.normal(k_dir, (3,)) * self.command_scale
        direction = jnp.select(
            [kind == 1, kind == 2], [translation, spin], jnp.where(kind == 0, 0.0, combined)
        )
        norm = jnp.linalg.norm(direction)
        unit = direction / jnp.where(norm > 0, norm, 1.0)
        reach = limits.max_speed(self.geometry, jnp.where(norm > 0, unit, 1.0), self.max_rates)
        frac = jax.random.uniform(k_frac, (), minval=c.min_fraction, maxval=c.max_fraction)
        beyond = jax.random.uniform(
            k_beyond, (), minval=c.beyond_min_fraction, maxval=c.beyond_max_fraction
        )
        frac = jnp.where(kind == 4, beyond, frac)
        return jnp.where(kind == 0, 0.0, unit * reach * frac)

    def command_schedule(
        self, key: jax.Array, steps: int, commands: CommandConfig | None = None
    ) -> jax.Array:
        """``(steps, 3)`` commands as an episode would draw them: a first command, then a
        new one at random times (the training task's process, from ``commands``)."""
        k0, k1, key = jax.random.split(key, 3)
        first = self.sample_command(k0, commands)
        start = self._resample_time(k1, jnp.asarray(0, jnp.int32), commands)

        def step(carry: tuple, t: jax.Array) -> tuple[tuple, jax.Array]:
            cmd, due, k = carry
            k, k_cmd, k_time = jax.random.split(k, 3)
            now = t >= due
            cmd = jnp.where(now, self.sample_command(k_cmd, commands), cmd)
            due = jnp.where(now, self._resample_time(k_time, t, commands), due)
            return (cmd, due, k), cmd

        _, out = jax.lax.scan(step, (first, start, key), jnp.arange(steps, dtype=jnp.int32))
        return out

    def _resample_time(
        self, key: jax.Array, now: jax.Array, commands: CommandConfig | None = None
    ) -> jax.Array:
        c = commands or self.config.commands
        # jnp (not Python) arithmetic: evaluation passes the config's values as traced arrays
        dt = self.config.control_dt
        lo = jnp.maximum(1, jnp.round(jnp.asarray(c.resample_min_s) / dt)).astype(jnp.int32)
        hi = jnp.maximum(lo, jnp.round(jnp.asarray(c.resample_max_s) / dt).astype(jnp.int32))
        return now + jax.random.randint(key, (), lo, hi + 1)

    def _sensor_vector(self, s: Sensors, key: jax.Array, noise_std: jax.Array) -> jax.Array:
        """Noisy encoder rates, gyro z, accelerometer and the odometry twist (scaled)."""
        k1, k2, k3 = jax.random.split(key, 3)
        n = self.n_wheels
        rate = s.wheel_rate + noise_std[0] * jax.random.normal(k1, (n,))
        gyro = s.gyro_z + noise_std[1] * jax.random.normal(k2)
        accel = s.accel + noise_std[2] * jax.random.normal(k3, (3,))
        odom = self._forward @ rate
        return jnp.concatenate(
            [
                rate / self.max_rates,
                (gyro / self.command_scale[2])[None],
                accel / GRAVITY,
                odom / self.command_scale,
            ]
        )

    @staticmethod
    def _delayed(info: dict[str, Any]) -> jax.Array:
        """The sensor vector as the robot observes it now: ``latency`` steps old."""
        return jnp.take(info["history"], info["latency"], axis=0)

    def _observe(self, sens: Sensors, info: dict[str, Any]) -> dict[str, jax.Array]:
        delayed = self._delayed(info)
        parts = [info["command"] / self.command_scale, delayed, info["last_action"]]
        tau = self.config.yaw_integral_tau
        if tau > 0:
            parts.append((info["yaw_integral"] / (tau * self.command_scale[2]))[None])
        state = jnp.concatenate(parts)
        p: RobotParams = info["params"]
        nom = self._nominal
        truth = sens.twist / self.command_scale
        privileged = jnp.concatenate(
            [
                state,
                truth,
                p.friction,
                p.payload_mass[None],
                p.payload_com,
                p.radius_scale,
                p.torque_limit / nom.torque_limit,
                p.kp / nom.kp,
                info["latency"].astype(jnp.float32)[None],
            ]
        )
        return {"state": state, "privileged_state": privileged}

    def command_from_obs(self, obs: dict[str, jax.Array]) -> jax.Array:
        """The (noise-free) command carried in the first three policy observations."""
        cmd = obs["state"][..., :3]
        return cmd * self.command_scale.reshape((1,) * (cmd.ndim - 1) + (3,))


class TrainingEnv(Wrapper):
    """A batch of :class:`MecanumEnv` robots with episode limits and automatic resets.

    Unlike Brax's ``AutoResetWrapper`` (which restores each slot's first state, so a slot
    keeps its randomized robot forever), a finished episode is reset from that robot's own
    rng stream: a fresh robot, command and latency per episode.
    ``state.info["truncation"]`` is 1 on the step an episode hits ``episode_length``.
    """

    def __init__(
        self, env: MecanumEnv, episode_length: int | None = None, chunk: int | None = None
    ):
        super().__init__(env)
        self.menv = env
        self.episode_length = episode_length or env.config.episode_length
        self.chunk = chunk if chunk is not None else cpu_chunk("fast", env.robot.impl)

    def reset(self, rng: jax.Array) -> State:
        return chunked_vmap(self.env.reset, self.chunk)(rng)

    def step(self, state: State, action: jax.Array) -> State:
        def one(s: State, a: jax.Array) -> State:
            nxt = self.env.step(s, a)
            done = nxt.info["step"] >= self.episode_length
            k_reset, k_next = jax.random.split(nxt.info["rng"])
            fresh = self.env.reset(k_reset)
            fresh.info["rng"] = k_next
            merged = jax.tree.map(
                lambda f, x: jnp.where(done, f, x),
                fresh.replace(pipeline_state=None),
                nxt.replace(pipeline_state=None),
            ).replace(pipeline_state=select(done, fresh.pipeline_state, nxt.pipeline_state))
            info = dict(merged.info)
            info["truncation"] = done.astype(jnp.float32)
            return merged.replace(
                reward=nxt.reward,
                metrics=nxt.metrics,
                done=done.astype(jnp.float32),
                info=info,
            )

        return chunked_vmap(one, self.chunk)(state, action)


def baseline_policy(env: MecanumEnv) -> Policy:
    """The analytic baseline behind the learned-policy interface ``(obs, key) -> (action, {})``.

    With residual actions it is the zero residual; otherwise it outputs the desaturated
    nominal inverse model's wheel rates divided by the rate limits.
    """

    def policy(obs: dict[str, jax.Array], key: jax.Array) -> tuple[jax.Array, dict[str, Any]]:
        del key
        command = env.command_from_obs(obs)
        if env.config.residual:
            return jnp.zeros((*command.shape[:-1], env.action_size)), {}
        rates = env.baseline_rates(command)
        return rates / env.max_rates.reshape((1,) * (rates.ndim - 1) + (-1,)), {}

    return policy


__all__ = [
    "REWARD_TERMS",
    "CommandConfig",
    "EnvConfig",
    "MecanumEnv",
    "NoiseConfig",
    "RandomizationConfig",
    "RewardConfig",
    "TrainingEnv",
    "baseline_policy",
    "load_env_config",
    "reward_terms",
    "scaled_reward_terms",
]
