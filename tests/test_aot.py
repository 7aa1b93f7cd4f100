"""The epoch compiled ahead of time from shapes (train/aot.py): the shapes it compiles for
are those of the states a learner places."""

import dataclasses
import json
from types import SimpleNamespace

import jax
import pytest

from mecanum_jax.config import ConfigError
from train import aot
from train.run import Run


def test_abstract_state_has_the_placed_states_shapes_and_dtypes(tiny, learner):
    abstract = aot.abstract_state(learner)
    placed = learner.init()
    for a, p in zip(jax.tree.leaves(abstract), jax.tree.leaves(placed), strict=True):
        assert (a.shape, a.dtype) == (p.shape, p.dtype)
        assert not p.weak_type


def _fake(parallel: str, platform: str) -> SimpleNamespace:
    return SimpleNamespace(parallel=parallel, devices=[SimpleNamespace(platform=platform)])


def test_compiles_ahead_by_choice_and_devices():
    assert aot.compiles_ahead(_fake("sharded", "gpu"), "auto")  # type: ignore[arg-type]
    assert not aot.compiles_ahead(_fake("sharded", "cpu"), "auto")  # type: ignore[arg-type]
    assert not aot.compiles_ahead(_fake("split", "gpu"), "auto")  # type: ignore[arg-type]
    assert not aot.compiles_ahead(_fake("sharded", "gpu"), "off")  # type: ignore[arg-type]
    assert aot.compiles_ahead(_fake("pmap", "cpu"), "on")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"run\.compile_ahead = 'on'.*'split'"):
        aot.compiles_ahead(_fake("split", "gpu"), "on")  # type: ignore[arg-type]


def test_compile_ahead_on_with_split_is_rejected_naming_the_field(tiny):
    cfg = dataclasses.replace(
        tiny, run=dataclasses.replace(tiny.run, compile_ahead="on", parallel="split")
    )
    with pytest.raises(ConfigError, match=r"run\.compile_ahead"):
        cfg.validate()


def test_a_run_compiling_ahead_trains_its_epoch(tiny, learner, tmp_path, monkeypatch):
    """``run.compile_ahead = "on"``: the epoch compiles on a worker thread during the
    reset, and the run's first epoch runs that program."""
    calls: list[object] = []
    real = aot.compile_epoch_ahead

    def spy(lrn):
        calls.append(lrn)
        return real(lrn)

    monkeypatch.setattr("train.run.compile_epoch_ahead", spy)
    monkeypatch.setattr("train.run._Loop.eval_due", lambda self, final: False)
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, compile_ahead="on"))
    run = Run.create(cfg, tmp_path / "ahead")
    summary = run.train(learner=learner, time_limit_s=0.0)
    assert calls == [learner]
    assert learner._compiled_epoch is not None
    assert summary["epochs"] == 1
    line = json.loads((run.dir / "metrics.jsonl").read_text().splitlines()[0])
    assert line["train"]["finite"] == 1.0
