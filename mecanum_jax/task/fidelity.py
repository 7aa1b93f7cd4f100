"""Which physics model the task simulates: the fast training model or the reference roller
model (:data:`mecanum_jax.sim.mjcf.FIDELITIES`; docs/physics_model.md).

The control loop is the same in both: one control step every ``control_dt``, with as many
physics substeps as that model's timestep fits in it. The fast model runs the task's own
physics settings (``physics_timestep``, ``contact_timeconst``, ``solver_iterations``),
tuned for training; the reference model runs the robot description's ``[sim]`` settings
(``reference_timestep``, contact time constant, Newton iterations), as validated in
docs/physics_validation.md, so the judge does not change with a training run's tuning.
Only the MJX implementation (``physics_impl``) is taken from the task for both: it computes
the same physics. Every :class:`~mecanum_jax.sim.state.RobotParams` field (friction,
payload, wheel radius, torque limit, servo gains, setpoint slew) applies to both models
(:meth:`~mecanum_jax.sim.robot_model.RobotModel.model_for`), so every scenario runs in
either.
"""

from __future__ import annotations

import dataclasses

import jax

from mecanum_jax.config import ConfigError, invalid
from mecanum_jax.sim.batching import CPU_CHUNK, CPU_GUARD_ROWS, CPU_HANG_ROWS
from mecanum_jax.sim.description import RobotDescription, resolve_description
from mecanum_jax.sim.mjcf import FIDELITIES, Fidelity
from mecanum_jax.task.config import EnvConfig


def check_fidelity(value: object, field: str) -> Fidelity:
    """``value`` if it names a fidelity; else a :class:`ConfigError` naming ``field``."""
    if value not in FIDELITIES:
        raise invalid(field, value, f"expected one of {list(FIDELITIES)}")
    return value


def simulated_description(
    config: EnvConfig, fidelity: Fidelity, task: RobotDescription
) -> RobotDescription:
    """The description the ``fidelity`` model is built from (see the module docstring):
    ``task``, the task's own (:meth:`EnvConfig.description`), or the robot's."""
    if fidelity == "fast":
        return task
    own = resolve_description(config.robot)
    return dataclasses.replace(own, sim=dataclasses.replace(own.sim, impl=task.sim.impl))


def model(
    config: EnvConfig, fidelity: object, task: RobotDescription
) -> tuple[RobotDescription, Fidelity]:
    """The description and the checked fidelity a :class:`~mecanum_jax.sim.physics.Robot`
    of ``config``'s task (whose description is ``task``) at ``fidelity`` is built from."""
    checked = check_fidelity(fidelity, "fidelity")
    return simulated_description(config, checked, task), checked


def substeps(config: EnvConfig, desc: RobotDescription, fidelity: Fidelity) -> int:
    """Physics steps per control step of the ``fidelity`` model built from ``desc``
    (:func:`simulated_description`); a :class:`ConfigError` naming the timestep if
    ``control_dt`` is not a whole multiple of it."""
    if fidelity == "fast":
        field, step = "env.physics_timestep", config.physics_timestep
    else:
        field, step = (
            f"robot {desc.robot.name!r}: sim.reference_timestep",
            desc.sim.reference_timestep,
        )
    ratio = config.control_dt / step
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6:
        raise invalid(
            field,
            step,
            f"the {fidelity} model needs env.control_dt = {config.control_dt} to be a whole "
            "multiple of its timestep",
        )
    return round(ratio)


CPU_EVAL_BATCH = {"fast": CPU_CHUNK["fast"], "reference": 4}
"""Robots per compiled evaluation rollout on the CPU, per fidelity. Larger vmapped MJX
batches deadlock jaxlib 0.10's CPU backend (:data:`~mecanum_jax.sim.batching.CPU_CHUNK`);
the evaluation's closed-loop rollout of the reference model hangs from 6 robots on
(measured on 2 cores: 1 to 5 finish, 6, 8 and 16 hang with every thread waiting), while the
validation's open-loop one runs 16."""


def cpu_batch(fidelity: Fidelity) -> int:
    """:data:`CPU_EVAL_BATCH` of ``fidelity``."""
    return CPU_EVAL_BATCH[fidelity]


def eval_batch(fidelity: Fidelity, requested: int | None, field: str, gpu_default: int) -> int:
    """Robots per compiled evaluation rollout: ``requested``, or the default of the backend
    (:func:`cpu_batch` on the CPU, ``gpu_default`` elsewhere). On the CPU a batch known to
    hang (a reference one above :data:`CPU_EVAL_BATCH`, a fast one that reaches
    ``batching.CPU_HANG_ROWS`` with its guard rows) is a :class:`ConfigError` naming
    ``field``."""
    cpu = jax.default_backend() == "cpu"
    if requested is None:
        return cpu_batch(fidelity) if cpu else gpu_default
    if cpu and fidelity == "reference" and requested > CPU_EVAL_BATCH[fidelity]:
        raise invalid(
            field,
            requested,
            f"the reference model's evaluation hangs on the CPU from 6 robots per batch; "
            f"use at most {CPU_EVAL_BATCH[fidelity]}",
        )
    if cpu and fidelity == "fast" and requested + CPU_GUARD_ROWS >= CPU_HANG_ROWS:
        raise invalid(
            field,
            requested,
            f"the fast model's evaluation hangs on the CPU from {CPU_HANG_ROWS} robots per "
            f"batch, its {CPU_GUARD_ROWS} guard rows included; use at most "
            f"{CPU_HANG_ROWS - CPU_GUARD_ROWS - 1} (64 is the fastest)",
        )
    return requested


def check_task(config: EnvConfig, fidelity: object, field: str) -> None:
    """Everything about running ``config``'s task in ``fidelity`` that can be checked
    before a model is compiled (the value, then the timestep); raises :class:`ConfigError`."""
    fidelity = check_fidelity(fidelity, field)
    try:
        desc = simulated_description(config, fidelity, config.description())
        substeps(config, desc, fidelity)
    except ConfigError as err:
        raise ConfigError(f"{field} = {fidelity!r}: {err}") from None


__all__ = [
    "CPU_EVAL_BATCH",
    "FIDELITIES",
    "Fidelity",
    "check_fidelity",
    "check_task",
    "cpu_batch",
    "eval_batch",
    "model",
    "simulated_description",
    "substeps",
]
