"""The epoch compiled ahead of time from shapes (train/aot.py) is the epoch: the states a
learner places run it without another compilation, and it computes what the jitted epoch
computes."""

import jax
import numpy as np
import pytest

from train import aot
from train.coldstart import CompileLog
from train.ppo import Learner


def test_abstract_state_has_the_placed_states_shapes_and_dtypes(tiny, learner):
    abstract = aot.abstract_state(learner)
    placed = learner.init()
    for a, p in zip(jax.tree.leaves(abstract), jax.tree.leaves(placed), strict=True):
        assert (a.shape, a.dtype) == (p.shape, p.dtype)
        assert not p.weak_type


@pytest.mark.full  # compiles the tiny epoch a second time: most of a minute on 2 cores
def test_the_epoch_compiled_ahead_runs_the_placed_states_without_recompiling(tiny, learner):
    fresh = Learner(tiny)
    job = aot.compile_epoch_ahead(fresh)
    ts, env_state = fresh.init()  # the reset runs while the epoch compiles
    job.result()
    with CompileLog() as log:
        ts, env_state, metrics = fresh.epoch(ts, env_state)
        jax.block_until_ready(metrics)
    assert not [p for p in log.programs() if p["compile_s"] > 1.0], log.programs()
    ref_ts, _, ref_metrics = learner.epoch(*learner.init())  # the suite's jitted epoch
    ours, ref = jax.tree.leaves((ts, metrics)), jax.tree.leaves((ref_ts, ref_metrics))
    for a, b in zip(ours, ref, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
