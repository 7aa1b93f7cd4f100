"""Values kept with the run's programs (train/loop/warm_start.py): the evaluation's
episodes and the baseline's figures on them.

A run draws its held-out episodes (robots, floors, commands) once and evaluates the
``analytic`` baseline on them once, before the first epoch's comparison. Both are a pure
function of what the run's key holds (the config with its evaluation's episodes, the robot,
the code, the versions, devices and flags), so :class:`Kept` keeps them beside the stored
programs under that key: a later start of the same run reads them back instead of drawing
and playing again (the baseline: on one H200 under Warp 3.3 s off a warm start of about
30 s; the episodes' samplers: about 0.4 s of the 2-core CPU's warm start,
docs/profiling.md). Each file holds its values exactly as computed (float bits kept), is
written atomically and checksummed by :class:`~train.loop.program_store.Store`, and a file
that does not read back whole is logged, removed and made again, never trusted.
"""

from __future__ import annotations

import io
import json
import pickle
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.evaluation.episodes import EpisodeBatch
from mecanum_jax.evaluation.metrics import Part
from mecanum_jax.host import on_host
from train.learner.periodic import Result
from train.loop.program_store import Key, Store

SUFFIX = ".baseline"
NAME = "baseline"
EPISODES_SUFFIX = ".episodes"
EPISODES = "episodes"
T = TypeVar("T")


def encode(result: Result) -> bytes:
    """``result`` as bytes: an npz of every part's ``num`` and ``den`` (their dtypes kept)
    and, as JSON, the values and the parts' kinds."""
    arrays: dict[str, np.ndarray] = {}
    kinds: dict[str, dict[str, str]] = {}
    for scenario, parts in result.parts.items():
        kinds[scenario] = {}
        for i, (metric, part) in enumerate(parts.items()):
            kinds[scenario][metric] = part.kind
            arrays[f"{scenario}.{i}.num"] = np.asarray(part.num)
            arrays[f"{scenario}.{i}.den"] = np.asarray(part.den)
    meta = {"values": result.values, "kinds": kinds}
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    out = io.BytesIO()
    np.savez(out, allow_pickle=False, **arrays)
    return out.getvalue()


def decode(payload: bytes) -> Result:
    """The :class:`Result` that :func:`encode` wrote; raises if anything is missing."""
    with np.load(io.BytesIO(payload), allow_pickle=False) as z:
        meta = json.loads(z["meta"].tobytes())
        parts = {
            scenario: {
                metric: Part(z[f"{scenario}.{i}.num"], z[f"{scenario}.{i}.den"], kind)
                for i, (metric, kind) in enumerate(kinds.items())
            }
            for scenario, kinds in meta["kinds"].items()
        }
    if set(parts) != set(meta["values"]):
        raise ValueError("its scenarios' values and parts differ")
    return Result(meta["values"], parts)


def encode_episodes(batches: dict[str, EpisodeBatch]) -> bytes:
    """``batches`` as bytes: their tree and every leaf as a NumPy array (dtypes kept)."""
    leaves, tree = jax.tree.flatten(batches)
    return pickle.dumps((tree, [np.asarray(x) for x in leaves]))


def decode_episodes(payload: bytes) -> dict[str, EpisodeBatch]:
    """The episodes :func:`encode_episodes` wrote, as host arrays (``mecanum_jax.host``)."""
    tree, leaves = pickle.loads(payload)
    with on_host():
        batches = jax.tree.unflatten(tree, [jnp.asarray(x) for x in leaves])
    if not all(isinstance(b, EpisodeBatch) for b in batches.values()):
        raise ValueError("not the evaluation's episodes")
    return batches


class Kept(Generic[T]):
    """``make()``'s value served from ``store`` under the run's key and ``name``: read back
    where the store holds it, else made and written."""

    def __init__(
        self,
        make: Callable[..., T],
        store: Store,
        name: str,
        suffix: str,
        codec: tuple[Callable[[T], bytes], Callable[[bytes], T]],
    ):
        self.make = make
        self.store = store
        self.name = name
        self.suffix = suffix
        self.encode, self.decode = codec
        self.key: Key = {**store.key, "program": name}

    def __call__(self, *args: Any) -> T:
        value = self.store.read(self.name, self.key, self.suffix, self.decode)
        if value is not None:
            self.store.loaded.append(self.name)
            return value
        value = self.make(*args)
        self.store.write(self.key, self.encode(value), self.suffix)
        self.store.written.append(self.name)
        return value


class StoredBaseline(Kept[Result]):
    """``evaluate(ts)`` (the learner's ``evaluate_baseline``) served from ``store``."""

    def __init__(self, evaluate: Callable[[Any], Result], store: Store):
        super().__init__(evaluate, store, NAME, SUFFIX, (encode, decode))


def stored_episodes(
    draw: Callable[[], dict[str, EpisodeBatch]], store: Store
) -> Kept[dict[str, EpisodeBatch]]:
    """``draw()`` (the periodic evaluation's) served from ``store``."""
    return Kept(draw, store, EPISODES, EPISODES_SUFFIX, (encode_episodes, decode_episodes))


__all__ = [
    "EPISODES_SUFFIX",
    "Kept",
    "StoredBaseline",
    "decode",
    "decode_episodes",
    "encode",
    "encode_episodes",
    "stored_episodes",
]
