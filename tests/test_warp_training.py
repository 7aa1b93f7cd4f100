"""Training under MJX's Warp implementation (env.physics_impl = "warp"), the GPU path, on
the CPU: Warp runs its kernels there too. Needs the warp extra, which `./dev test --full`
installs. A Warp data tree once crashed the learner's device program ('axis 0 is out of
bounds' in mjx/warp/types.py) while every JAX-physics test passed."""

import dataclasses
import json

import jax
import numpy as np
import pytest

pytest.importorskip("warp")

from train import checkpoint
from train.ppo import Learner
from train.run import Run

pytestmark = pytest.mark.full  # Warp compiles its kernels for the CPU on first use


def test_warp_training_interrupts_and_resumes(tiny, tmp_path, monkeypatch):
    cfg = dataclasses.replace(tiny, env=dataclasses.replace(tiny.env, physics_impl="warp"))
    learner = Learner(cfg)
    run = Run.create(cfg, tmp_path / "warp")
    real_epoch, calls = learner.epoch, {"n": 0}

    def epoch_then_ctrl_c(*args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_epoch(*args)

    monkeypatch.setattr(learner, "epoch", epoch_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        run.train(learner=learner)
    monkeypatch.setattr(learner, "epoch", real_epoch)
    assert checkpoint.latest_epoch(run.dir) == 1

    summary = Run.resume(run.dir).train(learner=learner)
    assert summary["epochs"] == 3
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]
    assert all(x["train"]["finite"] == 1.0 for x in lines), lines
    state, env_state = learner.init()
    host, env, meta = checkpoint.restore(
        run.dir, jax.tree.map(np.asarray, state), jax.tree.map(np.asarray, env_state)
    )
    assert meta["epoch"] == 3
    floats = [x for x in jax.tree.leaves(host) if np.issubdtype(x.dtype, np.floating)]
    assert floats
    assert all(np.isfinite(x).all() for x in floats)
    assert any(np.asarray(x).size and np.asarray(x).any() for x in jax.tree.leaves(env))
