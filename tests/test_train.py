"""The PPO trainer: configs, run directories, interrupt and resume, NaN stop, inference.

All runs use ``configs/train/tiny.toml`` on the suite's two CPU devices (so the pmap path
with gradient averaging is exercised) and share one compiled :class:`Learner`.
"""

import dataclasses
import importlib.util
import json
from pathlib import Path

import jax
import numpy as np
import pytest
from learners import deterministic_policy, final_train_state, random_obs

from mecanum_jax.config import ConfigError
from train.cli import train as cli
from train.config_loading import parse_train_config
from train.learner.policy import load_policy, restore_policy
from train.learner.ppo import Learner
from train.loop.run import Run, RunDirError
from train.loop.run_steps import TrainingDiverged
from train.store import checkpoint


def test_full_run_writes_its_directory(full_run, tiny):
    run, summary = full_run
    d = run.dir
    assert json.loads((d / "status.json").read_text())["state"] == "finished"
    assert parse_train_config(json.loads((d / "config.json").read_text()), "saved") == tiny
    lines = [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]
    assert lines[-1]["env_steps"] == 3 * tiny.steps_per_iteration * tiny.run.epoch_iterations
    for key in (
        "reward/tracking_lin",
        "reward/tracking_ang",
        "reward/action_rate",
        "reward/energy",
    ):
        assert key in lines[0]["train"]
    assert {"randomized", "nominal"} <= set(lines[0]["eval"])
    assert lines[0]["baseline"] == lines[-1]["baseline"]  # fixed held-out episodes
    assert list((d / "tb" / "seed_0").iterdir())  # TensorBoard events
    assert checkpoint.latest_epoch(d) == 3
    assert summary["epochs"] == 3
    assert summary["seeds"][0]["eval"]["nominal"]["rmse_lin"] > 0
    # wall time (and "beat at") counts the whole session: set-up, compilation, baseline
    assert summary["walltime_s"] == pytest.approx(summary["session_s"], abs=0.5)
    assert 0 < lines[0]["walltime"] < lines[-1]["walltime"] <= summary["walltime_s"]


def test_interrupted_run_resumes_exactly(full_run, tiny, learner, tmp_path, monkeypatch):
    reference, _ = full_run
    run = Run.create(tiny, tmp_path / "run")
    calls = {"n": 0}
    real_epoch = learner.epoch

    def epoch_then_ctrl_c(*args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt  # Ctrl-C during the second epoch
        return real_epoch(*args)

    monkeypatch.setattr(learner, "epoch", epoch_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        run.train(learner=learner)
    monkeypatch.setattr(learner, "epoch", real_epoch)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "interrupted"
    assert checkpoint.latest_epoch(run.dir) == 1  # the last completed epoch was saved

    resumed = Run.resume(run.dir)
    resumed.train(learner=learner)
    a, meta_a = final_train_state(reference, learner)
    b, meta_b = final_train_state(resumed, learner)
    assert meta_a["env_steps"] == meta_b["env_steps"]
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)  # optimizer, params, normalizer, keys: identical
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]


def test_metric_loggers_get_every_epoch_and_wandb_is_optional(tiny, learner, tmp_path, monkeypatch):
    """A user's logger and W&B (``run.wandb_project``) receive each epoch's numeric rows,
    the same figures as metrics.jsonl; without wandb installed the option fails early."""
    import sys
    import types

    class Recorder:
        def __init__(self):
            self.calls, self.closed = [], False

        def log(self, steps, rows):
            self.calls.append((steps, rows))

        def close(self):
            self.closed = True

    fake_runs = []

    def init(**kw):
        run = types.SimpleNamespace(kw=kw, logged=[], finished=False)
        run.log = lambda data, step: run.logged.append((step, data))
        run.finish = lambda: setattr(run, "finished", True)
        fake_runs.append(run)
        return run

    monkeypatch.setitem(sys.modules, "wandb", types.SimpleNamespace(init=init))
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *a: object())
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, wandb_project="mecanum"))
    user = Recorder()
    run = Run.create(cfg, tmp_path / "run", loggers=[user])
    run.train(learner=learner)
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [steps for steps, _ in user.calls] == [x["env_steps"] for x in lines]
    steps, rows = user.calls[-1]
    seed = tiny.run.seeds[0]
    last = {k: v for k, v in _flat(lines[-1]).items() if isinstance(v, float) and k != "walltime"}
    assert len(last) > 10
    key = next(k for k in last if "rmse" in k)  # an evaluation figure
    for k, v in last.items():
        assert rows[seed][k] == pytest.approx(v, rel=1e-6)
    assert user.closed
    (wb,) = fake_runs
    assert wb.kw["project"] == "mecanum"
    assert wb.kw["config"]["run"]["wandb_project"] == "mecanum"
    assert wb.finished
    assert wb.logged[-1][0] == steps
    assert wb.logged[-1][1][f"seed_{seed}/{key}"] == rows[seed][key]
    monkeypatch.undo()
    if importlib.util.find_spec("wandb") is None:
        with pytest.raises(ConfigError, match=r"run\.wandb_project = 'mecanum': needs the wandb"):
            dataclasses.replace(cfg).validate()  # a copy: cfg passed once, and stays passed


def _flat(d, prefix=""):
    out = {}
    for k, v in d.items():
        key = f"{prefix}/{k}" if prefix else k
        out |= _flat(v, key) if isinstance(v, dict) else {key: v}
    return out


def test_nan_stops_and_keeps_last_good_checkpoint(tiny, learner, tmp_path, monkeypatch):
    run = Run.create(tiny, tmp_path / "nan")
    calls = {"n": 0}
    real_epoch = learner.epoch

    def poisoned(*args):
        calls["n"] += 1
        ts, es, metrics = real_epoch(*args)
        if calls["n"] == 2:
            ts = ts.replace(params=jax.tree.map(lambda x: x * np.nan, ts.params))
            metrics = dict(metrics, finite=metrics["finite"] * 0)
        return ts, es, metrics

    monkeypatch.setattr(learner, "epoch", poisoned)
    with pytest.raises(
        TrainingDiverged, match=r"non-finite .* epoch 2 .* last good checkpoint: epoch 1"
    ):
        run.train(learner=learner)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "diverged"
    host, _ = final_train_state(run, learner)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(host.params))


@pytest.mark.full  # compiles the learner's finiteness check on its own
def test_nan_check_detects_non_finite_params(learner):
    ts, env_state = learner.init()

    def poison(x):
        x = np.array(x)
        if x.dtype.kind == "f":
            x[0, 0] = np.nan
        return x

    ts = ts.replace(params=jax.tree.map(poison, ts.params))
    _, _, metrics = learner.epoch(ts, env_state)
    assert float(np.asarray(metrics["finite"])[0, 0]) == 0.0


def test_run_directory_is_never_overwritten(full_run, tiny):
    run, _ = full_run
    before = (run.dir / "metrics.jsonl").read_text()
    with pytest.raises(RunDirError, match="already exists"):
        Run.create(tiny, run.dir)
    assert cli.main(["--config", "tiny", "--run-dir", str(run.dir)]) == 2
    assert (run.dir / "metrics.jsonl").read_text() == before


def test_resume_refuses_changed_config(full_run, tiny, tmp_path):
    run, _ = full_run
    import dataclasses
    import shutil

    # a copy: resuming takes the run's lock, and other workers read the shared run meanwhile
    mine = shutil.copytree(run.dir, tmp_path / "run", ignore=shutil.ignore_patterns(".lock"))
    changed = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, learning_rate=1.0))
    with pytest.raises(ConfigError, match=r"ppo\.learning_rate: cannot change when resuming"):
        Run.resume(mine, overrides=changed)


def test_policy_loads_into_plain_inference_function(full_run, learner):
    run, _ = full_run
    act, meta = load_policy(run.dir)
    assert meta["epoch"] == 3
    assert meta["robot"] == "o_rectangle"
    assert meta["observation_layout"][0] == ["command", 3]
    host, _ = final_train_state(run, learner)
    policy = deterministic_policy(learner, host)
    obs = random_obs(learner, 5, seed=0)
    a = np.asarray(act(obs))
    assert a.shape == (5, 4)
    assert np.all(np.abs(a) <= 1)
    np.testing.assert_allclose(
        a, np.asarray(policy(obs, jax.random.PRNGKey(1))[0]), rtol=1e-5, atol=1e-6
    )


def test_load_policy_errors(tmp_path):
    with pytest.raises(checkpoint.CheckpointError, match="no such directory"):
        load_policy(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(checkpoint.CheckpointError, match="no checkpoints"):
        load_policy(tmp_path / "empty")


def test_restoring_a_policy_builds_no_learner(full_run, monkeypatch):
    """A checkpoint restores into a template built from shapes alone, not a Learner."""
    run, _ = full_run

    def no_learner(*args, **kwargs):
        raise AssertionError("restore_policy built a Learner")

    monkeypatch.setattr(Learner, "__init__", no_learner)
    restored = restore_policy(run.dir)
    assert restored.epoch == 3
    assert np.all(np.isfinite(np.asarray(jax.tree.leaves(restored.params)[0])))


def test_bench_variants_take_the_trainers_flags(capsys):
    from train.tools import bench

    with pytest.raises(SystemExit):
        bench.main(["--config", "tiny", "--variant", "x --ppo.num-envz 3"])
    assert "--ppo.num-envz" in capsys.readouterr().err
    assert bench.main(["--config", "tiny", "--variant", "x --ppo.num-envs 3"]) == 2
    assert "ppo.num_envs = 3: must divide" in capsys.readouterr().out


def test_the_epoch_a_time_limit_stops_at_is_evaluated_and_logged(
    tiny, learner, tmp_path, monkeypatch
):
    """Between periodic evaluations (here: none but the final one), a run stopped by its
    time limit evaluates the epoch it stops at, and logs it in metrics.jsonl as the
    summary has it."""
    monkeypatch.setattr("train.loop.session.Session.eval_due", lambda self, final: final)
    run = Run.create(tiny, tmp_path / "limited")
    summary = run.train(learner=learner, time_limit_s=0.0)
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1]
    assert json.loads((run.dir / "status.json").read_text())["state"] == "stopped"
    (logged,) = [x for x in lines if "eval" in x]
    (seed,) = summary["seeds"]
    assert seed["eval"]
    for scenario, figures in seed["eval"].items():
        for k, v in figures.items():
            if isinstance(v, float):
                assert logged["eval"][scenario][k] == pytest.approx(v, rel=1e-6), (scenario, k)


@pytest.mark.parametrize(
    ("parallel", "impl", "alone"),
    [
        ("pmap", "jax", False),
        ("sharded", "jax", False),
        ("split", "warp", True),
        ("sharded", "warp", True),
        ("pmap", "warp", True),
    ],
)
def test_first_runs_alone_under_warp(parallel, impl, alone):
    """Under MuJoCo Warp (and on the split path) the baseline's first evaluation finishes
    before the first epoch starts: a program's first run captures Warp's CUDA graphs, and
    another thread's GPU work meanwhile breaks the capture (train/loop/run_steps.py)."""
    from types import SimpleNamespace

    from train.loop.aot import first_runs_alone

    learner = SimpleNamespace(
        parallel=parallel, env=SimpleNamespace(robot=SimpleNamespace(impl=impl))
    )
    assert first_runs_alone(learner) is alone  # type: ignore[arg-type]


def test_each_session_evaluates_its_first_epoch():
    """A first figure soon after the start: the session's first epoch is evaluated, then
    every ``run.eval_every`` epochs and the last one (a resumed session's first too)."""
    from types import SimpleNamespace

    from train.loop.session import Session

    cfg = SimpleNamespace(run=SimpleNamespace(eval_every=8))
    loop = Session(cfg, Path(), True, None, 0.0, None, None)  # type: ignore[arg-type]

    def evaluated(epochs: range) -> list[int]:
        out = []
        for loop.epoch in epochs:
            if loop.eval_due(final=loop.epoch == epochs[-1]):
                out.append(loop.epoch)
        return out

    assert evaluated(range(1, 18)) == [1, 8, 16, 17]
    loop.first_epoch = 11  # resumed after epoch 10
    assert evaluated(range(11, 20)) == [11, 16, 19]


def test_the_fresh_state_program_is_fresh_state_for_any_valid_seed(learner):
    """Seeds past int32 (``run.seeds`` allows up to 2**32 - 1) give the eager state's keys."""
    from train.learner.state import fresh_state, fresh_state_program

    program = fresh_state_program(learner.cfg, learner.env, learner.networks, learner.optimizer)
    for seed in (3, 2**31, 2**32 - 1):
        state, k_env = program(np.uint32(seed))
        eager, k_eager = fresh_state(
            learner.cfg, learner.env, learner.networks, learner.optimizer, seed
        )
        assert np.array_equal(k_env, k_eager)
        assert np.array_equal(state.key, eager.key)
