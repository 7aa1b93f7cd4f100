"""How a checkpoint stores a pytree: its leaves by name.

:func:`pack` turns a tree into a flat ``{name: array}`` dict, each name the leaf's path in
the tree (``jax.tree_util.keystr``, e.g. ``.optimizer_state[1][0].mu['params']['policy']
['params']['hidden_0']['kernel']``). :func:`unpack` puts such a dict back into a tree
shaped like a template, matching leaves by name: a leaf missing from either side, or of
another shape, is a :class:`CheckpointError` naming it. So a training state whose leaves
an upgrade reorders (a new optimizer field, a renamed layer) restores into the right slots
or not at all, never silently into the wrong ones.

Zero-size leaves are left out (orbax refuses them; MJX state has several) and rebuilt from
the template. The entry :data:`CHECKSUMS` holds each leaf's CRC-32, in the order of the
sorted names: data stored under another leaf's name (two leaves swapped) or changed on disk
is refused, naming the leaves.

The leaf-index format of earlier versions (``{"00000": leaf 0, "00001": leaf 1, ...}``,
in ``jax.tree.leaves`` order, zero-size leaves skipped) is recognised by its keys and
restored by index with a shape check, as it always was: a checkpoint in that format
cannot tell two reordered leaves of one shape apart.

:func:`prune` and :func:`graft` take the zero-size leaves (and any others) out of a tree
and put them back inside a compiled program: the learner's environment state crosses its
programs, and is checkpointed, pruned. :func:`batch_wide` names the leaves of the
environment state that belong to the whole batch rather than to a robot, which the learner
prunes too and grafts back fresh (:func:`fresh_batch_wide`).
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Collection, Mapping
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

Tree = TypeVar("Tree")
"""A pytree, and what is rebuilt in its shape."""
CHECKSUMS = "crc32"
"""The entry of a packed tree that holds its leaves' checksums (a leaf's name begins with
``.`` or ``[``, so none is called this)."""
INDEX_KEY = re.compile(r"\d{5}")
"""A key of the leaf-index format."""
_SHOWN = 6  # names listed per kind of mismatch


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupt, or does not match what is being loaded."""


def named_leaves(tree: object) -> list[tuple[str, Any]]:
    """``(name, leaf)`` pairs in ``jax.tree.leaves`` order; the name is the leaf's path."""
    pairs, _ = jax.tree_util.tree_flatten_with_path(tree)
    return [(jax.tree_util.keystr(path) or "<root>", x) for path, x in pairs]


def _crc(x: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(x).reshape(-1).view(np.uint8).data)


def pack(tree: object) -> dict[str, np.ndarray]:
    """A pytree as a flat ``{leaf name: numpy array}`` dict without its zero-size leaves,
    plus the :data:`CHECKSUMS` entry.

    Converted leaf by leaf: orbax refuses a process-local jax.Array in a multi-process run,
    and some optimizer states turn leaves back into jax arrays when rebuilt, so
    ``jax.tree.map(np.asarray, tree)`` would not do.
    """
    return with_checksums(
        {n: np.asarray(x) for n, x in named_leaves(tree) if math.prod(np.shape(x))}
    )


def with_checksums(flat: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``flat`` (``{leaf name: array}``) with a fresh :data:`CHECKSUMS` entry."""
    out = {k: v for k, v in flat.items() if k != CHECKSUMS}
    if out:
        out[CHECKSUMS] = np.array([_crc(out[n]) for n in sorted(out)], np.uint32)
    return out


def is_index_format(flat: Mapping[str, object]) -> bool:
    """Whether ``flat`` was packed by an earlier version, by leaf index."""
    return bool(flat) and all(INDEX_KEY.fullmatch(k) for k in flat)


def unpack(template: Tree, flat: Mapping[str, ArrayLike]) -> Tree:
    """Inverse of :func:`pack`: a tree shaped like ``template`` (arrays or shape structs),
    with numpy leaves, matched by name (by index for the leaf-index format). Raises
    :class:`CheckpointError` naming every missing, unexpected or misshaped leaf. Whether
    each leaf holds the data saved under its name (a swap, corruption) is checked where the
    tree is read, by :func:`corruption`."""
    if is_index_format(flat):
        return _unpack_by_index(template, flat)
    saved = {k: v for k, v in flat.items() if k != CHECKSUMS}
    named = named_leaves(template)
    missing, misshaped, out = [], [], []
    for name, x in named:
        shape = np.shape(x)
        if name not in saved:
            if math.prod(shape):
                missing.append(name)
            out.append(np.zeros(shape, x.dtype))
            continue
        value = np.asarray(saved[name])
        if value.shape != shape:
            misshaped.append(f"{name} (shape {value.shape}, expected {shape})")
        out.append(value)
    unexpected = sorted(set(saved) - {n for n, _ in named})
    problems = [
        _listed("missing from the checkpoint", missing),
        _listed("not in this state", unexpected),
        _listed("of another shape", misshaped),
    ]
    problems = [p for p in problems if p]
    if problems:
        raise CheckpointError("checkpoint leaves do not match this state: " + "; ".join(problems))
    return jax.tree.unflatten(jax.tree.structure(template), out)


def corruption(flat: Mapping[str, ArrayLike]) -> str:
    """Why the leaves of a packed tree do not hold the data they were saved with (``""``
    when they do, or when the tree carries no checksums): damage found after decoding."""
    if CHECKSUMS not in flat or is_index_format(flat):
        return ""
    saved = {k: v for k, v in flat.items() if k != CHECKSUMS}
    return _checksum_problem(saved, np.asarray(flat[CHECKSUMS]))


def _listed(what: str, names: list[str]) -> str:
    if not names:
        return ""
    more = f" and {len(names) - _SHOWN} more" if len(names) > _SHOWN else ""
    return f"{len(names)} {what}: {', '.join(names[:_SHOWN])}{more}"


def _checksum_problem(saved: Mapping[str, ArrayLike], sums: np.ndarray) -> str:
    """Which leaves do not hold the data saved under their names, and whose they hold."""
    names = sorted(saved)
    if sums.shape != (len(names),):
        return f"{CHECKSUMS}: {sums.size} checksums for {len(names)} leaves"
    expected = dict(zip(names, (int(s) for s in sums), strict=True))
    owner = {s: n for n, s in expected.items()}
    bad = []
    for name in names:
        actual = _crc(np.asarray(saved[name]))
        if actual != expected[name]:
            other = owner.get(actual)
            bad.append(name + (f" (holds the data saved as {other})" if other else ""))
    return _listed("not holding the data saved under their names (swapped or corrupt)", bad)


def _unpack_by_index(template: Tree, flat: Mapping[str, ArrayLike]) -> Tree:
    """The leaf-index format: leaf ``i`` of the template from key ``f"{i:05d}"``."""
    named = named_leaves(template)
    out, used = [], set()
    for i, (name, x) in enumerate(named):
        key = f"{i:05d}"
        if math.prod(np.shape(x)) == 0:
            out.append(np.zeros(x.shape, x.dtype))
            continue
        if key not in flat:
            raise CheckpointError(f"checkpoint leaf {key} ({name}): missing")
        value = np.asarray(flat[key])
        if np.shape(value) != np.shape(x):
            raise CheckpointError(
                f"checkpoint leaf {key} ({name}): shape {np.shape(value)}, expected "
                f"{np.shape(x)} (saved with another config or device count?)"
            )
        out.append(value)
        used.add(key)
    extra = sorted(set(flat) - used)
    if extra:
        raise CheckpointError(
            f"checkpoint leaves {', '.join(extra[:_SHOWN])}: not in this state, which has "
            f"{len(named)} leaves (saved with another config?)"
        )
    return jax.tree.unflatten(jax.tree.structure(template), out)


def prune(tree: object, drop: Collection[int] = ()) -> dict[str, Any]:
    """``tree``'s leaves as a flat ``{f"{i:05d}": leaf}`` dict, less its zero-size leaves
    and those at ``jax.tree.leaves`` positions ``drop``. A plain dict crosses device
    programs where the tree's own nodes may not: MuJoCo Warp's data types batch their
    leaves themselves and refuse a tree whose leaves were replaced by ``None``."""
    leaves = jax.tree.leaves(tree)
    return {f"{i:05d}": x for i, x in enumerate(leaves) if i not in drop and math.prod(np.shape(x))}


def graft(template: Tree, pruned: Mapping[str, jax.Array], fill: Mapping[int, jax.Array]) -> Tree:
    """Inverse of :func:`prune` (inside a compiled program too): the leaves at positions
    ``fill`` from it, zero-size ones as zeros shaped like the template's."""
    leaves, treedef = jax.tree.flatten(template)
    out = [
        fill[i]
        if i in fill
        else pruned[f"{i:05d}"]
        if math.prod(x.shape)
        else jnp.zeros(x.shape, x.dtype)
        for i, x in enumerate(leaves)
    ]
    return jax.tree.unflatten(treedef, out)


def batch_wide(template: object, robots: int) -> frozenset[int]:
    """The ``jax.tree.leaves`` positions of ``template``'s non-empty leaves without the
    robot axis (``robots`` first): MuJoCo Warp's contact buffers and their sizes, none under
    MJX's JAX. Scratch space each physics step refills, kept out of the learner's
    ``(D, S, E)`` layout; every program starts from fresh ones."""
    flat = jax.tree.leaves(template)
    return frozenset(
        i for i, x in enumerate(flat) if x.shape[:1] != (robots,) and math.prod(x.shape)
    )


def fresh_batch_wide(template: object, at: Collection[int]) -> dict[int, np.ndarray]:
    """The leaves at ``at`` of ``template`` (arrays or shapes) as every program starts
    them: zeros. MuJoCo Warp's batch-wide leaves are its contact buffers and their counters
    (``nacon``, ``ncollision``), which each physics step zeroes and refills, and which a
    reset leaves at zero (tests/test_warp_training.py checks it against a reset). Built
    from shapes alone, they let the epoch be compiled before the robots' first reset has
    run (train.loop.aot)."""
    flat = jax.tree.leaves(template)
    return {i: np.zeros(flat[i].shape, flat[i].dtype) for i in sorted(at)}


__all__ = [
    "CHECKSUMS",
    "CheckpointError",
    "batch_wide",
    "fresh_batch_wide",
    "graft",
    "is_index_format",
    "named_leaves",
    "pack",
    "prune",
    "unpack",
]
