"""Run an exported policy with NumPy alone: no JAX, MuJoCo or Brax on the robot.

This file depends only on NumPy and the standard library. Copy it next to the exported
``policy.npz`` (``mecanum-export`` does) and::

    from mecanum_policy import load           # this file, renamed on export
    policy = load("policy.npz")
    obs = policy.observation(command, wheel_rate, gyro_z, accel, last_action)
    action = policy.action(obs)                # the trained policy, deterministic
    setpoints = policy.wheel_setpoints(command, action, obs)   # rad/s per wheel, to the servos

Some policies observe state the caller keeps (``mecanum_loop.Controller`` keeps it all):
the ``feedback`` controller's integrator (``meta["residual_base"]``: ``integral =
feedback_integral_step(obs)`` after each step, 0 at start and, where ``feedback_reset``, at
each command change) and earlier sensor frames (``meta["obs_history"]`` > 0, a student: the
last ``sensor_frame(...)``s, newest first), passed to ``observation`` as
``feedback_integral`` and ``sensor_history``.

The export holds the network's weights, the observation normalizer (mean and deviation,
as Brax's running statistics apply it), the observation layout and scales, and the
nominal Jacobian and wheel-rate limits of the baseline the residual corrects.

Wheel order, units and signs are those of the robot description used for training
(``meta["robot"]``); wheel rates are rad/s of the wheel, positive rolling forward.
"""

from __future__ import annotations

import itertools
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
        self.feedback = meta.get("feedback") or {}
        self._nearest: NearestFeasible | None = None  # the feedback controller's reach
        if self.feedback_base:
            weight = float(self.feedback["omega_weight"])
            self._nearest = NearestFeasible(self.jacobian, self.max_rates, weight)

    @property
    def observation_size(self) -> int:
        return int(self.mean.shape[-1])

    @property
    def action_filter(self) -> float:
        """The actions' low-pass factor f (0: none): :meth:`action` returns
        ``f·last_action + (1 − f)·network``, with ``last_action`` read from ``obs``."""
        return float(self.meta.get("action_filter") or 0.0)

    @property
    def residual_at_stop(self) -> bool:
        """False: :meth:`action` takes the network's action as 0 while the observed command
        is a stop (every component exactly 0), before the filter (true in older exports)."""
        return bool(self.meta.get("residual_at_stop", True))

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
        wheel, or of the body twist (``meta["residual_space"]``), soft-thresholded by
        ``meta["residual_deadband"]``, 0 at a stop command where :attr:`residual_at_stop` is
        false, low-passed with the last action where trained so (:attr:`action_filter`)."""
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
        d = np.float32(self.meta.get("residual_deadband") or 0.0)  # 0: off
        action = np.sign(action) * np.maximum(np.abs(action) - d, np.float32(0.0))
        if not self.residual_at_stop:  # the base alone stops: no correction at a zero command
            stop = np.all(raw[..., :3] == 0.0, axis=-1, keepdims=True)
            action = np.where(stop, np.float32(0.0), action)
        f = np.float32(self.action_filter)
        if f > 0:
            action = f * raw[..., self.entry("last_action")] + (np.float32(1.0) - f) * action
        return action

    @property
    def feedback_base(self) -> bool:
        """Whether the residual corrects the ``feedback`` controller (its zero action *is*
        that controller), whose integrator the policy observes (``feedback_integral``)."""
        return bool(self.meta["residual"]) and self.meta.get("residual_base") == "feedback"

    def feedback_twist(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``feedback`` controller's PI-corrected twist (..., 3) for observations, with
        the yaw-rate error and the integrator (rad/s) it read from them."""
        x = np.asarray(obs, np.float32)
        scale = self.command_scale
        command = x[..., :3] * scale
        gyro = x[..., self.entry("gyro_z")][..., 0] * scale[2]
        integral = x[..., self.entry("feedback_integral")][..., 0] * scale[2]
        err = command[..., 2] - gyro
        u = np.float32(self.feedback["kp"]) * err + integral
        band = np.float32(self.feedback.get("deadband") or 0.0)  # 0 in older exports
        if band > 0:
            u = np.sign(u) * np.maximum(np.abs(u) - band, np.float32(0.0))
        return command + np.asarray([0, 0, 1], np.float32) * u[..., None], err, integral

    @property
    def feedback_hold_steps(self) -> int:
        """Control periods the ``feedback`` integrator holds after a command change (the
        export's ``feedback.hold_s``; 0 in exports made before it existed)."""
        hold_s = float(self.feedback.get("hold_s") or 0.0)
        return round(hold_s / float(self.meta["control_dt"]))

    @property
    def feedback_reset(self) -> bool:
        """Whether the ``feedback`` integrator restarts at 0 at each command change (the
        export's ``feedback.reset``; off in exports made before it existed)."""
        return bool(self.feedback.get("reset") or False)

    def feedback_integral_step(self, obs: np.ndarray, command_age: Any = None) -> np.ndarray:
        """The ``feedback`` controller's integrator after this step (rad/s): ``I + ki·e·dt``
        clipped to ``± i_max``, held while the corrected twist is out of the wheels' reach
        and the error would drive it further, and while ``command_age`` (control periods
        since ``obs``'s command changed, 0 on its first) is below the environment's
        :attr:`feedback_hold_steps`."""
        twist, err, integral = self.feedback_twist(obs)
        rates = twist @ self.jacobian.T
        saturated = np.max(np.abs(rates) / self.max_rates, axis=-1) > 1.0
        u = twist[..., 2] - np.asarray(obs, np.float32)[..., 2] * self.command_scale[2]
        hold = saturated & (err * u > 0)
        if self.feedback_hold_steps > 0:
            if command_age is None:
                raise ValueError(
                    f"command_age = None: this policy's feedback integrator holds for "
                    f"{self.feedback_hold_steps} control periods after a command change "
                    f"(feedback.hold_s), so its step needs the command's age"
                )
            hold = hold | (np.asarray(command_age) < self.feedback_hold_steps)
        ki, i_max = np.float32(self.feedback["ki"]), np.float32(self.feedback["i_max"])
        dt = np.float32(self.meta["control_dt"])
        grown = np.clip(integral + ki * err * dt, -i_max, i_max)
        return np.where(hold, integral, grown).astype(np.float32)

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
        feedback_integral: float | None = None,
        sensor_history: Any = None,
    ) -> np.ndarray:
        """The policy observation from raw measurements (what the environment builds).

        Args:
          command: (3,) target body twist vx, vy (m/s), ωz (rad/s).
          wheel_rate: (n,) encoder rates, rad/s of the wheel.
          gyro_z: yaw rate, rad/s.
          accel: (3,) accelerometer, specific force in the body frame, m/s² (+9.81 z at rest).
          last_action: (action_size,) the previous :meth:`action` (zeros at start).
          yaw_integral: the state of :meth:`yaw_integral_step`, required when the policy
            observes it (``yaw_integral_tau > 0``), rad.
          feedback_integral: the state of :meth:`feedback_integral_step`, required when the
            residual corrects the ``feedback`` controller (:attr:`feedback_base`), rad/s.
          sensor_history: (obs_history, frame size) the :meth:`sensor_frame` outputs of the
            control periods before this one, newest first (after a reset: this one's,
            repeated); required when the policy observes them (:attr:`obs_history` > 0).
        """
        tau = self.yaw_integral_tau
        if tau > 0 and yaw_integral is None:
            raise ValueError(
                f"yaw_integral = None: this policy observes the yaw-error integral "
                f"(tau = {tau} s); keep it with yaw_integral_step()"
            )
        if self.feedback_base and feedback_integral is None:
            raise ValueError(
                "feedback_integral = None: this policy corrects the feedback controller; "
                "keep its integrator with feedback_integral_step()"
            )
        frame = self.sensor_frame(wheel_rate, gyro_z, accel)
        parts = [
            np.asarray(command, np.float32) / self.command_scale,
            frame,
            np.asarray(last_action, np.float32),
        ]
        if tau > 0:
            parts.append(np.asarray([yaw_integral], np.float32) / (tau * self.command_scale[2]))
        if self.feedback_base:
            parts.append(np.asarray([feedback_integral], np.float32) / self.command_scale[2])
        if self.obs_history > 0:
            past = None if sensor_history is None else np.asarray(sensor_history, np.float32)
            if past is None or past.shape != (self.obs_history, frame.size):
                shape = None if past is None else past.shape
                raise ValueError(
                    f"sensor_history: shape {shape}, expected ({self.obs_history}, "
                    f"{frame.size}): this policy observes the {self.obs_history} "
                    "sensor_frame()s before this one, newest first"
                )
            parts.append(past.reshape(-1))
        return np.concatenate(parts).astype(np.float32)

    @property
    def obs_history(self) -> int:
        """How many earlier sensor frames the policy observes (0: none)."""
        return int(self.meta.get("obs_history") or 0)

    def sensor_frame(self, wheel_rate: Any, gyro_z: Any, accel: Any) -> np.ndarray:
        """One scaled sensor frame as the policy observes it: encoder rates, gyro z,
        accelerometer and the wheel-odometry twist (the earlier ones, where
        :attr:`obs_history` > 0: :meth:`observation`'s ``sensor_history``)."""
        rate = np.asarray(wheel_rate, np.float32)
        return np.concatenate(
            [
                rate / self.max_rates,
                np.asarray(gyro_z, np.float32).reshape(1) / self.command_scale[2],
                np.asarray(accel, np.float32) / np.float32(self.meta["gravity"]),
                (self.forward @ rate) / self.command_scale,
            ]
        ).astype(np.float32)

    def baseline_rates(self, command: Any) -> np.ndarray:
        """The analytic baseline: nominal inverse model, desaturated (uniformly scaled
        down until no wheel exceeds its rate limit)."""
        twist = np.asarray(command, np.float32)
        rates = twist @ self.jacobian.T
        excess = np.max(np.abs(rates) / self.max_rates, axis=-1, keepdims=True)
        return rates / np.maximum(excess, 1.0)

    def base_rates(self, command: Any, obs: Any = None) -> np.ndarray:
        """The setpoints the residual corrects: the analytic baseline, or the ``feedback``
        controller's (which reads its integrator and the gyro from ``obs``)."""
        if not self.feedback_base:
            return self.baseline_rates(command)
        if obs is None:
            raise ValueError("obs = None: this policy corrects the feedback controller")
        assert self._nearest is not None
        return self._nearest(self.feedback_twist(obs)[0]) @ self.jacobian.T

    def wheel_setpoints(self, command: Any, action: Any, obs: Any = None) -> np.ndarray:
        """Wheel-rate setpoints (rad/s) for the servos (``obs``: the observation the action
        answered; needed when the residual corrects the ``feedback`` controller)."""
        a = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        if not self.meta["residual"]:
            return np.clip(a * self.max_rates, -self.max_rates, self.max_rates)
        scale = np.float32(self.meta["residual_scale"])
        if self.meta.get("residual_space", "wheel") == "twist":
            correction = (a * (scale * self.command_scale)) @ self.jacobian.T
        else:
            correction = a * (scale * self.max_rates)
        rates = self.base_rates(command, obs) + correction
        return np.clip(rates, -self.max_rates, self.max_rates)


class NearestFeasible:
    """The feasible twist nearest a twist, ``argmin (vx−cx)² + (vy−cy)² + w·(ωz−cz)²`` over
    ``|J t| <= m`` (the library's ``limits.nearest_feasible``, in NumPy).

    The nearest point lies on a facet, an edge or a vertex of the polytope; the orthogonal
    projection onto each set of 1-3 active half-spaces is an affine map ``u = P c + q`` of
    the (weighted) twist, precomputed here (92 maps for 4 wheels). A twist is mapped by all
    of them and the nearest feasible result kept; a feasible twist passes unchanged.
    """

    def __init__(self, jacobian: np.ndarray, max_rates: np.ndarray, omega_weight: float):
        J = np.asarray(jacobian, np.float64)
        A = np.stack([J, -J], axis=1).reshape(-1, 3)
        b = np.repeat(np.asarray(max_rates, np.float64), 2)
        self.d = np.asarray([1.0, 1.0, np.sqrt(omega_weight)])
        self.Au, self.b = A / self.d, b
        maps, offsets = [], []
        for k in (1, 2, 3):
            for rows in itertools.combinations(range(len(A)), k):
                As, bs = self.Au[list(rows)], b[list(rows)]
                G = As @ As.T
                if abs(np.linalg.det(G)) <= 1e-8 * np.prod(np.sum(As * As, axis=1)):
                    continue  # rows dependent: no edge or vertex there
                Ginv = np.linalg.inv(G)
                maps.append(np.eye(3) - As.T @ Ginv @ As)
                offsets.append(As.T @ Ginv @ bs)
        self.P = np.asarray(maps)  # (K, 3, 3)
        self.q = np.asarray(offsets)  # (K, 3)
        self.tol = 1e-5 * float(np.max(b))

    def __call__(self, twist: Any) -> np.ndarray:
        t = np.asarray(twist, np.float64)
        c = t * self.d
        u = np.einsum("kij,...j->...ki", self.P, c) + self.q  # (..., K, 3)
        feasible = np.all(u @ self.Au.T <= self.b + self.tol, axis=-1)
        dist = np.where(feasible, np.sum((u - c[..., None, :]) ** 2, axis=-1), np.inf)
        best = np.take_along_axis(u, np.argmin(dist, axis=-1)[..., None, None], axis=-2)
        inside = np.all(c @ self.Au.T <= self.b, axis=-1)
        out = np.where(inside[..., None], t, best[..., 0, :] / self.d)
        return out.astype(np.float32)


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
