"""Restoring a trained policy (train/learner/policy.py): the shipped model restores and plays
the task its files state, restoring builds no model, a model directory evaluates its
packaged epoch, and a model's ``played_with`` is checked and kept."""

import dataclasses
import json
import re
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest
from tasks import WHEEL

from mecanum_jax.task import EnvConfig
from mecanum_jax.task.env import MecanumEnv
from mecanum_jax.task.shapes import task_shapes
from train.learner.policy import PROVENANCE, check_compatible, restore_policy
from train.learner.state import state_template
from train.store import checkpoint

ROOT = Path(__file__).resolve().parent.parent


def test_the_shipped_model_restores():
    """models/o_rectangle restores as a policy (its checkpoint's leaves are named; the
    leaf-index format of earlier runs: tests/test_checkpoint_format.py)."""
    restored = restore_policy(ROOT / "models" / "o_rectangle")
    assert restored.params["params"]


def test_the_shipped_model_plays_the_task_its_config_json_states():
    """Restored, it is the task config.json states, which is how it was trained: a field a
    saved config lacks means the value it ran with (``SAVED_ABSENT``), not today's default
    (``env.path_integrator = "euler"`` was once filled as today's "exact")."""
    from train.config_loading import config_diff
    from train.store.inputs import load_saved_config

    model = ROOT / "models" / "o_rectangle"
    restored = restore_policy(model)
    assert config_diff(load_saved_config(model, warn=False), restored.cfg) == []
    assert restored.cfg.env.path_integrator == "euler"


def test_restoring_builds_no_model(monkeypatch):
    """Restoring the shipped model builds no MJCF or MJX model (issue 66): its shapes and
    checks come from the config and the robot description, and its parameters are those
    the state template of a whole environment restores (as restoring did before)."""
    from mujoco import mjx

    from mecanum_jax.sim import mjcf

    def refused(*args, **kwargs):
        raise AssertionError("restoring built a model")

    model = ROOT / "models" / "o_rectangle"
    with monkeypatch.context() as m:
        m.setattr(mjcf, "build_model", refused)
        m.setattr(mjx, "put_model", refused)
        restored = restore_policy(model)
        cfg, meta = restored.cfg, restored.meta
        shapes = task_shapes(cfg.env)  # what restoring checks the checkpoint against
        for change, message in [
            ({"robot": "x_square"}, "trained on robot 'x_square', expected 'o_rectangle'"),
            ({"robot_fingerprint": "0" * 16}, "has changed since training"),
            ({"observation_layout": [["command", 3]]}, "observation layout [['command', 3]]"),
            ({"action_size": 4}, "action size 4, expected 3"),
        ]:
            with pytest.raises(checkpoint.CheckpointError) as err:
                check_compatible({**meta, **change}, shapes, "ckpt")
            assert message in str(err.value)
        with pytest.raises(AssertionError, match="built a model"):  # the trap holds
            MecanumEnv(dataclasses.replace(cfg.env, physics_impl="jax"))
    env = MecanumEnv(dataclasses.replace(cfg.env, physics_impl="jax"))
    assert (shapes.layout, shapes.privileged_layout, shapes.action_size) == (
        env.layout,
        env.privileged_layout,
        env.action_size,
    )
    sizes = {k: v.shape for k, v in restored.normalizer.mean.items()}
    assert sizes == env.observation_size
    assert sizes["state"] == (sum(s for _, s in meta["observation_layout"]),)
    epoch, items = checkpoint.read_checked(model, restored.epoch, ("train", "meta"))
    template = state_template(cfg, env, int(meta["devices"]))
    train = checkpoint.unpack_train(model, epoch, template, items)
    one = jax.tree.map(lambda x: x[0, list(cfg.run.seeds).index(restored.seed)], train)
    for got, want in (
        (restored.params, one.params.policy),
        (restored.normalizer, one.normalizer_params),
    ):
        assert jax.tree.structure(got) == jax.tree.structure(want)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "change",
    [
        {},
        WHEEL,
        {**WHEEL, "residual": False},
        {"yaw_integral_tau": 0.5, "obs_history": 2, "symmetric": True},
        {"robot": "custom_six"},
    ],
)
def test_the_shapes_are_the_controller_specs(change):
    """A task's shapes without its constants (what a restore reads) are those of the
    controller spec built from them (what an environment and an export read)."""
    shapes = task_shapes(dataclasses.replace(EnvConfig(), **change).validate())
    assert shapes.layout == shapes.control.layout
    assert shapes.action_size == shapes.control.action_size


def test_a_model_directory_evaluates_its_packaged_epoch(tmp_path):
    """A newer checkpoint beside a model's (a model unpacked over another) is not what the
    model is: without --epoch the packaged epoch restores; a provenance naming a missing
    epoch is refused by name."""
    model = tmp_path / "o_rectangle"
    shutil.copytree(ROOT / "models" / "o_rectangle", model)
    packaged = int(json.loads((model / PROVENANCE).read_text())["epoch"])
    ckpts = model / checkpoint.CHECKPOINT_DIR
    shutil.copytree(ckpts / str(packaged), ckpts / str(packaged + 5))
    assert restore_policy(model).epoch == packaged
    assert restore_policy(model, epoch=packaged + 5).epoch == packaged + 5
    with pytest.raises(checkpoint.CheckpointError, match=r"epoch = 99999: no such .* epochs: \["):
        restore_policy(model, epoch=99999)  # named as missing, not as a corrupt checkpoint
    shutil.rmtree(ckpts / str(packaged))
    with pytest.raises(checkpoint.CheckpointError, match=f"names epoch {packaged}"):
        restore_policy(model)


def test_a_start_does_not_wait_for_orbax():
    """orbax is imported at a run's first checkpoint or restore, not by the command lines'
    imports (about 0.6 s of a start on a GPU machine; docs/profiling.md)."""
    import subprocess
    import sys

    code = (
        "import sys, train.cli.train, train.tools.coldstart; "
        "print('orbax.checkpoint' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip().splitlines()[-1] == "False"


def _played(tmp_path: Path, deadband: float) -> Path:
    """A copy of the shipped model played with the network's deadband at ``deadband``: its
    ``provenance.json`` says so and its config.json states the task as played."""
    model = tmp_path / "played"
    shutil.copytree(ROOT / "models" / "o_rectangle", model)
    record = json.loads((model / "provenance.json").read_text())
    played = {"played_with": {"env.residual_deadband": deadband}}
    (model / "provenance.json").write_text(json.dumps({**record, **played}))
    config = json.loads((model / "config.json").read_text())
    config["env"]["residual_deadband"] = deadband
    (model / "config.json").write_text(json.dumps(config))
    return model


def test_a_model_is_played_as_its_provenance_states_and_keeps_what_it_trained(tmp_path):
    """``provenance.json``'s ``played_with`` sets a play-time field (the network's deadband);
    the checkpoint's config still states what the policy was trained with."""
    restored = restore_policy(_played(tmp_path, 0.03))
    assert restored.cfg.env.residual_deadband == 0.03
    assert restored.meta["config"]["env"]["residual_deadband"] == 0.02


@pytest.mark.parametrize(
    ("played", "message"),
    [
        ({"env.action_filter": 0.5}, "played_with.env.action_filter = 0.5: only"),
        ({"residual_deadband": 0.01}, "played_with.residual_deadband = 0.01: only"),
        ({"env.residual_deadband": "wide"}, "played_with.env.residual_deadband = 'wide'"),
        ({"env.residual_deadband": 2.0}, "env.residual_deadband = 2.0"),
        ([0.01], "played_with = [0.01]"),
    ],
)
def test_a_model_played_with_a_field_it_may_not_change_is_refused(tmp_path, played, message):
    model = tmp_path / "model"
    shutil.copytree(ROOT / "models" / "o_rectangle", model)
    record = json.loads((model / "provenance.json").read_text())
    (model / "provenance.json").write_text(json.dumps({**record, "played_with": played}))
    with pytest.raises(checkpoint.CheckpointError, match=re.escape(message)):
        restore_policy(model)


def test_a_played_model_packed_again_is_played_the_same(tmp_path):
    """``mecanum-export MODEL OUT --model`` of a played model keeps its ``played_with``: the
    new model's config.json (the task as played) and its restored config agree."""
    from train.cli.eval_target import check_config_task
    from train.learner.policy import package_model

    out = package_model(restore_policy(_played(tmp_path, 0.03)), tmp_path / "m", {})
    restored = restore_policy(out)
    check_config_task(restored)  # refuses a config.json that differs from the restored task
    assert restored.cfg.env.residual_deadband == 0.03
    assert json.loads((out / PROVENANCE).read_text())["played_with"] == {
        "env.residual_deadband": 0.03
    }
