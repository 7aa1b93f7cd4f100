"""Does the ``feedback`` controller's yaw on straight translations come from its integrator
carrying a correction across command changes, or picking one up in the servos' transients?

The residual policy starts from ``feedback``, and on translations (ωz = 0) ``feedback``
holds about twice ``analytic``'s steady yaw error (tuning episodes, docs/evaluation.md).
Variants of its integrator on the tuning episodes (configs/eval/tuning.toml), the same
episodes for all, each against ``feedback`` as shipped with a paired 95% interval:

- ``reset``: the integrator restarts at 0 when the command changes (a subclass here);
- ``hold H``: it does not integrate for H s after a command change
  (``FeedbackConfig.hold_s``, the library's rule);
- ``reset+hold H``: both;
- ``hold 0.4 + heading K``: the hold, and while it lasts a proportional correction
  ``K·ψ`` on the heading turned since the command changed, ``ψ = ∫(ωz_cmd − gyro) dt``
  (a subclass here): the heading the hold leaves turned is taken back inside the window
  the steady-state metric ignores, and the term is gone when the window ends, so it
  leaves no integrator offset behind (unlike a faster integrator in the window);
  ``--heading-translations`` applies it only while the command's ωz is 0.

    .venv/bin/python experiments/feedback_hold.py [--episodes 128] [--hold 0.2 0.4 0.8]
    .venv/bin/python experiments/feedback_hold.py --hold 0.4 --heading 3 6 10 --no-reset
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
from mecanum_jax.task import references as refs

FIGURES = ("ss_lin", "ss_wz", "rmse_wz", "settle_wz_s", "energy_j", "drift_m")


class ResetOnChange(MecanumEnv):
    """``MecanumEnv`` whose feedback integrator restarts at 0 when the command changes."""

    def set_command(self, state: Any, command: jax.Array) -> Any:
        changed = jnp.any(command != state.info["command"])
        s = super().set_command(state, command)
        integral = jnp.where(changed, 0.0, s.info["feedback_integral"])
        return s.replace(info={**s.info, "feedback_integral": integral})


class HeadingWindow(MecanumEnv):
    """``MecanumEnv`` whose ``feedback`` reference adds ``gain·ψ`` to its yaw-rate
    correction while the command is younger than the hold, ψ the heading turned short of
    the command since it changed (measured: the gyro as the controller sees it)."""

    def __init__(self, config: EnvConfig, gain: float, translations_only: bool):
        super().__init__(config)
        self.gain, self.translations_only = gain, translations_only
        self.window = config.feedback.hold_steps(config.control_dt)

    def reset_to(self, *args: Any, **kwargs: Any) -> Any:
        s = super().reset_to(*args, **kwargs)
        return s.replace(info={**s.info, "heading": jnp.asarray(0.0)})

    def _heading(self, info: dict[str, Any]) -> jax.Array:
        return jnp.where(info["command_age"] == 0, 0.0, info["heading"])

    def reference_rates(self, reference: Any, info: dict[str, Any]) -> jax.Array:
        on = info["command_age"] < self.window
        if self.translations_only:
            on = on & (info["command"][2] == 0.0)
        twist, _ = refs.feedback_twist(self, info)
        twist = twist.at[2].add(jnp.where(on, self.gain * self._heading(info), 0.0))
        rates = refs.nearest_rates(self, twist)
        others = super().reference_rates(reference, info)
        return jnp.where(jnp.asarray(reference) == 2, rates, others)

    def step(self, state: Any, action: jax.Array, reference: Any = None) -> Any:
        s = super().step(state, action, reference)
        err = state.info["command"][2] - refs.measured_yaw_rate(self, state.info)
        heading = self._heading(state.info) + err * self.config.control_dt
        return s.replace(info={**s.info, "heading": heading})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--hold", type=float, nargs="+", default=[0.2, 0.4, 0.8])
    ap.add_argument("--heading", type=float, nargs="*", default=[], help="gains K, 1/s")
    ap.add_argument("--heading-translations", action="store_true")
    ap.add_argument("--no-reset", action="store_true", help="leave out the reset variants")
    ap.add_argument("--against", default="feedback", help="the variant the intervals pair with")
    ap.add_argument("--max-batch", type=int, default=64)
    args = ap.parse_args()
    t0 = time.time()
    sset = scenarios.load_scenarios("tuning").select((), args.episodes)
    base = scenarios.eval_env_config(EnvConfig(), sset)

    def config(hold_s: float) -> EnvConfig:
        return dataclasses.replace(base, feedback=FeedbackConfig(hold_s=hold_s))

    envs: dict[str, MecanumEnv] = {"feedback": MecanumEnv(base)}
    envs |= {f"hold {h:g}": MecanumEnv(config(h)) for h in args.hold}
    if not args.no_reset:
        envs["reset"] = ResetOnChange(base)
        envs |= {f"reset+hold {h:g}": ResetOnChange(config(h)) for h in args.hold}
    t = args.heading_translations
    envs |= {f"hold .4+heading {k:g}": HeadingWindow(config(0.4), k, t) for k in args.heading}
    evaluators = {n: evaluation.Evaluator(e, max_batch=args.max_batch) for n, e in envs.items()}
    first = envs["feedback"]
    jac, dt = kinematics.jacobian(first.geometry), base.control_dt
    print(f"{args.episodes} episodes a scenario (configs/eval/tuning.toml): value, ratio to "
          f"analytic, and to {args.against} [paired 95% interval]")  # fmt: skip
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
                if k not in p:  # drift: scripted paths only
                    continue
                v, a = p[k].value(), parts["analytic"][k].value()
                if v is None or a is None:
                    cells.append(f"{k} –")
                    continue
                c = metrics.paired_ratio(p[k], parts[args.against][k], weights=weights)
                vs = "" if c is None else f" {c.ratio:.2f} [{c.lo:.2f}, {c.hi:.2f}]"
                cells.append(f"{k} {v:.3f} ({v / a:.2f}){vs}")
            print(f"  {name:>15s}: " + " | ".join(cells))
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
