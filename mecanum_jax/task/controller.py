"""The task's controller spec: what an environment's config says the robot-side
controller is (:func:`controller_meta`, the export's metadata, and the
:class:`~mecanum_jax.control.ControllerSpec` read from it), and a Brax state's ``info`` in
this task (:class:`TaskInfo`: the episode's entries and the controller state,
:func:`control_state`, :func:`with_control`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, ParamSpec, Protocol, TypedDict, TypeVar, cast

import jax
import numpy as np

from mecanum_jax.control import ControllerSpec, ControllerState, Layout, policy_layout
from mecanum_jax.control.state import FIELDS
from mecanum_jax.sim.description import RobotDescription, fingerprint
from mecanum_jax.sim.state import GRAVITY, RobotParams
from mecanum_jax.task.constants import RobotConstants

if TYPE_CHECKING:
    from _typeshed import DataclassInstance
    from brax.envs.base import State

P = ParamSpec("P")
R = TypeVar("R")


class ControllerConfig(Protocol):
    """What :func:`controller_meta` reads of a task's ``EnvConfig`` (not imported: it
    imports the reference controllers, which import this module)."""

    @property
    def residual(self) -> bool: ...
    @property
    def residual_scale(self) -> float: ...
    @property
    def residual_space(self) -> str: ...
    @property
    def residual_base(self) -> str: ...
    @property
    def feedback(self) -> DataclassInstance: ...
    @property
    def yaw_integral_tau(self) -> float: ...
    @property
    def path_tau(self) -> float: ...
    @property
    def path_integrator(self) -> str: ...
    @property
    def symmetric(self) -> bool: ...
    @property
    def obs_history(self) -> int: ...
    @property
    def action_filter(self) -> float: ...
    @property
    def residual_at_stop(self) -> bool: ...
    @property
    def residual_deadband(self) -> float: ...
    @property
    def residual_ramp_s(self) -> float: ...
    @property
    def control_dt(self) -> float: ...


def policy_shape(config: ControllerConfig, n_wheels: int) -> tuple[int, Layout]:
    """The action size and the observation layout of a task's policy on a robot of
    ``n_wheels`` wheels: the config's alone, no robot constants needed."""
    twist = config.residual and config.residual_space == "twist"
    action_size = 3 if twist else n_wheels
    feedback_base = config.residual and config.residual_base == "feedback"
    layout = policy_layout(
        n_wheels,
        action_size,
        config.yaw_integral_tau > 0,
        feedback_base,
        config.obs_history,
        config.path_tau > 0,
    )
    return action_size, layout


def controller_meta(
    config: ControllerConfig, desc: RobotDescription, constants: RobotConstants
) -> dict[str, object]:
    """What an exported policy's control loop needs of a task: the robot, the observation
    layout, the residual and its base, the filter and integrators, the limits and
    kinematics, the control period (the export's ``meta``, less the network's part).
    ``config``: the task's ``EnvConfig`` (not imported: it imports the reference
    controllers, which import this module)."""
    action_size, layout = policy_shape(config, constants.n_wheels)
    geometry = constants.geometry
    return {
        "robot": desc.robot.name,
        "robot_fingerprint": fingerprint(desc),
        "wheels": list(geometry.names),
        "action_size": action_size,
        "observation_layout": [list(x) for x in layout],
        "residual": config.residual,
        "residual_scale": config.residual_scale,
        "residual_space": config.residual_space,
        "residual_base": config.residual_base,
        "feedback": dataclasses.asdict(config.feedback),
        "yaw_integral_tau": config.yaw_integral_tau,
        "path_tau": config.path_tau,
        "path_integrator": config.path_integrator,
        "symmetric": config.symmetric,
        "obs_history": config.obs_history,
        "action_filter": config.action_filter,
        "residual_at_stop": config.residual_at_stop,
        "residual_deadband": config.residual_deadband,
        "residual_ramp_s": config.residual_ramp_s,
        "max_rates": np.asarray(constants.max_rates).tolist(),
        "command_scale": np.asarray(constants.command_scale).tolist(),
        "jacobian": np.asarray(constants.jacobian).tolist(),
        # the pseudo-inverse for a rank-deficient layout (x_square), as the task observes it
        "forward_matrix": np.asarray(constants.forward_matrix).tolist(),
        "gravity": GRAVITY,
        "control_dt": config.control_dt,
    }


def controller_spec(
    config: ControllerConfig, desc: RobotDescription, constants: RobotConstants
) -> ControllerSpec:
    """The controller a task's config describes (read back from its export metadata, so
    the environment and every export share one description)."""
    spec = ControllerSpec.from_meta(controller_meta(config, desc, constants))
    if spec.symmetric:
        from mecanum_jax.control.symmetry import mirrors

        mirrors(spec)  # an asymmetric robot is refused here, naming the wheel
    return spec


def allow_rank_promotion(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` traced with JAX's implicit rank promotion allowed: the controller's code
    broadcasts per-robot values against its constant tables (the array API's
    broadcasting), and Brax's normalizer and distributions rely on it too."""

    @functools.wraps(fn)
    def wrapped(*args: P.args, **kwargs: P.kwargs) -> R:
        with jax.numpy_rank_promotion("allow"):
            return fn(*args, **kwargs)

    return wrapped


class EpisodeInfo(TypedDict):
    """What an episode carries in a Brax state's ``info`` besides the controller's state
    (one robot's; the batch's arrays have the robots' axes in front)."""

    rng: jax.Array
    params: RobotParams
    """the robot's physical parameters, drawn at the reset"""
    latency: jax.Array
    """() int32: the sensors' delay, control steps"""
    noise_std: jax.Array
    """(3,) sensor noise: wheel rate, gyro, accelerometer"""
    next_resample: jax.Array
    """() int32: the step at which the command is next drawn"""
    step: jax.Array
    """() int32: control steps since the reset"""
    true_path_error: jax.Array
    """(3,) the path error of the true twist (the critic's and the path reward's)"""
    truncation: jax.Array
    """() 1.0 on the step an episode hits its length (:class:`~.env.TrainingEnv`)"""


class TaskInfo(EpisodeInfo):
    """A Brax state's ``info`` in this task: :class:`EpisodeInfo`, then the fields of the
    :class:`~mecanum_jax.control.ControllerState` (the same names; a test keeps them so)."""

    command: jax.Array
    command_age: jax.Array
    last_action: jax.Array
    history: jax.Array
    yaw_integral: jax.Array
    feedback_integral: jax.Array
    feedback_gains: jax.Array
    path_error: jax.Array


def task_info(state: State) -> TaskInfo:
    """A copy of ``state.info`` (Brax types it as a plain dict), as the task's."""
    return cast(TaskInfo, dict(state.info))


def control_state(info: TaskInfo) -> ControllerState:
    """The controller state kept in a Brax state's ``info``."""
    return ControllerState(**{k: info[k] for k in FIELDS})  # type: ignore[literal-required]


def with_control(info: EpisodeInfo, state: ControllerState) -> TaskInfo:
    """``info`` with the controller state ``state``."""
    return cast(TaskInfo, {**info, **state._asdict()})


__all__ = [
    "EpisodeInfo",
    "TaskInfo",
    "allow_rank_promotion",
    "control_state",
    "controller_meta",
    "controller_spec",
    "policy_shape",
    "task_info",
    "with_control",
]
