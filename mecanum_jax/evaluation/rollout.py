"""Batched evaluation: play a scenario's episodes with a policy and the reference controllers.

:class:`Evaluator` compiles **one** rollout program per episode-batch shape: a scenario's
physics, latency, noise and command schedule are arrays (:class:`~mecanum_jax.evaluation.scenarios.
EpisodeBatch`), and the learned policy's parameters and a per-episode controller code
(:func:`who_code`: the policy or one of ``env.REFERENCES``) are arguments, so every
scenario of the same size and every controller share the compilation. All controllers see
the same episodes: the same robots, commands, and sensor noise (the noise stream depends on
the episode key only, not on the actions).

Each run returns a :class:`~mecanum_jax.evaluation.traces.Trace` per job;
:mod:`mecanum_jax.evaluation.traces` turns it into the report's metrics.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.training.types import PolicyParams

from mecanum_jax.evaluation.episodes import EpisodeBatch
from mecanum_jax.evaluation.traces import Trace
from mecanum_jax.sim.batching import guard_rows
from mecanum_jax.task import REFERENCES, MecanumEnv
from mecanum_jax.task.controller import task_info

if TYPE_CHECKING:
    import numpy.typing as npt
    from brax.envs.base import State

PolicyApply = Callable[[PolicyParams, dict[str, jax.Array]], jax.Array]


LEARNED = -1
"""The ``who`` code of the learned policy; references are their index in ``REFERENCES``."""


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
    (``batching.CPU_CHUNK``: larger vmapped MJX batches deadlock jaxlib 0.10.2's CPU backend),
    and each chunk of fast robots plays ``batching.CPU_GUARD_ROWS`` more, wrapped round and
    dropped, so that an episode's figures do not depend on its row or its set.
    """

    def __init__(self, env: MecanumEnv, apply: PolicyApply | None = None, max_batch: int = 64):
        if max_batch < 1:
            raise ValueError(f"max_batch = {max_batch}: must be >= 1")
        self.env = env
        self.apply = apply
        self.max_batch = max_batch
        self.guard = guard_rows(env.robot.fidelity, env.robot.impl)
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
        length concatenated, the last chunk padded by wrapping round, and each followed by
        :attr:`guard` rows, wrapped round too, that are played and dropped."""
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
                end = lo + size + self.guard
                take = np.arange(lo, end) % total if end > total else slice(lo, end)
                part = jax.tree.map(lambda x, t=take: x[t], merged)
                chunks.append((tuple(idx), part, flags[take], min(size, total - lo)))
        return chunks


__all__ = ["LEARNED", "Evaluator", "who_code"]
