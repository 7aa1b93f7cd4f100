"""One number on every device: the kinematics' projections ask for full float32 products
themselves, and the entry points set the run's matmul precision before tracing."""

from __future__ import annotations

import types
from typing import Any

import jax
import jax.numpy as jnp
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.kinematics import geometry, limits
from mecanum_jax.precision import HIGHEST, matmul_precision, set_matmul_precision
from mecanum_jax.task import references


def dot_precisions(jaxpr: Any) -> list[Any]:
    """The ``precision`` of every ``dot_general`` in a jaxpr, sub-jaxprs included."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            found.append(eqn.params["precision"])
        for value in eqn.params.values():
            for sub in value if isinstance(value, list | tuple) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    found += dot_precisions(inner)
    return found


def all_highest(fn: Any, *args: Any) -> list[Any]:
    # under a low global default, so only an explicit precision can pass
    with jax.default_matmul_precision("bfloat16"):
        precisions = dot_precisions(jax.make_jaxpr(fn)(*args).jaxpr)
    assert precisions, "no dot_general traced: the check would pass vacuously"
    return [p for p in precisions if p != (HIGHEST, HIGHEST)]


DEFAULT = jax.lax.Precision.DEFAULT
GEOM = geometry.o_rectangle(0.05, 0.1, 0.125)
RATES = jnp.full((4,), 30.0)


def test_nearest_feasible_asks_for_highest_precision_on_every_product():
    twists = jnp.asarray([[3.0, 0.5, 2.0], [0.1, 0.0, 0.0], [0.0, -4.0, 9.0]])
    assert all_highest(lambda t: limits.nearest_feasible(GEOM, t, RATES, 0.1), twists) == []


def test_the_feasible_target_path_asks_for_highest_precision():
    """The steady-state error's target: the real robot's radii, then nearest_feasible."""
    robot = types.SimpleNamespace(geometry=GEOM, max_rates=RATES)
    w = references.FeedbackConfig().omega_weight
    fn = lambda c, s: references.feasible_target(robot, c, s, w)  # noqa: E731
    assert all_highest(fn, jnp.asarray([2.0, 1.0, 3.0]), jnp.full((4,), 1.03)) == []


def test_the_check_sees_a_product_at_the_default_precision():
    """The checks above can fail: a plain einsum is traced at the global default."""
    bad = all_highest(lambda a: jnp.einsum("ij,jk->ik", a, a), jnp.ones((3, 3)))
    assert len(bad) == 1


def test_set_matmul_precision_round_trip_and_bad_value():
    before = matmul_precision()
    try:
        set_matmul_precision("default")
        assert matmul_precision() == "default"
        set_matmul_precision("highest")
        assert matmul_precision() == "highest"
        with pytest.raises(ConfigError, match=r"--matmul-precision = 'tf32'"):
            set_matmul_precision("tf32", "--matmul-precision")
    finally:
        set_matmul_precision(before)


def test_mecanum_eval_sets_the_configs_precision_before_tracing(monkeypatch, tmp_path):
    """The evaluation's environment and rollouts are built under the run's precision."""
    from train.cli import eval_target, evaluate

    seen: dict[str, str] = {}
    real = eval_target.MecanumEnv

    def recording_env(*args: Any, **kwargs: Any) -> Any:
        seen["env"] = matmul_precision()
        return real(*args, **kwargs)

    monkeypatch.setattr(eval_target, "MecanumEnv", recording_env)
    before = matmul_precision()
    set_matmul_precision("default")
    try:
        args = evaluate.EvalArgs(
            target="baseline", only=("nominal",), episodes=2, seconds=0.5, out=str(tmp_path / "e")
        )
        target, _, _ = evaluate._prepare(args)
        assert seen["env"] == "highest"
        assert target.precision == "highest"
        args.matmul_precision = "default"
        args.out = str(tmp_path / "f")
        evaluate._prepare(args)
        assert seen["env"] == "default"
    finally:
        set_matmul_precision(before)


def _grad_products(name: str) -> list[Any]:
    from train.learner.losses import at_precision

    def loss(w: jax.Array, x: jax.Array) -> jax.Array:
        return jnp.sum(jnp.tanh(x @ w) @ w)

    fn = at_precision(jax.grad(loss), name)
    before = matmul_precision()
    set_matmul_precision("highest")
    try:
        return dot_precisions(jax.make_jaxpr(fn)(jnp.ones((3, 3)), jnp.ones((5, 3))).jaxpr)
    finally:
        set_matmul_precision(before)


def test_the_update_precision_applies_to_a_gradient_inside_and_only_there():
    """``ppo.update_precision``: the wrapped loss-and-gradient's products (forward and
    backward) follow it; ``run`` leaves them at the run's precision."""
    run, tf32 = _grad_products("run"), _grad_products("default")
    assert len(run) == len(tf32) >= 4
    assert all(p == (HIGHEST, HIGHEST) for p in run)
    assert all(p == (DEFAULT, DEFAULT) for p in tf32)
    with pytest.raises(ConfigError, match=r"ppo.update_precision = 'tf32'"):
        _grad_products("tf32")


def test_a_bad_update_precision_in_a_config_names_the_field():
    """A TOML file or a run's config.json is read through this parser."""
    from train.config_loading import parse_train_config

    with pytest.raises(ConfigError, match=r"ppo.update_precision = 'fast'"):
        parse_train_config({"ppo": {"update_precision": "fast"}}, "bad.toml")


@pytest.mark.full  # traces a learner's rollouts and update (MJX physics)
def test_the_learner_updates_at_its_update_precision_and_rolls_out_at_the_runs(tiny):
    """With ``update_precision = "default"`` the update's network products drop to the
    device's default while the rollouts (policy inference, physics) stay at ``highest``.
    The learner vmaps its update's scans over seeds, which re-traces their bodies after
    the scope has closed: the products must carry their precision explicitly."""
    import dataclasses

    import numpy as np

    from train.learner.parallel import AXIS
    from train.learner.ppo import Learner

    def products(cfg: Any) -> tuple[list[Any], list[Any]]:
        learner = Learner(cfg)
        state, env_keys = learner.init_training()
        ts = jax.tree.map(lambda x: jnp.asarray(x[0, 0]), state)
        keys = jnp.asarray(np.asarray(env_keys)[0, 0])
        env = jax.eval_shape(learner.train_env.reset, keys)
        one = lambda x: jax.ShapeDtypeStruct((1, *x.shape), x.dtype)  # noqa: E731
        ts, env = jax.tree.map(one, (ts, env))
        rollouts_fn = jax.vmap(learner.iteration_rollouts, axis_name=AXIS)
        update_fn = jax.vmap(learner.update, axis_name=AXIS)  # one device's share
        with jax.numpy_rank_promotion("allow"):  # as the learner's epoch runs them
            rollouts = jax.make_jaxpr(rollouts_fn)(ts, env)
            _, data, _, _ = jax.eval_shape(rollouts_fn, ts, env)
            update = jax.make_jaxpr(update_fn)(ts, data, ts.key)
        return dot_precisions(rollouts.jaxpr), dot_precisions(update.jaxpr)

    before = matmul_precision()
    set_matmul_precision("highest")
    try:
        roll_run, update_run = products(tiny)
        cfg = dataclasses.replace(
            tiny, ppo=dataclasses.replace(tiny.ppo, update_precision="default")
        )
        roll_tf32, update_tf32 = products(cfg)
    finally:
        set_matmul_precision(before)
    assert update_run
    assert all(p == (HIGHEST, HIGHEST) for p in roll_run + update_run)
    assert all(p == (HIGHEST, HIGHEST) for p in roll_tf32)
    assert len(update_tf32) == len(update_run)
    lowered = [p for p in update_tf32 if p == (DEFAULT, DEFAULT)]
    assert len(lowered) >= len(update_tf32) // 2, update_tf32


def test_the_throughput_table_names_the_updates_precision_where_it_differs():
    from train.tools.bench import _precision

    assert _precision({"matmul_precision": "highest", "update_precision": "run"}) == "highest"
    assert _precision({"matmul_precision": "highest", "update_precision": "highest"}) == "highest"
    assert _precision({"matmul_precision": "highest"}) == "highest"  # results before the field
    row = {"matmul_precision": "highest", "update_precision": "default"}
    assert _precision(row) == "highest/default"
