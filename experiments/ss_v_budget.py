"""Where is the randomized steady-state v error made, and where does a controller gain on it?

The randomized target asks ss v ≤ 0.85× `analytic`'s; the shipped policy reads 0.98× and
its privileged teacher 0.96× (docs/evaluation.md). This plays the training distribution on
the tuning seed (``tuning_randomized``, for diagnosis, not for choosing) with the shipped
policy, ``analytic`` and ``feedback`` on the same episodes, and splits the steady-state
squared v error (the ``ss_lin`` metric's own steps and target) by the episode's floor
(its lowest wheel friction), by its torque limit, by the time since the command changed,
by whether the command is beyond the wheels' reach (its target, the nearest feasible
twist of the true robot, differs from it), and by whether a wheel of `analytic`'s robot
sat at its torque limit. Per part: its share
of `analytic`'s Σ error², and each controller's Σ error² over `analytic`'s on the same
steps (a ratio of 1: no gain there) with its paired 95% bootstrap interval over episodes.

    .venv/bin/python experiments/ss_v_budget.py [MODEL] [--episodes 128]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from mecanum_jax.evaluation import metrics, scenarios
from train import evaluate as train_eval

WHO = ("policy", "analytic", "feedback")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default="models/o_rectangle")
    ap.add_argument("--episodes", type=int, default=128)
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes {args.episodes}: must be >= 1")
    out = Path(tempfile.mkdtemp(prefix="ss_v_budget-"))
    argv = [args.model, "--scenarios", "configs/eval/tuning.toml", "--only", "tuning_randomized"]
    argv += ["--episodes", str(args.episodes), "--no-plots", "--physics-impl", "jax"]
    argv += ["--references", "analytic", "feedback", "--out", str(out / "report")]
    target, sset, played = train_eval.play_traces(argv, "ss_v_budget")
    traces = played["tuning_randomized"]
    batch = scenarios.prepare(target.env, sset.scenarios[0])
    friction = np.min(np.asarray(batch.params.friction), axis=-1)  # (E,)
    torque = np.asarray(batch.params.torque_limit)[:, 0] / float(
        np.max(np.asarray(batch.params.torque_limit))
    )
    dt = target.env.config.control_dt
    command = np.asarray(traces["analytic"].command)
    since = (metrics.steps_since_change(command) + 1) * dt  # as the ss metrics count it
    steady = metrics.steady_mask(command, dt, metrics.MetricConfig()) > 0
    err2 = {}
    for who in WHO:
        t = traces[who]
        ss = np.asarray(t.twist)[..., :2] - np.asarray(t.target)[..., :2]
        err2[who] = np.where(steady, np.sum(ss**2, axis=-1), 0.0)
    saturated = np.asarray(traces["analytic"].saturated) > 0
    beyond = np.linalg.norm(np.asarray(traces["analytic"].target) - command, axis=-1) > 1e-4
    E, T = command.shape[:2]
    per_step = lambda x: np.broadcast_to(np.asarray(x)[:, None], (E, T))  # noqa: E731
    high = per_step(friction >= 0.6)
    parts = {
        "floor: lowest wheel friction < 0.3": per_step(friction < 0.3),
        "floor: 0.3-0.6": per_step((friction >= 0.3) & (friction < 0.6)),
        "floor: >= 0.6": high,
        "torque limit < 0.75 of the largest": per_step(torque < 0.75),
        "torque limit >= 0.75": per_step(torque >= 0.75),
        "0.5-1 s after a change": since < 1.0,
        "1-2 s": (since >= 1.0) & (since < 2.0),
        ">= 2 s": since >= 2.0,
        "command beyond the wheels' reach": beyond,
        "command within reach": ~beyond,
        "floor >= 0.6, command beyond reach": high & beyond,
        "floor >= 0.6, command within reach": high & ~beyond,
        "analytic's robot: a wheel at its torque limit": saturated,
        "no wheel at its torque limit": ~saturated,
    }
    weights = metrics.bootstrap_weights(E)  # one paired draw of episodes for every part

    def versus(who: str, mask: np.ndarray) -> str:
        """``who``'s Σ error² over `analytic`'s on the part's steps, with its paired 95%
        bootstrap interval over episodes (the evaluation's intervals)."""
        count = np.sum(steady & mask, axis=1).astype(float)
        mine = metrics.Part(np.sum(err2[who] * mask, axis=1), count, "mean")
        base = metrics.Part(np.sum(err2["analytic"] * mask, axis=1), count, "mean")
        c = metrics.paired_ratio(mine, base, weights=weights)
        return "-" if c is None else f"{c.ratio:.3f} [{c.lo:.3f}, {c.hi:.3f}]"

    total = float(np.sum(err2["analytic"]))
    print(f"{E} episodes, {int(np.sum(steady))} steady steps; ss v: " + ", ".join(
        f"{w} {np.sqrt(np.sum(err2[w]) / np.sum(steady)):.4f} m/s" for w in WHO))  # fmt: skip
    print("part | share of steady steps | share of analytic's Σ error² | policy / analytic | "
          "feedback / analytic")  # fmt: skip
    for name, mask in parts.items():
        a = float(np.sum(err2["analytic"] * mask))
        share_steps = float(np.sum(steady & mask)) / max(float(np.sum(steady)), 1.0)
        ratios = " | ".join(versus(w, mask) for w in WHO[::2])
        print(f"{name} | {share_steps:.2f} | {a / total:.2f} | {ratios}")


if __name__ == "__main__":
    main()
