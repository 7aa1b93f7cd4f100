"""train/learner/parallel.py: which devices a run takes, and how its program spreads over them."""

from __future__ import annotations

import dataclasses
import types

import jax
import pytest

from mecanum_jax import tracing
from train.config_loading import load_train_config
from train.learner import parallel


def _gpus(n: int) -> list[types.SimpleNamespace]:
    return [types.SimpleNamespace(platform="gpu", id=i) for i in range(n)]


def _cfg(impl: str, max_devices: int = 0, how: str = "auto"):
    cfg = load_train_config("gpu")
    env = dataclasses.replace(cfg.env, physics_impl=impl)
    run = dataclasses.replace(cfg.run, max_devices=max_devices, parallel=how)
    return dataclasses.replace(cfg, env=env, run=run)


def test_a_warp_run_on_several_gpus_splits_its_rollouts(monkeypatch, capsys):
    gpus = _gpus(2)
    monkeypatch.setattr(jax, "local_devices", lambda: gpus)
    assert [d.id for d in parallel.devices_for(_cfg("warp"))] == [0, 1]
    assert parallel.choose(_cfg("warp"), gpus, processes=1) == "split"
    # several processes cannot split (one process's devices are its mesh): sharded
    assert parallel.choose(_cfg("warp"), gpus, processes=2) == "sharded"
    assert parallel.choose(_cfg("jax"), gpus, processes=1) == "sharded"
    assert parallel.choose(_cfg("jax"), gpus[:1], processes=1) == "pmap"
    assert parallel.choose(_cfg("warp", how="pmap"), gpus, processes=1) == "pmap"
    assert capsys.readouterr().err == ""


def test_a_sharded_warp_run_takes_one_gpu_and_says_why(monkeypatch, capsys):
    monkeypatch.setattr(jax, "local_devices", lambda: _gpus(2))
    assert [d.id for d in parallel.devices_for(_cfg("warp", how="sharded"))] == [0]
    assert "training on 1 of 2 GPUs" in capsys.readouterr().err
    # asked for: as many as asked; under MJX's JAX physics: all of them
    assert [d.id for d in parallel.devices_for(_cfg("warp", 2, "sharded"))] == [0, 1]
    assert [d.id for d in parallel.devices_for(_cfg("jax", how="sharded"))] == [0, 1]
    assert capsys.readouterr().err == ""


def test_cpu_devices_are_all_taken_whatever_the_physics(monkeypatch):
    cpus = [types.SimpleNamespace(platform="cpu", id=i) for i in range(2)]
    monkeypatch.setattr(jax, "local_devices", lambda: cpus)
    assert len(parallel.devices_for(_cfg("warp", how="sharded"))) == 2
    assert parallel.choose(_cfg("warp"), cpus, processes=1) == "pmap"


@pytest.mark.parametrize("how", ["sharded", "split", "pmap"])
def test_the_mesh_is_the_sharded_paths_only(how):
    sharding = parallel.mesh_sharding(how, jax.local_devices())
    if how == "pmap":
        assert sharding is None
    else:
        assert sharding is not None
        assert sharding.spec[0] == parallel.MESH_AXIS


@pytest.mark.parametrize("how", ["sharded", "split", "pmap"])
def test_a_program_over_several_devices_draws_through_the_unrolled_threefry(how, threefry_flag):
    """XLA's partitioner cannot split the GPUs' threefry kernel (a custom call): where a
    program spans the devices, the kernel is turned off; pmap's programs keep it."""
    assert tracing.threefry_kernel_on_gpus()
    assert not parallel.partitionable_draws(how, jax.local_devices()[:1])
    assert getattr(jax.config, threefry_flag)
    spans = parallel.partitionable_draws(how, jax.local_devices())
    assert spans == (how != "pmap")
    assert getattr(jax.config, threefry_flag) == (how == "pmap")
