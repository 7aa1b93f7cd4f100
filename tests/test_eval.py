"""Evaluation: paired batched rollouts, metrics and the CLI (the scenarios: test_scenarios.py;
the export: test_export.py).

The CLI tests run ``mecanum-eval`` on a reduced scenario set (what CI checks); the
checkpoint tests use the session's tiny trained run (``full_run`` in conftest.py).
"""

import dataclasses
import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.evaluation import episodes, paired
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.evaluation.traces import Trace, per_episode, summarize, trace_parts
from mecanum_jax.task import MecanumEnv
from train.cli import evaluate as cli
from train.learner.policy import check_compatible, load_policy, restore_policy
from train.store import checkpoint


@pytest.fixture(scope="module")
def small(shipped):
    """Two scripted scenarios and two random ones, shortened."""
    return shipped.select(
        ["six_modes", "singular_pass", "nominal", "slippery"], episodes=3, seconds=3.0
    )


@pytest.fixture(scope="module")
def baseline_evaluator(eval_env):
    return evaluation.Evaluator(eval_env)


def test_evaluation_streams_never_meet_training_streams(learner, shipped):
    _, train_keys = learner.init_training()
    train = {tuple(k) for k in np.asarray(train_keys).reshape(-1, 2)}
    periodic = learner.evaluation.scenarios.scenarios
    # the periodic evaluation's episodes: their own stream, even with a scenario file's seed
    for s in periodic:
        for seed in (s.seed, *(x.seed for x in shipped.scenarios)):
            root = episodes.scenario_key(dataclasses.replace(s, seed=seed))
            train |= {tuple(np.asarray(k)) for k in [root, *jax.random.split(root, 3)]}
    for s in shipped.scenarios:
        s0 = shipped.select([s.name], episodes=64).scenarios[0]
        root = episodes.scenario_key(s0)
        ks = [root, *jax.random.split(root, 3)]
        episode = jax.random.split(ks[3], 64)
        drawn = {tuple(np.asarray(k)) for k in [*ks, *episode]}
        assert not drawn & train, s.name


def test_summarize_on_a_known_trace():
    E, T, dt = 2, 50, 0.02
    command = np.zeros((E, T, 3), np.float32)
    command[:, :25, 0] = 1.0  # 0.5 m forward, then stop
    twist = command.copy()
    twist[:, :, 1] = 0.1  # a constant sideways error of 0.1 m/s
    twist[1, :, 2] = 0.3  # episode 1 also turns at 0.3 rad/s
    pose = np.zeros((E, T, 3), np.float32)
    pose[:, :, 0] = np.minimum(np.arange(1, T + 1), 25) * dt
    pose[:, -1, :2] = [0.5, 0.05]  # ends 5 cm to the left of the commanded end point
    pose[:, -1, 2] = 0.2
    trace = Trace(
        command=command,
        target=command,
        twist=twist,
        pose=pose,
        start=np.zeros((E, 3)),
        energy_j=np.full((E, T), 0.5),
        saturated=np.zeros((E, T)),
        unstable=np.zeros((E, T)),
        wheel_torque=np.zeros((E, T, 4)),
        wheel_rate=np.zeros((E, T, 4)),
        qpos=np.zeros((E, T, 1)),
    )
    jac = np.ones((4, 3))
    m = summarize(trace, dt, True, jac)
    assert m["rmse_vx"] == pytest.approx(0.0)
    assert m["rmse_vy"] == pytest.approx(0.1)
    assert m["rmse_lin"] == pytest.approx(0.1)
    assert m["worst_rmse_lin"] == pytest.approx(0.1)
    assert m["rmse_wz"] == pytest.approx(np.sqrt(0.09 / 2))
    assert m["worst_rmse_wz"] == pytest.approx(0.3)
    assert m["drift_m"] == pytest.approx(0.05, abs=1e-6)
    assert m["heading_drift_rad"] == pytest.approx(0.2, abs=1e-6)
    assert m["energy_j"] == pytest.approx(25.0)
    assert m["energy_per_m"] == pytest.approx(25.0 / np.hypot(0.48, 0.05) + 0 * 1, rel=0.2)
    assert summarize(trace, dt, False, jac)["drift_m"] is None
    detail = per_episode(trace, dt, scripted=True)
    np.testing.assert_allclose(detail["rmse_wz"], [0.0, 0.3], atol=1e-6)
    np.testing.assert_allclose(detail["drift_m"], [0.05, 0.05], atol=1e-6)
    assert max(detail["rmse_wz"]) == pytest.approx(m["worst_rmse_wz"])
    # the per-episode steady-state figures pool, weighted by steady steps, into the summary's
    for key in ("ss_lin", "ss_wz"):
        rms, count = np.asarray(detail[key], float), np.asarray(detail["steady_steps"])
        assert count.sum() > 0
        pooled = np.sqrt(np.sum(count * rms**2) / np.sum(count))
        assert pooled == pytest.approx(m[key], rel=1e-6, abs=1e-9)


@pytest.mark.full  # tens of seconds of XLA compilation on 2 cores
def test_baseline_rollout_tracks_and_is_deterministic(eval_env, small, baseline_evaluator):
    sc = small.scenarios[2]  # nominal, random commands
    batch = episodes.prepare(eval_env, sc)
    a = baseline_evaluator.run(batch)
    b = baseline_evaluator.run(batch)
    np.testing.assert_array_equal(a.twist, b.twist)
    np.testing.assert_array_equal(a.command, np.asarray(batch.commands))
    m = summarize(a, eval_env.config.control_dt, False, eval_env.jacobian)
    assert m["unstable"] == 0
    # it tracks: far better than standing still
    still = np.sqrt(np.mean(np.sum(a.command[..., :2] ** 2, axis=-1)))
    assert m["rmse_lin"] < 0.6 * still


@pytest.mark.full  # a policy's rollout program: about 35 s of compilation on 2 cores
def test_references_apply_no_action_beside_a_policy(eval_env, small):
    """In a policy's evaluation the references' traces hold no action (flicker 0): the
    policy's output, computed on every rollout, is applied and recorded only for it."""

    def jittery(params, obs):  # a policy whose action follows its (noisy) sensors
        del params
        return jnp.tanh(10.0 * obs["state"][..., 3 : 3 + eval_env.action_size])

    ev = evaluation.Evaluator(eval_env, jittery)
    batch = episodes.prepare(eval_env, small.scenarios[2])
    pol, ana = ev.run_many([(batch, "policy"), (batch, "analytic")])
    assert np.max(np.abs(pol.action)) > 0.01
    np.testing.assert_array_equal(ana.action, 0.0)
    jac, dt = eval_env.jacobian, eval_env.config.control_dt
    assert trace_parts(ana, jac, dt)["flicker"].value() == 0.0
    assert trace_parts(pol, jac, dt)["flicker"].value() > 0.0


def _tiny_restored(full_run):
    run, _ = full_run
    return restore_policy(run.dir)


@pytest.mark.full  # tens of seconds of XLA compilation on 2 cores
def test_policy_and_baseline_face_the_same_episodes(full_run, small):
    restored = _tiny_restored(full_run)
    env = MecanumEnv(episodes.eval_env_config(restored.cfg.env, small))
    evaluator = evaluation.Evaluator(env, restored.apply)
    batch = episodes.prepare(env, small.scenarios[0])
    params = (restored.normalizer, restored.params)
    pol = evaluator.run(batch, params, "policy")
    base = evaluator.run(batch, params, "analytic")
    np.testing.assert_array_equal(pol.command, base.command)
    np.testing.assert_array_equal(pol.start, base.start)
    assert not np.array_equal(pol.twist, base.twist)  # the trained policy acts differently
    # the learned policy's actions in the rollout are those of the plain inference function
    act, _ = load_policy(full_run[0].dir)
    s = jax.vmap(env.reset_to)(batch.keys, batch.params, batch.latency, batch.noise_std)
    with jax.numpy_rank_promotion("allow"):
        np.testing.assert_allclose(
            np.asarray(restored.apply(params, s.obs)), np.asarray(act(s.obs)), atol=1e-6
        )


def _run_cli(argv):
    return cli.main([str(a) for a in argv])


@pytest.mark.full  # tens of seconds of XLA compilation on 2 cores
def test_eval_baseline_cli_reduced_set(tmp_path, capsys):
    """What CI checks: ``mecanum-eval baseline`` on CPU, on a reduced scenario set."""
    out = tmp_path / "base"
    argv = ["baseline", "--only", "nominal", "singular_pass", "--episodes", 2, "--seconds", 4]
    assert _run_cli([*argv, "--out", out]) == 0
    report = json.loads((out / "report.json").read_text())
    assert list(report["scenarios"]) == ["nominal", "singular_pass"]
    sp = report["scenarios"]["singular_pass"]
    assert "policy" not in sp
    assert sp["analytic"]["drift_m"] is not None
    assert sp["feedback"]["ss_wz"] is not None
    assert report["scenarios"]["nominal"]["analytic"]["drift_m"] is None
    assert len(sp["per_episode"]["analytic"]["drift_m"]) == 2
    cmp = sp["compare"]["analytic/feedback"]["drift_m"]
    assert cmp["lo"] <= cmp["ratio"] <= cmp["hi"]
    assert cmp["verdict"] in ("better", "worse", "tie")
    # every controller's per-episode parts, for scripts/compare_policies.py
    parts = paired.load_parts(out)
    assert parts["singular_pass"]["analytic"]["drift_m"].value() == pytest.approx(
        sp["analytic"]["drift_m"]
    )
    assert "parts.npz" in report["files"]
    for name in ("errors.png", "trajectories.png", "twist_nominal.png", "twist_singular_pass.png"):
        assert (out / name).stat().st_size > 1000
    assert not (tmp_path / "base.partial").exists()
    assert "singular_pass" in capsys.readouterr().out
    # an existing output is never overwritten
    assert _run_cli([*argv, "--out", out]) == 2
    assert "already exists" in capsys.readouterr().err


@pytest.mark.full
@pytest.mark.render
def test_eval_checkpoint_cli_with_video_and_export(full_run, tmp_path):
    run, _ = full_run
    out = tmp_path / "ev"
    argv = [run.dir, "--only", "six_modes", "--episodes", 2, "--seconds", 2.0]
    argv += ["--video", "--video-size", 96, 64, "--export", "--out", out]
    assert _run_cli(argv) == 0
    report = json.loads((out / "report.json").read_text())
    r = report["scenarios"]["six_modes"]
    assert set(r) >= {"policy", "analytic", "analytic_nearest", "feedback"}
    assert set(r["compare"]) == {"policy/analytic", "policy/analytic_nearest", "policy/feedback"}
    assert report["epoch"] == 3
    assert (out / "video_six_modes.mp4").stat().st_size > 1000
    import imageio.v3 as iio

    frames = iio.imread(out / "video_six_modes.mp4")
    assert frames.shape[1:3] == (64, 4 * 96)  # policy | the three references side by side
    assert (out / "policy.npz").exists()
    assert (out / "mecanum_robot.zip").exists()


def test_bad_checkpoints_and_targets(full_run, tmp_path, capsys):
    assert _run_cli([tmp_path / "nope", "--out", tmp_path / "o1"]) == 2
    assert "no such directory" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _run_cli([empty, "--out", tmp_path / "o2"]) == 2
    assert "no checkpoints" in capsys.readouterr().err
    assert _run_cli(["baseline", "--only", "icy", "--out", tmp_path / "o3"]) == 2
    assert "scenario 'icy'" in capsys.readouterr().err
    run, _ = full_run
    assert _run_cli([run.dir, "--robot", "x_square", "--out", tmp_path / "o4"]) == 2
    assert "--robot" in capsys.readouterr().err
    assert _run_cli([run.dir, "--seed", 5, "--out", tmp_path / "o5"]) == 2
    assert "seed = 5: this run trained seeds [0]" in capsys.readouterr().err
    # a corrupt checkpoint: its array files truncated
    bad = tmp_path / "corrupt"
    import shutil

    shutil.copytree(run.dir, bad)
    epoch = checkpoint.latest_epoch(bad)
    for f in (bad / "checkpoints" / str(epoch) / "train").rglob("*"):
        if f.is_file() and f.stat().st_size > 100:
            f.write_bytes(b"garbage")
    # named, the corrupt checkpoint is an error; unnamed, the newest clean one is used
    assert _run_cli([bad / "checkpoints" / str(epoch), "--out", tmp_path / "o6"]) == 2
    assert "is corrupt or incomplete" in capsys.readouterr().err
    with pytest.warns(checkpoint.SkippedCheckpointWarning, match=f"using epoch {epoch - 1}"):
        restored = restore_policy(bad)
    assert restored.epoch == epoch - 1
    for name in ("o1", "o2", "o3", "o4", "o5", "o6"):
        assert not (tmp_path / name).exists()


def test_checkpoint_of_another_robot_or_layout_is_refused(full_run, learner):
    _, meta = checkpoint.read_meta(full_run[0].dir)
    env = learner.env
    check_compatible(meta, env, "ok")  # the real one passes
    cases = [
        ({"robot": "x_square"}, "trained on robot 'x_square', expected 'o_rectangle'"),
        ({"robot_fingerprint": "0" * 16}, "has changed since training"),
        ({"observation_layout": [["command", 3]]}, "observation layout [['command', 3]]"),
        ({"action_size": 3}, "action size 3, expected 4"),
    ]
    for change, message in cases:
        with pytest.raises(checkpoint.CheckpointError) as err:
            check_compatible({**meta, **change}, env, "ckpt")
        assert message in str(err.value)


@pytest.mark.full  # tens of seconds of XLA compilation on 2 cores
def test_interrupted_evaluation_leaves_no_complete_looking_report(tmp_path, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "write_plots", interrupted)
    out = tmp_path / "ev"
    argv = ["baseline", "--only", "singular_pass", "--episodes", 1, "--seconds", 1, "--out", out]
    assert _run_cli(argv) == 130
    assert not out.exists()
    assert not (tmp_path / "ev.partial" / "report.json").exists()


@pytest.mark.full
def test_an_episode_reads_the_same_in_any_row_and_set(eval_env, shipped):
    """Jobs merged, cut into chunks of 16 robots (the last padded by wrapping round) and
    split back give each job's traces alone, bit for bit, though the second job's episodes
    sit in other rows of a chunk of the same shape."""
    chosen = shipped.select(["payload", "slippery"], episodes=20, seconds=1.0)
    batches = [episodes.prepare(eval_env, s) for s in chosen.scenarios]
    ev = evaluation.Evaluator(eval_env, max_batch=16)
    assert ev.guard == 8  # the suite runs on the CPU
    calls = []
    together = ev.run_many(
        [(b, "feedback") for b in batches], progress=lambda d, t: calls.append(t)
    )
    assert calls == [3, 3, 3]  # 40 episodes in chunks of 16: three calls of one program
    for b, got in zip(batches, together, strict=True):
        alone = ev.run(b, who="feedback")
        for x, y in zip(got, alone, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.full  # two command lines, each compiling its rollout with XLA's optimizations
def test_the_command_line_reads_an_episode_the_same_in_any_row(tmp_path, optimized_env):
    """Where XLA vectorizes (the command line's flags, not the suite's unoptimized ones), a
    chunk's last 8 rows are rounded another way; the guard rows keep every episode out of
    them. Swapping the references moves each one's episodes by 8 rows of a 16-row chunk:
    their per-episode figures stay equal bit for bit (with ``batching.CPU_GUARD_ROWS = 0``
    they differ: 2-core AVX-512 CPU, 2026-12-08)."""
    parts = []
    for refs in (["feedback", "analytic"], ["analytic", "feedback"]):
        out = tmp_path / "-".join(refs)
        argv = ["baseline", "--only", "payload", "--episodes", "8", "--seconds", "2"]
        argv += ["--max-batch", "16", "--no-plots", "--out", str(out), "--references", *refs]
        run = [sys.executable, "-m", "train.cli.evaluate", *argv]
        done = subprocess.run(run, env=optimized_env, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
        parts.append(np.load(out / "parts.npz"))
    a, b = parts
    assert sorted(a.keys()) == sorted(b.keys())
    assert json.loads(str(a["kinds"])) == json.loads(str(b["kinds"]))  # in the references' order
    differ = [k for k in a.files if k != "kinds" and not np.array_equal(a[k], b[k])]
    assert not differ, differ


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--video", "--video-episode", 5], "--video-episode = 5: scenarios have 2 episodes"),
        (["--video-scenarios", "nominal"], "--video-scenarios: needs --video"),
        (["--max-batch", 0], "--max-batch = 0: must be >= 1"),
        (["--max-batch", 248], "--max-batch = 248: the fast model's evaluation hangs on the CPU"),
        (["--fps", 0], "--fps = 0: must be in [1, 50]"),
        (["--progress-every-s", 0], "--progress-every-s = 0.0: must be > 0 seconds"),
        (["--export"], "--export: the baseline has no weights"),
        (["--seed", 1], "--seed = 1: only for a checkpoint"),
        (["--scenarios", "missing.toml"], "scenarios = 'missing.toml': no such file"),
    ],
)
def test_eval_cli_rejects_bad_arguments(extra, message, tmp_path, capsys):
    out = tmp_path / "o"
    assert _run_cli(["baseline", "--episodes", 2, "--out", out, *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_a_warp_task_is_evaluated_under_jax_on_the_cpu(monkeypatch):
    """Without --physics-impl, a task trained under Warp evaluates under MJX's JAX
    implementation on the CPU (30x faster there) and where the extra is absent; elsewhere,
    and for a JAX task, it keeps its own."""
    from train.cli.eval_target import default_impl

    assert jax.default_backend() == "cpu"
    assert default_impl("warp") == "jax"
    assert default_impl("jax") == ""
    assert default_impl("") == ""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *a: object())
    assert default_impl("warp") == ""
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *a: None)
    assert default_impl("warp") == "jax"
