"""An exported policy as one ONNX graph: raw policy observations in, actions and wheel-rate
setpoints out, for robot-side inference with onnxruntime (or any ONNX runtime).

The graph is traced from the controller's own code (:func:`.policy.outputs`, run on
:mod:`.onnx_xp`'s recording namespace), so it computes what the environment and the
NumPy policy compute: the normalizer and clip, the network (averaged over the mirror
group where the policy is symmetric), the deadband, the stop rule and the filter, the
base (analytic, or the ``feedback`` controller with its nearest-feasible projection), the
correction and the clip to the wheel-rate limits.

Inputs: ``observation`` (batch, observation_size), float32, laid out as
``meta["observation_layout"]`` (what :meth:`NumpyPolicy.observation` builds), and
``command_age`` (batch, 1), float32: control periods since the command last changed (0 at
its first), which the integrator's hold and the correction's ramp-in read. Outputs:
``action`` (batch, action_size) in [-1, 1] and ``wheel_setpoints`` (batch, n) in rad/s of
the wheel; a policy on the ``feedback`` controller has a third, ``feedback_integral``
(batch, 1), the integrator after this step, which the next observation carries (rad/s).
The export's metadata is stored as the
model's ``metadata_props``. Needs the ``onnx`` extra (``pip install mecanum-jax[onnx]``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from mecanum_jax import atomic
from mecanum_jax.deploy.onnx_xp import Namespace
from mecanum_jax.deploy.policy import NumpyPolicy, outputs

if TYPE_CHECKING:
    import onnx

OPSET = 18


def to_onnx(policy: NumpyPolicy) -> onnx.ModelProto:
    """The policy and its control loop as an ``onnx.ModelProto`` (see the module's doc)."""
    import onnx
    import onnx.helper as oh

    xp = Namespace()
    obs = xp.input("observation", 2)
    traced = outputs(policy, obs, xp.input("command_age", 2), xp)
    names = ["action", "wheel_setpoints", "feedback_integral"][: len(traced)]
    for name, value in zip(names, traced, strict=True):
        xp.g.op("Identity", value.name, out=name)
    f32 = onnx.TensorProto.FLOAT
    sizes = [policy.action_size, len(policy.max_rates), 1]
    outs = list(zip(names, sizes, strict=False))
    graph = oh.make_graph(
        xp.g.nodes,
        "mecanum_policy",
        [
            oh.make_tensor_value_info("observation", f32, ["batch", policy.observation_size]),
            oh.make_tensor_value_info("command_age", f32, ["batch", 1]),
        ],
        [oh.make_tensor_value_info(n, f32, ["batch", k]) for n, k in outs],
        xp.g.initializers,
    )
    model = oh.make_model(
        graph, opset_imports=[oh.make_opsetid("", OPSET)], producer_name="mecanum-jax"
    )
    model.ir_version = 8  # readable by onnxruntime >= 1.14
    oh.set_model_props(model, {"mecanum_policy_meta": json.dumps(policy.meta)})
    onnx.checker.check_model(model)
    return model


def write_onnx(policy: NumpyPolicy, path: str | Path) -> Path:
    """Write :func:`to_onnx` of ``policy`` to ``path`` (a ``.onnx`` file), atomically: a
    full disk leaves no file under ``path`` (:mod:`mecanum_jax.atomic`)."""
    path = Path(path)
    atomic.write_bytes(path, to_onnx(policy).SerializeToString())
    return path


__all__ = ["OPSET", "to_onnx", "write_onnx"]
