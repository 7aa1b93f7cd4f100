"""The NaN guard (train/loop/divergence.py): a non-finite loss or parameter stops the run
with an error naming the epoch and the first non-finite quantity, keeps the last good
checkpoint, says "diverged" in status.json, and the run resumes from that checkpoint,
with a lower learning rate if asked."""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from train.loop import divergence
from train.loop.run import Run
from train.loop.run_steps import TrainingDiverged
from train.store import checkpoint


def _poison_epoch(learner, monkeypatch, at: int, poison) -> None:
    """``learner.epoch``'s ``at``-th call returns ``poison(state, metrics)``."""
    real, calls = learner.epoch, []

    def epoch(*args):
        calls.append(1)
        ts, es, metrics = real(*args)
        if len(calls) == at:
            ts, metrics = poison(ts, metrics)
        return ts, es, metrics

    monkeypatch.setattr(learner, "epoch", epoch)


def _nan_loss(ts, metrics):
    return ts, dict(metrics, **{"loss/total_loss": metrics["loss/total_loss"] * np.nan})


def test_nan_loss_stops_keeps_the_last_good_checkpoint_and_resumes(
    tiny, learner, tmp_path, monkeypatch
):
    run = Run.create(tiny, tmp_path / "run")
    _poison_epoch(learner, monkeypatch, 2, _nan_loss)
    with pytest.raises(TrainingDiverged) as err:
        run.train(learner=learner)
    monkeypatch.undo()
    where = checkpoint.checkpoint_path(run.dir, 1)
    assert str(err.value) == (
        f"non-finite values in epoch 2 (loss/total_loss is nan in seed 0); stopped, last good "
        f"checkpoint: epoch 1 ({where}); resume it with --resume {run.dir} and a change, "
        "such as a lower --ppo.learning-rate"
    )
    status = json.loads((run.dir / "status.json").read_text())
    assert {k: status[k] for k in ("state", "epoch", "diverged_epoch", "seeds", "error")} == {
        "state": "diverged",
        "epoch": 1,
        "diverged_epoch": 2,
        "seeds": [0],
        "error": str(err.value),
    }
    assert status["last_checkpoint"]["epoch"] == 1
    assert checkpoint.latest_epoch(run.dir) == 1  # the bad state was never saved
    rows = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1, 2]  # the bad epoch's row, for the record
    assert rows[1]["train"]["loss/total_loss"] == "nan"

    # after a divergence the step sizes may change on resume (elsewhere they may not)
    lower = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, learning_rate=1e-5))
    assert Run.resume(run.dir, overrides=lower).cfg.ppo.learning_rate == 1e-5
    saved = json.loads((run.dir / "config.json").read_text())
    assert saved["ppo"]["learning_rate"] == 1e-5
    bigger = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, num_envs=16))
    with pytest.raises(ConfigError, match=r"ppo\.num_envs: cannot change when resuming"):
        Run.resume(run.dir, overrides=bigger)
    # (the shared learner has the first learning rate: back to it, to train here)
    Run.resume(run.dir, overrides=tiny).train(learner=learner)
    rows = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1, 2, 3]  # the bad row gave way to the new one
    assert np.isfinite(rows[1]["train"]["loss/total_loss"])
    assert json.loads((run.dir / "status.json").read_text())["state"] == "finished"
    with pytest.raises(ConfigError, match=r"ppo\.learning_rate: cannot change"):
        Run.resume(run.dir, overrides=lower)  # finished, not diverged


def test_the_first_non_finite_parameter_is_named(learner):
    ts, _ = learner.init()
    metrics = {"finite": np.array([0.0]), "loss/total_loss": np.array([1.0])}
    assert divergence.bad_seeds((7,), metrics) == [0]

    def poison(path, x):
        x = np.array(x)
        if "value" in jax.tree_util.keystr(path) and "hidden_1" in jax.tree_util.keystr(path):
            x[..., 0] = np.inf
        return x

    value_bad = ts.replace(params=jax.tree_util.tree_map_with_path(poison, ts.params))
    what = divergence.first_non_finite((7,), metrics, value_bad, 0)
    assert what == "value parameter params/hidden_1/bias is inf in seed 7"
    mean = jax.tree.map(lambda x: np.full_like(np.asarray(x), np.nan), ts.normalizer_params.mean)
    norm_bad = ts.replace(normalizer_params=ts.normalizer_params.replace(mean=mean))
    assert divergence.first_non_finite((7,), metrics, norm_bad, 0).startswith(
        "observation normalizer mean/"
    )
    fine = {"finite": np.array([1.0, 1.0]), "loss/v_loss": np.array([1.0, np.inf])}
    assert divergence.bad_seeds((3, 4), fine) == [1]
    assert divergence.first_non_finite((3, 4), fine, ts, 1) == "loss/v_loss is inf in seed 4"


DIVERGING = """
import sys
import jax
import numpy as np
from train.cli import train as cli
from train.learner.ppo import Learner

real, calls = Learner.epoch, []

def epoch(self, *args):
    calls.append(1)
    ts, es, metrics = real(self, *args)
    if len(calls) == 2:
        metrics = dict(metrics, finite=metrics["finite"] * 0)
        ts = ts.replace(params=jax.tree.map(lambda x: x * np.nan, ts.params))
    return ts, es, metrics

Learner.epoch = epoch
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.full  # two command-line runs, each compiling its learner: minutes on 2 cores
def test_cli_divergence_is_one_line_exit_3_and_resumes_with_a_lower_learning_rate(tmp_path):
    run = tmp_path / "run"
    env = {**os.environ, "COLUMNS": "300", "TTY_COMPATIBLE": "0"}
    script = textwrap.dedent(DIVERGING)
    args = ["--config", "tiny", "--run-dir", str(run)]
    proc = subprocess.run(
        [sys.executable, "-c", script, *args], env=env, capture_output=True, text=True
    )
    assert proc.returncode == 3, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    (line,) = [x for x in proc.stderr.splitlines() if x.startswith("error: ")]
    assert "non-finite values in epoch 2 (policy parameter params/hidden_0/bias is nan" in line
    assert "last good checkpoint: epoch 1" in line
    assert json.loads((run / "status.json").read_text())["state"] == "diverged"
    cmd = [sys.executable, "-m", "train.cli.train", "--resume", str(run)]
    proc = subprocess.run(
        [*cmd, "--ppo.learning-rate", "1e-4"], env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((run / "config.json").read_text())["ppo"]["learning_rate"] == 1e-4
    status = json.loads((run / "status.json").read_text())
    assert (status["state"], status["epoch"]) == ("finished", 3)
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1, 2, 3]


def test_a_path_error_beyond_its_leak_is_named_with_its_bound():
    """The true path error against τ times 2.5 times the reach (a bounded integrator's
    ceiling), as its root mean square from the path reward, else its mean: within it
    nothing is said; beyond it the warning names the figures and the first-order
    integrator; without a path error, or at a NaN (the NaN guard's), nothing."""
    scale = np.array([1.2, 1.6, 10.0])  # reach: hypot 2.0 m/s, so 15 m at τ = 3 s
    out = divergence.path_outgrown
    # one robot in 100 at 150 m: a mean of 1.5 m, a root mean square of 15.0 m
    far = {"path_m": np.array([1.5]), "reward/path_lin": np.array([-4.0 * 225.1])}
    assert out(far, 3.0, 0.0, scale) is None  # the mean alone misses it
    why = out(far, 3.0, 4.0, scale)
    assert why is not None
    assert why.startswith("the true path error's root mean square is 15 m, beyond the 15 m a")
    assert "env.path_integrator = 'euler'" in why
    assert out({"path_m": np.array([0.4, 14.9])}, 3.0, 0.0, scale) is None
    assert out({"path_m": np.array([0.4, 87.0])}, 3.0, 0.0, scale).startswith(
        "the true path error's mean is 87 m"
    )
    assert out({"path_m": np.array([87.0])}, 0.0, 4.0, scale) is None
    assert out({"path_m": np.array([np.nan])}, 3.0, 0.0, scale) is None
    assert out({}, 3.0, 4.0, scale) is None


def test_a_run_warns_once_when_the_path_error_outgrows_its_leak(
    tiny, learner, tmp_path, monkeypatch
):
    """The warning is a line of the run's log, said once, and the run goes on."""
    import io

    from rich.console import Console

    out = io.StringIO()
    run = Run.create(tiny, tmp_path / "run", console=Console(file=out, width=400))
    _poison_epoch(learner, monkeypatch, 1, lambda ts, m: (ts, dict(m, path_m=m["path_m"] + 1e3)))
    _poison_epoch(learner, monkeypatch, 2, lambda ts, m: (ts, dict(m, path_m=m["path_m"] + 1e3)))
    # tiny observes no path error (τ = 0): the check sees the config's τ as 3 s
    real = divergence.path_outgrown
    monkeypatch.setattr(divergence, "path_outgrown", lambda m, tau, w, s: real(m, 3.0, 0.0, s))
    run.train(learner=learner)
    text = out.getvalue()
    assert text.count("warning: epoch 1: the true path error's mean is") == 1
    assert "warning: epoch 2" not in text
    assert json.loads((run.dir / "status.json").read_text())["state"] == "finished"
