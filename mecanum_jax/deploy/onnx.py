"""An exported policy as one ONNX graph: raw policy observations in, actions and wheel-rate
setpoints out, for robot-side inference with onnxruntime (or any ONNX runtime).

The graph holds everything between the observation vector and the servos:

- the observation normalizer (``(obs − mean) / std``, as Brax's running statistics apply
  it) and the observation clip (``± clip_observations``);
- the policy network, deterministic (``action = tanh(loc)``), soft-thresholded where the
  policy was trained with ``residual_deadband``, 0 at a stop command where it was trained
  with ``residual_at_stop = false``, and low-passed where it was trained with an action
  filter;
- the control loop around it: the command read back from the observation's first three
  entries, the analytic baseline (nominal inverse model, desaturated uniformly), the
  residual correction per wheel or of the twist, and the clip to the wheel-rate limits.

Inputs: ``observation`` (batch, observation_size), float32, laid out as
``meta["observation_layout"]`` (what :meth:`NumpyPolicy.observation` builds). Outputs:
``action`` (batch, action_size) in [-1, 1] and ``wheel_setpoints`` (batch, n) in rad/s of
the wheel. A policy whose residual corrects the ``feedback`` controller has that
controller inside too (the PI-corrected twist, projected onto the nearest feasible twist
by :class:`NearestFeasible`'s precomputed maps) and a third output, ``feedback_integral``
(batch, 1): the controller's integrator after this step, which the next observation
carries (rad/s). Where that integrator holds after command changes (``feedback.hold_s``
in the metadata), the graph does not know the command's age: the caller keeps the input
integrator while the command is younger than ``hold_s`` (the control loop does, through
:meth:`NumpyPolicy.feedback_integral_step`). The export's metadata (robot, wheel order,
layout, scales) is stored as the model's ``metadata_props``. Needs the ``onnx`` extra
(``pip install mecanum-jax[onnx]``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from mecanum_jax import atomic
from mecanum_jax.deploy.policy import NearestFeasible, NumpyPolicy

OPSET = 17


class _Graph:
    """A small builder: named constants and nodes, each node's one output named for it."""

    def __init__(self) -> None:
        import onnx.helper as oh
        import onnx.numpy_helper as onh

        self._oh, self._onh = oh, onh
        self.nodes: list[Any] = []
        self.initializers: list[Any] = []
        self._count = 0

    def const(self, name: str, value: Any, dtype: Any = np.float32) -> str:
        self.initializers.append(self._onh.from_array(np.asarray(value, dtype), name))
        return name

    def op(self, kind: str, *inputs: str, name: str | None = None, **attrs: Any) -> str:
        self._count += 1
        out = name or f"{kind.lower()}_{self._count}"
        self.nodes.append(self._oh.make_node(kind, list(inputs), [out], **attrs))
        return out


def _activation(g: _Graph, kind: str, x: str) -> str:
    if kind == "swish":
        return g.op("Mul", x, g.op("Sigmoid", x))
    if kind in ("tanh", "relu", "elu"):
        return g.op({"tanh": "Tanh", "relu": "Relu", "elu": "Elu"}[kind], x)
    raise ValueError(f"activation = {kind!r}: not one of swish, tanh, relu, elu")


def to_onnx(policy: NumpyPolicy) -> Any:
    """The policy and its control loop as an ``onnx.ModelProto`` (see the module's doc)."""
    import onnx
    import onnx.helper as oh

    meta = policy.meta
    g = _Graph()
    n_obs, n_act = policy.observation_size, policy.action_size
    max_rates = policy.max_rates.astype(np.float32)
    centred = g.op("Sub", "observation", g.const("obs_mean", policy.mean))
    x = g.op("Div", centred, g.const("obs_std", policy.std))
    clip = float(meta.get("clip_observations") or 0.0)
    if clip > 0:
        x = g.op("Clip", x, g.const("clip_lo", -clip), g.const("clip_hi", clip))
    for i, (w, b) in enumerate(policy.layers):
        x = g.op("Add", g.op("MatMul", x, g.const(f"w{i}", w)), g.const(f"b{i}", b))
        if i < len(policy.layers) - 1:
            x = _activation(g, meta["activation"], x)
    start = g.const("zero", [0], np.int64)
    axis = g.const("last_axis", [-1], np.int64)
    loc = g.op("Slice", x, start, g.const("n_act", [n_act], np.int64), axis)
    # the command, scaled as observed: the observation's first three entries
    scaled = g.op("Slice", "observation", start, g.const("three", [3], np.int64), axis)
    g.const("one", 1.0)
    squashed = g.op("Tanh", loc)
    d = float(meta.get("residual_deadband") or 0.0)
    if d > 0:  # soft-thresholded (NumpyPolicy)
        shrunk = g.op("Relu", g.op("Sub", g.op("Abs", squashed), g.const("residual_deadband", d)))
        squashed = g.op("Mul", g.op("Sign", squashed), shrunk)
    if not policy.residual_at_stop:  # 0 while the observed command is a stop (NumpyPolicy)
        zero = g.op("Cast", g.op("Equal", scaled, g.const("stop_zero", 0.0)), to=1)  # FLOAT
        stop = g.op("ReduceMin", zero, axes=[-1], keepdims=1)
        squashed = g.op("Mul", squashed, g.op("Sub", "one", stop))
    f = float(meta.get("action_filter") or 0.0)
    if f > 0:  # low-passed with the last action the observation carries
        where = policy.entry("last_action")
        last = g.op(
            "Slice",
            "observation",
            g.const("last_start", [where.start], np.int64),
            g.const("last_end", [where.stop], np.int64),
            axis,
        )
        new = g.op("Mul", squashed, g.const("keep_new", 1.0 - f))
        action = g.op("Add", g.op("Mul", last, g.const("keep_last", f)), new, name="action")
    else:
        action = g.op("Identity", squashed, name="action")

    # the control loop: command from the observation, the desaturated baseline, the residual
    jt = g.const("jacobian_t", policy.jacobian.T)
    command = g.op("Mul", scaled, g.const("command_scale", policy.command_scale))
    m = g.const("max_rates", max_rates)
    outputs = []
    if policy.feedback_base:
        base = _feedback_base(g, policy, command, jt, m)
        outputs.append(("feedback_integral", 1))
    else:
        rates = g.op("MatMul", command, jt)
        excess = g.op("ReduceMax", g.op("Div", g.op("Abs", rates), m), axes=[-1], keepdims=1)
        base = g.op("Div", rates, g.op("Max", excess, "one"))
    scale = np.float32(meta["residual_scale"])
    if meta["residual"] and meta.get("residual_space", "wheel") == "twist":
        twist = g.op("Mul", action, g.const("twist_step", scale * policy.command_scale))
        raw = g.op("Add", base, g.op("MatMul", twist, jt))
    elif meta["residual"]:
        raw = g.op("Add", base, g.op("Mul", action, g.const("wheel_step", scale * max_rates)))
    else:
        raw = g.op("Mul", action, m)
    g.op("Min", g.op("Max", raw, g.const("neg_max_rates", -max_rates)), m, name="wheel_setpoints")

    f32 = onnx.TensorProto.FLOAT
    graph = oh.make_graph(
        g.nodes,
        "mecanum_policy",
        [oh.make_tensor_value_info("observation", f32, ["batch", n_obs])],
        [
            oh.make_tensor_value_info("action", f32, ["batch", n_act]),
            oh.make_tensor_value_info("wheel_setpoints", f32, ["batch", len(max_rates)]),
            *(oh.make_tensor_value_info(name, f32, ["batch", size]) for name, size in outputs),
        ],
        g.initializers,
    )
    model = oh.make_model(
        graph, opset_imports=[oh.make_opsetid("", OPSET)], producer_name="mecanum-jax"
    )
    model.ir_version = 8  # readable by onnxruntime >= 1.10
    oh.set_model_props(model, {"mecanum_policy_meta": json.dumps(meta)})
    onnx.checker.check_model(model)
    return model


def _entry(g: _Graph, policy: NumpyPolicy, name: str, scale: str) -> str:
    """Observation entry ``name`` (batch, size), times ``scale``."""
    where = policy.entry(name)
    lo = g.const(f"{name}_start", [where.start], np.int64)
    hi = g.const(f"{name}_end", [where.stop], np.int64)
    return g.op("Mul", g.op("Slice", "observation", lo, hi, "last_axis"), scale)


def _feedback_base(g: _Graph, policy: NumpyPolicy, command: str, jt: str, m: str) -> str:
    """The ``feedback`` controller's setpoints (batch, n), and its next integrator as the
    graph output ``feedback_integral`` (see :meth:`NumpyPolicy.feedback_integral_step`)."""
    fb = policy.feedback
    wz_scale = g.const("wz_scale", policy.command_scale[2])
    gyro = _entry(g, policy, "gyro_z", wz_scale)
    integral = _entry(g, policy, "feedback_integral", wz_scale)
    wz = g.op("Slice", command, g.const("two", [2], np.int64), "three", "last_axis")
    err = g.op("Sub", wz, gyro)  # (batch, 1)
    u = g.op("Add", g.op("Mul", err, g.const("kp", fb["kp"])), integral)
    band = float(fb.get("deadband") or 0.0)
    if band > 0:  # the correction shrunk towards 0 by the deadband
        shrunk = g.op("Relu", g.op("Sub", g.op("Abs", u), g.const("feedback_deadband", band)))
        u = g.op("Mul", g.op("Sign", u), shrunk)
    twist = g.op("Add", command, g.op("Mul", u, g.const("z_axis", [0.0, 0.0, 1.0])))
    # anti-windup: hold while the corrected twist is out of reach and e would push further
    reach = g.op("ReduceMax", g.op("Div", g.op("Abs", g.op("MatMul", twist, jt)), m),
                 axes=[-1], keepdims=1)  # fmt: skip
    saturated = g.op("Greater", reach, "one")
    g.const("zero_f", 0.0)
    pushing = g.op("Greater", g.op("Mul", err, u), "zero_f")
    step = g.op("Mul", err, g.const("ki_dt", fb["ki"] * float(policy.meta["control_dt"])))
    i_max = float(fb["i_max"])
    grown = g.op(
        "Clip", g.op("Add", integral, step), g.const("i_lo", -i_max), g.const("i_hi", i_max)
    )
    g.op("Where", g.op("And", saturated, pushing), integral, grown, name="feedback_integral")
    # the nearest feasible twist: every facet/edge/vertex projection, the nearest feasible
    near = NearestFeasible(policy.jacobian, policy.max_rates, float(fb["omega_weight"]))
    k = len(near.q)
    c = g.op("Mul", twist, g.const("weights", near.d))  # (batch, 3)
    maps = g.const("projections", near.P.transpose(2, 0, 1).reshape(3, 3 * k))  # c @ Pᵀ
    cand = g.op("Add", g.op("Reshape", g.op("MatMul", c, maps), g.const("k_by_3", [-1, k, 3],
                np.int64)), g.const("offsets", near.q))  # fmt: skip
    au_t = g.const("facets_t", near.Au.T)
    b = g.const("bounds", near.b)
    slack = g.op("Sub", g.const("bounds_tol", near.b + near.tol), g.op("MatMul", cand, au_t))
    feasible = g.op("GreaterOrEqual", g.op("ReduceMin", slack, axes=[-1], keepdims=0), "zero_f")
    diff = g.op("Sub", cand, g.op("Unsqueeze", c, g.const("axis1", [1], np.int64)))
    dist = g.op("ReduceSum", g.op("Mul", diff, diff), g.const("axis_last", [-1], np.int64),
                keepdims=0)  # fmt: skip
    dist = g.op("Where", feasible, dist, g.const("inf", np.inf))
    # the nearest point of a convex set is unique: average the (equal) minimizers
    best = g.op("Cast", g.op("Equal", dist, g.op("ReduceMin", dist, axes=[-1], keepdims=1)),
                to=1)  # fmt: skip
    weight = g.op("Unsqueeze", g.op("Div", best, g.op("ReduceSum", best, "axis_last",
                  keepdims=1)), "axis_last")  # fmt: skip
    nearest = g.op("ReduceSum", g.op("Mul", cand, weight), "axis1", keepdims=0)
    inside = g.op("GreaterOrEqual", g.op("ReduceMin", g.op("Sub", b, g.op("MatMul", c, au_t)),
                  axes=[-1], keepdims=1), "zero_f")  # fmt: skip
    feasible_twist = g.op("Where", inside, twist, g.op("Div", nearest, "weights"))
    return g.op("MatMul", feasible_twist, jt)


def write_onnx(policy: NumpyPolicy, path: str | Path) -> Path:
    """Write :func:`to_onnx` of ``policy`` to ``path`` (a ``.onnx`` file), atomically: a
    full disk leaves no file under ``path`` (:mod:`mecanum_jax.atomic`)."""
    path = Path(path)
    atomic.write_bytes(path, to_onnx(policy).SerializeToString())
    return path


__all__ = ["OPSET", "to_onnx", "write_onnx"]
