"""Which observations have outliers after normalization (docs/training.md).

Rolls randomized robots under the baseline plus exploration-like noise (tanh of
N(0, 0.3) residuals), normalizes the critic's observations by their own mean and standard
deviation (as Brax's running statistics do), and prints the features with the largest
|z|, and the per-step reward's range.

    .venv/bin/python experiments/observation_outliers.py [--robots 64] [--steps 250]
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.task import EnvConfig, MecanumEnv, TrainingEnv


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, default=64)
    ap.add_argument("--steps", type=int, default=250)
    ap.add_argument("--noise", type=float, default=0.3)
    args = ap.parse_args()
    env = MecanumEnv(EnvConfig())
    tenv = TrainingEnv(env, args.steps)

    @jax.jit
    def roll(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        def f(carry: tuple, _: None) -> tuple[tuple, tuple[jax.Array, jax.Array]]:
            s, k = carry
            k, k_a = jax.random.split(k)
            a = jnp.tanh(args.noise * jax.random.normal(k_a, (keys.shape[0], env.action_size)))
            ns = tenv.step(s, a)
            return (ns, k), (s.obs["privileged_state"], ns.reward)

        start = (tenv.reset(keys), jax.random.PRNGKey(0))
        return jax.lax.scan(f, start, None, length=args.steps)[1]

    with jax.numpy_rank_promotion("allow"):
        obs, reward = map(np.asarray, roll(jax.random.split(jax.random.PRNGKey(3), args.robots)))
    names = [f"{n}[{i}]" for n, k in env.privileged_layout for i in range(k)]
    x = obs.reshape(-1, obs.shape[-1])
    z = np.abs((x - x.mean(0)) / (x.std(0) + 1e-6))
    for j in np.argsort(-z.max(0))[:10]:
        print(
            f"{names[j]:22s} max |z| {z[:, j].max():7.1f}   "
            f"99.9th percentile {np.percentile(z[:, j], 99.9):5.1f}"
        )
    print(
        f"reward per step: min {reward.min():.2f}, 0.1th percentile "
        f"{np.percentile(reward, 0.1):.2f}, mean {reward.mean():.3f}, max {reward.max():.3f}"
    )


if __name__ == "__main__":
    main()
