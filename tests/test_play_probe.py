"""scripts/play_probe.py: a trained policy's task changed at play time, bad input refused."""

from __future__ import annotations

from pathlib import Path

import pytest

import mecanum_jax.task.config as task_config
import train.config_loading as config_loading
from scripts import play_probe

MODEL = Path(__file__).resolve().parents[1] / "models" / "o_rectangle"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["bogus=1", "--", "m"], "'bogus=1': expected FIELD=VALUE"),
        (["commands=1", "--", "m"], "'commands=1': expected FIELD=VALUE"),
        (["feedback.bogus=1", "--", "m"], "'feedback.bogus=1': expected FIELD=VALUE"),
        (["feedback.margin=1.5", "--", "m"], "env.feedback.margin = 1.5: must be in [0, 1)"),
        (["residual_deadband", "--", "m"], "'residual_deadband': expected FIELD=VALUE"),
        (["residual_deadband=abc", "--", "m"], "env.residual_deadband = 'abc': expected a number"),
    ],
)
def test_bad_changes_are_refused_naming_them(argv, message, capsys):
    assert play_probe.main(argv) == 2
    assert message in capsys.readouterr().err


def test_the_restored_policy_plays_the_changed_task(monkeypatch):
    """The change lands on top of the model's own ``played_with`` (the shipped model plays
    its network's deadband at 0.01), in the checkpoint's config and config.json alike."""
    from train.cli import evaluate
    from train.cli.eval_target import check_config_task
    from train.learner.policy import restore_policy

    monkeypatch.setattr(config_loading, "parse_train_config", config_loading.parse_train_config)
    monkeypatch.setattr(task_config, "played_with", task_config.played_with)
    assert restore_policy(MODEL).cfg.env.residual_deadband == 0.01  # unchanged, as shipped
    seen = []

    def fake_main(argv):
        restored = restore_policy(MODEL)
        check_config_task(restored)  # config.json read with the same change
        seen.append((argv, restored.cfg.env.residual_deadband))
        return 0

    monkeypatch.setattr(evaluate, "main", fake_main)
    assert play_probe.main(["residual_deadband=0.02", "--", str(MODEL), "--no-plots"]) == 0
    assert seen == [([str(MODEL), "--no-plots"], 0.02)]


def test_a_sections_field_is_changed_too(monkeypatch):
    from train.cli import evaluate
    from train.learner.policy import restore_policy

    monkeypatch.setattr(config_loading, "parse_train_config", config_loading.parse_train_config)
    monkeypatch.setattr(task_config, "played_with", task_config.played_with)
    seen = []
    monkeypatch.setattr(
        evaluate, "main", lambda argv: seen.append(restore_policy(MODEL).cfg.env.feedback) or 0
    )
    assert play_probe.main(["feedback.margin=0.05", "--", str(MODEL)]) == 0
    assert seen[0].margin == 0.05
    assert seen[0].hold_s == 0.4  # the rest of the section kept
