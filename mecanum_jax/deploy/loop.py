"""The robot-side control loop around an exported policy: NumPy alone (onnxruntime for
the ONNX backend), no JAX, MuJoCo or Brax.

Copy it next to the export with the policy module (``mecanum-export`` writes it as
``mecanum_loop.py`` beside ``policy.npz`` and ``mecanum_policy.py``) and call it once per
control period, ``meta["control_dt"]`` (0.02 s: 50 Hz)::

    from mecanum_loop import Controller        # this file, renamed on export
    ctrl = Controller.load("policy.npz")       # or "policy.onnx" (onnxruntime)
    ctrl.reset()                               # the robot at rest, before the first tick
    while running:                             # every control_dt
        setpoints, action = ctrl.step(command, wheel_rate, gyro_z, accel)
        send_to_servos(setpoints)              # rad/s per wheel, in meta["wheels"] order

At each tick :meth:`Controller.step` takes the command to track until the next tick and
the newest sensor readings the robot has (the training environment, ``MecanumEnv``, saw
them 0 to 2 ticks old, as a real robot's latency makes them; nothing is delayed here):

- ``wheel_rate``: encoder rates, rad/s of the wheel, positive rolling forward;
- ``gyro_z``: the IMU's yaw rate, rad/s;
- ``accel``: the accelerometer's specific force in the body frame, m/s² (+9.81 z at
  rest), as the environment measures it: the mean over the last control period.

It then does what the environment does between two policy calls, in its order:

1. advances the policy's own states with the command tracked *since the last tick* and
   the new readings (the leaky yaw-rate error integral, ``yaw_integral_step``; the
   ``feedback`` controller's integrator, ``feedback_integral_step``, restarted at 0 on a
   new command where ``feedback.reset``; none on the first tick after
   :meth:`Controller.reset`, where they start at 0) and, for a
   policy that observes earlier sensor frames, their history (``sensor_frame``; on the
   first tick, that tick's frame repeated);
2. builds the observation (``NumpyPolicy.observation``) from the new command, the
   readings, the last *applied* action and those states;
3. runs the policy: the action comes back low-passed with the last one
   (``action_filter``), i.e. the action the environment applies, and the wheel-rate
   setpoints are the baseline for the command plus the action's correction, clipped to
   the rate limits; that action is kept as the next tick's last action.

A new kind of policy state is one method of :class:`Controller` marked with
:func:`policy_state` (see ``_yaw_integral``): the observation entry it feeds, the
keyword ``NumpyPolicy.observation`` takes it by, and its update.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

if __package__:  # inside the mecanum_jax package
    from mecanum_jax.deploy.policy import ExportError, NumpyPolicy, load
else:  # pragma: no cover - copied beside an export, next to mecanum_policy.py
    from mecanum_policy import ExportError, NumpyPolicy, load  # type: ignore[no-redef]

SENSED = ("command", "wheel_rate", "gyro_z", "accel", "odometry_twist", "last_action")
"""Observation entries built from the command, the readings and the last action."""


class Reading(NamedTuple):
    """One tick's sensor readings (validated, float32)."""

    wheel_rate: np.ndarray  # (n,) rad/s
    gyro_z: float  # rad/s
    accel: np.ndarray  # (3,) m/s²


class PolicyState(NamedTuple):
    """One state the policy observes: its observation entry, the keyword
    ``NumpyPolicy.observation`` takes it by, its value after a reset (``None``: set by the
    update on the first tick, from that tick's reading), and its update
    ``(controller, value, tracked, reading) -> value``."""

    entry: str
    keyword: str
    initial: float | None
    update: Callable[[Any, Any, Any, Reading], Any]


def policy_state(entry: str, keyword: str, initial: float | None = 0.0) -> Callable[[Any], Any]:
    """Mark a :class:`Controller` method as the update of one policy state: the value of
    observation entry ``entry``, passed to ``NumpyPolicy.observation`` as ``keyword``,
    ``initial`` after :meth:`Controller.reset`. The method maps ``(value, tracked,
    reading)`` to the new value, ``tracked`` being the command of the period that ended;
    it runs from the second tick on, or, with ``initial=None``, on the first tick too
    (``value`` and ``tracked`` then ``None``)."""

    def mark(update: Any) -> Any:
        first = None if initial is None else float(initial)
        update.policy_state = PolicyState(entry, keyword, first, update)
        return update

    return mark


class Controller:
    """What a robot keeps between control ticks around a policy, and one tick of it."""

    def __init__(self, policy: NumpyPolicy, session: Any = None):
        """``policy``: the NumPy export (its network runs unless ``session`` is given).
        ``session``: an ``onnxruntime.InferenceSession`` of the ONNX export, which then
        computes the action and the setpoints from the observation."""
        self.policy = policy
        self.session = session
        self.n_wheels = len(policy.max_rates)
        self.wheels = list(policy.meta.get("wheels", range(self.n_wheels)))
        marked = [getattr(getattr(type(self), n), "policy_state", None) for n in dir(type(self))]
        known = {s.entry: s for s in marked if isinstance(s, PolicyState)}
        self.states: dict[str, PolicyState] = {}
        for entry, _ in policy.meta["observation_layout"]:
            if entry in known:
                self.states[entry] = known[entry]
            elif entry not in SENSED:
                raise ExportError(
                    f"observation_layout entry {entry!r}: this control loop keeps no such "
                    f"state (it knows {sorted(SENSED + tuple(known))})"
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

    def reset(self) -> None:
        """Forget everything: last action 0, every policy state at its initial value (the
        environment's reset; call it with the robot at rest)."""
        self.last_action = np.zeros(self.policy.action_size, np.float32)
        self.values = {e: s.initial for e, s in self.states.items()}
        self.tracked: np.ndarray | None = None  # the command of the period now ending
        self.command_age = 0  # periods since the tracked command changed (0: its first)
        self.observation: np.ndarray | None = None  # the last tick's, for logging
        self.reading: Reading | None = None  # the last tick's
        self.ticks = 0

    def step(
        self, command: Any, wheel_rate: Any, gyro_z: Any, accel: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        """One control tick (see the module's doc): wheel-rate setpoints (n,) rad/s to hold
        until the next tick, and the applied action (for logging)."""
        cmd = _vector("command", command, 3, "vx, vy m/s, ωz rad/s")
        reading = Reading(
            _vector("wheel_rate", wheel_rate, self.n_wheels, f"rad/s, wheels {self.wheels}"),
            float(_vector("gyro_z", gyro_z, (), "rad/s")),
            _vector("accel", accel, 3, "m/s², body frame"),
        )
        for entry, state in self.states.items():
            if self.tracked is not None or state.initial is None:
                self.values[entry] = state.update(self, self.values[entry], self.tracked, reading)
        changed = self.tracked is not None and bool(np.any(cmd != self.tracked))
        if changed and "feedback_integral" in self.values and self.policy.feedback_reset:
            self.values["feedback_integral"] = 0.0  # restarts with each new command
        keywords = {self.states[e].keyword: v for e, v in self.values.items()}
        obs = self.policy.observation(
            cmd, reading.wheel_rate, reading.gyro_z, reading.accel, self.last_action, **keywords
        )
        if self.session is None:
            action = self.policy.action(obs)
            setpoints = self.policy.wheel_setpoints(cmd, action, obs)
        else:
            action, setpoints = (
                x[0]
                for x in self.session.run(["action", "wheel_setpoints"], {"observation": obs[None]})
            )
        self.last_action = np.asarray(action, np.float32)
        if self.tracked is not None:
            self.command_age = 0 if changed else self.command_age + 1
        self.tracked = cmd
        self.reading = reading
        self.observation = obs
        self.ticks += 1
        return np.asarray(setpoints, np.float32), self.last_action.copy()

    # --- the policy's states: one method each ---------------------------------------------

    @policy_state("yaw_error_integral", "yaw_integral")
    def _yaw_integral(self, value: float, tracked: np.ndarray, reading: Reading) -> float:
        """The leaky yaw-rate error integral (``yaw_integral_tau``)."""
        return self.policy.yaw_integral_step(value, tracked, reading.gyro_z)

    @policy_state("feedback_integral", "feedback_integral")
    def _feedback_integral(self, value: float, tracked: np.ndarray, reading: Reading) -> float:
        """The integrator of the ``feedback`` controller the residual corrects: advanced
        from the last tick's observation (its command, gyro and integrator) and that
        command's age, as the environment advances it from the state its action answered."""
        assert self.observation is not None  # updates run from the second tick on
        return float(self.policy.feedback_integral_step(self.observation, self.command_age))

    @policy_state("sensor_history", "sensor_history", initial=None)
    def _sensor_history(
        self, value: np.ndarray | None, tracked: np.ndarray | None, reading: Reading
    ) -> np.ndarray:
        """The sensor frames of the ticks before this one, newest first
        (``obs_history``): after a reset, this tick's frame repeated (as the environment's
        reset fills its history with the first reading)."""
        policy = self.policy
        if value is None or self.reading is None:
            frame = policy.sensor_frame(*reading)
            return np.repeat(frame[None], policy.obs_history, axis=0)
        last = policy.sensor_frame(*self.reading)
        return np.concatenate([last[None], value[:-1]], axis=0)


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


__all__ = ["SENSED", "Controller", "PolicyState", "Reading", "policy_state"]
