"""Where along the ``six_modes`` sequence does the shipped policy's final drift grow?

The ``six_modes`` command kind is a fixed sequence (seed document 000's six motion modes at
half their reach, 1.2 s each, 0.3 s stops); here it is played on the tuning seed (101), so
only the sensor noise differs from the held-out scenario: for diagnosis, not for choosing.
For the shipped policy, ``analytic`` and ``feedback`` on the same episodes, prints at the
end of each segment the mean heading error and position error against the pose the
commands integrate to (``rollout.intended_poses``; the final one is the ``drift_m``
metric) (docs/evaluation.md, the shipped policy, six_modes drift).

    .venv/bin/python experiments/six_modes_drift.py [MODEL] [--episodes 16]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from mecanum_jax.evaluation import metrics
from mecanum_jax.evaluation.rollout import _wrap, intended_poses, relative_poses
from train import evaluate as train_eval

WHO = ("policy", "analytic", "feedback")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default="models/o_rectangle")
    ap.add_argument("--episodes", type=int, default=16)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="six_modes_drift-"))
    scenario = tmp / "six.toml"
    scenario.write_text(
        f"[defaults]\nepisodes = {args.episodes}\nseconds = 10.0\nseed = 101\n\n"
        '[scenarios.six]\ndescription = "the six_modes kind on the tuning seed"\n'
        'commands = { kind = "six_modes", speed = 0.5, segment_s = 1.2, pause_s = 0.3 }\n'
        "noise = { scale = 1.0 }\n"
    )
    argv = [args.model, "--scenarios", str(scenario), "--no-plots", "--physics-impl", "jax"]
    argv += ["--references", "analytic", "feedback", "--out", str(tmp / "out")]
    target, _, played = train_eval.play_traces(argv, "six_modes_drift")
    traces = played["six"]
    dt = target.env.config.control_dt
    command = np.asarray(traces["analytic"].command)
    seg = metrics.segment_ids(command[:1])[0]
    print("segment, its end | command | heading error rad: policy / analytic / feedback "
          "| position error m: policy / analytic / feedback")  # fmt: skip
    for s in np.unique(seg):
        end = int(np.nonzero(seg == s)[0][-1])
        heading, position = [], []
        for who in WHO:
            pose = relative_poses(traces[who])[:, end]
            goal = intended_poses(np.asarray(traces[who].command), dt)[:, end]
            heading.append(float(np.mean(_wrap(pose[:, 2] - goal[:, 2]))))
            position.append(float(np.mean(np.linalg.norm(pose[:, :2] - goal[:, :2], axis=-1))))
        c = command[0, end]
        print(f"{s:2d} t={end * dt:5.2f} s ({c[0]:+.2f}, {c[1]:+.2f}, {c[2]:+.2f}) | "
              + " / ".join(f"{h:+.4f}" for h in heading) + " | "
              + " / ".join(f"{p:.3f}" for p in position))  # fmt: skip


if __name__ == "__main__":
    main()
