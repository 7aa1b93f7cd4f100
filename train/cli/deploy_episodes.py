"""What ``mecanum-deploy-sim`` plays: a scenario's episodes as mecanum-eval prepares them
(the seeded commands, robots, latencies and sensor noise of ``configs/eval/``), or one
constant command held on the nominal robot. JAX prepares them before any control loop
runs; what comes out is NumPy."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.deploy.plant import PlantParams
from mecanum_jax.evaluation.scenarios import MAX_REACH

if TYPE_CHECKING:
    from train.config import TrainConfig


@dataclasses.dataclass
class Episodes:
    """What the rehearsal plays, per episode (NumPy)."""

    commands: np.ndarray  # (E, T, 3)
    params: list[PlantParams]
    latency: np.ndarray  # (E,) control periods
    noise_std: np.ndarray  # (E, 3) wheel rate, gyro, accel
    targets: np.ndarray  # (E, T, 3) the nearest feasible twist of the true robot
    scripted: bool
    jacobian: np.ndarray
    control_dt: float
    description: str


def check_reach(command: Sequence[float], reach: np.ndarray) -> None:
    """``--command`` within twice the model's reach (``command_scale``) on each axis, as
    a scenario file's commands are."""
    if command and np.any(np.abs(np.asarray(command)) > MAX_REACH * np.asarray(reach)):
        shown = np.round(np.asarray(reach, float), 3).tolist()
        raise ConfigError(f"--command = {list(command)}: beyond twice the reach {shown}")


def episodes(
    cfg: TrainConfig,
    *,
    scenarios: str = "default",
    scenario: str | None = None,
    count: int | None = None,
    seconds: float | None = None,
    command: Sequence[float] = (),
    latency: int | None = None,
    noise_scale: float | None = None,
) -> Episodes:
    """The episodes of ``scenario`` (default nominal) in the file ``scenarios``, or, with
    ``command``, that command held; ``count`` episodes of ``seconds`` where given, with
    ``latency`` (control periods) and ``noise_scale`` (of the training's sensor noise)
    replacing the scenario's."""
    from mecanum_jax.task import NoiseConfig
    from mecanum_jax.tracing import prepare_tracing

    prepare_tracing(cfg.run.matmul_precision, "run.matmul_precision")
    if command:
        eps = _command_episodes(cfg, command, count, seconds)
    else:
        eps = _scenario_episodes(cfg, scenarios, scenario, count, seconds)
    if latency is not None:
        eps.latency = np.full(len(eps.commands), latency)
    if noise_scale is not None:
        std = np.asarray(NoiseConfig(scale=noise_scale).std(), float)
        eps.noise_std = np.broadcast_to(std, eps.noise_std.shape).copy()
    return eps


def _scenario_episodes(
    cfg: TrainConfig,
    scenarios: str,
    scenario: str | None,
    count: int | None,
    seconds: float | None,
) -> Episodes:
    import jax
    import jax.numpy as jnp

    from mecanum_jax.evaluation import scenarios as scenario_files
    from mecanum_jax.evaluation.episodes import eval_env_config, prepare
    from mecanum_jax.task import MecanumEnv

    chosen = scenario_files.load_scenarios(scenarios).select(
        [scenario or "nominal"], count, seconds
    )
    sc = chosen.scenarios[0]
    task = dataclasses.replace(cfg.env, physics_impl="jax")
    env = MecanumEnv(eval_env_config(task, chosen))
    batch = prepare(env, sc)
    commands = np.asarray(batch.commands, np.float32)
    targets = jax.vmap(env.feasible_target)(jnp.asarray(commands), batch.params.radius_scale)
    return Episodes(
        commands=commands,
        params=[PlantParams.of(batch.params, i) for i in range(len(commands))],
        latency=np.asarray(batch.latency, int),
        noise_std=np.asarray(batch.noise_std, float),
        targets=np.asarray(targets),
        scripted=sc.scripted,
        jacobian=np.asarray(env.jacobian),
        control_dt=env.config.control_dt,
        description=f"{sc.name}: {sc.description}",
    )


def _command_episodes(
    cfg: TrainConfig, command: Sequence[float], count: int | None, seconds: float | None
) -> Episodes:
    """``command`` held on the nominal robot; its target as ``MecanumEnv.feasible_target``
    gives it (without building the MJX environment)."""
    import jax.numpy as jnp

    from mecanum_jax.kinematics import limits
    from mecanum_jax.kinematics import model as kinematics

    desc = dataclasses.replace(cfg.env, physics_impl="jax").description()
    geom = desc.build_geometry(warn_singular=False)
    max_rates = desc.max_wheel_rates(geom).astype(jnp.float32)
    held = jnp.asarray(command, jnp.float32)
    target = limits.nearest_feasible(geom, held, max_rates, cfg.env.feedback.omega_weight)
    E = count or 1
    T = max(1, round((seconds or 5.0) / cfg.env.control_dt))
    return Episodes(
        commands=np.broadcast_to(np.asarray(held), (E, T, 3)).copy(),
        params=[PlantParams.nominal(desc, geom.n_wheels)] * E,
        latency=np.zeros(E, int),
        noise_std=np.zeros((E, 3)),
        targets=np.broadcast_to(np.asarray(target, np.float32), (E, T, 3)).copy(),
        scripted=True,
        jacobian=np.asarray(kinematics.jacobian(geom), np.float32),
        control_dt=cfg.env.control_dt,
        description=f"constant command {list(command)} on the nominal robot",
    )


__all__ = ["Episodes", "check_reach", "episodes"]
