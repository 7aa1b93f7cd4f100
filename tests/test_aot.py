"""Programs compiled ahead of their first runs (train/loop/aot.py): the shapes they compile for
are those of the states a learner places."""

from types import SimpleNamespace

import jax
import pytest

from train.loop import aot


def test_abstract_state_has_the_placed_states_shapes_and_dtypes(tiny, learner):
    """Made from shapes alone (no reset runs), for the states the learner places."""
    abstract = aot.abstract_state(learner)
    placed = learner.init()
    for a, p in zip(jax.tree.leaves(abstract), jax.tree.leaves(placed), strict=True):
        assert (a.shape, a.dtype) == (p.shape, p.dtype)
        assert not p.weak_type


def test_compiling_together_leaves_the_first_runs_nothing_to_compile(learner, monkeypatch):
    """:func:`aot.compile_together` compiles the robots' reset, the baseline's evaluation
    and the epoch before any of them runs (under Warp, where they run one after the
    other): their first runs then compile nothing, and they were traced in the order every
    such start keeps (Warp's FFI numbers follow it): the reset, the epoch, the evaluation."""
    from train.learner.transfer import first_device
    from train.tools.compile_log import CompileLog

    evaluator = learner.evaluation.evaluator
    rollout = "jit(_rollout)"  # the evaluation's rollout, shared with the tiny run's tests
    if evaluator._run._cache_size():  # an earlier test of this process compiled it

        def fresh_rollout(*args):  # a program this process has not compiled yet
            return type(evaluator)._rollout(evaluator, *args)

        monkeypatch.setattr(evaluator, "_run", jax.jit(fresh_rollout))
        rollout = "jit(fresh_rollout)"
    order: list[str] = []
    reset = learner.reset_program
    trace, lower_epoch = learner.evaluation.trace, learner.lower_epoch
    monkeypatch.setattr(
        learner,
        "_reset",
        SimpleNamespace(lower=lambda *a: order.append("reset") or reset.lower(*a)),
    )
    monkeypatch.setattr(learner.evaluation, "trace", lambda *a: order.append("eval") or trace(*a))
    monkeypatch.setattr(learner, "lower_epoch", lambda *a: order.append("epoch") or lower_epoch(*a))
    with CompileLog() as log:
        host, compiled_reset = aot.compile_together(learner)
    assert order == ["reset", "epoch", "eval"]
    compiled = [e["name"] for e in log.events if e["event"] == "compile_s"]
    assert rollout in compiled  # the evaluation's rollout
    assert isinstance(compiled_reset, jax.stages.Compiled)  # the robots' reset
    assert "jit(_fun)" in compiled  # the epoch (train.learner.parallel.spread's)
    with CompileLog() as log:
        ts, env = learner.init(host, compiled_reset)
        learner.evaluate_baseline(first_device(ts))
        jax.block_until_ready(learner.epoch(ts, env))
    again = [e["name"] for e in log.events if e["event"] in ("trace_s", "compile_s")]
    big = (rollout, "jit(_fun)")
    assert [n for n in again if n in big] == []
    # the same start as an uncompiled one: the same fresh state
    ts2, env2 = learner.init(host, reset)
    for a, b in zip(jax.tree.leaves((ts, env)), jax.tree.leaves((ts2, env2)), strict=True):
        assert (a.shape, a.dtype) == (b.shape, b.dtype)
        assert bool((a == b).all())


def test_compiling_together_is_refused_on_the_split_path():
    learner = SimpleNamespace(parallel="split", n_processes=1)
    assert not aot.can_compile_together(learner)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="split"):
        aot.compile_together(learner)  # type: ignore[arg-type]
