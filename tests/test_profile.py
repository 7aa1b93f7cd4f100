"""The epoch profile (train/tools/profile.py), the cold-start breakdown
(train/tools/coldstart.py) and the scaling plot (scripts/plot_scaling.py), at tiny size on
the CPU. They check what is measured and printed, never how long anything took."""

import dataclasses
import io
import json
import os
import sys
from pathlib import Path

import jax
import pytest
from rich.console import Console

from train.tools import coldstart, compile_log, profile

PARTS = [
    "physics (MJX step)",
    "observation, reward, commands",
    "automatic resets, transitions",
    "policy inference (rollout)",
    "observation normalizer",
    "GAE",
    "update: forward, backward, optimizer",
    "rest of the epoch (not in a part)",
    "periodic evaluation (1 in 1)",
    "host syncs and transfers",
]
PROGRAMS = ["epoch", "physics", "task", "env", "rollout", "update", "normalizer", "gae"]


@pytest.mark.full  # compiles each part of an epoch on its own: most of a minute on 2 cores
def test_profile_times_and_prints_every_part(tiny, learner, tmp_path):
    """On the suite's tiny learner (its programs are compiled once for the whole suite)."""
    trace = tmp_path / "trace"
    result = profile.measure(tiny, 1, str(trace), log=lambda _: None, learner=learner)
    assert [p["part"] for p in result["parts"]] == PARTS
    for name in [*PROGRAMS, "evaluation", "metrics to host"]:
        assert result["programs"][name]["median_s"] > 0, name
    assert result["shapes"]["robots_per_seed_and_device"] == learner.envs_per_device
    assert list(trace.rglob("*.xplane.pb")), "no profiler trace written"
    console = Console(width=140, record=True, file=io.StringIO())
    console.print(profile.table(result))
    console.print(profile.summary(result))
    text = console.export_text()
    for part in PARTS:
        assert part in text
    assert "sum of the epoch's parts" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--repeats", "0"], "--repeats = 0: must be >= 1"),
        (["--json-out", "/no/such/dir/p.json"], "--json-out = '/no/such/dir/p.json'"),
        (["--ppo.num-envs", "0"], "ppo.num_envs"),
    ],
)
def test_profile_rejects_bad_arguments_before_compiling(args, message, capsys, monkeypatch):
    def fail(*a, **k):
        raise AssertionError("measured despite a bad argument")

    monkeypatch.setattr(profile, "measure", fail)
    assert profile.main(["--config", "tiny", *args]) == 2
    assert message in " ".join(capsys.readouterr().out.split())


def test_profile_trace_dir_must_be_a_directory(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(profile, "measure", lambda *a, **k: pytest.fail("measured"))
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert profile.main(["--config", "tiny", "--trace-dir", str(blocker)]) == 2
    assert "is not a directory" in capsys.readouterr().out


@pytest.mark.full  # a cold start of the tiny config, its compilations included
def test_coldstart_lists_phases_and_compiled_programs(tmp_path, capsys):
    out = tmp_path / "c.json"
    assert coldstart.main(["--config", "tiny", "--json-out", str(out)]) == 0
    report = json.loads(out.read_text())
    phases = [p["phase"] for p in report["phases"]]
    for phase in (
        "model and environment build",
        "robots' reset",
        "first epoch",
        "second epoch",
        "first evaluation: baseline",
        "first evaluation: policy",
    ):
        assert phase in phases
    # mecanum-train's order under JAX physics: the baseline beside the first epoch (its
    # phase the wait after it), the policy evaluated after the session's first epoch
    assert phases[-4:] == [
        "first epoch",
        "first evaluation: baseline",
        "first evaluation: policy",
        "second epoch",
    ]
    assert all(p["s"] >= 0 for p in report["phases"])
    assert report["programs"], "no compiled program listed"
    # the epoch's, compiled before the baseline's thread begins (train.loop.aot.begin_baseline),
    # or loaded from the warm-start store (train/loop/warm_start.py)
    loaded = (report["warm_start"] or {}).get("loaded", [])
    before = "the epoch compiled, the baseline's evaluation begun"
    assert phases.index(before) == phases.index("first epoch") - 1
    epoch = [p for p in report["programs"] if p["name"] == "jit(_fun)" and p["phase"] == before]
    assert "epoch" in loaded or epoch
    assert report["totals"]["programs"] == len(report["programs"])
    assert report["xla_flags"] == os.environ.get("XLA_FLAGS", "")  # what it compiled with
    text = capsys.readouterr().out
    assert "Compiled programs" in text
    assert "first evaluation: policy" in text


def test_coldstart_rejects_a_bad_config_flag(capsys):
    with pytest.raises(SystemExit) as exit_:
        coldstart.main(["--config", "tiny", "--ppo.num-envs", "0"])
    assert exit_.value.code == 2
    assert "ppo.num_envs" in capsys.readouterr().err


def test_compile_log_counts_recompilations():
    """A function compiled for two shapes is listed twice and counted as recompiled."""
    import jax
    import jax.numpy as jnp

    def twice_recompiled(x):
        return x * 2 + 1

    f = jax.jit(twice_recompiled)
    with compile_log.CompileLog() as log:
        f(jnp.ones(3))
        f(jnp.ones(4))
        f(jnp.ones(4))  # cached: no third compilation
    mine = [p for p in log.programs() if "twice_recompiled" in p["name"]]
    assert len(mine) == 2
    assert all(p["trace_s"] is not None for p in mine)  # tracing matched by name
    again = coldstart.summarize({}, log.programs())["totals"]["recompiled"]
    assert [r["count"] for n, r in again.items() if "twice_recompiled" in n] == [2]


def test_scaling_plot(tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
    try:
        import plot_scaling
    finally:
        sys.path.pop(0)
    files = []
    for n, sps in ((4096, 2.0e5), (1024, 1.0e5)):
        path = tmp_path / f"e{n}.json"
        result = {"num_envs": n, "steps_per_s_median": sps, "physics_steps_per_s_median": 4 * sps}
        path.write_text(json.dumps({"device": "cpu", "config": "gpu", "results": [result]}))
        files.append(str(path))
    png, merged = tmp_path / "s.png", tmp_path / "s.json"
    assert plot_scaling.main([*files, "--out", str(png), "--json-out", str(merged)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [r["num_envs"] for r in json.loads(merged.read_text())["results"]] == [1024, 4096]
    (tmp_path / "bad.json").write_text(json.dumps({"results": [{"num_envs": 8}]}))
    with pytest.raises(SystemExit, match="lacks"):
        plot_scaling.main([str(tmp_path / "bad.json"), "--out", str(png)])


@pytest.mark.full  # builds and resets a learner of its own
def test_the_physics_part_traces_for_a_residual_on_feedback(tiny):
    """The gpu config's residual corrects the feedback controller, whose setpoints read
    the state: the physics part must hand it over (it raised on the H100 once)."""
    from train.learner.ppo import Learner
    from train.tools.profile_parts import EpochParts

    cfg = dataclasses.replace(tiny, env=dataclasses.replace(tiny.env, residual_base="feedback"))
    learner = Learner(cfg)
    ts, env = learner.init()
    lowered = EpochParts(learner).programs["physics"].lower(ts, env)
    # the physics moves the robots on: the packed environment comes back in its own shapes
    shapes = [x.shape for x in jax.tree.leaves(lowered.out_info)]
    assert shapes == [x.shape for x in jax.tree.leaves(env)]
