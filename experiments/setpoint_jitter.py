"""Probe: how much the chassis shakes when the wheel setpoints flicker from step to step.

The nominal O-rectangle robot drives straight ahead (vx = 0.6 m/s) under the analytic
baseline plus a residual in the task's action units (± residual_scale · max rate per
wheel): zero, a constant residual, white noise of a few hundredths around it (what a
learned policy's actions do when they flicker), and the same noise low-passed as
``env.action_filter`` does. It prints, over the last 1.5 s of 3 s, the spread of the
true yaw rate, of the yaw rate averaged over each control step (from the pose), of vy,
and the wheels' energy.

Finding (2026-11-24, 2-core CPU): a constant residual leaves the yaw rate steady; white
noise of 0.03 (0.15 rad/s of setpoint per wheel) makes it swing by about 0.3 rad/s, ten
times what the wheel rates would turn the robot through the kinematics. The servos
accelerate the wheels' reflected rotor inertia within one control step, and the torque
spike reacts on the chassis through the rollers. Low-passing the same noise with f = 0.8
cuts the swing four to seven times (f = 0.9: nine to fourteen). A constant residual of
0.05 on three wheels, which puts them partly against each other, costs 7.8 J over the
1.5 s against the baseline's 0.3 J. The shipped policy is trained with f = 0.8
(docs/training.md, docs/evaluation.md).

    .venv/bin/python experiments/setpoint_jitter.py [--noise 0.01 0.03] [--filter 0.8 0.9]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.task import EnvConfig, MecanumEnv, NoiseConfig

SECONDS = 3.0
COMMAND = (0.6, 0.0, 0.0)


def play(env: MecanumEnv, actions: np.ndarray) -> dict[str, float]:
    """Roll the nominal robot under ``actions`` (T, 4); figures over the last half."""
    step = jax.jit(env.step)
    state = env.set_command(env.reset(jax.random.PRNGKey(0)), jnp.asarray(COMMAND))
    wz, vy, yaw, energy = [], [], [], 0.0
    half = len(actions) // 2
    for t, a in enumerate(actions):
        state = step(state, jnp.asarray(a, jnp.float32))
        sens = env.robot.sensors(state.pipeline_state)
        if t >= half - 1:
            wz.append(float(sens.twist[2]))
            vy.append(float(sens.twist[1]))
            yaw.append(float(sens.pose[2]))
            energy += float(state.metrics["energy_j"]) if t >= half else 0.0
    averaged = np.diff(np.unwrap(yaw)) / env.config.control_dt
    return {
        "wz_std": float(np.std(wz[1:])),
        "wz_step_avg_std": float(np.std(averaged)),
        "vy_std": float(np.std(vy[1:])),
        "energy_j": energy,
    }


def low_pass(actions: np.ndarray, f: float) -> np.ndarray:
    out = np.zeros_like(actions)
    last = np.zeros(actions.shape[1], actions.dtype)
    for t, a in enumerate(actions):
        last = f * last + (1 - f) * a
        out[t] = last
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", type=float, nargs="+", default=[0.01, 0.03])
    parser.add_argument("--filter", type=float, nargs="+", default=[0.8, 0.9])
    parser.add_argument("--offset", type=float, default=0.05, help="the constant residual")
    args = parser.parse_args()
    env = MecanumEnv(EnvConfig(noise=NoiseConfig(scale=0.0)).nominal())
    steps = round(SECONDS / env.config.control_dt)
    rng = np.random.default_rng(0)
    offset = np.array([-1.0, -1.0, 1.0, 0.0], np.float32) * args.offset
    cases = {
        "zero residual (the baseline)": np.zeros((steps, env.action_size), np.float32),
        f"constant residual {args.offset}": np.tile(offset, (steps, 1)),
    }
    for sigma in args.noise:
        noise = offset + rng.normal(0.0, sigma, (steps, env.action_size)).astype(np.float32)
        cases[f"constant + white noise {sigma}"] = noise
        for f in args.filter:
            cases[f"  noise {sigma} low-passed, f = {f}"] = low_pass(noise, f)
    head = ("ωz std", "ωz (step avg) std", "vy std", "energy J")
    print(f"{'residual':36s} {head[0]:>8s} {head[1]:>18s} {head[2]:>8s} {head[3]:>9s}")
    for name, actions in cases.items():
        r = play(env, actions)
        print(
            f"{name:36s} {r['wz_std']:8.3f} {r['wz_step_avg_std']:18.3f} "
            f"{r['vy_std']:8.3f} {r['energy_j']:9.1f}"
        )


if __name__ == "__main__":
    main()
