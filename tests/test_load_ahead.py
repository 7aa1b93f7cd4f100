"""Programs loaded ahead (train/loop/program_store.py's ``Ahead``), from the moment a run's
config is known while it imports the trainer and builds its learner: a warm start takes the
very executable the store holds for its run, never one of another run's key, and an entry
that does not load is left to the store, which logs it and makes it again."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from train.loop import program_store, warm_start

ORDER = ("reset", "epoch")


def _program():
    return jax.jit(lambda x: jnp.cumsum(jnp.sin(x) * 3.0))


X = np.linspace(0, 1, 32, dtype=np.float32)


def _store(tmp_path, key, lines=None):
    return warm_start.Store(tmp_path, key, (lines if lines is not None else []).append)


def _cold(tmp_path, key):
    out = warm_start.Stored(_program(), "epoch", _store(tmp_path, key))(X)
    assert len(list(tmp_path.glob(f"*{warm_start.SUFFIX}"))) == 1
    return out


def _warm(tmp_path, key, ahead, lines=None):
    store = _store(tmp_path, key, lines)
    store.ahead = ahead
    return store, warm_start.Stored(_program(), "epoch", store)(X)


def test_a_warm_start_takes_the_program_loaded_ahead(tmp_path, monkeypatch):
    cold = _cold(tmp_path, {"run": "a"})
    ahead = program_store.Ahead(tmp_path, {"run": "a"}, ORDER)
    assert len(ahead._loads) == 1
    assert all(f.result() is not None for f in ahead._loads.values())  # loaded on the thread
    # the store must not load the file itself: the executable comes from the thread
    monkeypatch.setattr(program_store, "_deserialize", None)
    store, warm = _warm(tmp_path, {"run": "a"}, ahead)
    assert (store.loaded, store.written, ahead._loads) == (["epoch"], [], {})
    assert store.loaded_ahead == ["epoch"]
    assert sorted(store.load_s["epoch"]) == ["deserialize", "read", "targets"]
    np.testing.assert_array_equal(np.asarray(cold), np.asarray(warm))


def test_only_the_runs_own_programs_and_names_are_loaded_ahead(tmp_path):
    _cold(tmp_path, {"run": "a"})
    assert program_store.Ahead(tmp_path, {"run": "b"}, ORDER)._loads == {}
    assert program_store.Ahead(tmp_path, {"run": "a"}, ("rollout",))._loads == {}
    assert program_store.Ahead(tmp_path / "absent", {"run": "a"}, ORDER)._loads == {}


def test_an_executable_that_does_not_load_ahead_is_judged_by_the_store(tmp_path):
    _cold(tmp_path, {"run": "a"})
    (path,) = tmp_path.glob(f"*{warm_start.SUFFIX}")
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0xFF  # damaged after its index was read
    path.write_bytes(bytes(blob))
    ahead = program_store.Ahead(tmp_path, {"run": "a"}, ORDER)
    lines: list[str] = []
    store, out = _warm(tmp_path, {"run": "a"}, ahead, lines)
    assert (store.loaded, store.written) == ([], ["epoch"])  # compiled again, rewritten
    assert "unusable" in lines[0]
    np.testing.assert_array_equal(np.asarray(out), np.asarray(_program()(X)))


def test_a_program_calling_mujoco_warp_is_left_to_the_runs_own_thread(tmp_path):
    """Its FFI targets are made where the store's tracers are: never on the thread."""
    _cold(tmp_path, {"run": "a"})
    (path,) = tmp_path.glob(f"*{warm_start.SUFFIX}")
    header, payload = program_store.unframe(path.read_bytes())
    serialized, trees, devices, _ = program_store.pickle.loads(payload)
    with_targets = (serialized, trees, devices, ["mujoco_warp_step_0"])
    path.write_bytes(program_store.frame(header, program_store.pickle.dumps(with_targets)))
    ahead = program_store.Ahead(tmp_path, {"run": "a"}, ORDER)
    assert ahead.take(header) is None


def test_nothing_is_loaded_ahead_where_the_store_is_off_or_on_several_devices(
    monkeypatch, tiny, tmp_path
):
    monkeypatch.setattr("train.loop.compilation_cache.in_force", lambda: None)
    assert warm_start.load_ahead(tiny) is None
    monkeypatch.setattr("train.loop.compilation_cache.in_force", lambda: tmp_path)
    one = jax.local_devices()[:1]
    monkeypatch.setattr(jax, "local_devices", lambda: one)
    assert isinstance(warm_start.load_ahead(tiny), program_store.Ahead)  # can fail
    monkeypatch.setattr(jax, "local_devices", lambda: one * 2)
    assert warm_start.load_ahead(tiny) is None
    monkeypatch.setattr(jax, "local_devices", lambda: one)
    monkeypatch.setenv(warm_start.ENV_VAR, "off")
    assert warm_start.load_ahead(tiny) is None


def test_loading_begun_before_the_trainer_imports_is_the_one_the_run_takes(
    tiny, tmp_path, monkeypatch
):
    """``mecanum-train`` begins loading its stored programs once its config is known
    (:func:`warm_start.begin_loading`, before the trainer's imports); the learner's own
    :func:`warm_start.load_ahead` then takes that loading, for that run only."""
    made: list[program_store.Ahead] = []

    class Counted(program_store.Ahead):
        def __init__(self, *args):
            made.append(self)
            super().__init__(*args)

    monkeypatch.setattr(warm_start, "Ahead", Counted)
    monkeypatch.setattr(warm_start, "_begun", None)  # this test's own, put back after it
    monkeypatch.setattr("train.loop.compilation_cache.in_force", lambda: tmp_path)
    monkeypatch.setattr(warm_start.jax, "local_devices", lambda: jax.devices("cpu")[:1])
    warm_start.begin_loading(tiny)
    assert len(made) == 1
    assert warm_start.load_ahead(tiny) is made[0]  # the one begun
    again = warm_start.load_ahead(tiny)  # taken once: a later learner begins its own
    assert again is made[1]
    other = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, entropy_cost=0.5))
    warm_start.begin_loading(tiny)
    assert warm_start.load_ahead(other) is made[3]  # not another run's
    assert made[3].key != made[2].key
