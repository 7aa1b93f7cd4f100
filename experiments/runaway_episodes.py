"""Which episodes dominate the randomized tracking error, and are they physical?

Runs the analytic baseline on randomized episodes of the training task (as the trainer's
periodic evaluation does) and, per episode, records the yaw-rate RMSE, the largest
|ωz| reached, the chassis tilt (smallest z component of its up axis) and height, and the
robot's randomized parameters. Prints the share of the total squared ω error carried by
the worst episodes, then the worst episodes themselves.

A mecanum base cannot turn faster than its wheels allow (the largest feasible ωz,
``env.command_scale[2]``) unless something else drives it: an episode with |ωz| far
beyond that is a physics artefact or a tipped robot, not a tracking error.

    .venv/bin/python experiments/runaway_episodes.py [--episodes 512] [--steps 500] [--chunk 64]
        [--seed 0] [--worst 10] [--physics-timestep 0.004] [--contact-timeconst 0.008]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from mecanum_jax.sim.physics import TIPPED_UP_Z
from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv, baseline_policy

_KEY = jax.random.PRNGKey(0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=512)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--chunk", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--worst", type=int, default=10)
    ap.add_argument("--physics-timestep", type=float, default=EnvConfig.physics_timestep)
    ap.add_argument("--contact-timeconst", type=float, default=EnvConfig.contact_timeconst)
    ap.add_argument(
        "--opt",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a MuJoCo option of the simulated model, e.g. iterations=10, cone=1 "
        "(elliptic), noslip_iterations=2",
    )
    args = ap.parse_args()
    for name in ("episodes", "steps", "chunk", "worst"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} {getattr(args, name)}: must be >= 1")
    env = MecanumEnv(
        EnvConfig(physics_timestep=args.physics_timestep, contact_timeconst=args.contact_timeconst)
    )
    for item in args.opt:
        name, _, value = item.partition("=")
        if not hasattr(env.robot.sim_model.opt, name) or not value:
            ap.error(f"--opt {item!r}: expected NAME=VALUE with a MuJoCo option name")
        setattr(env.robot.sim_model.opt, name, float(value) if "." in value else int(value))
    if args.opt:
        env.robot.mjx_model = mjx.put_model(env.robot.sim_model, impl="jax")
    tenv = TrainingEnv(env, args.steps + 1)  # no reset inside the episode
    policy = baseline_policy(env)
    free = env.robot.index.free_qpos
    w_max = float(env.command_scale[2])

    @jax.jit
    def run(keys: jax.Array) -> dict[str, jax.Array]:
        s0 = tenv.reset(keys)

        def f(s, _):
            a, _ = policy(s.obs, _KEY)  # the baseline ignores its key
            ns = tenv.step(s, a)
            q = ns.pipeline_state.data.qpos
            up_z = jax.vmap(env.robot.up_z)(ns.pipeline_state)
            twist = jax.vmap(env.robot.sensors)(ns.pipeline_state).twist
            return ns, (ns.metrics["error/wz2"], jnp.abs(twist[:, 2]), up_z, q[:, free + 2])

        _, (wz2, wz, up, z) = jax.lax.scan(f, s0, None, length=args.steps)
        p = s0.info["params"]
        return {
            "wz2": jnp.mean(wz2, 0),
            "max_wz": jnp.max(wz, 0),
            "min_up": jnp.min(up, 0),
            "max_z": jnp.max(z, 0),
            "friction": jnp.mean(p.friction, -1),
            "payload": p.payload_mass,
            "com_x": p.payload_com[:, 0],
            "com_y": p.payload_com[:, 1],
            "torque": jnp.mean(p.torque_limit, -1),
            "radius": jnp.mean(p.radius_scale, -1),
            "latency": s0.info["latency"].astype(jnp.float32),
        }

    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    parts = []
    with jax.numpy_rank_promotion("allow"):
        for i in range(0, args.episodes, args.chunk):
            parts.append(jax.tree.map(np.asarray, run(keys[i : i + args.chunk])))
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    wz2 = out["wz2"]
    order = np.argsort(-wz2)
    total = wz2.sum()
    print(
        f"{args.episodes} randomized episodes x {args.steps} steps, baseline policy, physics "
        f"step {args.physics_timestep} s, contact time constant {args.contact_timeconst} s, "
        f"options {args.opt}; "
        f"largest feasible |ωz| {w_max:.2f} rad/s"
    )
    print(f"RMSE ω over all: {np.sqrt(wz2.mean()):.3f} rad/s")
    for k in (k for k in (1, 5, 20) if k < args.episodes):
        share = wz2[order[:k]].sum() / total
        rest = np.sqrt(wz2[order[k:]].mean())
        print(f"  worst {k:3d} episodes carry {share:6.1%} of Σω²; RMSE ω without them {rest:.3f}")
    beyond = out["max_wz"] > 1.5 * w_max
    tipped = out["min_up"] < TIPPED_UP_Z
    print(
        f"episodes whose |ωz| exceeds 1.5x the largest feasible: {beyond.sum()} "
        f"({beyond.mean():.1%}); tipped (up-axis z < {TIPPED_UP_Z}): {tipped.sum()}"
    )
    cols = list(out)
    print("worst episodes:")
    print("  ep  rmse_wz " + " ".join(f"{c:>8s}" for c in cols[1:]))
    for i in order[: args.worst]:
        vals = " ".join(f"{out[c][i]:8.3f}" for c in cols[1:])
        print(f"{i:4d} {np.sqrt(wz2[i]):8.3f} {vals}")


if __name__ == "__main__":
    main()
