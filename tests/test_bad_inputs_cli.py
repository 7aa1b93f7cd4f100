"""Issue 67, the command lines' side: each bad input below is one line naming the field and
the value, exit code 2, before anything is built; a refused training run leaves no run
directory; the X-square trains, evaluates and exports (full tier: it trains)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mecanum_jax import bench, demo, memory
from mecanum_jax.bench_report import median_spread, warn_spread
from mecanum_jax.config import CONFIG_DIR, ConfigError
from train.cli import evaluate, export, train
from train.cli.eval_args import EvalArgs, check_args
from train.cli.eval_output import scorecard_table
from train.cli.paths import shipped_dir

MODEL = shipped_dir() / "o_rectangle"
ONEWAY = (
    """[robot]
name = "oneway"
[geometry]
layout = "custom"
"""
    + "".join(
        f'[[geometry.wheels]]\nname = "w{i}"\nx = {x}\ny = {y}\nradius = 0.05\n'
        "roller_angle_deg = 45\n"
        for i, (x, y) in enumerate([(0.1, 0.1), (-0.1, 0.1), (-0.1, -0.1), (0.1, -0.1)])
    )
    + "[motors]\nmax_motor_rpm = 9000.0\n"
)


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    return " ".join(line.strip() for line in lines)


def test_an_unusable_robot_leaves_no_run_directory(tmp_path, capsys):
    (tmp_path / "oneway.toml").write_text(ONEWAY)
    run_dir = tmp_path / "run"
    argv = ["--config", "tiny", "--env.robot", str(tmp_path / "oneway.toml")]
    assert train.main([*argv, "--run-dir", str(run_dir)]) == 2
    assert "robot 'oneway': the wheels cannot drive every planar" in _one_error_line(capsys)
    assert not run_dir.exists()


def test_a_training_config_as_the_robot_is_a_short_error(tmp_path, capsys):
    tiny = str(CONFIG_DIR / "train" / "tiny.toml")
    argv = ["--config", "tiny", "--env.robot", tiny, "--run-dir", str(tmp_path / "r")]
    assert train.main(argv) == 2
    text = _one_error_line(capsys)
    assert "not a robot description" in text
    assert len(text) < 300


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seconds", "0.001"], "--seconds = 0.001: an episode must last at least 0.1 s"),
        (["--seconds", "0.05"], "--seconds = 0.05"),
    ],
)
def test_eval_too_short_episodes(argv, message, capsys):
    assert evaluate.main(["baseline", "--only", "nominal", *argv]) == 2
    assert message in _one_error_line(capsys)
    check_args(EvalArgs("baseline", seconds=0.1))  # the minimum itself passes


def test_scorecard_says_when_its_verdicts_are_not_significant():
    metrics = {"ss_lin": {"mean": 1.0}, "ss_wz": {"mean": 1.0}}
    results = {
        name: {"episodes": n, "policy": metrics, "analytic": metrics, "compare": {}}
        for name, n in (("nominal", 2), ("slippery", 32))
    }
    table = scorecard_table(results, "policy", ["analytic"])
    assert table.caption is not None
    assert "nominal (2)" in str(table.caption)
    assert "slippery" not in str(table.caption)
    assert "not significant" in str(table.caption)
    results["nominal"]["episodes"] = 8
    assert scorecard_table(results, "policy", ["analytic"]).caption is None


def test_demo_speed_beyond_any_robot(capsys):
    assert demo.main(["--speed", "1e9"]) == 2
    assert "--speed = 1000000000.0: must be a number > 0 and at most 100" in _one_error_line(capsys)


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["kinematics", "--sizes", "0"], "--sizes"),
        (["kinematics", "--repeats", "0"], "--repeats"),
        (["physics", "--sizes", "4", "0"], "--sizes = [4, 0]: must be >= 1"),
        (["physics", "--repeats", "0"], "--repeats = 0: must be >= 1"),
    ],
)
def test_bench_bad_arguments_exit_2_with_error(argv, named, capsys):
    """Refused with one line that names the bad flag and its value, and no other flag."""
    assert bench.main(argv) == 2
    line = _one_error_line(capsys)
    assert line.startswith(f"error: {named}")
    assert "--steps" not in line


def test_bench_reports_the_spread_and_warns_when_repeats_disagree(capsys):
    from rich.console import Console

    from mecanum_jax.bench_kinematics import KinematicsBench, run_kinematics

    args = KinematicsBench(sizes=(16,), repeats=3, min_time=0.001, ops=("inverse",), numpy=False)
    row = run_kinematics(args, Console(width=200))["results"][0]
    assert set(row["spread"]) == {"jax", "latency", "copy"}
    assert "spread" in capsys.readouterr().out
    assert median_spread([1.0, 1.1, 1.0]) == pytest.approx((1.0, 0.1))
    console = Console(width=200, record=True)
    warn_spread(console, "inverse batch 16, jax time", 0.1)
    assert console.export_text() == ""
    warn_spread(console, "inverse batch 16, jax time", median_spread([1.0, 1.5, 1.0])[1])
    assert "repeats disagree by 50%" in console.export_text()


def test_an_edited_robot_in_a_models_config_is_named(tmp_path, capsys):
    model = tmp_path / "model"
    shutil.copytree(MODEL, model)
    config = json.loads((model / "config.json").read_text())
    config["env"]["robot"] = "x_square"
    (model / "config.json").write_text(json.dumps(config))
    assert evaluate.main([str(model), "--only", "nominal", "--episodes", "1"]) == 2
    text = _one_error_line(capsys)
    assert "env.robot = 'x_square', but the checkpoint was trained on robot 'o_rectangle'" in text


def test_an_edited_task_in_a_models_config_is_named(tmp_path, capsys):
    """config.json's [env] is what deploy-sim and a resumed run read: one that differs
    from the checkpoint's task (the shipped model's was edited by hand once) is refused."""
    model = tmp_path / "model"
    shutil.copytree(MODEL, model)
    config = json.loads((model / "config.json").read_text())
    assert config["env"]["path_integrator"] == "euler"
    config["env"]["path_integrator"] = "exact"
    (model / "config.json").write_text(json.dumps(config))
    assert evaluate.main([str(model), "--only", "nominal", "--episodes", "1"]) == 2
    text = _one_error_line(capsys)
    assert "env.path_integrator = 'exact' (trained: 'euler')" in text


def _cli(
    code: str, env: dict[str, str], cwd: Path, cap_gib: float = 12
) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter, its address space capped (a safety net: a
    guard that failed would meet the cap, not swap the machine)."""
    limit = int(cap_gib * 2**30)
    pre = f"import resource; resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))\n"
    full_env = {**os.environ, **env}
    return subprocess.run(
        [sys.executable, "-c", pre + code], env=full_env, cwd=cwd, capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip


@pytest.mark.parametrize("platform", ["tpu", "cuda"])
def test_a_backend_that_does_not_exist_is_one_line(platform, tmp_path):
    code = "import sys; from mecanum_jax import demo; sys.exit(demo.main([]))"
    out = _cli(code, {"JAX_PLATFORMS": platform}, tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"error: JAX_PLATFORMS = '{platform}'")
    assert "this environment has cpu" in lines[0]
    if platform == "cuda":
        assert "pip install 'mecanum-jax[cuda]'" in lines[0]


def test_training_too_large_for_memory_is_refused_before_building(tmp_path):
    argv = ["--config", "tiny", "--ppo.num-envs", "10000000", "--ppo.batch-size", "5000000"]
    argv += ["--run-dir", str(tmp_path / "big")]
    code = f"import sys; from train.cli import train; sys.exit(train.main({argv!r}))"
    out = _cli(code, {}, tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "ppo.num_envs = 10000000" in out.stderr
    assert "needs about" in out.stderr
    assert "GiB available on cpu" in out.stderr
    assert not (tmp_path / "big").exists()


def test_evaluation_too_large_for_memory_is_refused(tmp_path):
    # the CPU's largest batch (247 robots: from 256 with its guard rows jaxlib hangs), at the
    # longest episodes, under the test's 12 GiB address-space cap
    argv = ["baseline", "--only", "nominal", "slippery", "payload", "--episodes", "80"]
    argv += ["--max-batch", "240", "--seconds", "600", "--out", str(tmp_path / "e")]
    code = f"import sys; from train.cli import evaluate; sys.exit(evaluate.main({argv!r}))"
    out = _cli(code, {}, tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "evaluation of 240 robots at once" in out.stderr
    assert "needs about" in out.stderr


def test_the_estimates_grow_with_the_batch():
    small = memory.training_bytes(8, 16, 10)
    assert memory.training_bytes(10_000_000, 10_000_000, 10) > 100 * small
    memory.require_memory(small, "tiny", "")  # the tiny config fits anywhere
    with pytest.raises(ConfigError, match=r"huge: needs about .* GiB .* available on cpu"):
        memory.require_memory(10**15, "huge", "use fewer")


@pytest.mark.parametrize(
    ("run", "named"),
    [
        ({"num_eval_envs": 10**8}, "run.num_eval_envs = 100000000, run.eval_episode_length = 30"),
        ({"eval_episode_length": 10**8}, "run.num_eval_envs = 4, run.eval_episode_length"),
    ],
)
def test_a_periodic_evaluation_too_large_for_memory_is_named(run, named):
    """The evaluation's traces count, and the refusal names them, not the batch (10^8
    evaluation steps had run a tiny run on, unrefused, until it was killed)."""
    import dataclasses

    from train.config_loading import load_train_config

    cfg = load_train_config("tiny")
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, **run))
    with pytest.raises(ConfigError, match="needs about") as err:
        train._require_memory(cfg)
    assert str(err.value).startswith(named)
    assert "--run.num-eval-envs" in str(err.value)


def test_gpu_config_on_a_cpu_warns_at_start(tmp_path, capsys):
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("x")  # a run directory in use: refused right after the warning
    assert train.main(["--config", "gpu", "--run-dir", str(full)]) == 2
    err = capsys.readouterr().err
    assert "--config gpu on a CPU" in err
    assert "use --config quick" in err


def test_export_names_both_modules(tmp_path, capsys):
    assert export.main([str(MODEL), str(tmp_path / "p.npz")]) == 0
    err = capsys.readouterr().err.replace("\n", " ")
    assert "mecanum_robot.zip" in err
    assert "mecanum_policy.py" in err
    assert "mecanum_loop.py" in err
    assert (tmp_path / "mecanum_robot.zip").exists()


@pytest.mark.full
def test_x_square_trains_evaluates_and_exports(tmp_path):
    run_dir = tmp_path / "x"
    assert (
        train.main(["--config", "tiny", "--env.robot", "x_square", "--run-dir", str(run_dir)]) == 0
    )
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["seeds"][0]["eval"]
    out = tmp_path / "ev"
    argv = [str(run_dir), "--only", "nominal", "six_modes", "--episodes", "2", "--out", str(out)]
    assert evaluate.main([*argv, "--no-plots"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report["scenarios"]) == {"nominal", "six_modes"}
    # the report states the floors it drew (default.toml's [defaults] randomization)
    assert report["scenarios"]["six_modes"]["randomization"] == {"friction": [0.98, 1.02]}
    assert export.main([str(run_dir), str(tmp_path / "x.npz")]) == 0
