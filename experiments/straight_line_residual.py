"""What does a residual policy do on the scripted straight lines it loses?

On six_modes and singular_pass (the nominal robot translating, ωz = 0) the shipped policy
holds 5 to 10 times `analytic`'s steady yaw error. This plays those scenarios and prints,
per straight segment, from 0.5 s after the command change to its end (the steady-state
metric's window): the mean true yaw rate of the policy and of `analytic`, the mean and
standard deviation of the policy's applied action (the twist residual, in units of
``residual_scale`` of each axis' reach) and the policy's and `analytic`'s linear error
against the command::

    .venv/bin/python experiments/straight_line_residual.py models/o_rectangle [MODEL ...]

A constant action (small std) whose sign follows the command's direction is a
feedforward bias learned for the command, not a correction of a measured error.

``--all-segments`` prints instead every steady segment of six_modes (translations, spins
and the stop) in two episodes: the mean absolute yaw-rate error of the policy,
`analytic` and `feedback`, and the policy's mean yaw action: where the scenario's steady
ωz error comes from.
"""

from __future__ import annotations

import argparse

import numpy as np

from mecanum_jax.evaluation import metrics
from mecanum_jax.evaluation.rollout import Trace
from train import evaluate as train_eval

SETTLE_STEPS = 25  # 0.5 s at the 20 ms control period: the steady-state window's start


def v_error(trace: Trace, command: np.ndarray, steps: np.ndarray) -> float:
    """RMS linear error against the command over ``steps`` of episode 0, m/s."""
    e = trace.twist[0][steps, :2] - command[steps, :2]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def play(model: str, only: list[str], episodes: int, references: list[str]) -> dict:
    """Traces of ``only`` (scenario names) under MJX's JAX physics, by scenario and player."""
    argv = [model, "--only", *only, "--episodes", str(episodes), "--no-plots"]
    argv += ["--physics-impl", "jax", "--references", *references]
    return train_eval.play_traces(argv, "straight_line_residual")[2]


def steady_segments(command: np.ndarray) -> list[np.ndarray]:
    """Per constant-command segment of one episode's ``command`` (T, 3), its steps from
    the steady-state window's start on (segments shorter than that are left out)."""
    seg = metrics.segment_ids(command[None])[0]
    steady = metrics.steps_since_change(command[None])[0] >= SETTLE_STEPS
    out = [np.nonzero((seg == k) & steady)[0] for k in range(seg[-1] + 1)]
    return [s for s in out if len(s)]


def all_segments(model: str, episodes: int) -> None:
    """Per steady segment of six_modes: mean |ωz error| of the policy and the references."""
    by_who = play(model, ["six_modes"], episodes, ["analytic", "feedback"])["six_modes"]
    print(f"\n{model}: six_modes, mean |ωz error| (rad/s) from 0.5 s after each change")
    for ep in range(episodes):
        cmd = by_who["policy"].command[ep]
        for s in steady_segments(cmd):
            c = cmd[s[0]]
            err = {w: np.abs(by_who[w].twist[ep][s, 2] - c[2]).mean() for w in by_who}
            print(
                f"  episode {ep} command {np.round(c, 2)}: policy {err['policy']:.3f}, "
                f"analytic {err['analytic']:.3f}, feedback {err['feedback']:.3f} | "
                f"yaw action {by_who['policy'].action[ep][s, 2].mean():+.3f}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--all-segments", action="store_true", help="every six_modes segment")
    args = ap.parse_args()
    if args.all_segments:
        for model in args.models:
            all_segments(model, args.episodes)
        return
    for model in args.models:
        traces = play(model, ["singular_pass", "six_modes"], args.episodes, ["analytic"])
        print(f"\n{model}: episode 0, steps from 0.5 s after each change")
        for name, by_who in traces.items():
            pol, ana = by_who["policy"], by_who["analytic"]
            cmd = pol.command[0]
            for s in steady_segments(cmd):
                a = s[0]
                if cmd[a, 2] != 0 or not np.any(cmd[a, :2]):
                    continue
                act = pol.action[0][s]
                print(
                    f"  {name:13s} v_cmd {np.round(cmd[a, :2], 2)}: ωz policy "
                    f"{pol.twist[0][s, 2].mean():+.3f}, analytic {ana.twist[0][s, 2].mean():+.3f} "
                    f"rad/s | action {np.round(act.mean(axis=0), 3)} (std "
                    f"{act.std(axis=0).max():.3f}) | v error policy {v_error(pol, cmd, s):.3f}, "
                    f"analytic {v_error(ana, cmd, s):.3f} m/s"
                )


if __name__ == "__main__":
    main()
