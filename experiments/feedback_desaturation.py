"""Would the `feedback` base track v better with `analytic`'s uniform desaturation?

The shipped policy's v losses (payload, weak_motors, radius_error RMSE v; payload ss v in the
reference model) are its `feedback` base's: the policy ties `feedback`, which loses to
`analytic` by as much (docs/evaluation.md). `feedback` and `analytic_nearest` desaturate an
out-of-reach twist to the nearest feasible one, `analytic` scales it uniformly. This plays
the tuning episodes (``tuning_randomized`` and ``tuning_nominal`` of
configs/eval/tuning.toml: for choosing, not the held-out scenarios) with the references
twice on the same episodes: as they are, then with the references' nearest-feasible
desaturation replaced by uniform scaling (``mecanum_jax.task.references.nearest_rates``
patched in this process only). The second pass's `analytic_nearest` is then `analytic`
itself, which checks the patch and the pairing; its `feedback` is the same yaw-rate PI loop
on a uniformly desaturated twist ("feedback_uniform"). Prints, per scenario and for the
heavy (payload > 1.5 kg) and weak (torque limit < 0.75 of the largest) episodes of the
randomized mix, feedback_uniform's ratio to `feedback` and to `analytic` with paired 95%
bootstrap intervals over episodes (ss v, RMSE v, ss ωz, RMSE ωz, energy).

    .venv/bin/python experiments/feedback_desaturation.py [MODEL] [--episodes 128]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from mecanum_jax.evaluation import metrics, rollout, scenarios
from mecanum_jax.kinematics import limits
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import references
from train import evaluate as train_eval

SCENARIOS = ("tuning_randomized", "tuning_nominal")
FIGURES = ("ss_lin", "rmse_lin", "ss_wz", "rmse_wz", "energy_j")


def uniform_rates(env, twist):
    """`analytic`'s desaturation (uniform scaling) in place of the nearest feasible twist."""
    scaled, _ = limits.desaturate(env.geometry, twist, env.max_rates)
    return kinematics.apply_rows(env.jacobian, scaled)


def play(model: str, episodes: int, out: Path, name: str):
    argv = [model, "--scenarios", "configs/eval/tuning.toml", "--only", *SCENARIOS]
    argv += ["--episodes", str(episodes), "--no-plots", "--physics-impl", "jax"]
    argv += ["--references", "analytic", "analytic_nearest", "feedback", "--out", str(out / name)]
    return train_eval.play_traces(argv, "feedback_desaturation")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default="models/o_rectangle")
    ap.add_argument("--episodes", type=int, default=128)
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    out = Path(tempfile.mkdtemp(prefix="feedback_desaturation-"))
    target, sset, nearest = play(args.model, args.episodes, out, "nearest")
    references.nearest_rates = uniform_rates  # this process only
    _, _, uniform = play(args.model, args.episodes, out, "uniform")
    dt = target.env.config.control_dt
    jac = np.asarray(target.env.jacobian)
    for sc in sset.scenarios:
        a, a2 = nearest[sc.name]["analytic"], uniform[sc.name]["analytic_nearest"]
        gap = float(np.max(np.abs(np.asarray(a.twist) - np.asarray(a2.twist))))
        print(f"== {sc.name}: {len(np.asarray(a.twist))} episodes; patched analytic_nearest "
              f"against analytic: largest twist difference {gap:.2e}")  # fmt: skip
        parts = {
            "analytic": rollout.trace_parts(a, jac, dt),
            "feedback": rollout.trace_parts(nearest[sc.name]["feedback"], jac, dt),
            "feedback_uniform": rollout.trace_parts(uniform[sc.name]["feedback"], jac, dt),
        }
        batch = scenarios.prepare(target.env, sc)
        payload = np.asarray(batch.params.payload_mass).reshape(-1)
        torque = np.asarray(batch.params.torque_limit)[:, 0]
        groups = {"all": np.ones_like(payload, bool)}
        if sc.name == "tuning_randomized":
            groups["payload > 1.5 kg"] = payload > 1.5
            groups["torque limit < 0.75"] = torque < 0.75 * float(np.max(torque))
        for group, keep in groups.items():
            print(f"-- {group} ({int(np.sum(keep))} episodes)")
            for key in FIGURES:
                sub = {w: metrics.Part(p[key].num[keep], p[key].den[keep], p[key].kind)
                       for w, p in parts.items()}  # fmt: skip
                vals = {w: sub[w].value() for w in sub}
                cells = []
                for ref in ("feedback", "analytic"):
                    c = metrics.paired_ratio(sub["feedback_uniform"], sub[ref])
                    cells.append("-" if c is None else f"{c.ratio:.3f} [{c.lo:.3f}, {c.hi:.3f}]")
                print(f"{key:9s} analytic {vals['analytic']:.4f}  feedback {vals['feedback']:.4f}"
                      f"  feedback_uniform {vals['feedback_uniform']:.4f}  | uniform/feedback "
                      f"{cells[0]}  uniform/analytic {cells[1]}")  # fmt: skip


if __name__ == "__main__":
    main()
