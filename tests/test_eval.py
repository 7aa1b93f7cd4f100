"""Evaluation: scenario files, paired batched rollouts, metrics, the CLI, and the export.

The CLI tests run ``mecanum-eval`` on a reduced scenario set (what CI checks); the
checkpoint tests use the session's tiny trained run (``full_run`` in conftest.py).
"""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from loops import network_free

from mecanum_jax.config import ConfigError
from mecanum_jax.deploy import policy as deploy
from mecanum_jax.evaluation import episodes, paired, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.kinematics import singularity
from mecanum_jax.kinematics.modes import SIX_MODES
from mecanum_jax.task import EnvConfig, MecanumEnv
from train.cli import evaluate as cli
from train.cli import export
from train.learner.policy import check_compatible, load_policy, restore_policy
from train.store import checkpoint


@pytest.fixture(scope="module")
def shipped():
    return scenarios.load_scenarios("default")


@pytest.fixture(scope="module")
def env(shipped):
    return MecanumEnv(episodes.eval_env_config(EnvConfig(), shipped))


@pytest.fixture(scope="module")
def small(shipped):
    """Two scripted scenarios and two random ones, shortened."""
    return shipped.select(
        ["six_modes", "singular_pass", "nominal", "slippery"], episodes=3, seconds=3.0
    )


@pytest.fixture(scope="module")
def baseline_evaluator(env):
    return evaluation.Evaluator(env)


def test_default_scenarios_are_the_issue_list(shipped):
    assert shipped.names == [
        "nominal",
        "six_modes",
        "slippery",
        "payload",
        "radius_error",
        "weak_motors",
        "sensor_noise",
        "singular_pass",
    ]
    for s in shipped.scenarios:
        assert s.description, s.name
    by = {s.name: s for s in shipped.scenarios}
    assert by["nominal"].randomization == {}
    assert by["nominal"].noise.scale == 0
    assert by["slippery"].randomization_config(1.0).friction[1] < 0.5
    assert by["weak_motors"].command_config(EnvConfig().commands).p_beyond >= 0.5
    assert by["sensor_noise"].randomization["latency_steps"] == [2, 2]
    assert by["six_modes"].scripted
    assert by["singular_pass"].scripted
    assert not by["payload"].scripted


def test_six_modes_sequence_follows_seed_000(env, shipped):
    sc = shipped.select(["six_modes"]).scenarios[0]
    cmds = episodes.scripted_commands(env, sc)
    per = round(sc.commands.segment_s / env.config.control_dt)
    gap = round(sc.commands.pause_s / env.config.control_dt)
    for i, (_, unit, _) in enumerate(SIX_MODES.values()):
        seg = cmds[i * (per + gap) : i * (per + gap) + per]
        assert np.all(seg == seg[0])
        direction = seg[0] / np.linalg.norm(seg[0])
        np.testing.assert_allclose(direction, np.asarray(unit) / np.linalg.norm(unit), atol=1e-6)
        assert np.all(cmds[i * (per + gap) + per : (i + 1) * (per + gap)] == 0)
    assert np.all(cmds[6 * (per + gap) :] == 0)  # then stop


def test_singular_pass_drags_two_wheels_and_is_closed(env, shipped):
    sc = shipped.select(["singular_pass"]).scenarios[0]
    cmds = episodes.scripted_commands(env, sc)
    moving = cmds[np.linalg.norm(cmds, axis=-1) > 0]
    assert len(moving) > 0
    still = np.asarray(singularity.singular_wheels(env.geometry, jnp.asarray(moving), tol=1e-5))
    assert np.all(still.sum(axis=-1) == 2)  # two wheels only dragged at every moving step
    path = evaluation.intended_poses(cmds[None], env.config.control_dt)[0]
    np.testing.assert_allclose(path[-1], 0.0, atol=1e-5)  # out and back: a closed sequence
    assert np.max(np.linalg.norm(path[:, :2], axis=-1)) > 0.5


def test_episodes_do_not_follow_the_targets_command_mix(env, shipped):
    """A policy trained on another episode mix is judged on the same episodes."""
    from mecanum_jax.task import CommandConfig, RandomizationConfig

    other = MecanumEnv(
        dataclasses.replace(
            env.config,
            commands=CommandConfig(p_zero=0.0, p_translation=1.0, resample_max_s=9.0),
            randomization=RandomizationConfig(nominal_share=0.5),
        )
    )
    sc = shipped.select(["nominal"], 4, 3.0).scenarios[0]
    a, b = episodes.prepare(env, sc), episodes.prepare(other, sc)
    assert np.any(np.asarray(a.commands)[..., 2] != 0)  # spins: not the other's mix
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_prepare_is_seeded_and_applies_the_physics(env, shipped):
    sets = shipped.select(["slippery", "payload", "radius_error", "weak_motors", "sensor_noise"])
    by = {s.name: episodes.prepare(env, s) for s in sets.scenarios}
    again = episodes.prepare(env, sets.scenarios[0])
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(by["slippery"]), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    f = np.asarray(by["slippery"].params.friction)
    assert f.min() >= 0.12 * 0.9 - 1e-6
    assert f.max() <= 0.2 * 1.1 + 1e-6
    p = by["payload"].params
    assert np.all(np.asarray(p.payload_mass) >= 2.5)
    np.testing.assert_allclose(np.asarray(p.payload_com)[:, :2], [[0.06, 0.04]] * 32, atol=1e-6)
    r = np.asarray(by["radius_error"].params.radius_scale)
    assert r.max() < 1.0
    assert r.min() > 0.93
    nominal_torque = env.robot.nominal_params().torque_limit
    np.testing.assert_allclose(by["weak_motors"].params.torque_limit[0], 0.5 * nominal_torque)
    assert np.all(np.asarray(by["sensor_noise"].latency) == 2)
    np.testing.assert_allclose(by["sensor_noise"].noise_std[0], 2 * env.noise_std())
    # different scenarios draw different episodes from the same seed
    assert not np.array_equal(by["payload"].commands, by["radius_error"].commands)


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


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[scenarios.a]\nbogus = 1", "scenarios.a.bogus = 1: unknown key"),
        (
            "[scenarios.a.randomization]\nfriction = [0.5, 0.2]",
            "scenarios.a.randomization.friction = [0.5, 0.2]: lower bound above upper",
        ),
        ('[scenarios.a.commands]\nkind = "zigzag"', "scenarios.a.commands.kind = 'zigzag'"),
        (
            '[scenarios.a]\nseconds = 2.0\n[scenarios.a.commands]\nkind = "sequence"\n'
            "sequence = [[0.5, 0, 0, 3.0]]",
            "scenarios.a.commands.sequence = '3.0 s': longer than the episode",
        ),
        (
            '[scenarios.a.commands]\nkind = "sequence"\nsequence = [[3.0, 0, 0, 1.0]]',
            'scenarios.a.commands.sequence[0] = [3.0, 0.0, 0.0, 1.0]: units = "reach"',
        ),
        ('[scenarios.a.commands]\nkind = "six_modes"\np_zero = 0.5', "scenarios.a.commands.p_zero"),
        ("[scenarios.Bad]\n", "scenarios.Bad = 'Bad': scenario names are lower_snake_case"),
        ("[scenarios.a]\nepisodes = 0", "scenarios.a.episodes = 0: must be in [1, 4096]"),
        ("[scenarios.a.noise]\nscale = -1.0", "scenarios.a.noise.scale = -1.0: must be >= 0"),
        ("[defaults]\nseed = 'x'\n[scenarios.a]", "defaults.seed = 'x': expected an integer"),
        ("[defaults]\n", "expected at least one [scenarios.<name>] table"),
        ("[scenarios.a.randomization]\nenabled = false", "scenarios.a.randomization.enabled"),
    ],
)
def test_bad_scenario_files_name_the_field(tmp_path, text, message):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        scenarios.load_scenarios(path)
    assert message in str(err.value)


def test_scenario_selection_errors(shipped):
    with pytest.raises(ConfigError, match=r"scenario 'icy': not in .* available: \['nominal'"):
        shipped.select(["icy"])
    with pytest.raises(ConfigError, match="episodes = 0"):
        shipped.select(episodes=0)
    with pytest.raises(ConfigError, match="no such scenario file"):
        scenarios.load_scenarios("nonexistent")


def test_singular_pass_needs_a_layout_with_singular_directions(shipped):
    env3 = MecanumEnv(EnvConfig(robot="centripetal3"))
    sc = shipped.select(["singular_pass"]).scenarios[0]
    with pytest.raises(ConfigError, match="has no singular directions"):
        episodes.scripted_commands(env3, sc)


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
    trace = evaluation.Trace(
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
    m = evaluation.summarize(trace, dt, True, jac)
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
    assert evaluation.summarize(trace, dt, False, jac)["drift_m"] is None
    detail = evaluation.per_episode(trace, dt, scripted=True)
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
def test_baseline_rollout_tracks_and_is_deterministic(env, small, baseline_evaluator):
    sc = small.scenarios[2]  # nominal, random commands
    batch = episodes.prepare(env, sc)
    a = baseline_evaluator.run(batch)
    b = baseline_evaluator.run(batch)
    np.testing.assert_array_equal(a.twist, b.twist)
    np.testing.assert_array_equal(a.command, np.asarray(batch.commands))
    m = evaluation.summarize(a, env.config.control_dt, False, env.jacobian)
    assert m["unstable"] == 0
    # it tracks: far better than standing still
    still = np.sqrt(np.mean(np.sum(a.command[..., :2] ** 2, axis=-1)))
    assert m["rmse_lin"] < 0.6 * still


@pytest.mark.full  # a policy's rollout program: about 35 s of compilation on 2 cores
def test_references_apply_no_action_beside_a_policy(env, small):
    """In a policy's evaluation the references' traces hold no action (flicker 0): the
    policy's output, computed on every rollout, is applied and recorded only for it."""

    def jittery(params, obs):  # a policy whose action follows its (noisy) sensors
        del params
        return jnp.tanh(10.0 * obs["state"][..., 3 : 3 + env.action_size])

    ev = evaluation.Evaluator(env, jittery)
    batch = episodes.prepare(env, small.scenarios[2])
    pol, ana = ev.run_many([(batch, "policy"), (batch, "analytic")])
    assert np.max(np.abs(pol.action)) > 0.01
    np.testing.assert_array_equal(ana.action, 0.0)
    jac, dt = env.jacobian, env.config.control_dt
    assert evaluation.trace_parts(ana, jac, dt)["flicker"].value() == 0.0
    assert evaluation.trace_parts(pol, jac, dt)["flicker"].value() > 0.0


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
    assert (out / "mecanum_policy.py").exists()


def test_export_round_trip_in_numpy_alone(full_run, tmp_path, learner):
    """The exported policy, run by NumPy in a process without JAX, MuJoCo or Brax,
    computes the JAX policy's actions."""
    run, _ = full_run
    path = tmp_path / "export" / "policy.npz"
    assert export.main([str(run.dir), str(path)]) == 0
    act, _ = load_policy(run.dir)
    rng = np.random.default_rng(3)
    obs = {
        k: (3 * rng.normal(size=(256, *shape))).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }
    expected = np.asarray(act(obs))
    np.save(tmp_path / "obs.npy", obs["state"])
    script = textwrap.dedent(
        f"""
        import importlib.abc, importlib.util, sys
        import numpy as np

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path, target=None):
                if name.split(".")[0] in ("jax", "jaxlib", "mujoco", "brax", "flax", "mecanum_jax"):
                    raise ImportError("blocked: " + name)

        sys.meta_path.insert(0, Block())
        module = {str(path.parent / "mecanum_policy.py")!r}
        spec = importlib.util.spec_from_file_location("mp", module)
        mp = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mp)
        policy = mp.load({str(path)!r})
        actions = policy.action(np.load({str(tmp_path / "obs.npy")!r}))
        np.save({str(tmp_path / "numpy_actions.npy")!r}, actions)
        assert not any(m.split(".")[0] in ("jax", "mujoco", "brax") for m in sys.modules)
        """
    )
    env = dict(os.environ, PYTHONPATH="")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    got = np.load(tmp_path / "numpy_actions.npy")
    assert np.abs(expected).max() > 1e-3  # a non-trivial policy
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.full
def test_exported_control_loop_matches_the_environment(full_run, tmp_path, learner):
    run, _ = full_run
    path = tmp_path / "policy.npz"
    assert export.main([str(run.dir), str(path)]) == 0
    policy = deploy.load(path)
    env = learner.env
    rng = np.random.default_rng(5)
    for _ in range(20):
        command = rng.normal(size=3).astype(np.float32) * np.asarray(env.command_scale)
        action = rng.uniform(-1, 1, env.action_size).astype(np.float32)
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action),
            np.asarray(env.wheel_setpoints(jnp.asarray(command), jnp.asarray(action))),
            rtol=1e-5,
            atol=1e-4,
        )
    # the observation built from raw measurements is the environment's (noise-free, no lag)
    cfg = env.config.nominal()
    nominal = MecanumEnv(cfg)
    state = nominal.reset(jax.random.PRNGKey(1))
    state = nominal.step(state, jnp.full(nominal.n_wheels, 0.3))
    sens = nominal.robot.sensors(state.pipeline_state)
    obs = policy.observation(
        state.info["command"], sens.wheel_rate, sens.gyro_z, sens.accel, state.info["last_action"]
    )
    np.testing.assert_allclose(obs, np.asarray(state.obs["state"]), rtol=1e-5, atol=1e-5)


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


def test_exported_file_errors(tmp_path):
    with pytest.raises(deploy.ExportError, match="no such file"):
        deploy.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(deploy.ExportError, match="unreadable"):
        deploy.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(deploy.ExportError, match="not an export"):
        deploy.load(tmp_path / "other.npz")
    assert export.main(["baseline", str(tmp_path / "p.txt")]) == 2


@pytest.mark.full
def test_run_many_chunks_and_pads_like_single_runs(env, shipped, baseline_evaluator):
    """Jobs merged, cut into chunks of 4 robots (the last padded) and split back give the
    same traces as one batch per job."""
    chosen = shipped.select(["payload", "singular_pass"], episodes=3, seconds=1.0)
    batches = [episodes.prepare(env, s) for s in chosen.scenarios]
    chunked = evaluation.Evaluator(env, max_batch=4)
    calls = []
    jobs = [(b, "analytic") for b in batches]
    many = chunked.run_many(jobs, progress=lambda d, t: calls.append(t))
    assert calls == [2, 2]  # 6 episodes in chunks of 4: two calls of one compiled program
    for b, got in zip(batches, many, strict=True):
        want = baseline_evaluator.run(b)
        for x, y in zip(got, want, strict=True):
            np.testing.assert_allclose(x, y, atol=1e-4)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--video", "--video-episode", 5], "--video-episode = 5: scenarios have 2 episodes"),
        (["--video-scenarios", "nominal"], "--video-scenarios: needs --video"),
        (["--max-batch", 0], "--max-batch = 0: must be >= 1"),
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


def test_exported_twist_residual_setpoints_match_the_environment():
    """The NumPy control loop applies a twist-space residual as the environment does."""
    env = MecanumEnv(EnvConfig(residual_space="twist"))
    policy = network_free(env)
    rng = np.random.default_rng(3)
    for _ in range(20):
        command = rng.normal(size=3).astype(np.float32) * np.asarray(env.command_scale)
        action = rng.uniform(-1, 1, 3).astype(np.float32)
        np.testing.assert_allclose(
            policy.wheel_setpoints(command, action),
            np.asarray(env.wheel_setpoints(jnp.asarray(command), jnp.asarray(action))),
            rtol=1e-5,
            atol=1e-4,
        )


@pytest.mark.full  # compiles an environment of its own
def test_exported_action_filter_matches_the_environment_in_numpy_and_onnx():
    """action_filter = f: the NumPy policy and its ONNX graph return f·last_action (read
    from the observation) + (1 − f)·network, the action the environment applies."""
    f = 0.8
    env = MecanumEnv(EnvConfig(action_filter=f).nominal())
    policy = network_free(env)  # no hidden layer: network = tanh(first entries)
    rng = np.random.default_rng(6)
    obs = rng.normal(size=(64, env.observation_size["state"][0])).astype(np.float32)
    names = [name for name, _ in env.layout]
    start = sum(size for _, size in env.layout[: names.index("last_action")])
    last = obs[:, start : start + env.action_size]
    network = np.tanh(obs[:, : env.action_size])
    expected = f * last + (1 - f) * network
    np.testing.assert_allclose(policy.action(obs), expected, rtol=1e-5, atol=1e-6)
    # the environment applies the same blend of its last action and a new one
    state = env.reset(jax.random.PRNGKey(0))
    state = state.replace(info={**state.info, "last_action": jnp.asarray(last[0])})
    stepped = env.step(state, jnp.asarray(network[0]))
    np.testing.assert_allclose(stepped.info["last_action"], expected[0], rtol=1e-5, atol=1e-6)
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    session = ort.InferenceSession(
        to_onnx(policy).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    (action,) = session.run(["action"], {"observation": obs})
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.full
def test_yaw_error_integral_observation_matches_the_control_loop():
    """yaw_integral_tau > 0: the environment integrates the measured yaw-rate error as a
    robot-side loop would (deploy.yaw_integral_step), and observes it last."""
    env = MecanumEnv(EnvConfig(yaw_integral_tau=0.5).nominal())
    assert env.layout[-1] == ("yaw_error_integral", 1)
    policy = network_free(env)
    state = env.reset(jax.random.PRNGKey(2))
    state = env.set_command(state, jnp.array([0.2, 0.0, 1.5]))
    integral = 0.0
    step = jax.jit(env.step)
    for k in range(6):
        tracked = np.asarray(state.info["command"])
        action = jnp.full(env.action_size, 0.01 * (-1) ** k)
        state = step(state, action)
        sens = env.robot.sensors(state.pipeline_state)
        integral = policy.yaw_integral_step(integral, tracked, float(sens.gyro_z))
        assert float(state.info["yaw_integral"]) == pytest.approx(integral, rel=1e-4, abs=1e-6)
        obs = policy.observation(
            tracked, sens.wheel_rate, sens.gyro_z, sens.accel, np.asarray(action), integral
        )
        np.testing.assert_allclose(obs, np.asarray(state.obs["state"]), rtol=1e-5, atol=1e-5)
    assert abs(integral) > 1e-4  # the spin-up from rest left a measurable yaw error
    with pytest.raises(ValueError, match="yaw_integral = None"):
        policy.observation(tracked, sens.wheel_rate, sens.gyro_z, sens.accel, np.asarray(action))


def test_onnx_export_matches_the_jax_policy_and_the_control_loop(full_run, tmp_path, learner):
    """``mecanum-export --format onnx``: onnxruntime maps raw observations to the JAX
    policy's actions, and to the NumPy control loop's wheel-rate setpoints."""
    ort = pytest.importorskip("onnxruntime")
    run, _ = full_run
    path = tmp_path / "policy.onnx"
    assert export.main([str(run.dir), str(path), "--format", "onnx"]) == 0
    assert export.main([str(run.dir), str(tmp_path / "p.npz")]) == 0
    act, _ = load_policy(run.dir)
    rng = np.random.default_rng(5)
    obs = {
        k: (3 * rng.normal(size=(128, *shape))).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    action, setpoints = session.run(["action", "wheel_setpoints"], {"observation": obs["state"]})
    expected = np.asarray(act(obs))
    assert np.abs(expected).max() > 1e-3  # a non-trivial policy
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-5)
    numpy_policy = deploy.load(tmp_path / "p.npz")
    commands = obs["state"][:, :3] * numpy_policy.command_scale
    loop = numpy_policy.wheel_setpoints(commands, action)  # batched over rows
    assert np.abs(loop).max() >= numpy_policy.max_rates.max() * 0.999  # saturation exercised
    np.testing.assert_allclose(setpoints, loop, rtol=1e-5, atol=1e-4)
    # the file carries its own description of the observation layout
    meta = json.loads({p.key: p.value for p in _onnx_props(path)}["mecanum_policy_meta"])
    assert meta["observation_layout"] == [list(x) for x in learner.env.layout]
    # wrong suffix: refused naming the field and the value, nothing written
    assert export.main([str(run.dir), str(tmp_path / "x.npz"), "--format", "onnx"]) == 2
    assert not (tmp_path / "x.npz").exists()


def _onnx_props(path):
    import onnx

    return onnx.load(str(path)).metadata_props


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
