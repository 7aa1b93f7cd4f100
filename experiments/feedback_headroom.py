"""How much a policy *can* gain over the analytic baseline from what it observes.

Runs hand-written gyro-feedback controllers, built on the same residual action interface
and the same noisy, delayed observations a learned policy sees, against the open-loop
analytic baseline on identical episodes (same robots, commands and noise draws), and
prints the tracking RMSE and the mean tracking reward ``R[w_lin,σ_lin;w_ang,σ_ang]``
under several kernels and the task's own reward (``env reward``, with its quadratic terms
): does the reward rank them as the RMSE does? If a two-line
controller beats the baseline, the headroom is there, and a learned policy that does not
find it has a learning problem, not a physics one.

- ``p``: residual = kp · J[:, 2] · (ω_cmd − gyro), proportional yaw-rate feedback;
- ``i``: residual = last residual + ki·dt · J[:, 2] · (ω_cmd − gyro), an integrator
  carried through the ``last_action`` observation (the only memory a feedforward
  policy has).

    .venv/bin/python experiments/feedback_headroom.py [--robots 64] [--steps 250] [--gains 0.5 1 2]
        [--igains 2 5 10] [--residual-scale 0.1]
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv

# tracking terms (w_lin, σ_lin; w_ang, σ_ang) to score: the default and wider kernels
REWARDS = ((1.0, 0.25, 0.5, 1.0), (1.0, 0.25, 1.0, 4.0), (1.0, 1.0, 1.0, 4.0))


def make_policy(env: MecanumEnv, kind: str, gain: float):
    n = env.n_wheels
    col = env._jacobian[:, 2]  # wheel rates per rad/s of yaw rate
    scale = env.config.residual_scale * env.max_rates
    dt = env.config.control_dt
    i_gyro = 3 + n
    i_last = 3 + n + 1 + 3 + 3

    def policy(obs):
        s = obs["state"]
        w_cmd = s[2] * env.command_scale[2]
        w_meas = s[i_gyro] * env.command_scale[2]
        err = w_cmd - w_meas
        if kind == "baseline":
            return jnp.zeros(n)
        if kind == "p":
            return jnp.clip(gain * col * err / scale, -1, 1)
        last = s[i_last : i_last + n]
        return jnp.clip(last + gain * dt * col * err / scale, -1, 1)

    return policy


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, default=64)
    ap.add_argument("--steps", type=int, default=250)
    ap.add_argument("--gains", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--igains", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    ap.add_argument("--residual-scale", type=float, default=EnvConfig.residual_scale)
    args = ap.parse_args()
    variants = [("baseline", 0.0)]
    variants += [("p", g) for g in args.gains] + [("i", g) for g in args.igains]
    for scenario in ("randomized", "nominal"):
        cfg = EnvConfig(residual_scale=args.residual_scale)
        cfg = cfg if scenario == "randomized" else cfg.nominal()
        env = MecanumEnv(cfg)
        tenv = TrainingEnv(env, args.steps)
        print(f"\n{scenario}: {args.robots} robots x {args.steps} steps (RMSE v m/s, ω rad/s)")
        for kind, gain in variants:
            policy = jax.vmap(make_policy(env, kind, gain))

            @jax.jit
            def roll(keys, policy=policy, env=env, tenv=tenv):
                s = tenv.reset(keys)

                def f(s, _):
                    ns = tenv.step(s, policy(s.obs))
                    twist = jax.vmap(env.robot.sensors)(ns.pipeline_state).twist
                    return ns, (s.info["command"], twist, ns.reward)

                return jax.lax.scan(f, s, None, length=args.steps)[1]

            with jax.numpy_rank_promotion("allow"):
                keys = jax.random.split(jax.random.PRNGKey(7), args.robots)
                cmd, twist, env_reward = map(np.asarray, roll(keys))
            err = twist - cmd
            v = np.sqrt((err[..., 0] ** 2 + err[..., 1] ** 2).mean())
            w = np.sqrt((err[..., 2] ** 2).mean())
            ev2 = err[..., 0] ** 2 + err[..., 1] ** 2
            rewards = "  ".join(
                f"R[{lin:g},{sl:g};{ang:g},{sa:g}] "
                f"{(lin * np.exp(-ev2 / sl) + ang * np.exp(-(err[..., 2] ** 2) / sa)).mean():.4f}"
                for lin, sl, ang, sa in REWARDS
            )
            print(
                f"  {kind:8s} gain {gain:5.2f}: v {v:.3f}  ω {w:.3f}  {rewards}"
                f"  env reward {env_reward.mean():.4f}"
            )


if __name__ == "__main__":
    main()
