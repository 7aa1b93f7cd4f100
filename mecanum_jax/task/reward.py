"""The reward: ``Σ scale · term`` over named terms (:data:`REWARD_TERMS`).

Exp tracking kernels of the linear and yaw-rate errors, quadratic error penalties, and
small action-rate and energy penalties; the scales are :class:`RewardConfig`'s, and each
scaled term is reported in ``state.metrics`` as ``reward/<term>``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mecanum_jax.config import invalid, require
from mecanum_jax.sim.state import RobotParams, Sensors


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    """The reward's scales: it is Σ scale · term over REWARD_TERMS
    (reward_terms), and each scaled term is logged as reward/<term>."""

    tracking_lin: float = 1.0
    """Scale of exp(−|v_err|²/sigma_lin) (>= 0)."""
    tracking_ang: float = 0.5
    """Scale of exp(−ω_err²/sigma_ang) (>= 0)."""
    sigma_lin: float = 0.25
    """Width of the linear tracking kernel, (m/s)² (> 0)."""
    sigma_ang: float = 0.25
    """Width of the yaw-rate tracking kernel, (rad/s)² (> 0)."""
    error_lin: float = 1.0
    """Scale of the quadratic penalty −|v_err|², per (m/s)² (>= 0; 0: off)."""
    error_ang: float = 0.5
    """Scale of the quadratic penalty −ω_err², per (rad/s)² (>= 0; 0: off)."""
    action_rate: float = 0.01
    """Scale of −|a_t − a_(t−1)|², actions in [-1, 1] (>= 0)."""
    energy: float = 0.0005
    """Scale of −Σ|τ·ω|, the wheels' mechanical power in W (>= 0)."""
    path_lin: float = 0.0
    """Scale of −|e_xy|², the true path error's position part, per m² (>= 0; needs
    env.path_tau > 0, whose leak it shares)."""
    path_ang: float = 2.0
    """Scale of −e_θ², the true path error's heading part, per rad² (>= 0; as path_lin)."""
    target: str = "feasible"
    """What the twist error is measured against: "command", or "feasible", the nearest
    feasible twist of the robot as it is (the evaluation's steady-state target,
    MecanumEnv.feasible_target), so that beyond reach the reward asks for what the
    metric scores and its weights act only within reach."""

    def validate(self, where: str = "env.reward") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        require(self, where, ("sigma_lin", "sigma_ang"), lambda v: v > 0, "must be > 0")
        require(self, where, REWARD_TERMS, lambda v: v >= 0, "must be >= 0 (a weight)")
        if self.target not in REWARD_TARGETS:
            raise invalid(f"{where}.target", self.target, f"expected one of {REWARD_TARGETS}")


REWARD_TARGETS = ("command", "feasible")
"""What :attr:`RewardConfig.target` may name."""


REWARD_TERMS = (
    "tracking_lin",
    "tracking_ang",
    "error_lin",
    "error_ang",
    "action_rate",
    "energy",
    "path_lin",
    "path_ang",
)
"""The reward's terms, each scaled by the :class:`RewardConfig` field of the same name."""


def reward_terms(
    twist_error: jax.Array,
    action: jax.Array,
    last_action: jax.Array,
    power: jax.Array,
    cfg: RewardConfig,
    path_error: jax.Array | None = None,
) -> dict[str, jax.Array]:
    """The unscaled reward terms of one step (:data:`REWARD_TERMS`).

    ``twist_error`` is the true twist minus the command (vx, vy, ωz); ``power`` the wheels'
    mechanical power Σ|τ·ω| in W; ``path_error`` the true path error (x, y, heading; None:
    0). Tracking terms are in (0, 1], penalties are <= 0.
    """
    path = jnp.zeros_like(twist_error) if path_error is None else path_error
    lin2 = twist_error[..., 0] ** 2 + twist_error[..., 1] ** 2
    ang2 = twist_error[..., 2] ** 2
    return {
        "tracking_lin": jnp.exp(-lin2 / cfg.sigma_lin),
        "tracking_ang": jnp.exp(-ang2 / cfg.sigma_ang),
        "error_lin": -lin2,
        "error_ang": -ang2,
        "action_rate": -jnp.sum((action - last_action) ** 2, axis=-1),
        "energy": -power,
        "path_lin": -(path[..., 0] ** 2 + path[..., 1] ** 2),
        "path_ang": -(path[..., 2] ** 2),
    }


def scaled_reward_terms(terms: dict[str, jax.Array], cfg: RewardConfig) -> dict[str, jax.Array]:
    """Each term times its scale; the reward is their sum."""
    return {name: getattr(cfg, name) * terms[name] for name in REWARD_TERMS}


METRIC_NAMES = (
    *(f"reward/{name}" for name in REWARD_TERMS),
    "error/vx2",
    "error/vy2",
    "error/wz2",
    "energy_j",
    "path_m",
    "saturated",
    "unstable",
)
"""What each step reports in ``state.metrics``."""


def step_reward(
    cfg: RewardConfig,
    sens: Sensors,
    target: jax.Array,
    action: jax.Array,
    last_action: jax.Array,
    params: RobotParams,
    control_dt: float,
    path_error: jax.Array | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The reward of one control step and its metrics (:data:`METRIC_NAMES`, less
    ``unstable``, which the physics reports); ``target``: the twist tracked, the command or
    its nearest feasible twist (:attr:`RewardConfig.target`); ``path_error``: the true
    path error (``path_m`` reports its position part's length, m)."""
    err = sens.twist - target
    power = jnp.sum(jnp.abs(sens.wheel_torque * sens.wheel_rate))
    terms = reward_terms(err, action, last_action, power, cfg, path_error)
    scaled = scaled_reward_terms(terms, cfg)
    reward = sum(scaled.values(), jnp.asarray(0.0))
    saturated = jnp.mean(
        (jnp.abs(sens.wheel_torque) >= 0.99 * params.torque_limit).astype(jnp.float32)
    )
    metrics = {
        **{f"reward/{name}": value for name, value in scaled.items()},
        "error/vx2": err[0] ** 2,
        "error/vy2": err[1] ** 2,
        "error/wz2": err[2] ** 2,
        "energy_j": power * control_dt,
        "path_m": jnp.sqrt(-terms["path_lin"]),
        "saturated": saturated,
    }
    return reward, metrics


__all__ = [
    "METRIC_NAMES",
    "REWARD_TARGETS",
    "REWARD_TERMS",
    "RewardConfig",
    "reward_terms",
    "scaled_reward_terms",
    "step_reward",
]
