"""How much of the base controller's error could a policy predict from what it observes?

    python scripts/identifiability.py [--config gpu] [--robots 1024] [--frames 0 10 25]

A residual policy can only cancel an error it can predict. This rolls the `feedback`
controller (the `gpu` recipe's base) on the config's randomized robots and on the nominal
robot, with the training's sensor noise, and fits predictors of the next step's true twist
error (steady steps, at least 0.5 s after a command change, commands within reach) from
the policy's observation with 0, 10 or 25 earlier sensor frames, and from the observation
plus the critic's randomized parameters (what the privileged critic knows). Predictors are
fitted on 3/4 of the robots, in the config's share of nominal ones, and judged on the rest:
the RMS error left after subtracting the prediction, on randomized and on nominal robots,
beside `feedback`'s own. A predictor that leaves the nominal robot worse than `feedback`
would cost it precision as a correction (docs/controller.md, "What limits it"). Open loop:
it bounds what one correction could do, not what a trained policy does. CPU, about
8 minutes at the defaults.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from rich.console import Console
from rich.table import Table

from mecanum_jax.config import ConfigError
from mecanum_jax.control.spec import entry_slice, sensor_size
from mecanum_jax.evaluation import metrics
from mecanum_jax.kinematics import limits
from mecanum_jax.task import MecanumEnv
from mecanum_jax.task.references import REFERENCES
from train.config_loading import load_train_config

Predictor = Callable[[np.ndarray], np.ndarray]
"""A fitted predictor: features in, twist errors (vx, vy, ωz) out."""
CHUNK = 64
"""Robots rolled out per compiled call (a bounded output on a small CPU)."""
STEADY_STEPS = 25
"""Steps after a command change before a step counts as steady (0.5 s at 50 Hz)."""


def rollout(env: MecanumEnv, key: jax.Array, robots: int, steps: int) -> dict[str, np.ndarray]:
    """``feedback`` on ``robots`` fresh robots of ``env`` for ``steps`` control steps."""
    ref = jnp.asarray(REFERENCES.index("feedback"))

    def one(k: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        def body(st, _):
            nxt = env.step(st, jnp.zeros(env.action_size), ref)
            return nxt, (st.obs["state"], nxt.obs["privileged_state"], st.info["command"])

        return jax.lax.scan(body, env.reset(k), None, steps)[1]

    run = jax.jit(jax.vmap(one))
    keys = jax.random.split(key, robots)
    parts = [jax.tree.map(np.asarray, run(keys[i : i + CHUNK])) for i in range(0, robots, CHUNK)]
    state, priv, cmd = (np.concatenate([p[j] for p in parts]) for j in range(3))
    c = env.constants
    scale = np.asarray(c.command_scale)
    at = entry_slice(env.privileged_layout, "true_twist").start
    error = priv[..., at : at + 3] * scale - cmd  # the twist after the step, SI
    load = np.asarray(limits.saturation(c.geometry, cmd, c.max_rates))
    since = metrics.steps_since_change(cmd)
    steady = (since >= STEADY_STEPS) & (load <= 1.0) & np.any(cmd != 0, axis=-1)
    params = priv[..., at + 3 :]  # the randomized parameters after the true twist
    return {"state": state, "params": params, "error": error, "steady": steady}


def features(d: dict[str, np.ndarray], env: MecanumEnv, frames: int | None) -> np.ndarray:
    """The observation with ``frames`` earlier sensor frames; None: plus the parameters."""
    base = sum(size for name, size in env.layout if name != "sensor_history")
    if frames is None:
        return np.concatenate([d["state"][..., :base], d["params"]], axis=-1)
    return d["state"][..., : base + frames * sensor_size(env.constants.n_wheels)]


def fit_mlp(x: np.ndarray, y: np.ndarray, steps: int, seed: int) -> Predictor:
    """A 2×256 GELU network fitted to ``y`` by AdamW on standardized inputs and outputs."""
    mu, sd, ysd = x.mean(0), x.std(0) + 1e-6, y.std(0) + 1e-9
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed)
    params = []
    for a, b in zip([x.shape[1], 256, 256], [256, 256, y.shape[1]], strict=True):
        key, k = jax.random.split(key)
        params.append((jax.random.normal(k, (a, b)) * np.sqrt(2 / a), jnp.zeros(b)))

    def net(p, z):
        for w, b in p[:-1]:
            z = jax.nn.gelu(z @ w + b)
        return z @ p[-1][0] + p[-1][1]

    opt = optax.adamw(1e-3, weight_decay=1e-3)
    state = opt.init(params)

    @jax.jit
    def step(p, s, z, t):
        grad = jax.grad(lambda q: jnp.mean((net(q, z) - t) ** 2))(p)
        u, s = opt.update(grad, s, p)
        return optax.apply_updates(p, u), s

    xs, ys = jnp.asarray((x - mu) / sd), jnp.asarray(y / ysd)
    for _ in range(steps):
        i = rng.integers(0, len(xs), 4096)
        params, state = step(params, state, xs[i], ys[i])
    return lambda z: np.asarray(jax.jit(net)(params, jnp.asarray((z - mu) / sd))) * ysd


def fit_ridge(x: np.ndarray, y: np.ndarray, lam: float = 1e-2) -> Predictor:
    """A linear predictor (ridge regression on standardized inputs)."""
    mu, sd = x.mean(0), x.std(0) + 1e-6
    z = (x - mu) / sd
    w = np.linalg.solve(z.T @ z + lam * len(z) * np.eye(z.shape[1]), z.T @ (y - y.mean(0)))
    return lambda q: ((q - mu) / sd) @ w + y.mean(0)


def rms(e: np.ndarray) -> tuple[float, float]:
    """RMS linear (m/s) and yaw-rate (rad/s) error."""
    return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, -1)))), float(np.sqrt(np.mean(e[:, 2] ** 2)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="gpu")
    ap.add_argument("--robots", type=int, default=1024, help="robots per population")
    ap.add_argument("--steps", type=int, default=400, help="control steps per robot")
    ap.add_argument("--fit-steps", type=int, default=2500)
    ap.add_argument("--frames", type=int, nargs="+", default=[0, 10, 25])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.robots < CHUNK or args.robots % CHUNK:
        ap.error(f"--robots = {args.robots}: must be a positive multiple of {CHUNK}")
    if args.steps <= STEADY_STEPS:
        ap.error(f"--steps = {args.steps}: must be > {STEADY_STEPS} (the steady steps start there)")
    if args.fit_steps < 1 or min(args.frames) < 0:
        ap.error(f"--fit-steps = {args.fit_steps}, --frames = {args.frames}: need >= 1 and >= 0")
    try:  # a bad config or frame count: one line naming the field and value
        cfg = load_train_config(args.config).env
        cfg = dataclasses.replace(cfg, obs_history=max(args.frames), physics_impl="jax")
        cfg.validate()
    except ConfigError as err:
        ap.error(str(err))
    jax.config.update("jax_platforms", "cpu")
    share = cfg.randomization.nominal_share
    pops = {
        "randomized": dataclasses.replace(
            cfg, randomization=dataclasses.replace(cfg.randomization, nominal_share=0.0)
        ),
        "nominal": dataclasses.replace(
            cfg, randomization=dataclasses.replace(cfg.randomization, enabled=False)
        ),
    }
    key = jax.random.PRNGKey(args.seed)
    envs, data = {}, {}
    for name, c in pops.items():
        key, k = jax.random.split(key)
        envs[name] = MecanumEnv(c, robots=CHUNK)
        data[name] = rollout(envs[name], k, args.robots, args.steps)
    rng = np.random.default_rng(args.seed)
    n_fit = int(0.75 * args.robots)
    n_nom = min(n_fit, round(n_fit * share / max(1.0 - share, 1e-9)))
    fit_rows = {"randomized": np.arange(n_fit), "nominal": rng.permutation(n_fit)[:n_nom]}
    table = Table(
        title=f"`feedback`'s steady error within reach (RMS) left by a predictor "
        f"({args.config}, {args.robots} robots a population, held-out quarter)"
    )
    for col in (
        "features",
        "predictor",
        "randomized v",
        "randomized ωz",
        "nominal v",
        "nominal ωz",
    ):
        table.add_column(col)
    held = {n: d["steady"][n_fit:] for n, d in data.items()}
    errs = {n: d["error"][n_fit:][held[n]] for n, d in data.items()}
    table.add_row("-", "none (`feedback`)", *(f"{v:.4f}" for n in errs for v in rms(errs[n])))
    env = envs["randomized"]
    for frames in [*args.frames, None]:
        label = "+ parameters (privileged)" if frames is None else f"{frames} earlier frames"
        xs = {n: features(d, env, frames) for n, d in data.items()}
        x = np.concatenate([xs[n][fit_rows[n]][data[n]["steady"][fit_rows[n]]] for n in xs])
        y = np.concatenate(
            [data[n]["error"][fit_rows[n]][data[n]["steady"][fit_rows[n]]] for n in xs]
        )
        for kind, fit in (
            ("linear", fit_ridge(x, y)),
            ("MLP", fit_mlp(x, y, args.fit_steps, args.seed)),
        ):
            left = {n: errs[n] - fit(xs[n][n_fit:][held[n]]) for n in xs}
            table.add_row(label, kind, *(f"{v:.4f}" for n in left for v in rms(left[n])))
    Console(width=120).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
