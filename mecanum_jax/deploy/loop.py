"""The robot-side control loop around an exported policy: NumPy alone (onnxruntime for
the ONNX backend), no JAX, MuJoCo or Brax.

``mecanum-export`` packs it as ``mecanum_loop.py``, with ``mecanum_policy.py`` and
``mecanum_control/``, into ``mecanum_robot.zip`` beside ``policy.npz``. Put the archive on
the import path and call the loop once per control period, ``meta["control_dt"]`` (0.02 s:
50 Hz)::

    import sys; sys.path.insert(0, "mecanum_robot.zip")
    from mecanum_loop import Controller        # this file, renamed on export
    ctrl = Controller.load("policy.npz")       # or "policy.onnx" (onnxruntime)
    ctrl.reset()                               # the robot at rest, before the first tick
    while running:                             # every control_dt
        setpoints, action = ctrl.step(command, wheel_rate, gyro_z, accel)
        send_to_servos(setpoints)              # rad/s per wheel, in meta["wheels"] order

At each tick :meth:`Controller.step` takes the command to track until the next tick and
the newest sensor readings (the training environment saw them 0 to 2 ticks old, as a real
robot's latency makes them; nothing is delayed here):

- ``wheel_rate``: encoder rates, rad/s of the wheel, positive rolling forward;
- ``gyro_z``: the IMU's yaw rate, rad/s;
- ``accel``: the accelerometer's specific force in the body frame, m/s² (+9.81 z at
  rest), as the environment measures it: the mean over the last control period.

It then runs the controller's step functions (``mecanum_jax.control.step``), the ones the
environment runs: ``sense`` (the integrators, the command's age and the sensor history
advanced over the period that ended), ``observe``, the network, and ``act`` (the action
shaped, the setpoints, the ``feedback`` integrator advanced).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

if __package__:  # inside the mecanum_jax package
    from mecanum_jax.control import ControllerState
    from mecanum_jax.control import step as ctl
    from mecanum_jax.deploy.policy import ExportError, NumpyPolicy, load
else:  # pragma: no cover - in an export's archive (on sys.path), next to mecanum_policy.py
    from mecanum_control import ControllerState  # type: ignore[no-redef]
    from mecanum_control import step as ctl  # type: ignore[no-redef]
    from mecanum_policy import ExportError, NumpyPolicy, load  # type: ignore[no-redef]

KNOWN = (
    "command", "wheel_rate", "gyro_z", "accel", "odometry_twist", "last_action",
    "yaw_error_integral", "feedback_integral", "path_error", "sensor_history",
)  # fmt: skip
"""The observation entries the controller keeps."""


class Controller:
    """What a robot keeps between control ticks around a policy, and one tick of it."""

    def __init__(self, policy: NumpyPolicy, session: Any = None):
        """``policy``: the NumPy export (its network runs unless ``session`` is given).
        ``session``: an ``onnxruntime.InferenceSession`` of the ONNX export, which then
        computes the action and the setpoints from the observation."""
        self.policy = policy
        self.spec = policy.spec
        self.session = session
        self.n_wheels = len(policy.max_rates)
        self.wheels = list(policy.meta.get("wheels", range(self.n_wheels)))
        for entry, _ in policy.meta["observation_layout"]:
            if entry not in KNOWN:
                raise ExportError(
                    f"observation_layout entry {entry!r}: this control loop keeps no such "
                    f"state (it knows {sorted(KNOWN)})"
                )
        self.reset()

    @classmethod
    def load(cls, path: str | Path) -> Controller:
        """A controller for an export: ``.npz`` (NumPy network) or ``.onnx``
        (onnxruntime; the observation layout and scales come from the graph's metadata)."""
        path = Path(path)
        if path.suffix != ".onnx":
            return cls(load(path))
        if not path.is_file():
            raise ExportError(f"policy file {str(path)!r}: no such file")
        import onnxruntime

        session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        props = session.get_modelmeta().custom_metadata_map
        if "mecanum_policy_meta" not in props:
            raise ExportError(f"policy file {str(path)!r}: no mecanum_policy_meta; not an export")
        meta = json.loads(props["mecanum_policy_meta"])
        size = sum(int(s) for _, s in meta["observation_layout"])
        # the network lives in the graph: this policy only builds observations
        shell = NumpyPolicy([], np.zeros(size, np.float32), np.ones(size, np.float32), meta)
        return cls(shell, session)

    @property
    def backend(self) -> str:
        return "numpy" if self.session is None else "onnx"

    @property
    def last_action(self) -> np.ndarray:
        return (
            np.zeros(self.spec.action_size, np.float32)
            if self.state is None
            else self.state.last_action
        )

    @property
    def command_age(self) -> int:
        return 0 if self.state is None else int(self.state.command_age)

    def reset(self) -> None:
        """Forget everything (the environment's reset; call it with the robot at rest)."""
        self.state: ControllerState | None = None
        self.observation: np.ndarray | None = None  # the last tick's, for logging
        self.ticks = 0

    def step(
        self, command: Any, wheel_rate: Any, gyro_z: Any, accel: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        """One control tick (see the module's doc): wheel-rate setpoints (n,) rad/s to hold
        until the next tick, and the applied action (for logging)."""
        spec = self.spec
        cmd = _vector("command", command, 3, "vx, vy m/s, ωz rad/s")
        rate = _vector("wheel_rate", wheel_rate, self.n_wheels, f"rad/s, wheels {self.wheels}")
        gyro = _vector("gyro_z", gyro_z, (), "rad/s").reshape(1)
        frame = ctl.frame(spec, rate, gyro, _vector("accel", accel, 3, "m/s², body frame"), np)
        if self.state is None:
            state = ctl.initial_state(spec, frame, cmd, 1 + spec.obs_history, np)
        else:
            state = ctl.sense(spec, self.state, frame, cmd, 0, np)
        obs = ctl.observe(spec, state, 0, np).astype(np.float32)
        if self.session is None:
            setpoints, state = ctl.act(spec, state, self.policy.network(obs), 0, np)
        else:
            names = ["action", "wheel_setpoints"]
            if spec.feedback_base:
                names.append("feedback_integral")
            age = np.full((1, 1), state.command_age, np.float32)
            feeds = {"observation": obs[None], "command_age": age}
            out = [x[0] for x in self.session.run(names, feeds)]
            setpoints, integral = out[1], state.feedback_integral
            if spec.feedback_base:
                integral = out[2][0]
            state = state._replace(last_action=out[0], feedback_integral=np.float32(integral))
        self.state = state
        self.observation = obs
        self.ticks += 1
        return np.asarray(setpoints, np.float32), np.asarray(state.last_action, np.float32).copy()


def _vector(name: str, value: Any, size: int | tuple[()], unit: str) -> np.ndarray:
    """``value`` as float32 of shape ``(size,)`` (``()``: a scalar), finite, or a
    ``ValueError`` naming ``name`` and the value."""
    shape = size if isinstance(size, tuple) else (size,)
    what = "one finite value" if shape == () else f"{size} finite values"
    try:
        x = np.asarray(value, np.float32)
    except (TypeError, ValueError):
        x = np.full(1, np.nan, np.float32)  # fails the check below
    if x.shape != shape or not np.all(np.isfinite(x)):
        raise ValueError(f"{name} = {value!r}: expected {what} ({unit})")
    return x


__all__ = ["KNOWN", "Controller"]
