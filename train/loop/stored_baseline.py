"""The baseline's figures kept with the run's programs (train/loop/warm_start.py).

A run evaluates the ``analytic`` baseline once, on its fixed held-out episodes, before the
first epoch's comparison. Those figures are a pure function of what the run's key holds
(the config with its evaluation's episodes, the robot, the code, the versions, devices and
flags), so :class:`StoredBaseline` keeps them beside the stored programs under that key: a
later start of the same run reads them back instead of playing the baseline again (on one
H200 under Warp 3.3 s off a warm start of about 30 s, docs/profiling.md). The file holds every
scenario's values and per-episode parts exactly as computed (float bits kept), is written
atomically and checksummed by :class:`~train.loop.program_store.Store`, and a file that does
not read back whole is logged, removed and made again, never trusted.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from typing import Any

import numpy as np

from mecanum_jax.evaluation.metrics import Part
from train.learner.periodic import Result
from train.loop.program_store import Key, Store

SUFFIX = ".baseline"
NAME = "baseline"


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


class StoredBaseline:
    """``evaluate(ts)`` (the learner's ``evaluate_baseline``) served from ``store``: the
    figures read back where the run's key holds them, else played and written."""

    def __init__(self, evaluate: Callable[[Any], Result], store: Store):
        self.evaluate = evaluate
        self.store = store
        self.key: Key = {**store.key, "program": NAME}

    def __call__(self, ts: Any) -> Result:
        result = self.store.read(NAME, self.key, SUFFIX, decode)
        if result is not None:
            self.store.loaded.append(NAME)
            return result
        result = self.evaluate(ts)
        self.store.write(self.key, encode(result), SUFFIX)
        self.store.written.append(NAME)
        return result


__all__ = ["StoredBaseline", "decode", "encode"]
