"""Which physics step and solver settings can the training environment afford?

Throughput on the GPU falls with (physics substeps per control step) x (Newton iterations),
and robots tip over on slippery floors when the solve is not converged (docs/physics_model.md).
For each candidate ``TIMESTEP,TIMECONST,ITERATIONS`` (physics step s, contact time constant
s, Newton iterations) this prints, side by side:

- **steady tracking:** the nominal robot (high friction) driven by the analytic baseline
  for 3 s at five twists; the achieved body twist over the last second, as an error
  relative to the command's magnitude, and against the first candidate (the reference);
- **random actions:** direct wheel-rate actions drawn uniformly in [-1, 1] at every
  control step (PPO's exploration at its worst) on randomized robots: largest |qvel|,
  unstable resets, robots tipped;
- **baseline on randomized robots:** yaw-rate RMSE and robots tipped, as
  ``experiments/runaway_episodes.py`` counts them.

    .venv/bin/python experiments/physics_step_candidates.py 0.002,0.004,12 0.004,0.008,12 \\
        0.01,0.02,12 [--robots 64] [--chunks 4] [--steps 500]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.sim.physics import TIPPED_UP_Z, SimState
from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv, baseline_policy

TWISTS = np.array(
    [[1.0, 0.0, 0.0], [0.0, 0.8, 0.0], [0.0, 0.0, 3.0], [0.6, 0.4, 1.5], [-0.5, 0.5, -2.0]],
    np.float32,
)

_KEY = jax.random.PRNGKey(0)


def parse(spec: str) -> tuple[float, float, int]:
    try:
        ts, tc, it = spec.split(",")
        out = float(ts), float(tc), int(it)
    except ValueError:
        raise SystemExit(f"candidate {spec!r}: expected TIMESTEP,TIMECONST,ITERATIONS") from None
    if out[0] <= 0 or out[1] < 2 * out[0] or out[2] < 1:
        raise SystemExit(
            f"candidate {spec!r}: need timestep > 0, timeconst >= 2 x timestep, iterations >= 1"
        )
    return out


def tipped(env: MecanumEnv, states: SimState) -> jax.Array:
    return jax.vmap(env.robot.up_z)(states) < TIPPED_UP_Z


def steady(env: MecanumEnv, steps: int) -> np.ndarray:
    """Achieved body twists (len(TWISTS), 3) of the nominal robot under the baseline."""
    policy = baseline_policy(env)

    def one(key: jax.Array, cmd: jax.Array) -> jax.Array:
        s = env.set_command(env.reset(key), cmd)

        def f(s, _):
            a, _ = policy(s.obs, _KEY)  # the baseline ignores its key
            s = env.step(s, a)
            return s, env.robot.sensors(s.pipeline_state).twist

        _, tw = jax.lax.scan(f, s, None, length=steps)
        return jnp.mean(tw[-steps // 3 :], 0)

    keys = jax.random.split(jax.random.PRNGKey(0), len(TWISTS))
    return np.asarray(jax.jit(jax.vmap(one))(keys, jnp.asarray(TWISTS)))


def random_actions(env: MecanumEnv, robots: int, chunks: int, steps: int) -> dict[str, float]:
    tenv = TrainingEnv(env, steps + 1)

    @jax.jit
    def run(key: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        k0, k1 = jax.random.split(key)
        s0 = tenv.reset(jax.random.split(k0, robots))

        def f(carry, k):
            s, qmax, tip = carry
            a = jax.random.uniform(k, (robots, env.action_size), minval=-1.0, maxval=1.0)
            s = tenv.step(s, a)
            d = s.pipeline_state.data
            qmax = jnp.maximum(qmax, jnp.max(jnp.abs(d.qvel), -1))
            return (s, qmax, tip | tipped(env, s.pipeline_state)), None

        init = (s0, jnp.zeros(robots), jnp.zeros(robots, bool))
        (s, qmax, tip), _ = jax.lax.scan(f, init, jax.random.split(k1, steps))
        return qmax, s.pipeline_state.unstable, tip

    parts = [
        [np.asarray(x) for x in run(k)] for k in jax.random.split(jax.random.PRNGKey(1), chunks)
    ]
    return {
        "max_qvel": float(max(p[0].max() for p in parts)),
        "unstable": sum(int(p[1].sum()) for p in parts),
        "tipped": sum(int(p[2].sum()) for p in parts),
    }


def baseline_randomized(env: MecanumEnv, robots: int, chunks: int, steps: int) -> dict[str, float]:
    tenv = TrainingEnv(env, steps + 1)
    policy = baseline_policy(env)

    @jax.jit
    def run(key: jax.Array) -> tuple[jax.Array, jax.Array]:
        s0 = tenv.reset(jax.random.split(key, robots))

        def f(carry, _):
            s, tip = carry
            a, _ = policy(s.obs, _KEY)  # the baseline ignores its key
            s = tenv.step(s, a)
            return (s, tip | tipped(env, s.pipeline_state)), s.metrics["error/wz2"]

        (_, tip), wz2 = jax.lax.scan(f, (s0, jnp.zeros(robots, bool)), None, length=steps)
        return jnp.mean(wz2), tip

    parts = [run(k) for k in jax.random.split(jax.random.PRNGKey(2), chunks)]
    wz2 = np.mean([float(p[0]) for p in parts])
    tip = sum(int(np.asarray(p[1]).sum()) for p in parts)
    return {"rmse_wz": float(np.sqrt(wz2)), "tipped": tip}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("candidates", nargs="+", help="TIMESTEP,TIMECONST,ITERATIONS")
    # batches of 64: MJX batches >= 256 deadlock jaxlib 0.10.2 on CPU (docs/benchmarks.md)
    ap.add_argument("--robots", type=int, default=64, help="robots per batch")
    ap.add_argument("--chunks", type=int, default=4, help="batches, one after the other")
    ap.add_argument("--steps", type=int, default=500)
    args = ap.parse_args()
    for name in ("robots", "chunks", "steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} {getattr(args, name)}: must be >= 1")
    cands = [parse(c) for c in args.candidates]
    base = EnvConfig(residual=True)
    ref_twists = None
    print(
        f"twists: {TWISTS.tolist()}; {args.chunks} x {args.robots} robots x "
        f"{args.steps} control steps"
    )
    for ts, tc, it in cands:
        t0 = time.perf_counter()
        cfg = dataclasses.replace(
            base, physics_timestep=ts, contact_timeconst=tc, solver_iterations=it
        )
        nominal = MecanumEnv(cfg.nominal())
        tw = steady(nominal, 150)
        rel = np.linalg.norm(tw - TWISTS, axis=1) / np.linalg.norm(TWISTS, axis=1)
        if ref_twists is None:
            ref_twists = tw
        vs_ref = np.linalg.norm(tw - ref_twists, axis=1) / np.linalg.norm(TWISTS, axis=1)
        rand = random_actions(
            MecanumEnv(dataclasses.replace(cfg, residual=False)),
            args.robots,
            args.chunks,
            args.steps,
        )
        bl = baseline_randomized(MecanumEnv(cfg), args.robots, args.chunks, args.steps)
        print(
            f"step {ts * 1e3:g} ms, timeconst {tc * 1e3:g} ms, {it} iterations, "
            f"{round(0.02 / ts)} substeps | steady error max {rel.max():.2%} "
            f"(vs reference {vs_ref.max():.2%}) | random actions: max |qvel| "
            f"{rand['max_qvel']:.0f}, unstable {rand['unstable']}, tipped {rand['tipped']} | "
            f"baseline randomized: RMSE ω {bl['rmse_wz']:.3f}, tipped {bl['tipped']} "
            f"({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
