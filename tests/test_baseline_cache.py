"""The analytic baseline's evaluation kept on disk between starts (train/baseline_cache.py)."""

import dataclasses
import json
from types import SimpleNamespace

import jax
import numpy as np
import pytest

from mecanum_jax.evaluation.metrics import Part
from train import baseline_cache
from train.baseline_cache import SUBDIR, Entry, key, key_inputs, load, lookup, store
from train.config import apply_flags
from train.periodic import Result
from train.ppo import Learner, first_device


def _result(scale=1.0):
    """A small result of the trainer's shape: per scenario, values and per-episode parts."""
    parts, values = {}, {}
    for s, scenario in enumerate(("randomized", "nominal")):
        num = np.linspace(0.1, 0.9, 4, dtype=np.float32) * scale * (s + 1)
        parts[scenario] = {"ss_lin": Part(num, np.ones(4, np.float32), "rms")}
        parts[scenario]["energy_j"] = Part(num * 3, np.full(4, 2.0), "mean")
        values[scenario] = {"ss_lin": float(num.mean()), "drift_m": None, "unstable": 0}
    return Result(values, parts)


def _assert_same(a, b):
    assert json.dumps(a.values, sort_keys=True) == json.dumps(b.values, sort_keys=True)
    assert {s: sorted(p) for s, p in a.parts.items()} == {s: sorted(p) for s, p in b.parts.items()}
    for scenario, parts in a.parts.items():
        for metric, part in parts.items():
            other = b.parts[scenario][metric]
            assert other.kind == part.kind
            for x, y in ((part.num, other.num), (part.den, other.den)):
                assert x.dtype == y.dtype
                assert np.array_equal(x, y)


def test_a_stored_result_reads_back_equal(tmp_path):
    path = tmp_path / SUBDIR / "k.npz"
    stored = _result()
    assert store(path, "k" * 64, stored)
    back = load(path, "k" * 64)
    assert back is not None
    _assert_same(back, stored)
    assert back.values["randomized"]["drift_m"] is None
    assert [p.name for p in path.parent.iterdir()] == ["k.npz"]  # no temporary file left
    assert load(path, "another key") is None  # a file holds the key it was stored under
    assert load(tmp_path / "none.npz", "k" * 64) is None


@pytest.mark.parametrize(
    "damage",
    [
        lambda p: p.write_bytes(b"not an npz"),
        lambda p: p.write_bytes(p.read_bytes()[:100]),  # cut short
        lambda p: np.savez(p, meta=np.array("{}")),  # an npz of another layout
        lambda p: np.savez(p, meta=np.array(json.dumps({"format": 1, "key": "k", "values": {}}))),
    ],
)
def test_a_corrupt_file_is_ignored_and_replaced(tmp_path, capsys, monkeypatch, damage):
    """An unreadable file: one warning, computed anew and written over."""
    path = tmp_path / "k.npz"
    store(path, "k", _result())
    damage(path)
    assert load(path, "k") is None
    assert capsys.readouterr().err.count("warning: baseline cache: ignoring") == 1
    monkeypatch.setattr(baseline_cache, "lookup", lambda *a: Entry(path, "k", load(path, "k")))
    learner = SimpleNamespace(evaluate_baseline=lambda ts: _result(2.0))
    result, origin = baseline_cache.baseline(learner, None)  # type: ignore[arg-type]
    assert origin == "computed"
    _assert_same(load(path, "k"), result)


def test_an_unwritable_directory_only_warns(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert not store(blocker / SUBDIR / "k.npz", "k", _result())
    assert "warning: baseline cache: cannot write" in capsys.readouterr().err


@pytest.fixture
def jax_cache_options():
    """JAX's compilation cache options as they were before the test."""
    names = ("jax_enable_compilation_cache", "jax_compilation_cache_dir")
    saved = {name: getattr(jax.config, name) for name in names}
    yield
    for name, value in saved.items():
        jax.config.update(name, value)


def test_the_cache_lives_in_the_compilation_cache_and_is_off_with_it(
    tmp_path, jax_cache_options, monkeypatch
):
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    jax.config.update("jax_enable_compilation_cache", True)
    assert baseline_cache.directory() == tmp_path / SUBDIR
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    assert baseline_cache.directory() is None  # several processes: off
    monkeypatch.undo()
    jax.config.update("jax_enable_compilation_cache", False)
    assert baseline_cache.directory() is None
    learner = SimpleNamespace(evaluate_baseline=lambda ts: _result())
    assert lookup(learner) == Entry(None)  # type: ignore[arg-type]
    assert baseline_cache.baseline(learner, None)[1] == "off"  # type: ignore[arg-type]
    assert not (tmp_path / SUBDIR).exists()


def test_start_reads_a_hit_without_a_thread(tmp_path, monkeypatch):
    """mecanum-train's baseline: a finished future and one log line on a hit; on a miss
    the evaluation runs (in a thread) and is stored."""
    path = tmp_path / "k.npz"
    monkeypatch.setattr(baseline_cache, "lookup", lambda *a: Entry(path, "k", load(path, "k")))
    learner = SimpleNamespace(evaluate_baseline=lambda ts: _result())
    logged: list[str] = []
    job, origin = baseline_cache.start(learner, None, True, logged.append)  # type: ignore[arg-type]
    assert origin == "computed"
    assert not logged
    _assert_same(job.result(), _result())
    learner.evaluate_baseline = lambda ts: pytest.fail("evaluated despite the cache")
    job, origin = baseline_cache.start(learner, None, True, logged.append)  # type: ignore[arg-type]
    assert origin == "cache"
    assert job.done()
    _assert_same(job.result(), _result())
    assert len(logged) == 1
    assert str(path) in logged[0]


def test_the_key_follows_what_the_baseline_depends_on(tiny, learner):
    def key_of(flags):
        return key(key_inputs(Learner(apply_flags(tiny, flags))))

    same = key(key_inputs(learner))
    assert key_of([]) == same
    assert key_of(["--ppo.learning-rate", "0.01"]) == same  # training only
    assert key_of(["--run.seeds", "7"]) == same  # which seed, not how many
    assert key_of(["--run.baseline-cache", "False"]) == same
    assert key_of(["--env.randomization.friction", "0.2", "1.2"]) != same
    assert key_of(["--run.eval-seed", "5"]) != same
    assert key_of(["--run.seeds", "0", "1"]) != same  # the evaluation's robot count


def test_the_key_is_canonical():
    inputs = {"b": (1, 2.5), "a": {"y": [None, "x"], "x": True}}
    assert key(inputs) == key({"a": {"x": True, "y": (None, "x")}, "b": [1, 2.5]})
    assert key(inputs) != key({**inputs, "b": (1, 2.6)})


def test_the_key_follows_the_source(tmp_path, learner, monkeypatch):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "robot.toml").write_text("[robot]\n")
    monkeypatch.setattr(baseline_cache, "source_roots", lambda: [("pkg", package)])
    before = key(key_inputs(learner))
    (package / "__pycache__").mkdir()
    (package / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"bytecode")
    assert key(key_inputs(learner)) == before  # bytecode is not source
    (package / "sub" / "robot.toml").write_text("[robot]\nname = 'x'\n")
    assert key(key_inputs(learner)) != before
    (package / "sub" / "robot.toml").write_text("[robot]\n")
    assert key(key_inputs(learner)) == before
    (package / "a.py").rename(package / "b.py")
    assert key(key_inputs(learner)) != before  # names count too


def test_the_default_source_covers_the_library_and_the_robots():
    from mecanum_jax.config import CONFIG_DIR

    roots = dict(baseline_cache.source_roots())
    assert (roots["mecanum_jax"] / "evaluation" / "scenarios.py").is_file()
    assert roots["robots"] == CONFIG_DIR / "robots"
    assert (roots["robots"] / "drives").is_dir()
    assert {"train/periodic.py", "train/ppo.py", "train/baseline_cache.py"} <= set(roots)


def test_a_second_start_reads_the_baseline_back(learner, tmp_path, monkeypatch):
    monkeypatch.setattr(baseline_cache, "directory", lambda: tmp_path / SUBDIR)
    ts = first_device(learner.init_training()[0])
    first, origin = baseline_cache.baseline(learner, ts)
    assert origin == "computed"
    assert set(first.values) == {"randomized", "nominal"}
    assert len(list((tmp_path / SUBDIR).glob("*.npz"))) == 1
    monkeypatch.setattr(learner, "evaluate_baseline", lambda ts: pytest.fail("evaluated"))
    second, origin = baseline_cache.baseline(learner, ts)
    assert origin == "cache"
    _assert_same(second, first)
    assert lookup(learner, enabled=False) == Entry(None)  # run.baseline_cache = false


def test_turning_it_off_is_a_run_option(tiny):
    assert tiny.run.baseline_cache
    off = apply_flags(tiny, ["--run.baseline-cache", "False"])
    assert off == dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, baseline_cache=False))


def test_a_hit_that_runs_first_still_traces_the_evaluation_in_place(learner, tmp_path, monkeypatch):
    """Where the baseline runs before the first epoch (under MuJoCo Warp), a start that
    reads it back traces its evaluation program at that point all the same, and the policy's
    evaluation then reuses that trace: the process traces its programs in the order a
    start that computed the baseline did (Warp numbers its FFI calls in trace order, and the
    compilation cache's keys hold the numbers)."""
    from train.coldstart import CompileLog

    monkeypatch.setattr(baseline_cache, "directory", lambda: tmp_path / SUBDIR)
    ts = first_device(learner.init_training()[0])
    computed, _ = baseline_cache.baseline(learner, ts)  # stored
    evaluator = learner.evaluation.evaluator

    def fresh_rollout(*args):  # a program this process has not traced yet
        return type(evaluator)._rollout(evaluator, *args)

    monkeypatch.setattr(evaluator, "_run", jax.jit(fresh_rollout))
    monkeypatch.setattr(learner, "evaluate_baseline", lambda ts: pytest.fail("evaluated"))
    with CompileLog() as log:
        _, origin = baseline_cache.baseline(learner, ts, first=False)
    assert origin == "cache"
    assert [e for e in log.events if "fresh_rollout" in e["name"]] == []  # nothing traced
    with CompileLog() as log:
        read, origin = baseline_cache.baseline(learner, ts, first=True)
        traced = [e["event"] for e in log.events if "fresh_rollout" in e["name"]]
        assert (origin, traced) == ("cache", ["trace_s", "lower_s"])  # traced, not compiled
        replay = learner.evaluation.play("analytic", jax.tree.map(lambda x: x[0], _params(ts)))
    events = [e["event"] for e in log.events if "fresh_rollout" in e["name"]]
    assert events.count("trace_s") == 1  # the play reused the trace
    assert events.count("compile_s") == 1
    _assert_same(replay, computed)
    _assert_same(read, computed)


def _params(ts):
    return (ts.normalizer_params, ts.params.policy)
