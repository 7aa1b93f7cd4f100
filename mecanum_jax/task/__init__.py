"""The velocity-tracking task on the MJX robot (:mod:`.env`): its configuration, the
environment, Brax's training wrapper, and the reference controllers."""

from mecanum_jax.task.env import (
    REFERENCES,
    REWARD_TERMS,
    EnvConfig,
    MecanumEnv,
    TrainingEnv,
    baseline_policy,
    load_env_config,
)

__all__ = [
    "REFERENCES",
    "REWARD_TERMS",
    "EnvConfig",
    "MecanumEnv",
    "TrainingEnv",
    "baseline_policy",
    "load_env_config",
]
