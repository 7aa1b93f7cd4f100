"""Training spread over devices: the sharded and split paths against pmap on the suite's
two CPU devices, and 256 robots on the CPU."""

import dataclasses
import itertools

import jax
import numpy as np
import pytest
from learners import trains_through_a_run

from train.learner.ppo import Learner
from train.learner.transfer import to_host
from train.loop.run import Run


@pytest.mark.full
def test_sharded_parallel_trains_like_pmap(full_run, tiny, learner, tmp_path):
    """``run.parallel = "sharded"`` (jit over a device mesh, the workaround for pmap's
    compiler crash on 2 GPUs) computes Brax's pmap path's epoch, on both devices."""
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, parallel="sharded"))
    sharded = Learner(cfg)
    assert sharded.parallel == "sharded"
    host = to_host(learner.init())
    ts, es = sharded.place(*host)
    leaf = jax.tree.leaves(ts)[0]
    assert len(leaf.sharding.device_set) == 2
    assert leaf.sharding.spec[0] == "d"
    ref_ts, _, ref_m = learner.epoch(*learner.place(*host))
    got_ts, _, got_m = sharded.epoch(ts, es)
    # the same epoch up to the two compilations' rounding (~3e-7 after one iteration,
    # which the following iterations' rollouts amplify)
    for k, v in to_host(ref_m).items():
        np.testing.assert_allclose(to_host(got_m)[k], v, rtol=1e-4, atol=1e-6, err_msg=k)
    for x, y in zip(
        jax.tree.leaves(to_host(ref_ts)), jax.tree.leaves(to_host(got_ts)), strict=True
    ):
        if np.issubdtype(y.dtype, np.floating):  # (rng keys differ per device by design)
            np.testing.assert_array_equal(y[0], y[1])  # replicas agree: the all-reduce works
            np.testing.assert_allclose(y, x, rtol=1e-3, atol=1e-5)
        else:
            np.testing.assert_array_equal(y, x)
    # a whole run through it: checkpoints, logs, evaluation
    trains_through_a_run(cfg, sharded, tmp_path / "sharded", full_run[1]["epochs"])


@pytest.mark.full
def test_split_parallel_trains_like_pmap(full_run, tiny, learner, tmp_path):
    """``run.parallel = "split"`` (each device's rollouts in a program of its own, the
    update over the mesh: train/learner/split_epoch.py) computes Brax's pmap path's epoch, with
    each device's robots stepped on that device, and a whole run goes through it."""
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, parallel="split"))
    split = Learner(cfg)
    assert split.parallel == "split"
    with pytest.raises(ValueError, match="compiles its programs on first use"):
        split.compile_epoch(*split.init())
    host = to_host(learner.init())
    ts, es = split.place(*host)
    ref_ts, ref_es, ref_m = learner.epoch(*learner.place(*host))
    got_ts, got_es, got_m = split.epoch(ts, es)
    for tree in (got_ts, got_es):  # each device keeps its own slice
        for leaf in jax.tree.leaves(tree):
            assert [s.data.shape[0] for s in leaf.addressable_shards] == [1, 1]
            assert len(leaf.sharding.device_set) == 2
    for k, v in to_host(ref_m).items():
        np.testing.assert_allclose(to_host(got_m)[k], v, rtol=1e-4, atol=1e-6, err_msg=k)
    pairs = itertools.chain(
        zip(jax.tree.leaves(to_host(ref_ts)), jax.tree.leaves(to_host(got_ts)), strict=True),
        zip(jax.tree.leaves(to_host(ref_es)), jax.tree.leaves(to_host(got_es)), strict=True),
    )
    for x, y in pairs:
        assert x.shape == y.shape
        if np.issubdtype(y.dtype, np.floating):
            np.testing.assert_allclose(y, x, rtol=1e-3, atol=1e-5)
        else:
            np.testing.assert_array_equal(y, x)
    trains_through_a_run(cfg, split, tmp_path / "split", full_run[1]["epochs"])


@pytest.mark.full
def test_cpu_trains_256_robots(tiny, tmp_path):
    """256 robots on CPU used to hang (jaxlib's batched LAPACK deadlock); chunked, they
    train. One epoch of the tiny config at 256 environments."""
    cfg = dataclasses.replace(
        tiny,
        ppo=dataclasses.replace(tiny.ppo, num_envs=256, batch_size=128, num_timesteps=2560),
        run=dataclasses.replace(tiny.run, epoch_iterations=1),
    )
    summary = Run.create(cfg, tmp_path / "r256").train()
    assert summary["epochs"] == 1
    assert summary["env_steps_per_seed"] == 2560
