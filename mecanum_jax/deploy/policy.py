"""Run an exported policy with NumPy alone: no JAX, MuJoCo or Brax on the robot.

This file depends only on NumPy, the standard library and the controller package
(``mecanum_jax.control``). ``mecanum-export`` packs them, as ``mecanum_policy.py`` and
``mecanum_control/``, into ``mecanum_robot.zip`` beside the exported ``policy.npz``::

    import sys; sys.path.insert(0, "mecanum_robot.zip")
    from mecanum_policy import load           # this file, renamed on export
    policy = load("policy.npz")
    obs = policy.observation(command, wheel_rate, gyro_z, accel, last_action)
    action = policy.action(obs)                # the trained policy, deterministic
    setpoints = policy.wheel_setpoints(command, action, obs)   # rad/s per wheel, to the servos

The controller's states (the integrators, the sensor history) are kept by
``mecanum_loop.Controller``, which runs the same step functions as the training
environment (``mecanum_jax.control.step``). The export holds the network's weights, the
observation normalizer (mean and deviation, as Brax's running statistics apply it) and
the controller's description (``meta``: :class:`ControllerSpec`).

Wheel order, units and signs are those of the robot description used for training
(``meta["robot"]``); wheel rates are rad/s of the wheel, positive rolling forward.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

if __package__:  # inside the mecanum_jax package
    from mecanum_jax.control import ControllerSpec
    from mecanum_jax.control import step as ctl
    from mecanum_jax.control.network import network_output
else:  # pragma: no cover - in an export's archive (on sys.path), next to mecanum_control/
    from mecanum_control import ControllerSpec  # type: ignore[no-redef]
    from mecanum_control import step as ctl  # type: ignore[no-redef]
    from mecanum_control.network import network_output  # type: ignore[no-redef]

FORMAT = "mecanum-policy/1"


class ExportError(ValueError):
    """An exported policy file is missing, corrupt or of another format."""


class NumpyPolicy:
    """A deterministic policy: ``action = tanh(MLP(clip((obs - mean) / std))[:n])``
    (clipped to ``± meta["clip_observations"]`` when that is > 0), shaped and applied by
    the controller :attr:`spec` describes."""

    def __init__(
        self,
        layers: list[tuple[np.ndarray, np.ndarray]],
        mean: np.ndarray,
        std: np.ndarray,
        meta: dict[str, Any],
    ):
        self.layers = layers
        self.mean = mean
        self.std = std
        self.meta = meta
        self.spec = spec = ControllerSpec.from_meta(meta)
        self.action_size = spec.action_size
        self.max_rates = spec.max_rates
        self.command_scale = spec.command_scale
        self.jacobian = spec.jacobian
        self.gains = ctl.gains(spec, np)

    @property
    def observation_size(self) -> int:
        return int(self.mean.shape[-1])

    @property
    def residual_at_stop(self) -> bool:
        return self.spec.residual_at_stop

    @property
    def feedback_base(self) -> bool:
        return self.spec.feedback_base

    @property
    def feedback_hold_steps(self) -> int:
        return self.spec.feedback.hold_steps

    @property
    def feedback_reset(self) -> bool:
        return self.spec.feedback.reset

    @property
    def yaw_integral_tau(self) -> float:
        return self.spec.yaw_integral_tau

    @property
    def obs_history(self) -> int:
        return self.spec.obs_history

    def entry(self, name: str) -> slice:
        """Where the observation entry ``name`` lies in the observation vector."""
        try:
            return self.spec.entry(name)
        except KeyError:
            raise ExportError(f"observation_layout has no {name} entry") from None

    def _checked(self, obs: Any) -> np.ndarray:
        x = np.asarray(obs, np.float32)
        if x.shape[-1:] != (self.observation_size,):
            raise ValueError(
                f"obs: shape {x.shape}, expected (..., {self.observation_size}) "
                f"(layout {self.meta['observation_layout']})"
            )
        return x

    def network(self, obs: Any, xp: Any = np) -> Any:
        """The network's output in [-1, 1] for observations (before the controller)."""
        clip = float(self.meta.get("clip_observations") or 0.0)
        activation = self.meta["activation"]
        return network_output(
            self.spec, self.layers, self.mean, self.std, clip, activation, obs, xp
        )

    def decoded(self, obs: Any, xp: Any = np) -> tuple[Any, Any, Any, Any]:
        """The command, last action, gyro z and ``feedback`` integrator an observation
        carries (unscaled; the last two (..., 1), the integrator 0 where not observed)."""
        spec, scale = self.spec, self.spec.command_scale
        command = obs[..., 0:3] * xp.asarray(scale)
        last = obs[..., self.entry("last_action")]
        gyro = obs[..., self.entry("gyro_z")] * float(scale[2])
        if spec.feedback_base:
            integral = obs[..., self.entry("feedback_integral")] * float(scale[2])
        else:
            integral = gyro * 0.0
        return command, last, gyro, integral

    def action(self, obs: Any, command_age: Any = None) -> np.ndarray:
        """The applied action (..., action_size) for policy observations: the network's,
        soft-thresholded, 0 at a stop command where trained so, low-passed with the last
        action the observation carries (:func:`mecanum_jax.control.step.shape_action`),
        and ramped in by the command's age (..., control periods since it changed) where
        the policy was trained with ``residual_ramp_s``, which then needs it."""
        x = self._checked(obs)
        command, last, _, _ = self.decoded(x)
        action = ctl.shape_action(self.spec, self.network(x), command, last, np)
        if self.spec.residual_ramp_s <= 0:
            return action
        if command_age is None:
            raise ValueError(
                f"command_age = None: this policy's correction ramps in over "
                f"{self.spec.residual_ramp_s} s after a command change (residual_ramp_s), "
                f"so its action needs the command's age"
            )
        age = np.asarray(command_age, np.float32)[..., None]
        return ctl.ramp_in(self.spec, action, age, np).astype(np.float32)

    def feedback_twist(self, obs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``feedback`` controller's PI-corrected twist (..., 3) for observations, with
        the yaw-rate error and the integrator (rad/s) it read from them."""
        command, _, gyro, integral = self.decoded(self._checked(obs))
        twist, err = ctl.feedback_twist(self.spec, command, gyro, integral, self.gains, np)
        return twist, err[..., 0], integral[..., 0]

    def feedback_integral_step(self, obs: Any, command_age: Any = None) -> np.ndarray:
        """The ``feedback`` controller's integrator after this step (rad/s); held while
        ``command_age`` (periods since the command changed) is below
        :attr:`feedback_hold_steps`, which then needs it."""
        if self.feedback_hold_steps > 0 and command_age is None:
            raise ValueError(
                f"command_age = None: this policy's feedback integrator holds for "
                f"{self.feedback_hold_steps} control periods after a command change "
                f"(feedback.hold_s), so its step needs the command's age"
            )
        command, _, gyro, integral = self.decoded(self._checked(obs))
        age = None if command_age is None else np.asarray(command_age)[..., None]
        out = ctl.feedback_integral_step(self.spec, command, gyro, integral, self.gains, age, np)
        return out[..., 0].astype(np.float32)

    def yaw_integral_step(self, integral: float, command: Any, gyro_z: float) -> float:
        """One control step of the leaky yaw-rate error integral the policy observes:
        ``e^(−dt/τ)·I + (ω_cmd − gyro)·dt``."""
        tau, dt = self.yaw_integral_tau, self.spec.control_dt
        if tau <= 0:
            raise ValueError("yaw_integral_step: this policy does not use a yaw-error integral")
        err = float(np.asarray(command, np.float32)[2]) - float(gyro_z)
        return float(np.exp(-dt / tau)) * float(integral) + err * dt

    def observation(
        self,
        command: Any,
        wheel_rate: Any,
        gyro_z: Any,
        accel: Any,
        last_action: Any,
        yaw_integral: float | None = None,
        feedback_integral: float | None = None,
        sensor_history: Any = None,
        path_error: Any = None,
    ) -> np.ndarray:
        """The policy observation from raw measurements and the controller's states
        (:func:`mecanum_jax.control.step.observe`; ``sensor_history``: the
        :meth:`sensor_frame` outputs of the periods before this one, newest first)."""
        spec = self.spec
        needed = {
            "yaw_integral": (spec.yaw_integral_tau > 0, yaw_integral),
            "feedback_integral": (spec.feedback_base, feedback_integral),
            "path_error": (spec.path_tau > 0, path_error),
        }
        for name, (used, value) in needed.items():
            if used and value is None:
                raise ValueError(f"{name} = None: this policy observes it; keep it with Controller")
        frame = self.sensor_frame(wheel_rate, gyro_z, accel)
        frames = [frame[None]]
        if spec.obs_history > 0:
            past = None if sensor_history is None else np.asarray(sensor_history, np.float32)
            if past is None or past.shape != (spec.obs_history, frame.size):
                shape = None if past is None else past.shape
                raise ValueError(
                    f"sensor_history: shape {shape}, expected ({spec.obs_history}, "
                    f"{frame.size}): this policy observes the {spec.obs_history} "
                    "sensor_frame()s before this one, newest first"
                )
            frames.append(past)
        f32 = lambda v: np.asarray(0.0 if v is None else v, np.float32)  # noqa: E731
        state = ctl.ControllerState(
            command=f32(command),
            command_age=np.int32(0),
            last_action=f32(last_action),
            history=np.concatenate(frames, axis=0),
            yaw_integral=f32(yaw_integral),
            feedback_integral=f32(feedback_integral),
            feedback_gains=self.gains,
            path_error=f32(np.zeros(3) if path_error is None else path_error),
        )
        return ctl.observe(spec, state, 0, np).astype(np.float32)

    def sensor_frame(self, wheel_rate: Any, gyro_z: Any, accel: Any) -> np.ndarray:
        """One scaled sensor frame as the policy observes it: encoder rates, gyro z,
        accelerometer and the wheel-odometry twist."""
        rate = np.asarray(wheel_rate, np.float32)
        gyro = np.asarray(gyro_z, np.float32).reshape(1)
        accel = np.asarray(accel, np.float32)
        return ctl.frame(self.spec, rate, gyro, accel, np).astype(np.float32)

    def baseline_rates(self, command: Any) -> np.ndarray:
        """The analytic baseline: nominal inverse model, desaturated uniformly."""
        return ctl.baseline_rates(self.spec, np.asarray(command, np.float32), np)

    def wheel_setpoints(self, command: Any, action: Any, obs: Any = None) -> np.ndarray:
        """Wheel-rate setpoints (rad/s) for the servos (``obs``: the observation the action
        answered; needed when the residual corrects the ``feedback`` controller)."""
        cmd = np.asarray(command, np.float32)
        a = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        if self.feedback_base:
            if obs is None:
                raise ValueError("obs = None: this policy corrects the feedback controller")
            _, _, gyro, integral = self.decoded(self._checked(obs))
        else:
            gyro = integral = np.zeros((*cmd.shape[:-1], 1), np.float32)
        return ctl.setpoints(self.spec, cmd, a, gyro, integral, self.gains, np)


def outputs(policy: NumpyPolicy, obs: Any, command_age: Any, xp: Any) -> list[Any]:
    """What the ONNX graph computes from observations (..., size) and the command's age
    (..., 1; control periods since it changed, float) on namespace ``xp``: the applied
    action, the wheel-rate setpoints and, on the ``feedback`` controller, its integrator
    after this step (:func:`mecanum_jax.control.step.act` on the state they carry)."""
    spec = policy.spec
    command, last, gyro, integral = policy.decoded(obs, xp)
    action = ctl.shape_action(spec, policy.network(obs, xp), command, last, xp)
    action = ctl.ramp_in(spec, action, command_age, xp)
    gains = xp.asarray(policy.gains)
    rates = ctl.setpoints(spec, command, action, gyro, integral, gains, xp)
    if not spec.feedback_base:
        return [action, rates]
    return [
        action,
        rates,
        ctl.feedback_integral_step(spec, command, gyro, integral, gains, command_age, xp),
    ]


def load(path: str | Path) -> NumpyPolicy:
    """Load a policy written by ``mecanum-export``."""
    path = Path(path)
    where = f"policy file {str(path)!r}"
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
    except FileNotFoundError:
        raise ExportError(f"{where}: no such file") from None
    except Exception as err:  # zipfile/np errors for corrupt files
        raise ExportError(f"{where}: unreadable: {err}") from None
    if "meta" not in data:
        raise ExportError(f"{where}: no 'meta' entry; not an export")
    meta = json.loads(str(data["meta"]))
    if meta.get("format") != FORMAT:
        raise ExportError(f"{where}: format {meta.get('format')!r}, expected {FORMAT!r}")
    f32 = {k: v.astype(np.float32) for k, v in data.items() if k[0] in "wb"}
    layers = [(f32[f"w{i}"], f32[f"b{i}"]) for i in range(int(meta["layers"]))]
    return NumpyPolicy(layers, data["obs_mean"], data["obs_std"], meta)
