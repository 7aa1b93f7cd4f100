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


GEOM = geometry.o_rectangle(0.05, 0.1, 0.125)
RATES = jnp.full((4,), 30.0)


def test_nearest_feasible_asks_for_highest_precision_on_every_product():
    twists = jnp.asarray([[3.0, 0.5, 2.0], [0.1, 0.0, 0.0], [0.0, -4.0, 9.0]])
    assert all_highest(lambda t: limits.nearest_feasible(GEOM, t, RATES, 0.1), twists) == []


def test_the_feasible_target_path_asks_for_highest_precision():
    """The steady-state error's target: the real robot's radii, then nearest_feasible."""
    env = types.SimpleNamespace(
        geometry=GEOM,
        max_rates=RATES,
        config=types.SimpleNamespace(feedback=references.FeedbackConfig()),
    )
    fn = lambda c, s: references.feasible_target(env, c, s)  # noqa: E731
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
    from train import evaluate

    seen: dict[str, str] = {}
    real = evaluate.MecanumEnv

    def recording_env(*args: Any, **kwargs: Any) -> Any:
        seen["env"] = matmul_precision()
        return real(*args, **kwargs)

    monkeypatch.setattr(evaluate, "MecanumEnv", recording_env)
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
