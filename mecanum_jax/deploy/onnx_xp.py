"""An array namespace that records ONNX nodes: the controller's code, run on it, becomes
the ONNX graph (:mod:`.onnx`), so the graph is derived from the code the environment and
the NumPy policy run, not written beside it.

It covers what :mod:`mecanum_jax.control` uses: arithmetic and comparisons (Python
scalars and NumPy arrays become float32 constants), ``@`` with a constant matrix,
elementwise functions, reductions over one axis, ``where``, ``clip``, ``concat``, ``take``
with constant indices, ``astype`` and indexing of the trailing axes with ``...``, slices,
``None`` and integers. The batch axis stays symbolic.
"""

from __future__ import annotations

import builtins
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt
    import onnx

FLOAT, BOOL, INT32, INT64 = 1, 9, 6, 7  # onnx.TensorProto's element types

Operand: TypeAlias = "Value | npt.ArrayLike"
"""What the namespace takes as an array: a traced value, or a constant NumPy array or scalar."""


class Graph:
    """The nodes and constants recorded so far; each node's one output named for it."""

    def __init__(self) -> None:
        import onnx.helper as oh
        import onnx.numpy_helper as onh

        self._oh, self._onh = oh, onh
        self.nodes: list[onnx.NodeProto] = []
        self.initializers: list[onnx.TensorProto] = []
        self._count = 0

    def name(self, kind: str) -> str:
        self._count += 1
        return f"{kind.lower()}_{self._count}"

    def const(self, value: npt.ArrayLike, dtype: npt.DTypeLike = np.float32) -> str:
        name = self.name("const")
        self.initializers.append(self._onh.from_array(np.asarray(value, dtype), name))
        return name

    def op(self, kind: str, *inputs: str, out: str | None = None, **attrs: Any) -> str:
        name = out or self.name(kind)
        self.nodes.append(self._oh.make_node(kind, list(inputs), [name], **attrs))
        return name


class Value:
    """One traced array: its name in the graph, its rank and its element type."""

    __array_ufunc__ = None  # NumPy arrays defer to this class's reflected operators

    def __init__(self, xp: Namespace, name: str, ndim: int, dtype: int = FLOAT):
        self.xp, self.name, self.ndim, self.dtype = xp, name, ndim, dtype

    def _bin(
        self, kind: str, other: Operand, swap: bool = False, dtype: int | None = None
    ) -> Value:
        o = self.xp.asarray(other)
        a, b = (o, self) if swap else (self, o)
        out = self.xp.g.op(kind, a.name, b.name)
        return Value(self.xp, out, max(a.ndim, b.ndim), self.dtype if dtype is None else dtype)

    def __add__(self, o: Operand) -> Value:
        return self._bin("Add", o)

    def __radd__(self, o: Operand) -> Value:
        return self._bin("Add", o, True)

    def __sub__(self, o: Operand) -> Value:
        return self._bin("Sub", o)

    def __rsub__(self, o: Operand) -> Value:
        return self._bin("Sub", o, True)

    def __mul__(self, o: Operand) -> Value:
        return self._bin("Mul", o)

    def __rmul__(self, o: Operand) -> Value:
        return self._bin("Mul", o, True)

    def __truediv__(self, o: Operand) -> Value:
        return self._bin("Div", o)

    def __rtruediv__(self, o: Operand) -> Value:
        return self._bin("Div", o, True)

    def __neg__(self) -> Value:
        return self.xp._unary("Neg", self)

    def __matmul__(self, o: Operand) -> Value:
        return self._bin("MatMul", o)

    def __gt__(self, o: Operand) -> Value:
        return self._bin("Greater", o, dtype=BOOL)

    def __ge__(self, o: Operand) -> Value:
        return self._bin("GreaterOrEqual", o, dtype=BOOL)

    def __lt__(self, o: Operand) -> Value:
        return self._bin("Less", o, dtype=BOOL)

    def __le__(self, o: Operand) -> Value:
        return self._bin("LessOrEqual", o, dtype=BOOL)

    def __eq__(self, o: Operand) -> Value:  # type: ignore[override]
        return self._bin("Equal", o, dtype=BOOL)

    __hash__ = object.__hash__

    def __getitem__(self, key: object) -> Value:
        items = key if isinstance(key, tuple) else (key,)
        if not items or items[0] is not Ellipsis:
            raise TypeError(f"onnx_xp: index {key!r}: only x[..., ...] is traced")
        rest, g = items[1:], self.xp.g
        real = [k for k in rest if k is not None]
        x, ndim = self.name, self.ndim
        dropped = 0
        for j, k in enumerate(real):
            axis = self.ndim - len(real) + j - dropped
            if isinstance(k, slice):
                if k.step not in (None, 1):
                    raise TypeError(f"onnx_xp: slice {k!r}: steps are not traced")
                lo = 0 if k.start is None else k.start
                hi = np.iinfo(np.int64).max if k.stop is None else k.stop
                cs = [g.const([v], np.int64) for v in (lo, hi, axis)]
                x = g.op("Slice", x, *cs)
            elif isinstance(k, int):
                x = g.op("Gather", x, g.const(k, np.int64), axis=axis)
                ndim, dropped = ndim - 1, dropped + 1
            else:
                raise TypeError(f"onnx_xp: index item {k!r} is not traced")
        kept = [k for k in rest if not isinstance(k, int)]
        news = [i for i, k in enumerate(kept) if k is None]
        if news:
            out_ndim = ndim + len(news)
            axes = [out_ndim - len(kept) + i for i in news]
            x = g.op("Unsqueeze", x, g.const(axes, np.int64))
            ndim = out_ndim
        return Value(self.xp, x, ndim, self.dtype)


class Namespace:
    """The array namespace (``xp``) that records into :attr:`g`."""

    float32, int32, bool = FLOAT, INT32, BOOL

    def __init__(self) -> None:
        self.g = Graph()

    def input(self, name: str, ndim: int) -> Value:
        return Value(self, name, ndim)

    def asarray(self, x: Operand, dtype: int | None = None) -> Value:
        if isinstance(x, Value):
            return x
        a = np.asarray(x)
        np_dtypes: dict[int | None, type[np.generic]] = {
            INT32: np.int32,
            INT64: np.int64,
            BOOL: np.bool_,
        }
        np_dtype = np_dtypes.get(dtype, np.float32)
        if a.dtype == np.bool_ and dtype is None:
            np_dtype = np.bool_
        kinds = {np.int32: INT32, np.int64: INT64, np.bool_: BOOL}
        kind = kinds.get(np_dtype, FLOAT)
        return Value(self, self.g.const(a, np_dtype), a.ndim, kind)

    def _unary(self, kind: str, x: Operand, **attrs: Any) -> Value:
        v = self.asarray(x)
        return Value(self, self.g.op(kind, v.name, **attrs), v.ndim, v.dtype)

    def abs(self, x: Operand) -> Value:
        return self._unary("Abs", x)

    def sign(self, x: Operand) -> Value:
        return self._unary("Sign", x)

    def tanh(self, x: Operand) -> Value:
        return self._unary("Tanh", x)

    def exp(self, x: Operand) -> Value:
        return self._unary("Exp", x)

    def cos(self, x: Operand) -> Value:
        return self._unary("Cos", x)

    def sin(self, x: Operand) -> Value:
        return self._unary("Sin", x)

    def maximum(self, a: Operand, b: Operand) -> Value:
        return self.asarray(a)._bin("Max", b)

    def minimum(self, a: Operand, b: Operand) -> Value:
        return self.asarray(a)._bin("Min", b)

    def clip(self, x: Operand, lo: Operand, hi: Operand) -> Value:
        return self.minimum(self.maximum(x, lo), hi)

    def where(self, cond: Value, a: Operand, b: Operand) -> Value:
        va, vb = self.asarray(a), self.asarray(b)
        out = self.g.op("Where", cond.name, va.name, vb.name)
        return Value(self, out, max(cond.ndim, va.ndim, vb.ndim), va.dtype)

    def logical_and(self, a: Value, b: Value) -> Value:
        return a._bin("And", b, dtype=BOOL)

    def logical_or(self, a: Value, b: Value) -> Value:
        return a._bin("Or", b, dtype=BOOL)

    def astype(self, x: Value, dtype: int) -> Value:
        return Value(self, self.g.op("Cast", x.name, to=dtype), x.ndim, dtype)

    def _reduce(self, kind: str, x: Value, axis: int, keepdims: builtins.bool) -> Value:
        axes = self.g.const([axis], np.int64)
        out = self.g.op(kind, x.name, axes, keepdims=int(keepdims))
        return Value(self, out, x.ndim - (0 if keepdims else 1), x.dtype)

    def sum(self, x: Value, axis: int = -1, keepdims: builtins.bool = False) -> Value:
        return self._reduce("ReduceSum", x, axis, keepdims)

    def max(self, x: Value, axis: int = -1, keepdims: builtins.bool = False) -> Value:
        return self._reduce("ReduceMax", x, axis, keepdims)

    def min(self, x: Value, axis: int = -1, keepdims: builtins.bool = False) -> Value:
        return self._reduce("ReduceMin", x, axis, keepdims)

    def all(self, x: Value, axis: int = -1, keepdims: builtins.bool = False) -> Value:
        low = self.min(self.astype(x, FLOAT), axis, keepdims)
        return self.astype(low, BOOL)

    def argmin(self, x: Value, axis: int = -1) -> Value:
        out = self.g.op("ArgMin", x.name, axis=axis, keepdims=0)
        return Value(self, out, x.ndim - 1, INT64)

    def arange(self, n: int) -> Value:
        return self.asarray(np.arange(n, dtype=np.int64), INT64)

    def concat(self, parts: list[Operand], axis: int = -1) -> Value:
        vs = [self.asarray(p) for p in parts]
        return Value(self, self.g.op("Concat", *(v.name for v in vs), axis=axis), vs[0].ndim)

    def take(self, x: Value, indices: npt.ArrayLike, axis: int = -1) -> Value:
        idx = np.asarray(indices, np.int64)
        out = self.g.op("Gather", x.name, self.g.const(idx, np.int64), axis=axis)
        return Value(self, out, x.ndim - 1 + idx.ndim, x.dtype)


__all__ = ["Graph", "Namespace", "Value"]
