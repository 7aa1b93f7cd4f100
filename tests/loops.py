"""Shared test helpers: exported policies of a task without a trained network."""

import numpy as np

from mecanum_jax.deploy.policy import NumpyPolicy
from mecanum_jax.deploy.write import task_meta
from mecanum_jax.task import MecanumEnv


def network_free(env: MecanumEnv) -> NumpyPolicy:
    """An export of ``env``'s task with no hidden layer and an identity normalizer (the
    action is tanh of the first observation entries): the control loop's half, for tasks
    no shipped policy has."""
    size = env.observation_size["state"][0]
    meta = {**task_meta(env), "activation": "tanh"}
    return NumpyPolicy([], np.zeros(size), np.ones(size), meta)


def constant(env: MecanumEnv, bias: np.ndarray, **meta: object) -> NumpyPolicy:
    """An export of ``env``'s task whose network answers ``tanh(bias)`` to any observation
    (one layer of zero weights, an identity normalizer); ``meta`` overrides export fields."""
    size = env.observation_size["state"][0]
    layers = [(np.zeros((size, env.action_size), np.float32), np.asarray(bias, np.float32))]
    meta = {**task_meta(env), "activation": "tanh", **meta}
    return NumpyPolicy(layers, np.zeros(size, np.float32), np.ones(size, np.float32), meta)
