"""How far off a scripted path does desaturation alone leave a robot?

    python scripts/desaturation_drift.py [--scenarios stress] [--only fast_slalom] [--config gpu]

Beyond the wheels' reach a controller cannot drive the command, and the evaluation's drift
(the final position against the command's path) then charges what its desaturation gives
up. This replays each scripted scenario's commands as if the robot tracked a desaturated
twist exactly, on SE(2) as the evaluation integrates the command's path, and prints the
drift each desaturation leaves: `analytic`'s uniform scaling (the direction kept) and the
nearest feasible twist in the reference controllers' metric (the steady-state target,
`feedback`'s projection), each at the limits and at `feedback`'s headroom. No dynamics:
what is left is the desaturation's own share of a drift (docs/evaluation.md). Seconds.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation import episodes, scenarios
from mecanum_jax.evaluation.traces import intended_poses
from mecanum_jax.kinematics import limits
from mecanum_jax.task import MecanumEnv

Desaturation = Callable[[np.ndarray], np.ndarray]


def desaturations(env: MecanumEnv) -> dict[str, Desaturation]:
    """Name → twist map (..., 3) → (..., 3): the desaturations compared."""
    c, cfg = env.constants, env.config.feedback
    geom, m, w = c.geometry, np.asarray(c.max_rates), cfg.omega_weight
    margin = cfg.margin

    def uniform(frac: float) -> Desaturation:
        return lambda t: np.asarray(limits.desaturate(geom, jnp.asarray(t), m * frac)[0])

    def nearest(frac: float) -> Desaturation:
        return lambda t: np.asarray(limits.nearest_feasible(geom, jnp.asarray(t), m * frac, w))

    out = {"uniform": uniform(1.0), "nearest": nearest(1.0)}
    if margin > 0:
        out[f"uniform at {1 - margin:.0%}"] = uniform(1.0 - margin)
        out[f"nearest at {1 - margin:.0%}"] = nearest(1.0 - margin)
    return out


def drifts(env: MecanumEnv, commands: np.ndarray, dt: float) -> dict[str, float]:
    """Mean final drift (m) over episodes of each desaturation's twists tracked exactly,
    against the path of ``commands`` (E, T, 3)."""
    goal = intended_poses(commands, dt)[:, -1, :2]
    out = {}
    for name, f in desaturations(env).items():
        end = intended_poses(f(commands), dt)[:, -1, :2]
        out[name] = float(np.mean(np.linalg.norm(end - goal, axis=-1)))
    return out


def main(argv: list[str] | None = None) -> int:
    from train.config_loading import load_train_config

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", default="stress", help="scenario file (name or path)")
    p.add_argument("--only", nargs="*", default=[], help="these scenarios (default: scripted)")
    p.add_argument("--config", default="gpu", help="train config whose [env] is the task")
    p.add_argument("--episodes", type=int, default=4, help="episodes a scenario")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes = {args.episodes}: must be >= 1")
    try:
        sets = scenarios.load_scenarios(args.scenarios)
        names = args.only or [s.name for s in sets.scenarios if s.scripted]
        chosen = sets.select(names, args.episodes, None)
        cfg = load_train_config(args.config).env
    except ConfigError as e:
        p.error(str(e))
    env = MecanumEnv(episodes.eval_env_config(cfg, sets))
    for sc in chosen.scenarios:
        cmd = np.asarray(episodes.prepare(env, sc).commands)
        row = drifts(env, cmd, cfg.control_dt)
        print(sc.name, "  ".join(f"{k} {v:.3f} m" for k, v in row.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
