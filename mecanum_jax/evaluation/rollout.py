"""Batched evaluation: play a scenario's episodes with a policy and the reference controllers.

:class:`Evaluator` compiles **one** rollout program per episode-batch shape: a scenario's
physics, latency, noise and command schedule are arrays (:class:`~mecanum_jax.evaluation.scenarios.
EpisodeBatch`), and the learned policy's parameters and a per-episode controller code
(:func:`who_code`: the policy or one of ``env.REFERENCES``) are arguments, so every
scenario of the same size and every controller share the compilation. All controllers see
the same episodes: the same robots, commands, and sensor noise (the noise stream depends on
the episode key only, not on the actions).

:func:`summarize` turns a :class:`Trace` into the report's metrics
(:mod:`mecanum_jax.evaluation.metrics` defines them and their paired comparison):

- ``rmse_vx``, ``rmse_vy`` (m/s), ``rmse_wz`` (rad/s), ``rmse_lin`` (of the velocity
  vector), over every control step of every episode, against the command in force;
  ``worst_rmse_lin`` and ``worst_rmse_wz``: the same over the worst single episode;
- ``ss_*``: steady-state error against the nearest feasible twist of the true robot;
  ``settle_lin_s``, ``settle_wz_s``: settling time after command steps;
- for scripted (fixed-sequence) scenarios, the final pose error against the path the
  commands describe — ``drift_m`` and ``heading_drift_rad`` (mean over episodes); on a
  closed sequence that is the distance from the start;
- ``energy_j``: Σ|τ·ω|·dt per episode (mean over episodes); ``energy_per_m`` per metre
  travelled; ``null_energy_j`` the part of it in the wheels' null space;
- ``saturated``: the fraction of wheel-steps with the torque at its limit;
- ``unstable``: physics resets (should be 0).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Generic, NamedTuple, TypeVar

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.training.types import PolicyParams

from mecanum_jax.evaluation import metrics
from mecanum_jax.evaluation.episodes import EpisodeBatch
from mecanum_jax.kinematics import odometry
from mecanum_jax.task import REFERENCES, MecanumEnv
from mecanum_jax.task.controller import task_info

if TYPE_CHECKING:
    import numpy.typing as npt
    from brax.envs.base import State

PolicyApply = Callable[[PolicyParams, dict[str, jax.Array]], jax.Array]
A = TypeVar("A", np.ndarray, jax.Array)
"""A :class:`Trace`'s arrays: NumPy on the host, JAX in the rollout program."""
METRICS = (
    "rmse_vx",
    "rmse_vy",
    "rmse_wz",
    "rmse_lin",
    "ss_vx",
    "ss_vy",
    "ss_wz",
    "ss_lin",
    "settle_lin_s",
    "settle_wz_s",
    "worst_rmse_lin",
    "worst_rmse_wz",
    "drift_m",
    "heading_drift_rad",
    "energy_j",
    "energy_per_m",
    "null_energy_j",
    "saturated",
    "unstable",
)


LEARNED = -1
"""The ``who`` code of the learned policy; references are their index in ``REFERENCES``."""


class Trace(NamedTuple, Generic[A]):
    """A rollout, per episode and control step (leading axes E, T); numpy on the host."""

    command: A  # (E, T, 3) command in force during the step
    target: A  # (E, T, 3) the command's nearest feasible twist for the true robot
    twist: A  # (E, T, 3) true body twist at the end of the step
    pose: A  # (E, T, 3) world pose (x, y, yaw) at the end of the step
    start: A  # (E, 3) pose before the first step
    energy_j: A  # (E, T)
    saturated: A  # (E, T)
    unstable: A  # (E, T)
    wheel_torque: A  # (E, T, n) N·m
    wheel_rate: A  # (E, T, n) rad/s
    qpos: A  # (E, T, nq), for rendering
    action: A | None = None  # (E, T, a) the action applied (after the filter); 0 for references


def who_code(who: str) -> int:
    """``"policy"`` → :data:`LEARNED`; a reference's name → its index in ``REFERENCES``."""
    if who == "policy":
        return LEARNED
    if who not in REFERENCES:
        raise ValueError(f"{who!r}: not a policy; expected 'policy' or one of {REFERENCES}")
    return REFERENCES.index(who)


class Evaluator:
    """Rollouts of ``env`` under a learned policy (``apply(params, obs) -> action``) or a
    reference controller (``REFERENCES``), compiled once per chunk shape.

    :meth:`run_many` plays many episode batches at once: they are concatenated along the
    episode axis (each episode with its own controller code) and cut into chunks of at most
    ``max_batch`` robots, the last one padded, so a whole evaluation is a few calls of one
    compiled program. On a GPU one chunk holds everything; on CPU keep ``max_batch`` at 64
    (``batching.CPU_CHUNK``: larger vmapped MJX batches deadlock jaxlib 0.10.2's CPU backend).
    """

    def __init__(self, env: MecanumEnv, apply: PolicyApply | None = None, max_batch: int = 64):
        if max_batch < 1:
            raise ValueError(f"max_batch = {max_batch}: must be >= 1")
        self.env = env
        self.apply = apply
        self.max_batch = max_batch
        self._run: jax.stages.Wrapped = jax.jit(self._rollout)

    def _feasible_targets(self, batch: EpisodeBatch) -> jax.Array:
        """(E, T, 3): each command's nearest feasible twist for the robot as it really is
        (its wheels' actual radii, the rate limits), in the reference controllers' metric."""
        return jax.vmap(self.env.feasible_target)(batch.commands, batch.params.radius_scale)

    def _rollout(
        self, params: object, who: jax.Array, batch: EpisodeBatch, gains: jax.Array
    ) -> Trace[jax.Array]:
        env = self.env
        state = jax.vmap(env.reset_to)(batch.keys, batch.params, batch.latency, batch.noise_std)
        info = task_info(state)
        info["feedback_gains"] = jnp.broadcast_to(gains, info["feedback_gains"].shape)
        state = state.replace(info=info)
        start = jax.vmap(env.robot.sensors)(state.pipeline_state).pose

        def step(s: State, command: jax.Array) -> tuple[State, dict[str, jax.Array]]:
            s = jax.vmap(env.set_command)(s, command)
            action = jnp.zeros((command.shape[0], env.action_size))
            if self.apply is not None:
                with jax.numpy_rank_promotion("allow"):  # Brax's normalizer broadcasts
                    action = self.apply(params, s.obs)
                # a reference applies no action: its trace (flicker) must not hold the
                # policy's, computed on the reference's trajectory
                action = jnp.where(jnp.expand_dims(jnp.asarray(who) < 0, -1), action, 0.0)
            ns = jax.vmap(env.step)(s, action, who)
            sens = jax.vmap(env.robot.sensors)(ns.pipeline_state)
            m = ns.metrics
            out = {  # the trace's fields of one step (the target and start are per episode)
                "command": command,
                "twist": sens.twist,
                "pose": sens.pose,
                "energy_j": m["energy_j"],
                "saturated": m["saturated"],
                "unstable": m["unstable"],
                "wheel_torque": sens.wheel_torque,
                "wheel_rate": sens.wheel_rate,
                "qpos": ns.pipeline_state.data.qpos,
                "action": ns.info["last_action"],
            }
            return ns, out

        _, steps = jax.lax.scan(step, state, jnp.swapaxes(batch.commands, 0, 1))
        steps = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), steps)
        return Trace(start=start, target=self._feasible_targets(batch), **steps)

    def run(
        self, batch: EpisodeBatch, params: object = None, who: str = "analytic"
    ) -> Trace[np.ndarray]:
        """Play ``batch`` with ``who`` (``"policy"`` or a reference's name)."""
        return self.run_many([(batch, who)], params)[0]

    def run_many(
        self,
        jobs: Sequence[tuple[EpisodeBatch, str]],
        params: object = None,
        progress: Callable[[int, int], None] | None = None,
        feedback_gains: npt.ArrayLike | None = None,
    ) -> list[Trace[np.ndarray]]:
        """Play every ``(batch, who)`` job; batches of equal length run together.

        ``who`` is ``"policy"`` or a reference's name (``REFERENCES``).
        ``progress(done, total)`` is called after each compiled chunk.
        ``feedback_gains``: ``(kp, ki, i_max)`` of the ``feedback`` controller (default: the
        environment's config); traced, so a gain sweep compiles once.
        """
        gains = self._gains(feedback_gains)
        chunks = self._chunks(jobs)
        results: list[Trace[np.ndarray] | None] = [None] * len(jobs)
        outputs: dict[tuple[int, ...], list[Trace[np.ndarray]]] = {}
        for n, (idx, part, flags, keep) in enumerate(chunks):
            out = self._run(params, jnp.asarray(flags), part, gains)
            outputs.setdefault(idx, []).append(Trace(*(np.asarray(x)[:keep] for x in out)))
            if progress is not None:
                progress(n + 1, len(chunks))
        for idx_t, parts in outputs.items():
            whole = Trace(*(np.concatenate(xs) for xs in zip(*parts, strict=True)))
            lo = 0
            for i in idx_t:
                e = len(jobs[i][0].keys)
                results[i] = jax.tree.map(lambda x, lo=lo, e=e: x[lo : lo + e], whole)
                lo += e
        return [r for r in results if r is not None]

    def trace_many(
        self, jobs: Sequence[tuple[EpisodeBatch, str]], params: object = None
    ) -> list[jax.stages.Lowered]:
        """Trace and lower the programs :meth:`run_many` would run for ``jobs``, running
        nothing, and return them (``jax.stages.Lowered``, one per distinct chunk shape); a
        later :meth:`run_many` of the same shapes reuses the trace, and the compilation of
        a returned program (train/loop/aot.py). MuJoCo Warp numbers its FFI calls in the
        order a process traces them, and the persistent compilation cache's keys hold those
        numbers, so a start must trace its programs in the order of another to find the
        other's compiled programs."""
        gains = self._gains(None)
        lowered: dict[tuple[tuple[int, ...], ...], jax.stages.Lowered] = {}
        for _, part, flags, _ in self._chunks(jobs):
            key = tuple(np.shape(x) for x in jax.tree.leaves((part, flags)))
            if key not in lowered:
                lowered[key] = self._run.lower(params, jnp.asarray(flags), part, gains)
        return list(lowered.values())

    def _gains(self, feedback_gains: npt.ArrayLike | None) -> jax.Array:
        gains = self.env.feedback_gains() if feedback_gains is None else feedback_gains
        return jnp.asarray(gains, jnp.float32)

    def _chunks(
        self, jobs: Sequence[tuple[EpisodeBatch, str]]
    ) -> list[tuple[tuple[int, ...], EpisodeBatch, np.ndarray, int]]:
        """The compiled calls of :meth:`run_many`: ``(job indices, episodes, controller
        codes, episodes kept)``, each of ``max_batch`` episodes at most; batches of equal
        length concatenated, the last chunk padded by wrapping round."""
        codes = [who_code(who) for _, who in jobs]
        if self.apply is None and LEARNED in codes:
            raise ValueError("this Evaluator has no learned policy: evaluate a reference")
        by_length: dict[int, list[int]] = {}
        for i, (batch, _) in enumerate(jobs):
            by_length.setdefault(int(batch.commands.shape[1]), []).append(i)
        chunks = []
        for idx in by_length.values():
            merged = jax.tree.map(
                lambda *xs: np.concatenate([np.asarray(x) for x in xs]),
                *[jobs[i][0] for i in idx],
            )
            flags = np.concatenate([np.full(len(jobs[i][0].keys), codes[i], np.int32) for i in idx])
            total = len(flags)
            size = min(self.max_batch, total)
            for lo in range(0, total, size):
                take = (
                    (np.arange(lo, lo + size) % total)
                    if lo + size > total
                    else slice(lo, lo + size)
                )
                part = jax.tree.map(lambda x, t=take: x[t], merged)
                chunks.append((tuple(idx), part, flags[take], min(size, total - lo)))
        return chunks


def relative_poses(trace: Trace[np.ndarray]) -> np.ndarray:
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


def trace_parts(
    trace: Trace[np.ndarray],
    jacobian: npt.ArrayLike,
    dt: float,
    cfg: metrics.MetricConfig | None = None,
) -> dict[str, metrics.Part]:
    """The per-episode metrics of a rollout (:func:`.metrics.episode_parts`), and the
    flicker of its actions where it has them (:func:`.metrics.flicker_part`)."""
    parts = metrics.episode_parts(
        trace.command,
        trace.target,
        trace.twist,
        trace.pose,
        trace.start,
        trace.energy_j,
        trace.saturated,
        trace.wheel_torque,
        trace.wheel_rate,
        np.asarray(jacobian),
        dt,
        cfg,
    )
    if trace.action is not None:
        parts["flicker"] = metrics.flicker_part(np.asarray(trace.action))
    return parts


def summarize(
    trace: Trace[np.ndarray],
    dt: float,
    scripted: bool,
    jacobian: npt.ArrayLike,
    cfg: metrics.MetricConfig | None = None,
    parts: dict[str, metrics.Part] | None = None,
) -> dict[str, float | None]:
    """The report's metrics of one rollout (see the module docstring); ``parts``: its
    :func:`trace_parts` if already computed."""
    err = trace.twist - trace.command
    parts = trace_parts(trace, jacobian, dt, cfg) if parts is None else parts
    out: dict[str, float | None] = metrics.summary(parts)
    out |= {
        "worst_rmse_lin": float(np.max(np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, 1)))),
        "worst_rmse_wz": float(np.max(np.sqrt(np.mean(err[..., 2] ** 2, axis=1)))),
        "drift_m": None,
        "heading_drift_rad": None,
        "unstable": float(np.sum(trace.unstable > 0)),
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = float(np.mean(np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1)))
        out["heading_drift_rad"] = float(np.mean(np.abs(_wrap(final[:, 2] - goal[:, 2]))))
    return out


def drift_parts(trace: Trace[np.ndarray], dt: float) -> dict[str, metrics.Part]:
    """Final position and heading drift of a scripted rollout, per episode."""
    final = relative_poses(trace)[:, -1]
    goal = intended_poses(trace.command, dt)[:, -1]
    ones = np.ones(len(final))
    return {
        "drift_m": metrics.Part(np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1), ones, "mean"),
        "heading_drift_rad": metrics.Part(np.abs(_wrap(final[:, 2] - goal[:, 2])), ones, "mean"),
    }


def per_episode(
    trace: Trace[np.ndarray], dt: float, scripted: bool, cfg: metrics.MetricConfig | None = None
) -> dict[str, list[float | None]]:
    """Per-episode RMSE of v and ωz, steady-state error of v and ωz (``None`` for an episode
    without steady steps) and its count of steady steps (the summary's ``ss_*`` pool them,
    weighted by that count), and the final drift of scripted scenarios: for scripts that
    look for the episodes where a policy fails, or where two devices differ."""
    err = trace.twist - trace.command
    parts = metrics.tracking_parts(
        trace.command, trace.target, trace.twist, dt, cfg or metrics.MetricConfig()
    )
    count = parts["ss_lin"].den

    def steady(name: str) -> list[float | None]:
        num = parts[name].num
        return [float(np.sqrt(n / c)) if c > 0 else None for n, c in zip(num, count, strict=True)]

    out: dict[str, list[float | None]] = {
        "rmse_lin": np.sqrt(np.mean(err[..., 0] ** 2 + err[..., 1] ** 2, axis=1)).tolist(),
        "rmse_wz": np.sqrt(np.mean(err[..., 2] ** 2, axis=1)).tolist(),
        "ss_lin": steady("ss_lin"),
        "ss_wz": steady("ss_wz"),
        "steady_steps": [float(c) for c in count],
    }
    if scripted:
        final = relative_poses(trace)[:, -1]
        goal = intended_poses(trace.command, dt)[:, -1]
        out["drift_m"] = np.linalg.norm(final[:, :2] - goal[:, :2], axis=-1).tolist()
    return out


__all__ = [
    "LEARNED",
    "METRICS",
    "Evaluator",
    "Trace",
    "drift_parts",
    "intended_poses",
    "per_episode",
    "relative_poses",
    "summarize",
    "trace_parts",
    "who_code",
]
