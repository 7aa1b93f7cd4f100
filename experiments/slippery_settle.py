"""Why does ``feedback`` settle the yaw rate more slowly than ``analytic`` on slippery floors?

On the tuning seed's slippery floors (``tuning_slippery`` of configs/eval/tuning.toml),
every segment that begins with a yaw-rate step of at least 0.2 rad/s, settled as the
evaluation settles it (metrics.settling_times: the first sample after which ωz stays in
the band around the feasible target; a segment that ends outside counts whole). Variants
of the `gpu` config's integrator (held 0.4 s after each change): as it is, limited to
0.2 rad/s, restarted at 0 at each command change (``FeedbackConfig.reset``), not held,
and restarted but not held. Prints each one's mean settling time, the share of segments
that never settle and the error over their last 0.2 s, then the segments that ``feedback``
as it is settles latest against ``analytic`` (docs/evaluation.md, the shipped policy).

    .venv/bin/python experiments/slippery_settle.py [--episodes 64]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Any

import numpy as np

from mecanum_jax.evaluation import metrics, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.task import EnvConfig, MecanumEnv
from train.config import load_train_config

VARIANTS: dict[str, dict[str, Any]] = {
    "as in gpu.toml before": {},
    "i_max 0.2": {"i_max": 0.2},
    "restart": {"reset": True},
    "no hold": {"hold_s": 0.0},
    "restart, no hold": {"reset": True, "hold_s": 0.0},
}


def segments(trace: evaluation.Trace, dt: float) -> dict[tuple[int, int], tuple]:
    """Per (episode, segment) with a yaw step: settling time, whether it never settled,
    the target, the previous target and the mean |error| over the last 10 steps."""
    command, target = np.asarray(trace.command), np.asarray(trace.target)
    err = np.abs(np.asarray(trace.twist)[..., 2] - target[..., 2])
    seg = metrics.segment_ids(command)
    previous = np.concatenate([np.zeros_like(target[:, :1]), target[:, :-1]], axis=1)
    out = {}
    for e in range(command.shape[0]):
        for s in np.unique(seg[e]):
            m = seg[e] == s
            first = int(np.argmax(m))
            step = abs(target[e, first, 2] - previous[e, first, 2])
            if step < 0.2:
                continue
            outside = np.nonzero(err[e][m] > max(0.1 * step, 0.1))[0]
            n = int(m.sum())
            settle = (min(outside[-1] + 2, n) if outside.size else 1) * dt
            never = bool(outside.size and outside[-1] == n - 1)
            out[(e, int(s))] = (settle, never, target[e, first, 2], previous[e, first, 2],
                                float(err[e][m][-10:].mean()))  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=64)
    args = ap.parse_args()
    t0 = time.time()
    sset = scenarios.load_scenarios("tuning").select(("tuning_slippery",), args.episodes)
    gpu = load_train_config("gpu").env
    held = dataclasses.replace(gpu.feedback, reset=False, deadband=0.0)
    base = scenarios.eval_env_config(dataclasses.replace(EnvConfig(), feedback=held), sset)
    envs = {
        name: MecanumEnv(dataclasses.replace(base, feedback=dataclasses.replace(held, **kw)))
        for name, kw in VARIANTS.items()
    }
    first = next(iter(envs.values()))
    dt, scenario = base.control_dt, sset.scenarios[0]
    batch = scenarios.prepare(first, scenario)
    (trace,) = evaluation.Evaluator(first, max_batch=64).run_many([(batch, "analytic")])
    found = {"analytic": segments(trace, dt)}
    for name, env in envs.items():
        (trace,) = evaluation.Evaluator(env, max_batch=64).run_many([(batch, "feedback")])
        found[name] = segments(trace, dt)
    keys = list(found["analytic"])
    print(f"{scenario.name}, {args.episodes} episodes: {len(keys)} segments with a yaw step")
    for name, segs in found.items():
        settle = np.array([segs[k][0] for k in keys])
        never = np.array([segs[k][1] for k in keys])
        end = np.array([segs[k][4] for k in keys])
        print(f"  {name:>22s}: mean settle {settle.mean():.3f} s, never settles "
              f"{never.mean():.0%}, |error| at the end {end.mean():.3f} rad/s")  # fmt: skip
    a, f = found["analytic"], found["as in gpu.toml before"]
    worst = sorted(keys, key=lambda k: a[k][0] - f[k][0])[:8]
    print("\nlatest under feedback as it was (s; rad/s):")
    for k in worst:
        print(f"  episode {k[0]:3d}: analytic {a[k][0]:.2f}, feedback {f[k][0]:.2f}; target "
              f"{a[k][2]:+.2f} after {a[k][3]:+.2f}; end error {a[k][4]:.2f} against "
              f"{f[k][4]:.2f}")  # fmt: skip
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
