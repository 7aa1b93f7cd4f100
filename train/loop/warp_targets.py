"""MuJoCo Warp's FFI targets, for executables that are loaded without being traced.

MJX's Warp implementation calls its kernels through XLA FFI targets that Warp registers
when a call is first traced (``mujoco.mjx.warp.ffi.jax_callable_variadic_tuple``), one per
call structure (the shim, the model's and data's layout, the batch), named in the order
they were made (``..._func_wrapper_0``, ``_1``, ...). An executable compiled in one process
names the targets of that process; loaded into a fresh one, which has traced nothing,
those targets do not exist and XLA refuses it (``No FFI handler registered``).

:func:`used` records, when a program is stored, each Warp target it calls: its name, a
fingerprint of its call structure and its batch. :func:`register` makes them in a fresh
process before the program is loaded: in the order of their numbers, each by tracing (not
running) one physics step of the robot at its batch (``jax.eval_shape``), which is what made
it in the first place; it succeeds only if every target then exists under its name with its
fingerprint, so an executable never calls a target of another structure. Where it does
not, the program is compiled as usual (train/loop/warm_start.py).
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TypedDict

import jax
import jax.numpy as jnp

if TYPE_CHECKING:
    from mecanum_jax.sim.physics import Robot
    from mecanum_jax.sim.state import RobotParams, SimState


class Target(TypedDict):
    """A Warp target a program calls."""

    name: str
    fingerprint: str
    """:func:`fingerprint` of its call structure."""
    batch: int
    """The robots per call."""


Tracer = Callable[[int], None]
"""Traces one physics step at a batch (:func:`step_tracer`)."""

_CALL = re.compile(r'custom_call_target="([^"]+)"')
_NUMBER = re.compile(r"_(\d+)$")


def _registry() -> dict[tuple[Any, ...], Any]:
    """MJX's Warp callables by their call structure ({} without MJX's Warp implementation)."""
    import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

    try:
        from mujoco.mjx.warp import ffi
    except ImportError:  # no warp extra: no Warp targets anywhere
        return {}
    return dict(ffi._JAX_CALLABLE_VARIADIC_TUPLE_REGISTRY)


def fingerprint(key: tuple[Any, ...]) -> str:
    """A callable's call structure as a digest that is the same in every process: the
    shim by its qualified name, then the flattened signature, the pytree, the output
    count and shapes and the remaining options as they print."""
    func, *rest = key
    text = repr((func.__module__, func.__qualname__, *rest))
    return hashlib.sha256(text.encode()).hexdigest()


def _batch(key: tuple[Any, ...]) -> int:
    """The robots per call: the leading size of the outputs (``output_dims``)."""
    dims = dict(key[6] or ())
    shape = dims.get("act") or next(iter(dims.values()), (1,))
    return int(shape[0])


def used(hlo_text: str) -> list[Target]:
    """The Warp targets a compiled program's HLO text calls, by number."""
    names = set(_CALL.findall(hlo_text))
    found = [
        Target(name=c.name, fingerprint=fingerprint(k), batch=_batch(k))
        for k, c in _registry().items()
        if c.name in names
    ]
    return sorted(found, key=_number)


def _number(target: Target) -> int:
    match = _NUMBER.search(target["name"])
    return int(match.group(1)) if match else -1


def _made(target: Target) -> bool:
    """Whether ``target`` exists in this process under its name, with its structure."""
    return any(
        c.name == target["name"] and fingerprint(k) == target["fingerprint"]
        for k, c in _registry().items()
    )


def register(targets: Sequence[Target], tracers: Sequence[Tracer]) -> bool:
    """Make ``targets`` (:func:`used`'s) in this process, tracing a physics step with each
    of ``tracers`` at each missing target's batch, in the order of their numbers; whether
    every target then exists under its name with its structure."""
    for target in sorted(targets, key=_number):
        for trace in tracers:
            if _made(target):
                break
            trace(target["batch"])
    return all(_made(t) for t in targets)


def step_tracer(robot: Robot, substeps: int) -> Tracer:
    """Traces ``robot``'s physics step at a batch as a program does: once unbatched for a
    batch of 1 (a reset's step), else vmapped over that many robots (a rollout's)."""

    def trace(batch: int) -> None:
        params = robot.nominal_params()

        def one(p: RobotParams) -> SimState:
            return robot.step(robot.reset(p), jnp.zeros(robot.n_wheels), p, substeps)

        if batch == 1:
            jax.eval_shape(one, params)
        else:
            lead = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *jnp.shape(x))), params)
            jax.eval_shape(jax.vmap(one), lead)

    return trace


__all__ = ["Target", "Tracer", "fingerprint", "register", "step_tracer", "used"]
