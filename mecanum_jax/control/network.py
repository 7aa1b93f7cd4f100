"""The policy network as the robot runs it: normalizer, MLP, ``tanh``, and the mirror
average of a symmetric policy (NumPy and the tracer of ONNX graphs; training runs the same
network through Flax and :func:`mecanum_jax.control.symmetry.symmetrize`).
Depends on the standard library and the namespace passed in (copied beside exports).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .spec import ControllerSpec
from .symmetry import symmetrize

ACTIVATIONS: dict[str, Callable[[Any, Any], Any]] = {
    "swish": lambda x, xp: x / (1.0 + xp.exp(-x)),
    "tanh": lambda x, xp: xp.tanh(x),
    "relu": lambda x, xp: xp.maximum(x, 0.0),
    "elu": lambda x, xp: xp.where(x > 0.0, x, xp.exp(xp.minimum(x, 0.0)) - 1.0),
}


def network_output(
    spec: ControllerSpec,
    layers: list[tuple[Any, Any]],
    mean: Any,
    std: Any,
    clip: float,
    activation: str,
    obs: Any,
    xp: Any,
) -> Any:
    """The deterministic action ``tanh(loc)`` for observations (..., size): ``loc`` the
    MLP's first ``action_size`` outputs on the normalized (and clipped, ``clip`` > 0)
    observation, averaged over the mirror group where ``spec.symmetric``."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation = {activation!r}: not one of {sorted(ACTIVATIONS)}")
    act = ACTIVATIONS[activation]
    # once, outside loc: the mirror average's passes share one copy (one ONNX initializer each)
    mu, sigma = xp.asarray(mean), xp.asarray(std)
    weights = [(xp.asarray(w), xp.asarray(b)) for w, b in layers]

    def loc(o: Any) -> Any:
        x = (o - mu) / sigma
        if clip > 0:
            x = xp.clip(x, -clip, clip)
        for i, (w, b) in enumerate(weights):
            x = x @ w + b
            if i < len(weights) - 1:
                x = act(x, xp)
        return x[..., : spec.action_size]

    return xp.tanh(symmetrize(spec, loc, obs, xp) if spec.symmetric else loc(obs))


__all__ = ["ACTIVATIONS", "network_output"]
