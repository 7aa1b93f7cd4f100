"""Does ramping the baseline's wheel-rate setpoints (traction control) cut tracking error?

The error budget (docs/training.md) leaves the acceleration transients as the one part of
the baseline's error a policy might shrink on slippery floors: a step in the setpoints
spins the wheels up at the torque limit, and on ice they slip. This plays the analytic
baseline with its setpoints slewed by at most ``δ · max_rate`` per control step (direct
wheel-rate actions, so ``a ← a_prev + clip(a_baseline − a_prev, ±δ)``) on the training
task's randomized robots and on the nominal one, side by side with the unramped baseline
(δ = inf), on the same episodes.

    .venv/bin/python experiments/ramped_baseline.py [--deltas inf 0.2 0.1 0.05] [--robots 64]
        [--chunks 4] [--steps 500]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv


def play(env: MecanumEnv, delta: float, robots: int, chunks: int, steps: int) -> dict[str, float]:
    tenv = TrainingEnv(env, steps + 1)

    @jax.jit
    def run(key: jax.Array) -> dict[str, jax.Array]:
        s0 = tenv.reset(jax.random.split(key, robots))

        def f(s, _):
            target = jax.vmap(env.baseline_rates)(s.info["command"]) / env.max_rates
            last = s.info["last_action"]
            a = last + jnp.clip(target - last, -delta, delta)
            s = tenv.step(s, a)
            m = s.metrics
            return s, (m["error/vx2"] + m["error/vy2"], m["error/wz2"], m["energy_j"])

        _, (v2, w2, e) = jax.lax.scan(f, s0, None, length=steps)
        return {"v2": jnp.mean(v2), "w2": jnp.mean(w2), "energy": jnp.sum(e) / robots}

    parts = [run(k) for k in jax.random.split(jax.random.PRNGKey(0), chunks)]
    mean = {k: float(np.mean([float(p[k]) for p in parts])) for k in parts[0]}
    return {"rmse_v": mean["v2"] ** 0.5, "rmse_w": mean["w2"] ** 0.5, "energy": mean["energy"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--deltas", type=float, nargs="+", default=[float("inf"), 0.2, 0.1, 0.05])
    # batches of 64: MJX batches >= 256 deadlock jaxlib 0.10.2 on CPU (docs/benchmarks.md)
    ap.add_argument("--robots", type=int, default=64)
    ap.add_argument("--chunks", type=int, default=4)
    ap.add_argument("--steps", type=int, default=500)
    args = ap.parse_args()
    for name in ("robots", "chunks", "steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} {getattr(args, name)}: must be >= 1")
    for d in args.deltas:
        if not d > 0:
            ap.error(f"--deltas {d}: must be > 0 (inf: no ramp)")
    cfg = EnvConfig(residual=False)
    envs = {
        "randomized": MecanumEnv(cfg),
        "nominal": MecanumEnv(cfg.nominal()),
    }
    print(f"{args.chunks} x {args.robots} robots x {args.steps} control steps (50 Hz)")
    print("| scenario | δ per step | RMSE v (m/s) | RMSE ω (rad/s) | energy per episode (J) |")
    print("|---|---|---|---|---|")
    for name, env in envs.items():
        for d in args.deltas:
            r = play(env, d, args.robots, args.chunks, args.steps)
            print(
                f"| {name} | {d:g} | {r['rmse_v']:.3f} | {r['rmse_w']:.3f} | {r['energy']:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
