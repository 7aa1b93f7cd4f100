"""scripts/identifiability.py: the predictors, the features and the rollout's labels."""

from __future__ import annotations

import numpy as np
import pytest

from scripts.identifiability import features, fit_ridge, main, rms, rollout


def test_ridge_recovers_a_linear_map_and_rms_splits_the_axes():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4000, 5))
    w = rng.normal(size=(5, 3))
    y = x @ w + np.array([0.1, -0.2, 0.3])
    predict = fit_ridge(x, y, lam=1e-9)
    np.testing.assert_allclose(predict(x[:10]), y[:10], atol=1e-6)
    assert rms(np.array([[3.0, 4.0, 2.0], [3.0, 4.0, -2.0]])) == (5.0, 2.0)


@pytest.mark.full
def test_rollout_labels_feedbacks_next_error_on_steady_commands_within_reach():
    import jax

    from mecanum_jax.kinematics import limits
    from mecanum_jax.task import EnvConfig, MecanumEnv

    cfg = EnvConfig(obs_history=2, physics_impl="jax")
    env = MecanumEnv(cfg, robots=64)
    d = rollout(env, jax.random.PRNGKey(1), 64, 40)
    c = env.constants
    assert d["error"].shape == (64, 40, 3)
    assert d["steady"].shape == (64, 40)
    cmd = d["state"][..., :3] * np.asarray(c.command_scale)  # the command comes first
    load = np.asarray(limits.saturation(c.geometry, cmd, c.max_rates))
    assert not np.any(d["steady"][:, :25])  # 0.5 s into the episode at the earliest
    assert np.all(load[d["steady"]] <= 1.0 + 1e-5)
    assert np.any(d["steady"])
    n = c.n_wheels
    base = sum(size for name, size in env.layout if name != "sensor_history")
    assert features(d, env, 0).shape[-1] == base
    assert features(d, env, 2).shape[-1] == base + 2 * (n + 1 + 3 + 3)
    assert features(d, env, None).shape[-1] == base + d["params"].shape[-1]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--robots", "10"], "--robots = 10"),
        (["--steps", "5"], "--steps = 5"),
        (["--frames", "60"], "env.obs_history = 60"),
        (["--config", "nosuch"], "config = 'nosuch'"),
    ],
)
def test_bad_arguments_name_the_field_and_value(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
