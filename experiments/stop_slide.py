"""Why the start of a diagonal after a stop from speed turns the robot under `feedback`
and not under `analytic` (docs/evaluation.md, six_modes drift).

A sequence like six_modes' on the tuning seed (101): forward and back at half the reach,
0.3 s stops, then the diagonal at half its reach; the nominal robot, sensor noise on, MJX's
JAX physics. Prints, per controller, how far the diagonal's first 0.5 s turn the robot
(mean and spread over the episodes) and how fast it still slides when the diagonal
starts, for:

- `analytic` and `feedback` of the ``gpu`` config (the shipped policy's base);
- `feedback` with ``ki = 0`` (then exactly `analytic`'s setpoints);
- `feedback` with a correction deadband (``env.feedback.deadband``);
- `analytic` with a yaw command of ±0.0011 and ±0.011 rad/s through the backward run and
  its stop (an asymmetry in the wheels' setpoints, nothing else)::

    .venv/bin/python experiments/stop_slide.py [--episodes 16] [--deadband 0.01]
"""

from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np

from mecanum_jax.evaluation import metrics
from train import evaluate as train_eval

GPU = Path(__file__).resolve().parents[1] / "configs" / "train" / "gpu.toml"
DIAGONAL = 4  # the segment index of the diagonal


def sequence(yaw: float) -> list[list[float]]:
    """Forward, stop, back, stop (``yaw`` of the yaw reach through the last two), diagonal."""
    return [[0.5, 0, 0, 1.2], [0, 0, 0, 0.3], [-0.5, 0, yaw, 1.2], [0, 0, yaw, 0.3],
            [0.25, 0.25, 0, 1.2], [0, 0, 0, 0.6]]  # fmt: skip


def scenarios(path: Path, episodes: int, yaws: dict[str, float]) -> Path:
    lines = ["[defaults]", f"episodes = {episodes}", "seconds = 5.1", "seed = 101", ""]
    for name, yaw in yaws.items():
        lines += [
            f"[scenarios.{name}]",
            f'description = "forward, back and stop with yaw {yaw} of the reach, diagonal"',
            f'commands = {{ kind = "sequence", sequence = {sequence(yaw)} }}',
            "noise = { scale = 1.0 }",
            "",
        ]
    path.write_text("\n".join(lines))
    return path


def config(path: Path, **feedback: float) -> Path:
    """The ``gpu`` config with ``[env.feedback]`` fields replaced or added."""
    text = GPU.read_text()
    for key, value in feedback.items():
        pattern = rf"(?m)^{key} = .*$"
        line = f"{key} = {value}"
        text = (
            re.sub(pattern, line, text)
            if re.search(pattern, text)
            else text.replace("[env.feedback]\n", f"[env.feedback]\n{line}\n")
        )
    path.write_text(text)
    return path


def play(cfg: Path, scenario_file: Path, references: list[str], out: Path) -> dict:
    argv = ["baseline", "--config", str(cfg), "--scenarios", str(scenario_file), "--no-plots"]
    argv += ["--physics-impl", "jax", "--references", *references, "--out", str(out)]
    return train_eval.play_traces(argv, "stop_slide")[2]


def report(label: str, trace) -> None:
    seg = metrics.segment_ids(trace.command[:1])[0]
    idx = np.nonzero(seg == DIAGONAL)[0]
    turn = trace.twist[:, idx[:25], 2].sum(axis=1) * 0.02
    slide = trace.twist[:, idx[0] - 1, 0].mean()
    print(
        f"{label:44s} diagonal's first 0.5 s turn {turn.mean():+.4f} rad "
        f"(sd {turn.std():.4f}); sliding at its start {slide:+.3f} m/s"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--deadband", type=float, default=0.01)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="stop_slide-"))
    plain = scenarios(tmp / "plain.toml", args.episodes, {"plain": 0.0})
    runs = {
        "gpu config": (GPU, ["analytic", "feedback"]),
        "ki = 0": (config(tmp / "ki0.toml", ki=0.0), ["feedback"]),
        f"deadband {args.deadband}": (
            config(tmp / "band.toml", deadband=args.deadband),
            ["feedback"],
        ),
    }
    for label, (cfg, refs) in runs.items():
        by = play(cfg, plain, refs, tmp / label.replace(" ", "_"))["plain"]
        for who in refs:
            report(f"{who} ({label})", by[who])
    yaws = {"p1": 1e-4, "m1": -1e-4, "p2": 1e-3, "m2": -1e-3}  # of the 11 rad/s reach
    skewed = scenarios(tmp / "skewed.toml", 2, yaws)
    for name, by in play(GPU, skewed, ["analytic"], tmp / "skewed").items():
        report(f"analytic, yaw {yaws[name]:+g} of reach through back+stop", by["analytic"])


if __name__ == "__main__":
    main()
