"""The baseline's figures kept with the run's programs (train/loop/stored_baseline.py): read
back bit for bit, and a stale or corrupt file is never used."""

import math

import numpy as np
import pytest

from mecanum_jax.evaluation.metrics import Part
from train.learner.periodic import Result
from train.loop import program_store
from train.loop.stored_baseline import SUFFIX, StoredBaseline, decode, encode


def _result(seed=0):
    rng = np.random.default_rng(seed)
    parts = {
        "nominal": {
            "ss_lin": Part(rng.random(64, np.float32), np.ones(64, np.float32), "rms"),
            "drift_m": Part(rng.random(64), rng.integers(0, 2, 64).astype(np.float64), "mean"),
        },
        "randomized": {"ss_wz": Part(rng.random(8, np.float32), np.zeros(8, np.float32), "rms")},
    }
    values = {
        "nominal": {"ss_lin": float(rng.random()), "drift_m": 1 / 3, "settle_s": math.nan},
        "randomized": {"ss_wz": None},
    }
    return Result(values, parts)


def _same(a, b):
    assert repr(a.values) == repr(b.values)  # NaN spelt out, so two NaNs compare equal
    assert list(a.parts) == list(b.parts)
    for scenario, parts in a.parts.items():
        assert list(parts) == list(b.parts[scenario])
        for metric, part in parts.items():
            other = b.parts[scenario][metric]
            assert part.kind == other.kind
            for x, y in ((part.num, other.num), (part.den, other.den)):
                assert (x.dtype, x.tobytes()) == (y.dtype, y.tobytes())


def test_the_figures_read_back_bit_for_bit():
    result = _result()
    _same(result, decode(encode(result)))
    with pytest.raises(AssertionError):
        _same(result, decode(encode(_result(seed=1))))  # the comparison can fail


def _stored(tmp_path, calls, key=None, lines=None):
    def evaluate(ts):
        calls.append(ts)
        return _result()

    log = (lines if lines is not None else []).append
    return StoredBaseline(evaluate, program_store.Store(tmp_path, key or {"run": "a"}, log))


def test_a_second_start_reads_the_figures_instead_of_playing(tmp_path):
    calls = []
    first = _stored(tmp_path, calls)
    _same(first("ts"), _result())
    assert (calls, first.store.written, first.store.loaded) == (["ts"], ["baseline"], [])
    second = _stored(tmp_path, calls)
    _same(second("ts"), _result())
    assert (calls, second.store.loaded, second.store.written) == (["ts"], ["baseline"], [])
    other = _stored(tmp_path, calls, key={"run": "b"})  # another config, robot or code
    other("ts")
    assert (len(calls), other.store.loaded) == (2, [])


@pytest.mark.parametrize("damage", ["flip", "truncate", "stale", "garbage"])
def test_a_damaged_or_stale_file_is_played_again(tmp_path, damage):
    calls, lines = [], []
    first = _stored(tmp_path, calls)
    first("ts")
    (path,) = tmp_path.glob(f"*{SUFFIX}")
    blob = path.read_bytes()
    if damage == "flip":
        blob = blob[:-10] + bytes([blob[-10] ^ 1]) + blob[-9:]
    elif damage == "truncate":
        blob = blob[: len(blob) // 2]
    elif damage == "stale":  # a file of another key under this name
        blob = program_store.frame({"run": "other", "program": "baseline"}, b"x")
    else:  # intact framing, a payload that is no result
        blob = program_store.frame(first.key, b"not an npz")
    path.write_bytes(blob)
    again = _stored(tmp_path, calls, lines=lines)
    _same(again("ts"), _result())
    assert (len(calls), again.store.loaded, again.store.written) == (2, [], ["baseline"])
    assert any("baseline" in line and "unusable" in line for line in lines), lines
    _same(decode(program_store.unframe(path.read_bytes())[1]), _result())  # rewritten whole


def _episodes(seed=0):
    from mecanum_jax.evaluation.episodes import EpisodeBatch

    rng = np.random.default_rng(seed)
    batch = EpisodeBatch(
        rng.integers(0, 2**32, (4, 2), dtype=np.uint32),
        {"friction": rng.random((4, 4), np.float32), "mass": rng.random(4, np.float32)},
        rng.integers(0, 3, 4).astype(np.int32),
        rng.random((4, 3), np.float32),
        rng.random((4, 30, 3), np.float32),
    )
    return {"randomized": batch, "nominal": batch._replace(latency=np.zeros(4, np.int32))}


def test_the_episodes_read_back_bit_for_bit_and_a_damaged_file_is_drawn_again(tmp_path):
    import jax

    from train.loop.stored_baseline import EPISODES_SUFFIX, decode_episodes, stored_episodes

    def same(a, b):
        (la, ta), (lb, tb) = jax.tree.flatten(a), jax.tree.flatten(b)
        assert ta == tb
        for x, y in zip(la, lb, strict=True):
            assert (np.asarray(x).dtype, np.asarray(x).tobytes()) == (y.dtype, y.tobytes())

    drawn = []

    def kept(lines):
        draw = lambda: drawn.append(1) or _episodes()  # noqa: E731
        return stored_episodes(draw, program_store.Store(tmp_path, {"run": "a"}, lines.append))

    same(_episodes(), kept([])())
    loaded = kept([])
    same(loaded(), jax.tree.map(np.asarray, _episodes()))
    assert (len(drawn), loaded.store.loaded) == (1, ["episodes"])
    with pytest.raises(AssertionError):
        same(decode_episodes(loaded.encode(_episodes(seed=1))), _episodes())
    (path,) = tmp_path.glob(f"*{EPISODES_SUFFIX}")
    path.write_bytes(program_store.frame(loaded.key, b"not episodes"))
    lines: list[str] = []
    again = kept(lines)
    same(again(), _episodes())
    assert (len(drawn), again.store.written) == (2, ["episodes"])
    assert "unusable" in lines[0]
