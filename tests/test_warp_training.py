"""Training under MJX's Warp implementation (env.physics_impl = "warp"), the GPU path, on
the CPU: Warp runs its kernels there too. Needs the warp extra, which `./dev test --full`
installs. A Warp data tree once crashed the learner's device program ('axis 0 is out of
bounds' in mjx/warp/types.py) while every JAX-physics test passed.

The runs are fresh `mecanum-train` processes with the persistent compilation cache off:
inside the long test process, writing a Warp program's XLA:CPU executable to the cache
crashed twice in CI (abort, then segfault, in jax's put_executable_and_time)."""

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("warp")

pytestmark = pytest.mark.full  # Warp compiles its kernels for the CPU on first use


def _train(*args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    cmd = [sys.executable, "-m", "train.cli.train", "--compilation-cache", "off", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)


def test_warp_training_stops_and_resumes(tmp_path):
    run = tmp_path / "warp"
    # a time limit that the first epoch passes: the run stops resumably after it
    first = _train(
        "--config", "tiny", "--env.physics-impl", "warp", "--run-dir", str(run),
        "--max-minutes", "0.001",
    )  # fmt: skip
    assert first.returncode == 0, first.stderr[-3000:]
    assert json.loads((run / "status.json").read_text())["state"] == "stopped"
    done = [json.loads(x)["epoch"] for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert done == [1]
    second = _train("--resume", str(run))
    assert second.returncode == 0, second.stderr[-3000:]
    lines = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]
    assert all(x["train"]["finite"] == 1.0 for x in lines), lines
    summary = json.loads((run / "summary.json").read_text())
    assert summary["epochs"] == 3


SHARED_CHECK = """
import jax, numpy as np
from train.config_loading import apply_flags, load_train_config
from train.learner.ppo import Learner
flags = ["--env.physics-impl", "warp", "--ppo.num-envs", "16", "--ppo.batch-size", "16"]
learner = Learner(apply_flags(load_train_config("tiny"), flags, "check"))
fresh = learner._shared  # built from shapes, before any reset
assert len(fresh) > 0 and sorted(fresh) == sorted(learner._shared_at), learner._shared_at
# a reset of one robot, and the robots' batch reset: their counters (the small leaves)
# are what the learner starts every program with; the buffers the learner zeroes
one = jax.tree.leaves(jax.jit(learner.env.reset)(jax.numpy.zeros((2,), jax.numpy.uint32)))
_, keys = learner.init_training()
batch = jax.tree.leaves(learner.reset_program(keys))
for leaves in (one, batch):
    for i, y in fresh.items():
        x = np.asarray(leaves[i])
        assert x.dtype == y.dtype and x.shape == y.shape, i
        assert x.size > 64 or np.array_equal(x, y), (i, x)
ts, env = learner.init()
ts, env, metrics = learner.epoch(ts, env)
assert np.all(np.asarray(metrics["finite"]) > 0)
print("ok", len(fresh))
"""


def test_batch_wide_leaves_are_those_a_reset_makes():
    """MuJoCo Warp's batch-wide buffers, built from shapes before any reset, hold the
    counters a reset of one robot and the robots' batch reset make, and an epoch runs on
    them."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    done = subprocess.run(
        [sys.executable, "-c", SHARED_CHECK], capture_output=True, text=True, env=env,
        timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "ok " in done.stdout
