"""The epoch compiled ahead of time from shapes (train/aot.py): the shapes it compiles for
are those of the states a learner places."""

import jax

from train import aot


def test_abstract_state_has_the_placed_states_shapes_and_dtypes(tiny, learner):
    abstract = aot.abstract_state(learner)
    placed = learner.init()
    for a, p in zip(jax.tree.leaves(abstract), jax.tree.leaves(placed), strict=True):
        assert (a.shape, a.dtype) == (p.shape, p.dtype)
        assert not p.weak_type
