"""Self-contained run directories: a run copies its robot description (and the config file
it was given) into ``inputs/``; evaluation, export and model directories use the copies, so
a run outlives the user's TOML (train.store.inputs)."""

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import pytest

from mecanum_jax.config import CONFIG_DIR
from train.config import TrainConfig
from train.config_loading import load_train_config, parse_train_config
from train.store import inputs

ROBOT = CONFIG_DIR / "robots" / "o_rectangle.toml"


def _cfg(robot: str) -> TrainConfig:
    cfg = TrainConfig()
    return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, robot=robot))


def _restored(robot: str, run: Path) -> TrainConfig:
    """The config a run of ``robot`` restores with (as restore_policy reads it)."""
    return parse_train_config(inputs.use_copies(_cfg(robot).to_dict(), run), "saved")


@pytest.fixture
def custom(tmp_path):
    """A user's own robot file (the built-in one under another name) and a run of it."""
    path = tmp_path / "my_robot.toml"
    shutil.copyfile(ROBOT, path)
    run = tmp_path / "run"
    inputs.save_inputs(run, _cfg(str(path)))
    return path, run


def test_the_robot_description_is_copied_with_its_fingerprint(custom):
    path, run = custom
    index = json.loads((run / "inputs" / "inputs.json").read_text())
    assert index["robot"]["source"] == str(path.resolve())
    assert (run / "inputs" / "robot.toml").read_bytes() == path.read_bytes()
    assert index["robot"]["sha256"] == inputs.sha256(path)


def test_the_copy_serves_when_the_original_is_deleted_silently(custom):
    path, run = custom
    path.unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cfg = _restored(str(path), run)
    assert cfg.env.robot == str((run / "inputs" / "robot.toml").resolve())
    assert cfg.env.description().robot.name == "o_rectangle"


def test_an_intact_original_keeps_its_name(custom):
    """Where the saved name still gives the bytes the run trained on, the config is left as
    saved, so it compares equal to the user's (a resumed run's)."""
    path, run = custom
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cfg = _restored(str(path), run)
    assert cfg.env.robot == str(path)
    assert inputs.robot_copy(run, str(path)) is None


def test_an_edited_original_is_named_beside_the_copy(custom):
    path, run = custom
    path.write_text(path.read_text().replace("wheel_radius = 0.05", "wheel_radius = 0.06"))
    with pytest.warns(inputs.EditedInputWarning) as record:
        cfg = _restored(str(path), run)
    message = str(record[0].message)
    assert str(path) in message
    assert str(run / "inputs" / "robot.toml") in message
    assert cfg.env.description().geometry.wheel_radius == 0.05  # the copy's


def test_a_built_in_robot_is_copied_too_and_a_run_without_copies_is_unchanged(tmp_path):
    inputs.save_inputs(tmp_path / "run", _cfg("o_rectangle"))
    assert (tmp_path / "run" / "inputs" / "robot.toml").read_bytes() == ROBOT.read_bytes()
    old = _cfg("o_rectangle").to_dict()
    assert inputs.use_copies(old, tmp_path) is old  # no inputs/: as before


def test_a_tampered_copy_is_refused(custom):
    _, run = custom
    (run / "inputs" / "robot.toml").write_text("[robot]\n")
    with pytest.raises(inputs.ConfigError, match="does not match its SHA-256"):
        inputs.robot_copy(run, "o_rectangle")


def test_the_config_file_a_run_was_given_is_copied(tmp_path):
    from train.cli.train import _config_file
    from train.loop.run import Run

    Run.create(load_train_config("tiny"), tmp_path / "run", _config_file("tiny")).close()
    copy = tmp_path / "run" / "inputs" / "config.toml"
    assert load_train_config(copy) == load_train_config("tiny")


@pytest.mark.full  # trains the tiny run (a minute of compilation on 2 cores), then evaluates
def test_a_run_on_a_deleted_custom_robot_evaluates_and_exports(tmp_path, monkeypatch, capsys):
    from train.cli import deploy_sim, evaluate, export

    monkeypatch.chdir(tmp_path)
    shutil.copyfile(ROBOT, tmp_path / "my_robot.toml")
    argv = ["--config", "tiny", "--env.robot", "my_robot.toml", "--run-dir", "run"]
    from train.cli import train

    assert train.main(argv) == 0
    assert (tmp_path / "run" / "inputs" / "config.toml").is_file()
    Path("my_robot.toml").unlink()
    assert export.main(["run", "p.npz"]) == 0
    assert export.main(["run", "model", "--model"]) == 0
    assert (tmp_path / "model" / "inputs" / "robot.toml").is_file()
    short = ["--only", "nominal", "--episodes", "2", "--seconds", "0.2", "--no-plots"]
    assert evaluate.main(["run", *short, "--out", "ev"]) == 0
    assert evaluate.main(["model", *short, "--out", "ev_model"]) == 0
    assert json.loads((tmp_path / "ev_model" / "report.json").read_text())["robot"] == "o_rectangle"
    assert deploy_sim.main(["model", "--episodes", "1", "--seconds", "0.2", "--out", "d.json"]) == 0
    capsys.readouterr()


def test_a_run_resumes_after_its_custom_robot_is_deleted(tmp_path):
    """--resume reads the run's copy; config.json keeps the robot as the user named it."""
    from train.loop.run import Run

    path = tmp_path / "my_robot.toml"
    shutil.copyfile(ROBOT, path)
    tiny = load_train_config("tiny")
    cfg = dataclasses.replace(tiny, env=dataclasses.replace(tiny.env, robot=str(path)))
    run_dir = tmp_path / "run"
    Run.create(cfg, run_dir)
    path.unlink()
    longer = dataclasses.replace(cfg.ppo, num_timesteps=2 * cfg.ppo.num_timesteps)
    saved = inputs.load_saved_config(run_dir)
    run = Run.resume(run_dir, overrides=dataclasses.replace(saved, ppo=longer))
    assert run.cfg.env.robot == str((run_dir / "inputs" / "robot.toml").resolve())
    assert run.cfg.env.description().robot.name == "o_rectangle"
    written = json.loads((run_dir / "config.json").read_text())
    assert written["env"]["robot"] == str(path)
    assert written["ppo"]["num_timesteps"] == longer.num_timesteps
