"""The epoch compiled ahead of time from shapes (train/aot.py): the shapes it compiles for
are those of the states a learner places."""

from types import SimpleNamespace

import jax
import pytest

from train import aot


def test_abstract_state_has_the_placed_states_shapes_and_dtypes(tiny, learner):
    abstract = aot.abstract_state(learner)
    placed = learner.init()
    for a, p in zip(jax.tree.leaves(abstract), jax.tree.leaves(placed), strict=True):
        assert (a.shape, a.dtype) == (p.shape, p.dtype)
        assert not p.weak_type


def test_compiling_ahead_is_refused_under_warp_naming_the_field():
    """Under MJX's Warp implementation a worker-thread compilation broke the main thread's
    graph capture (H200, 2026-11-27): refused before any tracing."""
    learner = SimpleNamespace(env=SimpleNamespace(robot=SimpleNamespace(impl="warp")))
    with pytest.raises(ValueError, match=r"env\.physics_impl = 'warp'"):
        aot.compile_epoch_ahead(learner)  # type: ignore[arg-type]
