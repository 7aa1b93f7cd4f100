"""Where six_modes' drift is made: per segment end, the mean position and heading error
against the intended pose, and the mean yaw rate through one segment (default 4, the
diagonal), for a model and the references; 16 episodes, MJX's JAX physics
(docs/evaluation.md, six_modes drift)::

    .venv/bin/python experiments/six_modes_turn.py models/o_rectangle [SEGMENT]
"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from straight_line_residual import play

from mecanum_jax.evaluation import metrics
from mecanum_jax.evaluation.rollout import intended_poses, relative_poses

by = play(sys.argv[1], ["six_modes"], 16, ["analytic", "analytic_nearest", "feedback"])["six_modes"]
k = int(sys.argv[2]) if len(sys.argv) > 2 else 4
cmd = by["policy"].command
seg = metrics.segment_ids(cmd[:1])[0]
ends = [np.nonzero(seg == i)[0][-1] for i in range(seg[-1] + 1)]
idx = np.nonzero(seg == k)[0]
print("segments:", [np.round(cmd[0, i], 2).tolist() for i in ends])
for who, tr in by.items():
    pose, goal = relative_poses(tr), intended_poses(tr.command, 0.02)
    pos = np.linalg.norm(pose[:, :, :2] - goal[:, :, :2], axis=-1).mean(0)
    hdg = np.abs(pose[:, :, 2] - goal[:, :, 2]).mean(0)
    print(
        f"{who:16s} position error at segment ends, m: " + " ".join(f"{pos[i]:.3f}" for i in ends)
    )
    print(
        f"{who:16s} heading error at segment ends, rad: " + " ".join(f"{hdg[i]:.3f}" for i in ends)
    )
print(f"segment {k} (command {cmd[0, idx[0]]}): mean yaw rate every 2nd step, rad/s x 100")
for who, tr in by.items():
    wz = tr.twist[:, idx, 2].mean(0)
    print(f"{who:16s} " + " ".join(f"{x * 100:+.0f}" for x in wz[::2]))
