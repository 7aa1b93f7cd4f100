"""Where do `analytic_nearest`, `feedback` and the policy lose RMSE v to `analytic` on load?

On the held-out weak_motors and payload scenarios (configs/eval/default.toml) the two
references that desaturate to the nearest feasible twist, and the shipped policy (a
residual on `feedback`), read about 1.03× and 1.05× `analytic`'s RMSE v (docs/evaluation.md).
RMSE v is the ``rmse_lin`` metric (mecanum_jax/evaluation/metrics.py): the (vx, vy) error
of the twist against the *command* (not the feasible target), over every step of the
episode. This plays those scenarios with the shipped policy and the three references on
the same episodes (2-core CPU is fine, JAX physics) and splits each episode's steps into
disjoint parts: transient (not yet ``settle_s`` after a command change, the steps the ss
metrics leave out) and steady, each with the command within the wheels' reach or beyond
it (its target, the true robot's nearest feasible twist, differs from it by > 1e-4). Per
part: its share of steps and of `analytic`'s Σ error², and per controller Σ error² over
`analytic`'s on those steps with a paired 95% bootstrap interval over episodes (2000
resamples, seed 0), and the part's share of the controller's whole-episode excess. Last
column: the gap built into the desaturation, Σ ‖v − v_command‖² (and Σ (ωz − ωz_command)²)
of the twist that nearest-feasible desaturation aims at over that of `analytic`'s uniform
scaling (the kinematic twists of their wheel setpoints, nominal geometry), on the part's
steps ("-" where uniform scaling aims at the command).

    .venv/bin/python experiments/rmse_v_budget.py [--only weak_motors,payload] [--episodes 32]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation import metrics, scenarios
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import MecanumEnv, references
from train import evaluate as train_eval

MODEL = "models/o_rectangle"
WHO = ("policy", "analytic_nearest", "feedback")
REFS = ("analytic", "analytic_nearest", "feedback")


def budget(name: str, traces: dict, env: MecanumEnv) -> None:
    """Print one scenario's whole-episode ratios and its table of parts."""
    dt = env.config.control_dt
    command = np.asarray(traces["analytic"].command)
    E, T = command.shape[:2]
    steady = metrics.steady_mask(command, dt, metrics.MetricConfig()) > 0
    target = np.asarray(traces["analytic"].target)
    beyond = np.linalg.norm(target - command, axis=-1) > 1e-4
    for who in WHO:  # the same episodes, so the same commands and targets
        assert np.array_equal(np.asarray(traces[who].command), command), who
    err2 = {}
    for who in ("analytic", *WHO):
        t = traces[who]
        e = np.asarray(t.twist)[..., :2] - command[..., :2]
        err2[who] = np.sum(e**2, axis=-1)  # (E, T)
        rmse = metrics.tracking_parts(command, np.asarray(t.target), np.asarray(t.twist), dt,
                                      metrics.MetricConfig())["rmse_lin"]  # fmt: skip
        assert np.allclose(rmse.num, np.sum(err2[who], axis=1)), who  # the metric's own error
    aimed = {  # the twist each desaturation aims at, (E, T, 3)
        k: np.asarray(kinematics.forward(env.geometry, f(env, jnp.asarray(command))))
        for k, f in (("uniform", references.baseline_rates), ("nearest", references.nearest_rates))
    }
    gap2 = {k: (v - command) ** 2 for k, v in aimed.items()}
    gap2 = {k: np.stack([g[..., 0] + g[..., 1], g[..., 2]], -1) for k, g in gap2.items()}
    weights = metrics.bootstrap_weights(E)  # one paired draw of episodes for every part
    ones = np.ones(E)

    def versus(who: str, mask: np.ndarray) -> str:
        mine = metrics.Part(np.sum(err2[who] * mask, axis=1), ones, "mean")
        base = metrics.Part(np.sum(err2["analytic"] * mask, axis=1), ones, "mean")
        c = metrics.paired_ratio(mine, base, weights=weights)
        return "-" if c is None else f"{c.ratio:.3f} [{c.lo:.3f}, {c.hi:.3f}]"

    full = np.ones((E, T), bool)
    print(f"\n== {name}: {E} episodes × {T} steps ({T * dt:.1f} s); RMSE v (m/s): " + ", ".join(
        f"{w} {np.sqrt(np.mean(err2[w])):.4f}" for w in ("analytic", *WHO)))  # fmt: skip
    print("whole episode, RMSE v over analytic's (paired 95% interval; rmse_lin's ratio):")
    for who in WHO:
        mine = metrics.Part(np.sum(err2[who], axis=1), np.full(E, float(T)), "rms")
        base = metrics.Part(np.sum(err2["analytic"], axis=1), np.full(E, float(T)), "rms")
        c = metrics.paired_ratio(mine, base, weights=weights)
        assert c is not None
        print(f"  {who}: {c.ratio:.4f} [{c.lo:.4f}, {c.hi:.4f}] (Σ err² {versus(who, full)})")
    parts = {
        "transient, within reach": ~steady & ~beyond,
        "transient, beyond reach": ~steady & beyond,
        "transient, all": ~steady,
        "steady, within reach": steady & ~beyond,
        "steady, beyond reach": steady & beyond,
        "steady, all": steady,
        "whole episode": full,
    }
    total = float(np.sum(err2["analytic"]))
    excess = {w: float(np.sum(err2[w])) - total for w in WHO}
    print("part | steps | analytic's Σ err² | " + " | ".join(
        f"{w}/analytic Σ err² [95%] (share of its excess)" for w in WHO)
        + " | aimed gap nearest/uniform: v, ωz")  # fmt: skip
    for label, mask in parts.items():
        a = float(np.sum(err2["analytic"] * mask))
        cells = []
        for who in WHO:
            extra = float(np.sum(err2[who] * mask)) - a
            share = f"{extra / excess[who]:+.2f}" if excess[who] != 0 else "-"
            cells.append(f"{versus(who, mask)} ({share})")
        u = np.sum(gap2["uniform"][mask], axis=0)  # (2,): v, ωz
        n = np.sum(gap2["nearest"][mask], axis=0)
        cells.append(f"{n[0] / u[0]:.3f}, {n[1] / u[1]:.3f}" if u[0] > 1e-6 * mask.sum() else "-")
        print(f"{label} | {np.mean(mask):.3f} | {a / total:.3f} | " + " | ".join(cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="weak_motors,payload", help="comma list of scenarios")
    ap.add_argument("--episodes", type=int, default=32)
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    known = scenarios.load_scenarios("default").names
    bad = [n for n in names if n not in known]
    if not names or bad:
        ap.error(f"--only {args.only!r}: expected a comma list of {', '.join(known)}")
    out = Path(tempfile.mkdtemp(prefix="rmse_v_budget-"))
    argv = [MODEL, "--only", *names, "--episodes", str(args.episodes), "--no-plots"]
    argv += ["--physics-impl", "jax", "--references", *REFS, "--out", str(out / "report")]
    try:
        target, _, played = train_eval.play_traces(argv, "rmse_v_budget")
    except ConfigError as err:
        ap.error(f"--only {args.only!r} --episodes {args.episodes}: {err}")
    print(f"{MODEL} and {', '.join(REFS)} on configs/eval/default.toml, JAX physics; "
          "v error = twist (vx, vy) − command, every step (rmse_lin)")  # fmt: skip
    for name in names:
        budget(name, played[name], target.env)


if __name__ == "__main__":
    main()
