"""A shared test helper: an exported policy's control loop without its network."""

import numpy as np

from mecanum_jax.deploy.policy import NumpyPolicy
from mecanum_jax.task import MecanumEnv
from train.cli.export import task_meta


def network_free(env: MecanumEnv) -> NumpyPolicy:
    """An export of ``env``'s task with no hidden layer and an identity normalizer (the
    action is tanh of the first observation entries): the control loop's half, for tasks
    no shipped policy has."""
    size = env.observation_size["state"][0]
    meta = {**task_meta(env), "activation": "tanh"}
    return NumpyPolicy([], np.zeros(size), np.ones(size), meta)
