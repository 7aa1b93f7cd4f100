"""Shared test helpers: a learner's deterministic policy, random observations, a run's
last checkpoint, a whole run through a learner."""

import json

import jax
import numpy as np

from train.loop.run import Run
from train.store import checkpoint


def deterministic_policy(learner, state):
    """The deterministic policy of seed 0 (device 0) of a ``(D, S, ...)`` training state."""
    one = jax.tree.map(lambda x: x[0, 0], state)
    return learner.make_policy(
        (one.normalizer_params, one.params.policy, one.params.value), deterministic=True
    )


def random_obs(learner, n, seed):
    """``n`` standard-normal observations of ``learner``'s shapes."""
    rng = np.random.default_rng(seed)
    return {
        k: rng.normal(size=(n, *shape)).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }


def final_train_state(run, learner):
    """A run's last checkpoint restored on the host: ``(training state, meta)``."""
    state, env_state = learner.init()
    host, _, meta = checkpoint.restore(
        run.dir, jax.tree.map(np.asarray, state), jax.tree.map(np.asarray, env_state)
    )
    return host, meta


def trains_through_a_run(cfg, learner, run_dir, epochs):
    """A whole run through ``learner``: checkpoints, logs, evaluation, a finite end."""
    run = Run.create(cfg, run_dir)
    summary = run.train(learner=learner)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "finished"
    assert summary["epochs"] == epochs
    restored, _ = final_train_state(run, learner)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(restored))
