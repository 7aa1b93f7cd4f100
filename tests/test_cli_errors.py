"""Bad input to any command line is one line naming the path or field, and exit code 2,
never a traceback; all of these fail before anything compiles. The command lines run in
process, from a folder holding the bad inputs."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mecanum_jax import demo
from mecanum_jax.deploy import ros2
from train.cli import deploy_sim, evaluate, export, train
from train.cli.paths import resolve_model, shipped_dir

MODEL = shipped_dir() / "o_rectangle"


@pytest.fixture
def here(tmp_path, monkeypatch):
    """The CWD: a file, a full folder, an empty one, bad TOML, binary junk, and a model
    directory whose config.json is truncated."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x\n")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "summary.json").write_text("{}\n")
    (tmp_path / "empty").mkdir()
    (tmp_path / "bad.toml").write_text("not = [toml")
    (tmp_path / "junk.toml").write_bytes(b"\xff\xfe\x00junk")
    broken = tmp_path / "broken"
    broken.mkdir()
    text = (MODEL / "config.json").read_text()
    (broken / "config.json").write_text(text[: len(text) // 3])  # truncated
    for name in ("policy.npz", "provenance.json"):
        shutil.copyfile(MODEL / name, broken / name)
    return tmp_path


TRAIN = ["--config", "tiny"]
EVAL = ["--only", "nominal", "--episodes", "1"]
CASES = [
    # durations and counts
    (train.main, ["--max-minutes", "-1"], "--max-minutes = -1.0"),
    (train.main, ["--max-minutes", "0"], "--max-minutes = 0.0"),
    (train.batch_main, ["--configs", "tiny", "--max-minutes", "-2"], "--max-minutes = -2.0"),
    (train.main, [*TRAIN, "--ppo.num-timesteps", "-5"], "ppo.num_timesteps = -5"),
    (train.batch_main, ["--configs", "tiny", "--seeds", "-1"], "run.seeds = [-1]"),
    (evaluate.main, ["baseline", "--episodes", "-1"], "episodes = -1"),
    (evaluate.main, ["baseline", "--seconds", "0"], "seconds = 0.0"),
    (deploy_sim.main, ["--episodes", "0"], "--episodes = 0"),
    (demo.main, ["--speed", "-1"], "--speed = -1.0"),
    # unwritable outputs
    (train.main, [*TRAIN, "--run-dir", "/proc/x/y"], "'/proc/x/y'"),
    (train.main, [*TRAIN, "--run-dir", "afile/run"], "--run-dir = 'afile/run'"),
    (train.batch_main, ["--configs", "tiny", "--out", "/proc/x"], "--out = '/proc/x'"),
    (evaluate.main, ["baseline", *EVAL, "--out", "/proc/x/y"], "--out = '/proc/x/y'"),
    (evaluate.main, ["baseline", *EVAL, "--out", "afile/y"], "'afile/y'"),
    (export.main, [str(MODEL), "/proc/x/p.npz"], "out = '/proc/x/p.npz'"),
    (export.main, [str(MODEL), "afile/m", "--model"], "out = 'afile/m'"),
    (deploy_sim.main, [str(MODEL), "--out", "/proc/x/y.json"], "--out = '/proc/x/y.json'"),
    (ros2.main, ["o_rectangle.yaml", "afile/x.toml"], "'o_rectangle.yaml'"),
    # directories that are files, or are missing, or empty
    (train.main, [*TRAIN, "--run-dir", "afile"], "--run-dir = 'afile'"),
    (train.main, ["--resume", "afile"], "--resume = 'afile': not a directory"),
    (train.main, ["--resume", "missing"], "--resume = 'missing': no such directory"),
    (train.main, ["--resume", "empty"], "'empty': not a run directory"),
    (evaluate.main, ["afile", *EVAL], "'afile': not a directory"),
    (evaluate.main, ["missing", *EVAL], "'missing': no such directory"),
    (evaluate.main, ["empty", *EVAL], "'empty': no checkpoints"),
    (export.main, ["afile", "p.npz"], "'afile': not a directory"),
    (deploy_sim.main, ["afile"], "model = 'afile': not a directory"),
    (deploy_sim.main, ["empty"], "model = 'empty': no config.json"),
    # a corrupt config.json is refused, not replaced by the checkpoint's
    (train.main, ["--resume", "broken"], "'broken/config.json'"),
    (evaluate.main, ["broken", *EVAL], "'broken/config.json'"),
    (export.main, ["broken", "p.npz"], "'broken/config.json'"),
    (export.main, ["broken", "m", "--model"], "'broken/config.json'"),
    (deploy_sim.main, ["broken"], "'broken/config.json'"),
    # bad or unknown configs and descriptions
    (train.main, ["--config", "nosuch"], "config = 'nosuch'"),
    (train.main, ["--config", "bad.toml"], "'bad.toml': invalid TOML"),
    (train.main, ["--config", "junk.toml"], "'junk.toml': not a text file"),
    (train.main, [*TRAIN, "--env.robot", "junk.toml"], "'junk.toml': not a text file"),
    (evaluate.main, ["baseline", *EVAL, "--robot", "junk.toml"], "'junk.toml': not a text file"),
    (train.main, [*TRAIN, "--env.robot", "full"], "'full'"),
    (train.main, [*TRAIN, "--env.robot", "bad.toml"], "'bad.toml': invalid TOML"),
    (evaluate.main, ["baseline", "--robot", "bad.toml", *EVAL], "'bad.toml'"),
    (evaluate.main, ["baseline", "--scenarios", "missing.toml"], "'missing.toml'"),
    (demo.main, ["--robot", "bad.toml"], "'bad.toml': invalid TOML"),
    (demo.main, ["--robot", "junk.toml"], "'junk.toml': not a text file"),
    (demo.main, ["--robot", "nosuch"], "robot = 'nosuch'"),
    (ros2.main, ["junk.toml"], "params = 'junk.toml'"),
    (ros2.main, ["o_rectangle", "--to-ros", "x.toml"], "out = 'x.toml'"),
    # a probe's changes of the task (--play): the item, the field and the value named
    (evaluate.main, ["baseline", *EVAL, "--play", "residual_deadband"], "'residual_deadband'"),
    (evaluate.main, ["baseline", *EVAL, "--play", "bogus=1"], "--play.bogus = 1"),
    (evaluate.main, ["baseline", *EVAL, "--play", "feedback=1"], "--play.feedback = 1"),
    (evaluate.main, ["baseline", *EVAL, "--play", "feedback.margin=1.5"], "margin = 1.5"),
    (evaluate.main, ["baseline", *EVAL, "--play", "path_tau=x"], "'path_tau=x'"),
    (evaluate.main, [str(MODEL), *EVAL, "--play", "path_tau=0"], "--play path_tau=0"),
    (evaluate.main, [str(MODEL), *EVAL, "--export", "--play", "path_tau=1"], "a probe"),
    # a tuple field: its error in plain text (no rich markup)
    (deploy_sim.main, ["--command", "1", "2"], "--command = [1.0, 2.0]"),
    # a command no robot drives: beyond twice the model's reach (a scenario file's bound)
    (deploy_sim.main, [str(MODEL), "--command", "0", "0", "1e9"], "beyond twice the reach"),
]


def _ids(case):
    main, argv, _ = case
    return f"{main.__module__.rsplit('.', 1)[-1]}.{main.__name__} {' '.join(argv)}"


@pytest.mark.parametrize("case", CASES, ids=[_ids(c) for c in CASES])
def test_bad_input_is_one_line_and_exit_code_2(case, here, capsys):
    main, argv, names = case
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = [line for line in captured.err.splitlines() if line.strip()]
    assert len(err) == 1, captured.err
    assert names in err[0], err[0]
    assert "Traceback" not in captured.err + captured.out
    assert "[bold]" not in err[0]
    assert "[/" not in err[0]
    # nothing written: only the inputs the fixture made
    made = {"afile", "full", "empty", "bad.toml", "junk.toml", "broken"}
    assert {p.name for p in here.iterdir()} <= made | {"runs"}
    assert not (here / "runs").exists() or not any((here / "runs").iterdir())


def test_a_broken_config_is_never_packed_into_a_model(here):
    assert export.main(["broken", "m", "--model"]) == 2
    assert not Path("m").exists()
    assert not Path("m.partial").exists()


RST = re.compile(r"``|:(data|class|func|mod|meth|attr):`")


@pytest.mark.parametrize(
    "main", [train.main, evaluate.main, export.main, deploy_sim.main], ids=lambda m: m.__module__
)
def test_help_is_plain_text(main, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "--help" in text
    assert not RST.search(text), RST.search(text)


def test_the_shipped_model_is_found_by_name_from_anywhere(here):
    for name in ("shipped", "o_rectangle", "models/o_rectangle"):
        assert Path(resolve_model(name)) == MODEL
    assert resolve_model("afile") == "afile"  # an existing path is itself


def test_a_refused_training_config_never_imports_the_trainer():
    """``mecanum-train`` checks its input before it imports the learner and the physics
    (MJX, Brax): a refusal comes in the seconds the config takes (a fresh interpreter)."""
    script = (
        "import json, sys\n"
        "from train.cli import train\n"
        "code = train.main(['--config', 'tiny', '--ppo.num-envs', '0'])\n"
        "print(json.dumps([code, sorted(sys.modules)]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    code, modules = json.loads(proc.stdout.strip().splitlines()[-1])
    assert code == 2
    assert "ppo.num_envs = 0" in proc.stderr
    assert "jax" in modules  # the config's checks ran
    heavy = [m for m in modules if m.startswith(("brax", "mujoco.mjx", "train.learner.ppo"))]
    assert not heavy, heavy
