"""The trainer's periodic evaluation, on :mod:`mecanum_jax.evaluation.rollout`.

Each seed's deterministic policy and the analytic baseline play the same held-out episodes
of the training task (:func:`mecanum_jax.evaluation.scenarios.task_scenarios`: ``randomized`` and
``nominal``, from ``run.eval_seed``), in the physics model ``run.eval_fidelity`` (the fast
training model by default, or the reference roller model), through the rollout, the metrics
and the paired intervals that ``mecanum-eval`` uses. A policy *beats* the baseline when, on
``randomized``, the paired 95% interval of its steady-state error ratio lies below 1 for
the velocity and for the yaw rate (:data:`BEAT_METRICS`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import jax
import numpy as np

from mecanum_jax.evaluation import episodes, metrics, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.evaluation.compare import TRAINING_COMPARED, ratios
from mecanum_jax.evaluation.traces import summarize, trace_parts
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import fidelity as fid
from mecanum_jax.task.env import MecanumEnv
from train.config import TrainConfig

if TYPE_CHECKING:
    from brax.training.agents.ppo.networks import PPONetworks
    from brax.training.types import PolicyParams
    from jax.stages import Lowered, Wrapped

BEAT_SCENARIO = "randomized"
BEAT_METRICS = ("ss_lin", "ss_wz")
N_BOOT = 1000
"""Bootstrap resamples of the logged ratios' intervals."""
Comparison = dict[str, dict[str, dict[str, float | str]]]
"""Per scenario, per metric, a ratio's fields (``compare.ratios``)."""


def deterministic_apply(networks: PPONetworks) -> evaluation.PolicyApply:
    """``apply((normalizer, policy params), obs) -> action``: the policy's mode."""

    def apply(params: PolicyParams, obs: dict[str, jax.Array]) -> jax.Array:
        logits = networks.policy_network.apply(params[0], params[1], obs)
        return networks.parametric_action_distribution.mode(logits)

    return apply


@dataclasses.dataclass
class Result:
    """One controller's evaluation: per scenario, the metrics and their per-episode parts."""

    values: dict[str, dict[str, float | None]]
    parts: dict[str, dict[str, metrics.Part]]


class PeriodicEvaluation:
    """The held-out evaluation a training run repeats (see the module docstring)."""

    def __init__(self, cfg: TrainConfig, env: MecanumEnv, networks: PPONetworks, on_gpu: bool):
        r = cfg.run
        seconds = r.eval_episode_length * cfg.env.control_dt
        self.scenarios = scenarios.task_scenarios(cfg.env, r.num_eval_envs, seconds, r.eval_seed)
        # the training environment serves unless the scenarios need more latency history
        eval_cfg = episodes.eval_env_config(cfg.env, self.scenarios)
        # one chunk on a GPU; on CPU 64 fast or 4 reference robots (larger MJX batches
        # deadlock its backend: fidelity.CPU_EVAL_BATCH)
        fidelity = fid.check_fidelity(r.eval_fidelity, "run.eval_fidelity")
        max_batch = 2 * r.num_eval_envs if on_gpu else fid.cpu_batch(fidelity)
        robots = max_batch * len(r.seeds)
        too_few = env.robot.impl == "warp" and env.robot.robots < robots  # contact buffer
        if eval_cfg != env.config or too_few or fidelity != env.robot.fidelity:
            env = MecanumEnv(eval_cfg, robots=robots, fidelity=fidelity)
        self.env = env
        self.evaluator = evaluation.Evaluator(self.env, deterministic_apply(networks), max_batch)
        self._jacobian = np.asarray(kinematics.jacobian(self.env.geometry))
        self._batches: dict[str, episodes.EpisodeBatch] | None = None

    def store_programs(self, wrap: Callable[[Wrapped], Wrapped]) -> None:
        """Run the rollout through ``wrap(jitted rollout)`` (train/loop/warm_start.py)."""
        self.evaluator._run = wrap(self.evaluator._run)

    def draw(self) -> dict[str, episodes.EpisodeBatch]:
        """Every scenario's episodes, drawn now (train/loop/warm_start.py keeps them)."""
        return {s.name: episodes.prepare(self.env, s) for s in self.scenarios.scenarios}

    def batches(self) -> dict[str, episodes.EpisodeBatch]:
        """The episodes, drawn once (the same for every evaluation of the run)."""
        if self._batches is None:
            self._batches = self.draw()
        return self._batches

    def play(self, who: str, params: object = None) -> Result:
        """``who`` (``"policy"`` with ``params = (normalizer, policy params)``, or a
        reference's name) on every scenario."""
        batches = self.batches()
        traces = self.evaluator.run_many([(b, who) for b in batches.values()], params)
        dt = self.env.config.control_dt
        values, parts = {}, {}
        for name, trace in zip(batches, traces, strict=True):
            parts[name] = trace_parts(trace, self._jacobian, dt)
            values[name] = summarize(trace, dt, False, self._jacobian, parts=parts[name])
        return Result(values, parts)

    def trace(self, who: str, params: object = None) -> list[Lowered]:
        """Trace and lower what :meth:`play` would run, running nothing; the lowered
        programs (``Evaluator.trace_many``)."""
        return self.evaluator.trace_many([(b, who) for b in self.batches().values()], params)

    def policies(self, params: PolicyParams, n_seeds: int) -> list[Result]:
        """Each seed's deterministic policy; ``params`` has a leading seed axis."""
        return [
            self.play("policy", jax.tree.map(lambda x, i=i: x[i], params)) for i in range(n_seeds)
        ]


def compare(policy: Result, baseline: Result) -> Comparison:
    """Per scenario, policy / baseline ratios of
    :data:`~mecanum_jax.evaluation.compare.TRAINING_COMPARED` with paired intervals."""
    return {
        name: ratios(parts, baseline.parts[name], TRAINING_COMPARED, N_BOOT)
        for name, parts in policy.parts.items()
    }


def beats(comparison: Mapping[str, Mapping[str, Mapping[str, float | str]]]) -> bool:
    """Whether the interval of every :data:`BEAT_METRICS` ratio on :data:`BEAT_SCENARIO`
    lies entirely below 1 (a tie or an undefined ratio is no win)."""
    scenario = comparison.get(BEAT_SCENARIO, {})
    return all(scenario.get(k, {}).get("verdict") == "better" for k in BEAT_METRICS)


__all__ = [
    "BEAT_METRICS",
    "PeriodicEvaluation",
    "Result",
    "beats",
    "compare",
    "deterministic_apply",
]
