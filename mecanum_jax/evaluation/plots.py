"""Plots and videos of an evaluation's traces (matplotlib, Pillow): commanded against
achieved twist, trajectories, the error table, and clips side by side."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mecanum_jax.evaluation.traces import Trace, intended_poses, relative_poses
from mecanum_jax.task import REFERENCES

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_COLORS = {
    "policy": "tab:blue",
    "analytic": "tab:orange",
    "analytic_nearest": "tab:green",
    "feedback": "tab:red",
    "command": "black",
}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_twist(
    traces: dict[str, Trace[np.ndarray]], dt: float, title: str, out: Path, episode: int = 0
) -> Path:
    """Commanded against achieved vx, vy, ωz over time, every policy overlaid."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    first = next(iter(traces.values()))
    t = np.arange(1, first.command.shape[1] + 1) * dt
    labels = ("vx (m/s)", "vy (m/s)", "ωz (rad/s)")
    for i, ax in enumerate(axes):
        ax.plot(
            t,
            first.command[episode, :, i],
            color=_COLORS["command"],
            lw=1.2,
            ls="--",
            label="command",
        )
        for name, tr in traces.items():
            ax.plot(t, tr.twist[episode, :, i], color=_COLORS.get(name), lw=1.0, label=name)
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=10)
    return _save(fig, out)


def plot_trajectories(
    traces: dict[str, dict[str, Trace[np.ndarray]]],
    dt: float,
    scripted: dict[str, bool],
    out: Path,
    episode: int = 0,
) -> Path:
    """Top-down paths (start frame) per scenario: each policy, and the commanded path of
    scripted scenarios."""
    plt = _pyplot()
    names = list(traces)
    cols = min(4, len(names))
    rows = (len(names) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.6 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        per = traces[name]
        first = next(iter(per.values()))
        if scripted[name]:
            goal = intended_poses(first.command[episode : episode + 1], dt)[0]
            ax.plot(
                goal[:, 0], goal[:, 1], color=_COLORS["command"], ls="--", lw=1, label="commanded"
            )
        for who, tr in per.items():
            p = relative_poses(tr)[episode]
            ax.plot(p[:, 0], p[:, 1], color=_COLORS.get(who), lw=1.2, label=who)
            ax.plot(p[-1, 0], p[-1, 1], "o", color=_COLORS.get(who), ms=3)
        ax.plot(0, 0, "k+", ms=8)
        ax.set_title(name, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"top-down paths, episode {episode}, start frame (m)", fontsize=10)
    return _save(fig, out)


def plot_errors(results: dict[str, dict[str, dict[str, Any]]], out: Path) -> Path:
    """Bar chart of the steady-state error of v (m/s) and ωz (rad/s) per scenario, every
    controller side by side."""
    plt = _pyplot()
    names = list(results)
    whos: list[str] = sorted({w for r in results.values() for w in r}, key=_policy_order)
    fig, axes = plt.subplots(1, 2, figsize=(min(14.0, 4 + 1.2 * len(names)), 3.8))
    x = np.arange(len(names))
    width = 0.8 / len(whos)
    for ax, key, label in zip(
        axes,
        ("ss_lin", "ss_wz"),
        ("steady-state error v (m/s)", "steady-state error ωz (rad/s)"),
        strict=True,
    ):
        for j, who in enumerate(whos):
            vals = [results[n].get(who, {}).get(key, np.nan) for n in names]
            ax.bar(
                x + (j - (len(whos) - 1) / 2) * width,
                vals,
                width,
                label=who,
                color=_COLORS.get(who),
            )
        ax.set_xticks(x, names, rotation=35, ha="right", fontsize=8)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("steady-state tracking error per scenario", fontsize=10)
    return _save(fig, out)


def _policy_order(who: str) -> int:
    order = ("policy", *REFERENCES)
    return order.index(who) if who in order else len(order)


def _save(fig: Figure, out: Path) -> Path:
    import matplotlib.pyplot as plt

    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def side_by_side(videos: Sequence[np.ndarray], labels: Sequence[str]) -> np.ndarray:
    """Frames (T, H, W·k, 3): the given equal-length clips next to each other, labelled."""
    from PIL import Image, ImageDraw

    out = np.concatenate(list(videos), axis=2)
    w = videos[0].shape[2]
    labelled = []
    for frame in out:
        img = Image.fromarray(frame)
        draw = ImageDraw.Draw(img)
        for i, label in enumerate(labels):
            draw.rectangle([i * w + 4, 4, i * w + 8 + 7 * len(label), 20], fill=(0, 0, 0))
            draw.text((i * w + 6, 6), label, fill=(255, 255, 255))
        labelled.append(np.asarray(img))
    return np.stack(labelled)


__all__ = ["plot_errors", "plot_trajectories", "plot_twist", "side_by_side"]
