"""Does the ``feedback`` controller's yaw on straight translations come from its integrator
carrying a correction across command changes, or picking one up in the servos' transients?

The residual policy starts from ``feedback``, and on translations (ωz = 0) ``feedback``
holds about twice ``analytic``'s steady yaw error (tuning episodes, docs/evaluation.md).
Variants of its integrator on the tuning episodes (configs/eval/tuning.toml), the same
episodes for all, each against ``feedback`` as shipped with a paired 95% interval:

- ``reset``: the integrator restarts at 0 when the command changes (a subclass here);
- ``hold H``: it does not integrate for H s after a command change
  (``FeedbackConfig.hold_s``, the library's rule);
- ``reset+hold H``: both.

    .venv/bin/python experiments/feedback_hold.py [--episodes 128] [--hold 0.2 0.4 0.8]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp

from mecanum_jax.evaluation import metrics, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv

FIGURES = ("ss_lin", "ss_wz", "rmse_wz", "settle_wz_s", "energy_j")


class ResetOnChange(MecanumEnv):
    """``MecanumEnv`` whose feedback integrator restarts at 0 when the command changes."""

    def set_command(self, state: Any, command: jax.Array) -> Any:
        changed = jnp.any(command != state.info["command"])
        s = super().set_command(state, command)
        integral = jnp.where(changed, 0.0, s.info["feedback_integral"])
        return s.replace(info={**s.info, "feedback_integral": integral})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--hold", type=float, nargs="+", default=[0.2, 0.4, 0.8])
    ap.add_argument("--max-batch", type=int, default=64)
    args = ap.parse_args()
    t0 = time.time()
    sset = scenarios.load_scenarios("tuning").select((), args.episodes)
    base = scenarios.eval_env_config(EnvConfig(), sset)

    def config(hold_s: float) -> EnvConfig:
        return dataclasses.replace(base, feedback=FeedbackConfig(hold_s=hold_s))

    envs: dict[str, MecanumEnv] = {"feedback": MecanumEnv(base), "reset": ResetOnChange(base)}
    envs |= {f"hold {h:g}": MecanumEnv(config(h)) for h in args.hold}
    envs |= {f"reset+hold {h:g}": ResetOnChange(config(h)) for h in args.hold}
    evaluators = {n: evaluation.Evaluator(e, max_batch=args.max_batch) for n, e in envs.items()}
    first = envs["feedback"]
    jac, dt = kinematics.jacobian(first.geometry), base.control_dt
    print(f"{args.episodes} episodes a scenario (configs/eval/tuning.toml): value, ratio to "
          "analytic, and to feedback [paired 95% interval]")  # fmt: skip
    for sc in sset.scenarios:
        batch = scenarios.prepare(first, sc)
        (tr,) = evaluators["feedback"].run_many([(batch, "analytic")])
        parts = {"analytic": evaluation.trace_parts(tr, jac, dt)}
        for name, ev in evaluators.items():
            (tr,) = ev.run_many([(batch, "feedback")])
            parts[name] = evaluation.trace_parts(tr, jac, dt)
        weights = metrics.bootstrap_weights(args.episodes)
        print(f"\n{sc.name}")
        for name, p in parts.items():
            cells = []
            for k in FIGURES:
                v, a = p[k].value(), parts["analytic"][k].value()
                if v is None or a is None:
                    cells.append(f"{k} –")
                    continue
                c = metrics.paired_ratio(p[k], parts["feedback"][k], weights=weights)
                vs = "" if c is None else f" {c.ratio:.2f} [{c.lo:.2f}, {c.hi:.2f}]"
                cells.append(f"{k} {v:.3f} ({v / a:.2f}){vs}")
            print(f"  {name:>15s}: " + " | ".join(cells))
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
