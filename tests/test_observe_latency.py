"""``env.observe_latency``: the policy observes its observation latency in control steps,
and the robot-side loop, told the robot's delay, builds the same observation."""

from __future__ import annotations

import numpy as np
import pytest
from loops import network_free
from test_deploy_loop import _lockstep

from mecanum_jax.deploy import load, save
from mecanum_jax.deploy.loop import Controller
from mecanum_jax.task import EnvConfig, MecanumEnv, RandomizationConfig
from mecanum_jax.task import observations as obs_
from train.cli.export import task_meta


def test_the_latency_comes_after_the_integrators_and_before_the_history():
    layout = obs_.policy_layout(4, 3, True, True, history=2, latency=True)
    names = [name for name, _ in layout]
    assert names[-4:] == [
        "yaw_error_integral",
        "feedback_integral",
        "latency_steps",
        "sensor_history",
    ]
    assert dict(layout)["latency_steps"] == 1
    assert "latency_steps" not in dict(obs_.policy_layout(4, 3, True, True, history=2))


@pytest.fixture(scope="module")
def env():
    rand = RandomizationConfig(enabled=True, latency_steps=(0, 2))
    cfg = EnvConfig(
        residual_space="twist", residual_base="feedback", observe_latency=True, randomization=rand
    )
    return MecanumEnv(cfg)


def test_the_export_says_so_and_the_loop_needs_the_delay(env, tmp_path):
    """The layout entry and ``meta["observe_latency"]`` travel in the export; a loop not
    told the delay stops at its first tick naming ``latency_steps``, as does a delay out
    of range, and a loop told it observes it."""
    assert task_meta(env)["observe_latency"] is True
    assert ("latency_steps", 1) in env.layout
    policy = network_free(env)
    path = save(tmp_path / "policy.npz", policy.layers, policy.mean, policy.std, policy.meta)
    reading = (np.zeros(3), np.zeros(4), 0.0, np.asarray([0.0, 0.0, 9.81]))
    with pytest.raises(ValueError, match=r"latency_steps = None"):
        Controller.load(path).step(*reading)
    with pytest.raises(ValueError, match=r"latency_steps = 11"):
        Controller.load(path, latency_steps=11).step(*reading)
    ctrl = Controller.load(path, latency_steps=2)
    ctrl.step(*reading)
    assert ctrl.observation is not None
    assert ctrl.observation[load(path).entry("latency_steps")] == 2.0


@pytest.mark.full  # the environment's step, unjitted, tick by tick
def test_the_loop_observes_the_latency_as_the_environment(env):
    """Two periods of latency, noisy readings, the command changing: the loop told the
    delay builds the environment's observation at every tick; one told 0 does not."""
    commands = np.repeat(np.array([[0.3, 0.0, 0.5], [0.0, -0.4, -1.5]], np.float32), 6, 0)
    policy = network_free(env)
    obs_err, set_err, _ = _lockstep(env, Controller(policy, latency_steps=2), commands, 2)
    assert obs_err < 1e-5
    assert set_err < 1e-3
    wrong, _, _ = _lockstep(env, Controller(policy, latency_steps=0), commands, 2)
    assert wrong > 0.5
