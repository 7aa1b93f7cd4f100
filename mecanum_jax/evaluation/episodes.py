"""From a scenario to arrays: its episodes as an :class:`EpisodeBatch` for one environment.

An :class:`EpisodeBatch` holds plain arrays (per-episode physics parameters, latency,
noise levels, command schedule, rng keys) that one compiled rollout
(:mod:`mecanum_jax.evaluation.rollout`) plays for any scenario of the same size. The
episodes are drawn on the CPU from the scenario's own rng key (:func:`scenario_key`), so
two policies evaluated on one scenario face the same episodes on every device. Scripted
scenarios (:mod:`mecanum_jax.evaluation.scenarios`) get their fixed command sequence
(:func:`scripted_commands`).
"""

from __future__ import annotations

import dataclasses
import weakref
import zlib
from typing import TYPE_CHECKING, NamedTuple, TypeAlias, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import invalid
from mecanum_jax.evaluation.scenarios import JUDGE_COMMANDS, MAX_REACH, Scenario, ScenarioSet
from mecanum_jax.host import host_side
from mecanum_jax.kinematics import limits, singularity
from mecanum_jax.kinematics.modes import SIX_MODES
from mecanum_jax.sim.state import RobotParams
from mecanum_jax.task import CommandConfig, EnvConfig, MecanumEnv
from mecanum_jax.task.commands import command_schedule
from mecanum_jax.task.randomization import sample_params

if TYPE_CHECKING:
    from collections.abc import Callable

    from mecanum_jax.task.randomization import RandomizationConfig

C = TypeVar("C")
Samplers: TypeAlias = (
    "tuple[Callable[[jax.Array, RandomizationConfig], tuple[RobotParams, jax.Array]],"
    " Callable[[jax.Array, CommandConfig], jax.Array]]"
)
"""Batched ``(keys, config) -> (params, latency)`` and ``(keys, config) -> commands``."""


class EpisodeBatch(NamedTuple):
    """What one evaluation rollout needs, per episode (leading axis E)."""

    keys: jax.Array  # (E, 2) rng of each episode's sensor noise
    params: RobotParams  # (E, ...) physics
    latency: jax.Array  # (E,) control steps
    noise_std: jax.Array  # (E, 3) wheel rate, gyro, accel
    commands: jax.Array  # (E, T, 3) command at each control step


def scenario_key(scenario: Scenario) -> jax.Array:
    """The root key of a scenario: its seed and name, in the evaluation domain."""
    root = jax.random.fold_in(jax.random.PRNGKey(scenario.seed), scenario.stream)
    return jax.random.fold_in(root, zlib.crc32(scenario.name.encode()) & 0x7FFFFFFF)


def steps(env: MecanumEnv, scenario: Scenario) -> int:
    return max(1, round(scenario.seconds / env.config.control_dt))


def scripted_commands(env: MecanumEnv, scenario: Scenario) -> np.ndarray:
    """The (T, 3) command sequence of a scripted scenario (zeros after its end)."""
    c = scenario.commands
    T = steps(env, scenario)
    scale = np.asarray(env.command_scale, np.float64)
    reachable = np.asarray(env.constants.reachable, np.float64)  # the identity for rank 3
    segments: list[tuple[np.ndarray, float]] = []

    def reach(direction: np.ndarray) -> float:
        d = jnp.asarray(direction / np.linalg.norm(direction), jnp.float32)
        return float(limits.max_speed(env.geometry, d, env.max_rates))

    def toward(direction: np.ndarray, seconds: float) -> None:
        direction = reachable @ direction  # a direction the layout cannot drive: a stop
        norm = np.linalg.norm(direction)
        twist = direction / norm * reach(direction) * c.speed if norm > 1e-6 else 0 * direction
        segments.append((twist, seconds))
        if c.pause_s > 0:
            segments.append((np.zeros(3), c.pause_s))

    if c.kind == "sequence":
        for i, seg in enumerate(c.sequence):
            twist = np.asarray(seg[:3], np.float64)
            if c.units == "si" and np.any(np.abs(twist) > MAX_REACH * scale):
                raise invalid(
                    f"scenarios.{scenario.name}.commands.sequence[{i}]",
                    list(seg),
                    f"beyond twice the reach of robot {env.desc.robot.name!r} "
                    f"({np.round(scale, 3).tolist()} m/s, m/s, rad/s)",
                )
            twist = reachable @ (twist * scale if c.units == "reach" else twist)
            segments.append((twist, seg[3]))
    elif c.kind == "six_modes":
        for _, unit, _ in SIX_MODES.values():
            toward(np.asarray(unit, np.float64), c.segment_s)
    elif c.kind == "singular_pass":
        directions = singularity.singular_directions(env.geometry)
        if not directions:
            raise invalid(
                f"scenarios.{scenario.name}.commands.kind",
                c.kind,
                f"robot {env.desc.robot.name!r} has no singular directions",
            )
        for d in directions:
            v = np.array([np.cos(d.heading), np.sin(d.heading), 0.0])
            toward(v, c.segment_s)
            toward(-v, c.segment_s)
    else:
        raise ValueError(f"scenario {scenario.name!r} is not scripted")
    out = np.zeros((T, 3), np.float32)
    t = 0
    for twist, seconds in segments:
        n = round(seconds / env.config.control_dt)
        if t + n > T and scenario.truncate:
            n = T - t
        if t + n > T:
            raise invalid(
                f"scenarios.{scenario.name}.seconds",
                scenario.seconds,
                f"too short for its command sequence ({sum(s for _, s in segments):.2f} s)",
            )
        out[t : t + n] = twist
        t += n
    return out


@host_side  # drawn on the CPU: the same episodes on every device (mecanum_jax.host)
def prepare(env: MecanumEnv, scenario: Scenario) -> EpisodeBatch:
    """The scenario's episodes as arrays for ``env`` (whose latency history must be long
    enough: see :func:`eval_env_config`)."""
    E, T = scenario.episodes, steps(env, scenario)
    rand = scenario.randomization_config(env.desc.sim.floor_friction)
    if rand.latency_steps[1] > env.max_latency:
        raise invalid(
            f"scenarios.{scenario.name}.randomization.latency_steps",
            list(rand.latency_steps),
            f"this environment keeps at most {env.max_latency} steps of history",
        )
    k_params, k_cmd, k_run = jax.random.split(scenario_key(scenario), 3)
    samplers = _samplers(env, T)
    params, latency = samplers[0](jax.random.split(k_params, E), _as_arrays(rand))
    if scenario.scripted:
        commands = jnp.broadcast_to(jnp.asarray(scripted_commands(env, scenario)), (E, T, 3))
    else:
        # the judge's mix, not the target's: a variant trained on another command mix is
        # judged on the same episodes as every other target
        mix = scenario.command_config(JUDGE_COMMANDS)
        commands = samplers[1](jax.random.split(k_cmd, E), _as_arrays(mix))
    noise = jnp.broadcast_to(env.noise_std(scenario.noise), (E, 3))
    return EpisodeBatch(jax.random.split(k_run, E), params, latency, noise, commands)


_SAMPLERS: weakref.WeakKeyDictionary[MecanumEnv, dict[int, Samplers]] = weakref.WeakKeyDictionary()


def _samplers(env: MecanumEnv, steps: int) -> Samplers:
    """Compiled (parameters, command schedule) samplers of ``env``, taking the scenario's
    configs as traced values: compiled once per environment and episode length."""
    cache = _SAMPLERS.setdefault(env, {})
    if steps not in cache:
        robot, dt = env.constants, env.config.control_dt
        draw_params = lambda k, r: sample_params(robot, k, r)  # noqa: E731
        schedule = lambda k, c: command_schedule(robot, k, steps, c, dt)  # noqa: E731
        cache[steps] = (
            jax.jit(jax.vmap(draw_params, in_axes=(0, None))),
            jax.jit(jax.vmap(schedule, in_axes=(0, None))),
        )
    return cache[steps]


def _as_arrays(config: C) -> C:
    """A config dataclass (a pytree) with its numbers as float32/int32 arrays."""
    return jax.tree.map(jnp.asarray, config)


def eval_env_config(base: EnvConfig, scenarios: ScenarioSet) -> EnvConfig:
    """The task config to evaluate ``scenarios`` in: ``base`` (the policy's task) with a
    latency history long enough for every scenario. Physics, noise and commands come from
    each scenario's :class:`EpisodeBatch`, not from this config."""
    need = max(
        [base.randomization.latency_steps[1]]
        + [int(s.randomization.get("latency_steps", (0, 0))[1]) for s in scenarios.scenarios]
    )
    lo = min(base.randomization.latency_steps[0], need)
    return dataclasses.replace(
        base, randomization=dataclasses.replace(base.randomization, latency_steps=(lo, need))
    )


__all__ = [
    "EpisodeBatch",
    "eval_env_config",
    "prepare",
    "scenario_key",
    "scripted_commands",
]
