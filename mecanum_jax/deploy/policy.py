"""Run an exported policy with NumPy alone: no JAX, MuJoCo or Brax on the robot.

This file depends only on NumPy and the standard library. Copy it next to the exported
``policy.npz`` (``mecanum-export`` does) and::

    from mecanum_policy import load           # this file, renamed on export
    policy = load("policy.npz")
    obs = policy.observation(command, wheel_rate, gyro_z, accel, last_action)
    action = policy.action(obs)                # the trained policy, deterministic
    setpoints = policy.wheel_setpoints(command, action)   # rad/s per wheel, to the servos

The export holds the policy network's weights, the observation normalizer (mean and
standard deviation, as Brax's running statistics apply it) and what the control loop
needs around the network: the observation layout and scales, the nominal inverse model
(Jacobian) and wheel-rate limits for the baseline the residual actions are added to.

Wheel order, units and signs are those of the robot description used for training
(``meta["robot"]``); wheel rates are rad/s of the wheel, positive rolling forward.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "mecanum-policy/1"
_ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "swish": lambda x: x / (1.0 + np.exp(-x)),
    "tanh": np.tanh,
    "relu": lambda x: np.maximum(x, 0.0),
    "elu": lambda x: np.where(x > 0, x, np.expm1(np.minimum(x, 0.0))),
}


class ExportError(ValueError):
    """An exported policy file is missing, corrupt or of another format."""


class NumpyPolicy:
    """A deterministic policy: ``action = tanh(MLP(clip((obs - mean) / std))[:n])``
    (clipped to ``± meta["clip_observations"]`` when that is > 0)."""

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
        self.activation = _ACTIVATIONS[meta["activation"]]
        self.action_size = int(meta["action_size"])
        self.max_rates = np.asarray(meta["max_rates"], np.float32)
        self.command_scale = np.asarray(meta["command_scale"], np.float32)
        self.jacobian = np.asarray(meta["jacobian"], np.float32)
        self.forward = np.asarray(meta["forward_matrix"], np.float32)

    @property
    def observation_size(self) -> int:
        return int(self.mean.shape[-1])

    @property
    def action_filter(self) -> float:
        """The actions' low-pass factor f (0: none): :meth:`action` returns
        ``f·last_action + (1 − f)·network``, with ``last_action`` read from ``obs``."""
        return float(self.meta.get("action_filter") or 0.0)

    def entry(self, name: str) -> slice:
        """Where the observation entry ``name`` lies in the observation vector."""
        start = 0
        for entry, size in self.meta["observation_layout"]:
            if entry == name:
                return slice(start, start + int(size))
            start += int(size)
        raise ExportError(f"observation_layout has no {name} entry")

    def action(self, obs: np.ndarray) -> np.ndarray:
        """Actions (..., action_size) in [-1, 1] for policy observations: a correction per
        wheel, or of the body twist (``meta["residual_space"]``), low-passed with the last
        action when the policy was trained so (:attr:`action_filter`)."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1:] != (self.observation_size,):
            raise ValueError(
                f"obs: shape {x.shape}, expected (..., {self.observation_size}) "
                f"(layout {self.meta['observation_layout']})"
            )
        raw = x
        x = (x - self.mean) / self.std
        clip = float(self.meta.get("clip_observations") or 0.0)
        if clip > 0:
            x = np.clip(x, -clip, clip)
        for i, (w, b) in enumerate(self.layers):
            x = x @ w + b
            if i < len(self.layers) - 1:
                x = self.activation(x)
        action = np.tanh(x[..., : self.action_size])
        f = np.float32(self.action_filter)
        if f > 0:
            action = f * raw[..., self.entry("last_action")] + (np.float32(1.0) - f) * action
        return action

    @property
    def yaw_integral_tau(self) -> float:
        """The yaw-error integral's time constant, s (0: the policy does not observe it)."""
        return float(self.meta.get("yaw_integral_tau") or 0.0)

    def yaw_integral_step(self, integral: float, command: Any, gyro_z: float) -> float:
        """One control step of the leaky yaw-rate error integral the policy observes:
        ``e^(−dt/τ)·I + (ω_cmd − gyro)·dt``, with ``command`` the twist tracked during the
        step and ``gyro_z`` the yaw rate as measured at its end (rad/s)."""
        tau, dt = self.yaw_integral_tau, float(self.meta["control_dt"])
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
    ) -> np.ndarray:
        """The policy observation from raw measurements (what the environment builds).

        Args:
          command: (3,) target body twist vx, vy (m/s), ωz (rad/s).
          wheel_rate: (n,) encoder rates, rad/s of the wheel.
          gyro_z: yaw rate, rad/s.
          accel: (3,) accelerometer, specific force in the body frame, m/s² (+9.81 z at rest).
          last_action: (action_size,) the previous action returned by :meth:`action`
            (zeros at start).
          yaw_integral: the state of :meth:`yaw_integral_step`, required when the policy
            observes it (``yaw_integral_tau > 0``), rad.
        """
        tau = self.yaw_integral_tau
        if tau > 0 and yaw_integral is None:
            raise ValueError(
                f"yaw_integral = None: this policy observes the yaw-error integral "
                f"(tau = {tau} s); keep it with yaw_integral_step()"
            )
        rate = np.asarray(wheel_rate, np.float32)
        odometry = self.forward @ rate
        return np.concatenate(
            [
                np.asarray(command, np.float32) / self.command_scale,
                rate / self.max_rates,
                np.asarray([gyro_z], np.float32) / self.command_scale[2],
                np.asarray(accel, np.float32) / np.float32(self.meta["gravity"]),
                odometry / self.command_scale,
                np.asarray(last_action, np.float32),
                *(
                    [np.asarray([yaw_integral], np.float32) / (tau * self.command_scale[2])]
                    if tau > 0
                    else []
                ),
            ]
        ).astype(np.float32)

    def baseline_rates(self, command: Any) -> np.ndarray:
        """The analytic baseline: nominal inverse model, desaturated (uniformly scaled
        down until no wheel exceeds its rate limit)."""
        twist = np.asarray(command, np.float32)
        rates = twist @ self.jacobian.T
        excess = np.max(np.abs(rates) / self.max_rates, axis=-1, keepdims=True)
        return rates / np.maximum(excess, 1.0)

    def wheel_setpoints(self, command: Any, action: Any) -> np.ndarray:
        """Wheel-rate setpoints (rad/s) for the servos."""
        a = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        if self.meta["residual"] and self.meta.get("residual_space", "wheel") == "twist":
            correction = a * (np.float32(self.meta["residual_scale"]) * self.command_scale)
            rates = self.baseline_rates(command) + correction @ self.jacobian.T
        elif self.meta["residual"]:
            rates = self.baseline_rates(command) + a * (
                np.float32(self.meta["residual_scale"]) * self.max_rates
            )
        else:
            rates = a * self.max_rates
        return np.clip(rates, -self.max_rates, self.max_rates)


def load(path: str | Path) -> NumpyPolicy:
    """Load a policy written by ``mecanum-export``."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
    except FileNotFoundError:
        raise ExportError(f"policy file {str(path)!r}: no such file") from None
    except Exception as err:  # zipfile/np errors for corrupt files
        raise ExportError(f"policy file {str(path)!r}: unreadable: {err}") from None
    if "meta" not in data:
        raise ExportError(f"policy file {str(path)!r}: no 'meta' entry; not an export")
    meta = json.loads(str(data["meta"]))
    if meta.get("format") != FORMAT:
        raise ExportError(
            f"policy file {str(path)!r}: format {meta.get('format')!r}, expected {FORMAT!r}"
        )
    layers = []
    for i in range(int(meta["layers"])):
        layers.append((data[f"w{i}"].astype(np.float32), data[f"b{i}"].astype(np.float32)))
    return NumpyPolicy(layers, data["obs_mean"], data["obs_std"], meta)


def save(
    path: str | Path,
    layers: list[tuple[np.ndarray, np.ndarray]],
    mean: np.ndarray,
    std: np.ndarray,
    meta: dict[str, Any],
) -> Path:
    """Write an export (atomically: a crash leaves no half-written file)."""
    path = Path(path)
    arrays = {f"w{i}": np.asarray(w, np.float32) for i, (w, _) in enumerate(layers)}
    arrays |= {f"b{i}": np.asarray(b, np.float32) for i, (_, b) in enumerate(layers)}
    meta = dict(meta, format=FORMAT, layers=len(layers))
    arrays["obs_mean"] = np.asarray(mean, np.float32)
    arrays["obs_std"] = np.asarray(std, np.float32)
    arrays["meta"] = np.asarray(json.dumps(meta))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    with tmp.open("wb") as f:
        savez: Any = np.savez
        savez(f, **arrays)
    tmp.replace(path)
    return path
