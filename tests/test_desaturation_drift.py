"""scripts/desaturation_drift.py: the drift a desaturation alone leaves on a scripted path."""

from __future__ import annotations

import numpy as np
import pytest

from mecanum_jax.evaluation import episodes, scenarios
from mecanum_jax.kinematics import limits
from mecanum_jax.task import MecanumEnv
from scripts.desaturation_drift import desaturations, drifts, main


@pytest.fixture(scope="module")
def stress():
    from train.config_loading import load_train_config

    cfg = load_train_config("gpu").env
    sets = scenarios.load_scenarios("stress").select(["fast_slalom", "short_bursts"], 2)
    env = MecanumEnv(episodes.eval_env_config(cfg, sets))
    cmds = {sc.name: np.asarray(episodes.prepare(env, sc).commands) for sc in sets.scenarios}
    return env, cmds, cfg.control_dt


def test_beyond_reach_each_desaturation_is_feasible_and_leaves_its_own_drift(stress):
    env, cmds, dt = stress
    c = env.constants
    for name, f in desaturations(env).items():
        twists = f(cmds["fast_slalom"])
        frac = 1.0 - env.config.feedback.margin if name.endswith("%") else 1.0
        sat = np.asarray(limits.saturation(c.geometry, twists, np.asarray(c.max_rates) * frac))
        assert np.all(sat <= 1.0 + 1e-4), name
    d = drifts(env, cmds["fast_slalom"], dt)
    assert set(d) == {"uniform", "nearest", "uniform at 95%", "nearest at 95%"}
    assert all(v > 0.1 for v in d.values()), d  # the command is out of reach
    assert d["uniform at 95%"] > d["uniform"], d  # less speed, less of the path


def test_within_reach_nothing_is_desaturated(stress):
    env, cmds, dt = stress
    assert drifts(env, cmds["short_bursts"], dt) == pytest.approx(
        dict.fromkeys(desaturations(env), 0.0), abs=1e-6
    )


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--episodes", "0"], "--episodes = 0"),
        (["--scenarios", "nosuch"], "scenarios = 'nosuch'"),
        (["--only", "nosuch"], "scenario 'nosuch'"),
        (["--config", "nosuch"], "config = 'nosuch'"),
    ],
)
def test_refuses_bad_input_naming_it(argv, named, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert named in capsys.readouterr().err
