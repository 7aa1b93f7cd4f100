"""Evaluating controllers: scenarios (:mod:`.scenarios`) and their episodes as arrays
(:mod:`.episodes`), batched rollouts (:mod:`.rollout`), their traces' figures
(:mod:`.traces`) and plots (:mod:`.plots`), tracking metrics and paired statistics
(:mod:`.metrics`), one controller's ratios to another's and its wins, ties and losses
(:mod:`.compare`), and velocity spaces of the drives (:mod:`.velocity_space`).

The metrics import eagerly (NumPy only); the names that need the environment import on
first use.
"""

from typing import TYPE_CHECKING

from mecanum_jax._lazy import exports
from mecanum_jax.evaluation.metrics import Comparison, MetricConfig, paired_ratio, verdict

if TYPE_CHECKING:
    from mecanum_jax.evaluation.rollout import Evaluator
    from mecanum_jax.evaluation.scenarios import Scenario, ScenarioSet, load_scenarios
    from mecanum_jax.evaluation.traces import Trace

__getattr__, __dir__ = exports(
    __name__,
    {
        "Evaluator": ".rollout",
        "Trace": ".traces",
        "Scenario": ".scenarios",
        "ScenarioSet": ".scenarios",
        "load_scenarios": ".scenarios",
    },
)

__all__ = [
    "Comparison",
    "Evaluator",
    "MetricConfig",
    "Scenario",
    "ScenarioSet",
    "Trace",
    "load_scenarios",
    "paired_ratio",
    "verdict",
]
