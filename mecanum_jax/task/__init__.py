"""The velocity-tracking task on the MJX robot.

- :mod:`.env`: the Brax environment (:class:`MecanumEnv`) and its batched training form;
- :mod:`.config`: :class:`EnvConfig`, the task's settings;
- :mod:`.commands`, :mod:`.randomization`, :mod:`.observations`, :mod:`.reward`: its parts;
- :mod:`.references`: the reference controllers (``analytic``, the baseline, among them);
- :mod:`.constants`: :class:`~.constants.RobotConstants`, what those parts know of the robot;
- :mod:`.shapes`: :class:`~.shapes.TaskShapes`, the task as its policy sees it, without physics.

The settings and the task's parts import eagerly; the environment (MJX, Brax) on first use.
"""

from typing import TYPE_CHECKING

from mecanum_jax._lazy import exports
from mecanum_jax.task.commands import CommandConfig
from mecanum_jax.task.config import EnvConfig
from mecanum_jax.task.constants import RobotConstants
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.randomization import RandomizationConfig
from mecanum_jax.task.references import REFERENCES, FeedbackConfig, baseline_policy
from mecanum_jax.task.reward import REWARD_TERMS, RewardConfig, reward_terms, scaled_reward_terms

if TYPE_CHECKING:
    from mecanum_jax.task.env import MecanumEnv, TrainingEnv

__getattr__, __dir__ = exports(__name__, {"MecanumEnv": ".env", "TrainingEnv": ".env"})

__all__ = [
    "REFERENCES",
    "REWARD_TERMS",
    "CommandConfig",
    "EnvConfig",
    "FeedbackConfig",
    "MecanumEnv",
    "NoiseConfig",
    "RandomizationConfig",
    "RewardConfig",
    "RobotConstants",
    "TrainingEnv",
    "baseline_policy",
    "reward_terms",
    "scaled_reward_terms",
]
