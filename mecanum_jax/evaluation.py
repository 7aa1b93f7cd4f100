"""Batched evaluation: play a scenario's episodes with a policy and the analytic baseline.

:class:`Evaluator` compiles **one** rollout program per episode-batch shape: a scenario's
physics, latency, noise and command schedule are arrays (:class:`~mecanum_jax.scenarios.
EpisodeBatch`), and the learned policy's parameters and a ``use_baseline`` flag are
arguments, so every scenario of the same size and both policies share the compilation.
Both policies see the same episodes: the same robots, commands, and sensor noise (the
noise stream depends on the episode key only, not on the actions).

:func:`summarize` turns a :class:`Trace` into the report's metrics:

- ``rmse_vx``, ``rmse_vy`` (m/s), ``rmse_wz`` (rad/s), ``rmse_lin`` (of the velocity
  vector), over every control step of every episode, against the command in force;
  ``worst_rmse_lin`` and ``worst_rmse_wz``: the same over the worst single episode (one
  robot that spins away hides in the mean);
- for scripted (fixed-sequence) scenarios, the final pose error against the path the
  commands describe — ``drift_m`` and ``heading_drift_rad`` (mean over episodes); on a
  closed sequence that is the distance from the start;
- ``energy_j``: Σ|τ·ω|·dt per episode (mean over episodes), with the servos' torques and
  wheel rates sampled at every control step;
- ``saturated``: the fraction of wheel-steps with the torque at its limit;
- ``unstable``: physics resets (should be 0).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax import odometry
from mecanum_jax.env import MecanumEnv, baseline_policy
from mecanum_jax.scenarios import EpisodeBatch

PolicyApply = Callable[[Any, dict[str, jax.Array]], jax.Array]
METRICS = (
    "rmse_vx",
    "rmse_vy",
    "rmse_wz",
    "rmse_lin",
    "worst_rmse_lin",
    "worst_rmse_wz",
    "drift_m",
    "heading_drift_rad",
    "energy_j",
    "saturated",
    "unstable",
)


class Trace(NamedTuple):
    """A rollout, per episode and control step (leading axes E, T); numpy on the host."""

    command: Any  # (E, T, 3) command in force during the step
    twist: Any  # (E, T, 3) true body twist at the end of the step
    pose: Any  # (E, T, 3) world pose (x, y, yaw) at the end of the step
    start: Any  # (E, 3) pose before the first step
    energy_j: Any  # (E, T)
    saturated: Any  # (E, T)
    unstable: Any  # (E, T)
    qpos: Any  # (E, T, nq), for rendering


class Evaluator:
    """Rollouts of ``env`` under a learned policy (``apply(params, obs) -> action``) or the
    analytic baseline, compiled once per chunk shape.

    :meth:`run_many` plays many episode batches at once: they are concatenated along the
    episode axis (each episode with its own policy flag) and cut into chunks of at most
    ``max_batch`` robots, the last one padded, so a whole evaluation is a few calls of one
    compiled program. On a GPU one chunk holds everything; on CPU keep ``max_batch`` at 64
    (larger MJX batches deadlock jaxlib 0.10.2's CPU backend, see docs/benchmarks.md).
    """

    def __init__(self, env: MecanumEnv, apply: PolicyApply | None = None, max_batch: int = 64):
        if max_batch < 1:
            raise ValueError(f"max_batch = {max_batch}: must be >= 1")
        self.env = env
        self.apply = apply
        self.max_batch = max_batch
        self._baseline = baseline_policy(env)
        self._run = jax.jit(self._rollout)

    def _rollout(self, params: Any, use_baseline: jax.Array, batch: EpisodeBatch) -> Trace:
        env = self.env
        state = jax.vmap(env.reset_to)(batch.keys, batch.params, batch.latency, batch.noise_std)
        start = jax.vmap(env.robot.sensors)(state.pipeline_state).pose

        def step(s: Any, command: jax.Array) -> tuple[Any, Trace]:
            s = jax.vmap(env.set_command)(s, command)
            action, _ = self._baseline(s.obs, jax.random.PRNGKey(0))
            if self.apply is not None:
                with jax.numpy_rank_promotion("allow"):  # Brax's normalizer broadcasts
                    learned = self.apply(params, s.obs)
                action = jnp.where(use_baseline[:, None], action, learned)
            ns = jax.vmap(env.step)(s, action)
            sens = jax.vmap(env.robot.sensors)(ns.pipeline_state)
            m = ns.metrics
            out = Trace(
                command=command,
                twist=sens.twist,
                pose=sens.pose,
                start=None,
                energy_j=m["energy_j"],
                saturated=m["saturated"],
                unstable=m["unstable"],
                qpos=ns.pipeline_state.data.qpos,
            )
            return ns, out

        _, trace = jax.lax.scan(step, state, jnp.swapaxes(batch.commands, 0, 1))
        trace = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), trace)
        return trace._replace(start=start)

    def run(self, batch: EpisodeBatch, params: Any = None, baseline: bool = False) -> Trace:
        """Play ``batch``; ``baseline=True`` (or no learned policy) plays the baseline."""
        return self.run_many([(batch, baseline)], params)[0]

    def run_many(
        self,
        jobs: Sequence[tuple[EpisodeBatch, bool]],
        params: Any = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> list[Trace]:
        """Play every ``(batch, baseline?)`` job; batches of equal length run together.

        ``progress(done, total)`` is called after each compiled chunk.
        """
        if self.apply is None and not all(b for _, b in jobs):
            raise ValueError("this Evaluator has no learned policy: pass baseline=True")
        results: list[Trace | None] = [None] * len(jobs)
        by_length: dict[int, list[int]] = {}
        for i, (batch, _) in enumerate(jobs):
            by_length.setdefault(int(batch.commands.shape[1]), []).append(i)
        chunks = []
        for idx in by_length.values():
            merged = jax.tree.map(
                lambda *xs: np.concatenate([np.asarray(x) for x in xs]),
                *[jobs[i][0] for i in idx],
            )
            flags = np.concatenate([np.full(len(jobs[i][0].keys), jobs[i][1]) for i in idx])
            flags |= self.apply is None
            total = len(flags)
            size = min(self.max_batch, total)
            for lo in range(0, total, size):
                chunks.append((idx, merged, flags, total, lo, size))
        outputs: dict[tuple[int, ...], list[Trace]] = {}
        for n, (idx, merged, flags, total, lo, size) in enumerate(chunks):
            take = (np.arange(lo, lo + size) % total) if lo + size > total else slice(lo, lo + size)
            part = jax.tree.map(lambda x, t=take: x[t], merged)
            out = self._run(params, jnp.asarray(flags[take]), part)
            keep = min(size, total - lo)
            outputs.setdefault(tuple(idx), []).append(Trace(*(np.asarray(x)[:keep] for x in out)))
            if progress is not None:
                progress(n + 1, len(chunks))
        for idx_t, parts in outputs.items():
            whole = Trace(*(np.concatenate(xs) for xs in zip(*parts, strict=True)))
            lo = 0
            for i in idx_t:
                e = len(jobs[i][0].keys)
                results[i] = Trace(*(x[lo : lo + e] for x in whole))
                lo += e
        return [r for r in results if r is not None]


def relative_poses(trace: Trace) -> np.ndarray:
    """Poses (E, T, 3) in each episode's start frame (x forward, y left, yaw from start)."""
    start = trace.start[:, None, :]
    d = trace.pose[..., :2] - start[..., :2]
    c, s = np.cos(start[..., 2]), np.sin(start[..., 2])
    x = c * d[..., 0] + s * d[..., 1]
    y = -s * d[..., 0] + c * d[..., 1]
    yaw = _wrap(trace.pose[..., 2] - start[..., 2])
    return np.stack([x, y, yaw], axis=-1)


def intended_poses(commands: np.ndarray, dt: float) -> np.ndarray:
    """The path (E, T, 3) that the commands (E, T, 3) describe from the start, exactly on SE(2)."""
    path = odometry.integrate_twists(
        jnp.zeros((commands.shape[0], 3)), jnp.swapaxes(jnp.asarray(commands), 0, 1), dt
    )
    return np.swapaxes(np.asarray(path), 0, 1)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def summarize(trace: Trace, dt: float, scripted: bool) -> dict[str, float | None]:
    """The report's metrics of one rollout (see the module docstring)."""
    err = trace.twist - trace.command
    out: dict[str, float | None] = {
        "rmse_vx": float(np.sqrt(np.mean(err[..., 0] ** 2))),
        "rmse_vy": float(np.sqrt(np.mean(err[..., 1] ** 2))),
        "rmse_wz": float(np.sqrt(np.mean(err[..., 2] ** 2))),
        "rmse_lin": float(np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2))),
        "worst_rmse_lin": float(np.max(np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, 1)))),
        "worst_rmse_wz": float(np.max(np.sqrt(np.mean(err[..., 2] ** 2, axis=1)))),
        "drift_m": None,
        "heading_drift_rad": None,
        "energy_j": float(np.mean(np.sum(trace.energy_j, axis=1))),
        "saturated": float(np.mean(trace.saturated)),
        "unstable": float(np.sum(trace.unstable > 0)),
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = float(np.mean(np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1)))
        out["heading_drift_rad"] = float(np.mean(np.abs(_wrap(final[:, 2] - goal[:, 2]))))
    return out


def per_episode(trace: Trace, dt: float, scripted: bool) -> dict[str, list[float]]:
    """Per-episode RMSE of v and ωz (and final drift of scripted scenarios), for scripts
    that look for the episodes where a policy fails."""
    err = trace.twist - trace.command
    out = {
        "rmse_lin": np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, axis=1)).tolist(),
        "rmse_wz": np.sqrt(np.mean(err[..., 2] ** 2, axis=1)).tolist(),
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1).tolist()
    return out


# --- plots (matplotlib) ---------------------------------------------------------------------

_COLORS = {"policy": "tab:blue", "baseline": "tab:orange", "command": "black"}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_twist(
    traces: dict[str, Trace], dt: float, title: str, out: Path, episode: int = 0
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
    traces: dict[str, dict[str, Trace]],
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
    """Bar chart of RMSE of v (m/s) and ωz (rad/s) per scenario, every policy side by side."""
    plt = _pyplot()
    names = list(results)
    whos: list[str] = sorted({w for r in results.values() for w in r}, key=_policy_order)
    fig, axes = plt.subplots(1, 2, figsize=(min(14.0, 4 + 1.2 * len(names)), 3.8))
    x = np.arange(len(names))
    width = 0.8 / len(whos)
    for ax, key, label in zip(
        axes, ("rmse_lin", "rmse_wz"), ("RMSE v (m/s)", "RMSE ωz (rad/s)"), strict=True
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
    fig.suptitle("tracking error per scenario", fontsize=10)
    return _save(fig, out)


def _policy_order(who: str) -> int:
    return {"policy": 0, "baseline": 1}.get(who, 2)


def _save(fig: Any, out: Path) -> Path:
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


__all__ = [
    "METRICS",
    "Evaluator",
    "Trace",
    "intended_poses",
    "per_episode",
    "plot_errors",
    "plot_trajectories",
    "plot_twist",
    "relative_poses",
    "side_by_side",
    "summarize",
]
