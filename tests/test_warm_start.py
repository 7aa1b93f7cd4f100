"""The warm-start store of compiled programs (train/loop/warm_start.py): a program loaded
from it gives the numbers of the one compiled, and a stale or corrupt entry is never used."""

import dataclasses
import functools
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from train.loop import program_store, warm_start


def _program():
    """A small program with random numbers, floats and a pytree in and out."""

    def f(state, x):
        key, sub = jax.random.split(state["key"])
        noise = jax.random.normal(sub, x.shape)
        return {"key": key, "sum": jnp.sum(jnp.sin(x) * noise)}, jnp.cumsum(x * noise)

    return jax.jit(f)


def _counted_program(traced):
    """:func:`_program`, each of its tracings counted in ``traced``."""
    f = _program()

    def counted(state, x):
        traced.append(1)
        return f(state, x)

    return jax.jit(counted)


def _args():
    return {"key": jax.random.PRNGKey(3), "sum": jnp.float32(0)}, np.linspace(
        0, 1, 64, dtype=np.float32
    )


def _store(tmp_path, key=None, lines=None):
    log = (lines if lines is not None else []).append
    return warm_start.Store(tmp_path, key or {"run": "a"}, log)


def test_a_loaded_program_gives_the_compiled_ones_numbers_bit_for_bit(tmp_path):
    cold_store = _store(tmp_path)
    cold = warm_start.Stored(_program(), "f", cold_store)(*_args())
    assert cold_store.written == ["f"]
    assert cold_store.loaded == []
    warm_store = _store(tmp_path)
    warm = warm_start.Stored(_program(), "f", warm_store)(*_args())
    assert warm_store.loaded == ["f"]
    assert warm_store.written == []
    assert cold_store.load_s == {}  # the read-back after writing is not a load
    assert sorted(warm_store.load_s["f"]) == ["deserialize", "read", "targets"]
    assert all(0 <= t < 60 for t in warm_store.load_s["f"].values())
    for a, b in zip(jax.tree.leaves(cold), jax.tree.leaves(warm), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert np.asarray(a).dtype == np.asarray(b).dtype
    direct = _program()(*_args())  # and those of the plain jitted function
    for a, b in zip(jax.tree.leaves(direct), jax.tree.leaves(warm), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_lowering_from_shapes_finds_the_stored_program_without_tracing(tmp_path):
    """``Stored.lower`` (as train.loop.aot compiles ahead from shapes): cold, it traces,
    compiles and writes the program; warm, it traces nothing, and the placed arrays'
    first call runs the loaded program, with the same numbers."""
    traced: list[int] = []
    program = functools.partial(_counted_program, traced)

    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype), _args())
    cold_store = _store(tmp_path)
    cold_fn = warm_start.Stored(program(), "f", cold_store)
    cold = cold_fn.lower(*shapes).compile()(*_args())
    assert cold_store.written == ["f"]
    assert len(traced) == 1
    warm_store = _store(tmp_path)
    warm_fn = warm_start.Stored(program(), "f", warm_store)
    warm = warm_fn.lower(*shapes).compile()(*_args())
    assert warm_store.loaded == ["f"]
    assert warm_store.written == []
    assert len(traced) == 1  # the warm lowering traced nothing
    for a, b in zip(jax.tree.leaves(cold), jax.tree.leaves(warm), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_another_run_of_the_same_lowered_program_loads_it_after_tracing(tmp_path):
    """After an edit that leaves the program as it was (another code hash), the index
    misses: the program is traced, its executable found by the lowered text and loaded,
    not compiled, and the next start of that run traces nothing."""
    traced: list[int] = []
    program = functools.partial(_counted_program, traced)

    cold = warm_start.Stored(program(), "f", _store(tmp_path, {"run": "a"}))(*_args())
    edited = _store(tmp_path, {"run": "b"})
    out = warm_start.Stored(program(), "f", edited)(*_args())
    assert (edited.loaded, edited.written, len(traced)) == (["f"], [], 2)
    again = _store(tmp_path, {"run": "b"})
    warm_start.Stored(program(), "f", again)(*_args())
    assert (again.loaded, again.written, len(traced)) == (["f"], [], 2)
    for a, b in zip(jax.tree.leaves(cold), jax.tree.leaves(out), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_changed_program_is_never_served_the_old_one(tmp_path):
    warm_start.Stored(_program(), "f", _store(tmp_path, {"run": "a"}))(*_args())

    def changed(state, x):  # the same signature, another computation
        return _program()(state, x * 2)

    store = _store(tmp_path, {"run": "b"})
    out = warm_start.Stored(jax.jit(changed), "f", store)(*_args())
    assert (store.loaded, store.written) == ([], ["f"])
    np.testing.assert_array_equal(np.asarray(out[1]), np.asarray(jax.jit(changed)(*_args())[1]))


def test_a_stale_entry_is_not_used(tmp_path):
    """A file whose stored key differs from the one asked for (a collision, a rename)."""
    first = _store(tmp_path, {"run": "a"})
    full_key = {"run": "a", "program": "f", "signature": "s"}
    first.save("f", full_key, _program().lower(*_args()).compile())
    path = first.path(full_key)
    moved = first.path({**full_key, "signature": "t"})
    path.rename(moved)
    lines: list[str] = []
    assert _store(tmp_path, lines=lines).load("f", {**full_key, "signature": "t"}) is None
    assert "stale" in lines[0]
    assert not moved.exists()


@pytest.mark.parametrize("suffix", [warm_start.SUFFIX, warm_start.INDEX_SUFFIX])
@pytest.mark.parametrize("damage", ["flip", "truncate", "garbage"])
def test_a_corrupt_file_is_rebuilt(tmp_path, damage, suffix):
    warm_start.Stored(_program(), "f", _store(tmp_path))(*_args())
    (path,) = tmp_path.glob(f"*{suffix}")
    blob = bytearray(path.read_bytes())
    if damage == "flip":
        blob[len(blob) // 2] ^= 0xFF
    elif damage == "truncate":
        del blob[len(blob) // 3 :]
    else:
        blob = bytearray(b"not a program")
    path.write_bytes(bytes(blob))
    lines: list[str] = []
    store = _store(tmp_path, lines=lines)
    out = warm_start.Stored(_program(), "f", store)(*_args())
    # a broken executable is compiled again; a broken index entry is traced again,
    # and the intact executable it pointed at loads
    assert (store.loaded, store.written) == (
        ([], ["f"]) if suffix == warm_start.SUFFIX else (["f"], [])
    )
    assert "unusable" in lines[0]
    np.testing.assert_array_equal(np.asarray(out[1]), np.asarray(_program()(*_args())[1]))
    assert _store(tmp_path).load("f", _key_of(path.parent)) is not None  # rewritten whole
    warm = _store(tmp_path)
    warm_start.Stored(_program(), "f", warm)(*_args())
    assert (warm.loaded, warm.written) == (["f"], [])  # the index rewritten whole too


def _key_of(directory):
    (path,) = directory.glob(f"*{warm_start.SUFFIX}")
    header, _ = program_store.unframe(path.read_bytes())
    return header


def test_the_key_holds_the_config_the_versions_the_devices_and_the_code(tiny, threefry_flag):
    key = warm_start.run_key(tiny, jax.devices())
    assert set(key) >= {"config", "robot", "versions", "devices", "xla_flags", "code"}
    assert set(key["versions"]) >= {"jax", "jaxlib", "mujoco", "mujoco-mjx", "warp-lang"}
    other = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, entropy_cost=0.5))
    assert warm_start.run_key(other, jax.devices())["config"] != key["config"]
    assert warm_start.run_key(tiny, jax.devices()) == key  # deterministic
    # a program lowered with the GPUs' threefry kernel is not served to a run without it
    jax.config.update(threefry_flag, not getattr(jax.config, threefry_flag))
    assert warm_start.run_key(tiny, jax.devices())["jax_flags"] != key["jax_flags"]


def test_it_is_off_where_it_cannot_serve(monkeypatch):
    def learner(impl="jax", parallel="pmap", processes=1, devices=1):
        robot = SimpleNamespace(robot=SimpleNamespace(impl=impl))
        cpus = jax.devices("cpu")[:1] * devices  # why_not reads their count and platform
        return SimpleNamespace(
            n_processes=processes, parallel=parallel, env=robot, n_devices=devices, devices=cpus
        )

    assert warm_start.why_not(learner(), {}) in (None, "the persistent compilation cache is off")
    assert "MECANUM_WARM_START" in warm_start.why_not(learner(), {warm_start.ENV_VAR: "off"})
    monkeypatch.setattr("train.loop.compilation_cache.in_force", lambda: "/tmp")
    assert warm_start.why_not(learner(), {}) is None
    assert warm_start.why_not(learner(impl="warp"), {}) is None  # (warp_targets.py)
    assert "split" in warm_start.why_not(learner(parallel="split"), {})
    assert "processes" in warm_start.why_not(learner(processes=2), {})
    assert "several CPU devices" in warm_start.why_not(learner(devices=2), {})


@pytest.mark.full
def test_a_warm_start_of_the_tiny_run_matches_a_cold_one_bit_for_bit(tmp_path):
    """Fresh processes on one cache. The second loads the reset, the epoch and the
    rollout, traces none of them, and its epochs' metrics and evaluations are the first's.
    With the index gone (as after an edit of the sources) the third loads them, compiling
    none; with the rollout's executable gone and JAX's persistent cache kept, the fourth
    compiles and writes it (never from that cache, whose executables XLA:CPU
    re-serializes broken), and each runs as written."""
    logs = []

    def start(name):
        out = tmp_path / f"{name}.json"
        cmd = [sys.executable, "-m", "train.tools.coldstart", "--config", "tiny", "--to-end"]
        cmd += ["--compilation-cache", str(tmp_path / "cache"), "--json-out", str(out)]
        # one CPU device, as a user's CPU has (the store is off over several CPU devices)
        flags = os.environ.get("XLA_FLAGS", "").replace(
            "--xla_force_host_platform_device_count=2", ""
        )
        env = {**os.environ, "XLA_FLAGS": flags}
        run = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
        logs.append(run.stderr)
        return json.loads(out.read_text())

    names = ["baseline", "episodes", "epoch", "fresh", "reset", "rollout"]
    cold, warm = start("cold"), start("warm")
    assert sorted(warm["warm_start"]["loaded"]) == names
    assert warm["warm_start"]["loaded_ahead"] == ["fresh", "reset", "epoch", "rollout"]
    assert warm["warm_start"]["written"] == []
    assert not any(p["name"] == "jit(_rollout)" for p in warm["programs"])  # not traced
    store = tmp_path / "cache" / warm_start.SUBDIR
    for index in store.glob(f"*{warm_start.INDEX_SUFFIX}"):
        index.unlink()
    edited = start("edited")
    assert (sorted(edited["warm_start"]["loaded"]), edited["warm_start"]["written"]) == (names, [])
    # the rollout's executable gone (the cheapest to compile), JAX's cache of it kept
    for index in store.glob(f"*{warm_start.INDEX_SUFFIX}"):
        header, payload = program_store.unframe(index.read_bytes())
        if isinstance(header, dict) and header["program"] == "rollout":
            program_store.Store(store, {}, print).path(json.loads(payload)).unlink()
    rebuilt = start("rebuilt")
    assert (sorted(rebuilt["warm_start"]["loaded"]), rebuilt["warm_start"]["written"]) == (
        ["baseline", "episodes", "epoch", "fresh", "reset"],
        ["rollout"],
    )
    assert not any("failed to run" in log for log in logs), logs

    def figures(report):
        return [
            {k: v for k, v in p.items() if k in ("metrics", "values")} for p in report["phases"]
        ]

    assert figures(cold) == figures(warm) == figures(edited) == figures(rebuilt)


TRAINER_MODULES = (
    "train.learner.ppo",
    "train.learner.iteration",
    "train.learner.transfer",
    "train.learner.losses",
    "train.learner.split_epoch",
    "train.learner.parallel",
    "train.loop.run",
    "train.loop.run_steps",
    "train.loop.aot",
    "train.loop.warm_start",
)
EVAL_IMPORTS = """
import json, sys
from pathlib import Path
import train.cli.evaluate
from train.learner.policy import restore_policy
restore_policy(Path(sys.argv[1]))
print(json.dumps(sorted(sys.modules)))
"""


def test_evaluating_a_saved_model_imports_no_trainer():
    """``mecanum-eval MODEL`` imports the CLI and restores the policy without the learner,
    the trainer's loop or their programs (a fresh interpreter)."""
    from pathlib import Path

    model = Path(__file__).parents[1] / "models" / "o_rectangle"
    cmd = [sys.executable, "-c", EVAL_IMPORTS, str(model)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    imported = set(json.loads(out.strip().splitlines()[-1]))
    assert not imported & set(TRAINER_MODULES)


WARP_PROGRAM = """
import json, sys
from pathlib import Path
import jax, jax.numpy as jnp
from mecanum_jax.task import MecanumEnv
from mecanum_jax.task.config import EnvConfig
from train.loop import warm_start, warp_targets

env = MecanumEnv(EnvConfig(physics_impl="warp"))
tracers = [warp_targets.step_tracer(env.robot, env.substeps)] if sys.argv[2] == "on" else []
lines = []
store = warm_start.Store(Path(sys.argv[1]), {"run": "warp"}, lines.append, tracers)

def rollout(key):
    state = jax.vmap(env.reset)(jax.random.split(key, 8))
    def tick(s, _):
        s = jax.vmap(env.step)(s, jnp.full((8, env.action_size), 0.3))
        return s, s.reward
    return jax.lax.scan(tick, state, None, length=3)[1]

rewards = warm_start.Stored(jax.jit(rollout), "rollout", store)(jax.random.PRNGKey(0))
print(json.dumps({"rewards": jnp.asarray(rewards).tolist(), "loaded": store.loaded,
                  "written": store.written, "log": lines}))
"""


@pytest.mark.full
def test_a_warp_program_loads_into_a_fresh_process_once_its_ffi_targets_are_made(tmp_path):
    """MuJoCo Warp's FFI targets exist only once a call is traced: a fresh process loads a
    stored Warp rollout after warp_targets.register made them (and gets its numbers);
    without the tracer that makes them the entry is refused and compiled again."""
    pytest.importorskip("warp")

    def start(tracers):
        cmd = [sys.executable, "-c", WARP_PROGRAM, str(tmp_path), tracers]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    cold = start("on")
    assert cold["written"] == ["rollout"]
    assert cold["loaded"] == []
    warm = start("on")
    assert warm["loaded"] == ["rollout"]
    assert warm["written"] == []
    assert warm["rewards"] == cold["rewards"]
    blind = start("off")  # a process that cannot make the targets does not trust the file
    assert blind["loaded"] == []
    assert any("Warp FFI targets" in line for line in blind["log"])
    assert blind["rewards"] == cold["rewards"]
