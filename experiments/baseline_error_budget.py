"""Where the analytic baseline's tracking error comes from (docs/training.md).

Runs the baseline on the nominal scenario (and optionally the randomized one) with the
evaluation command mix, and splits the squared velocity error by time since the last
command change and by whether the command is within the motors' reach. Usage:

    .venv/bin/python experiments/baseline_error_budget.py [--robots 64] [--chunks 1] [--seed 7]
        [--steps 250] [--randomized]

``--chunks`` batches of ``--robots`` run one after the other (MJX batches >= 256 deadlock
jaxlib 0.10.2 on CPU).
"""

import argparse

import jax
import numpy as np

from mecanum_jax.kinematics import limits
from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv, baseline_policy

_KEY = jax.random.PRNGKey(0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, default=64)
    ap.add_argument("--steps", type=int, default=250)
    ap.add_argument("--chunks", type=int, default=1)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--randomized", action="store_true")
    args = ap.parse_args()
    for field in ("robots", "steps", "chunks"):
        if getattr(args, field) < 1:
            ap.error(f"--{field} {getattr(args, field)}: must be >= 1")
    cfg = EnvConfig() if args.randomized else EnvConfig().nominal()
    env = MecanumEnv(cfg)
    tenv = TrainingEnv(env, args.steps)
    policy = baseline_policy(env)

    @jax.jit
    def roll(keys):
        s = tenv.reset(keys)

        def f(s, _):
            a, _ = policy(s.obs, _KEY)  # the baseline ignores its key
            ns = tenv.step(s, a)
            twist = jax.vmap(env.robot.sensors)(ns.pipeline_state).twist
            return ns, (s.info["command"], twist)

        return jax.lax.scan(f, s, None, length=args.steps)[1]

    with jax.numpy_rank_promotion("allow"):
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.robots * args.chunks)
        outs = [roll(k) for k in np.split(np.asarray(keys), args.chunks)]
        cmd, twist = (np.concatenate([np.asarray(o[i]) for o in outs], axis=1) for i in (0, 1))
    err = twist - cmd
    lin2, ang2 = err[..., 0] ** 2 + err[..., 1] ** 2, err[..., 2] ** 2
    since = np.zeros(cmd.shape[:2], int)
    for t in range(1, cmd.shape[0]):
        same = np.all(cmd[t] == cmd[t - 1], axis=-1)
        since[t] = np.where(same, since[t - 1] + 1, 0)
    sat = np.asarray(limits.saturation(env.geometry, cmd.reshape(-1, 3), env.max_rates))
    beyond = sat.reshape(cmd.shape[:2]) > 1.0
    total_lin, total_ang = lin2.sum(), ang2.sum()
    name = "randomized" if args.randomized else "nominal"
    print(f"scenario: {name}, {args.chunks} x {args.robots} robots x {args.steps} steps")
    print(f"overall RMSE: v {np.sqrt(lin2.mean()):.3f} m/s, ω {np.sqrt(ang2.mean()):.3f} rad/s")
    print(
        "| part | share of steps | RMSE v (m/s) | RMSE ω (rad/s) "
        "| share of Σ v-err² | share of Σ ω-err² |"
    )
    print("|---|---|---|---|---|---|")
    parts = {
        "transient (< 0.3 s after a change), within reach": (since < 15) & ~beyond,
        "steady (≥ 0.3 s), within reach": (since >= 15) & ~beyond,
        "beyond reach (any time)": beyond,
    }
    for name, m in parts.items():
        print(
            f"| {name} | {m.mean():.2f} | {np.sqrt(lin2[m].mean()):.3f} "
            f"| {np.sqrt(ang2[m].mean()):.3f}"
            f" | {lin2[m].sum() / total_lin:.2f} | {ang2[m].sum() / total_ang:.2f} |"
        )


if __name__ == "__main__":
    main()
