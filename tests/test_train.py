"""The PPO trainer: configs, run directories, interrupt and resume, NaN stop, inference.

All runs use ``configs/train/tiny.toml`` on the suite's two CPU devices (so the pmap path
with gradient averaging is exercised) and share one compiled :class:`Learner`.
"""

import ast
import dataclasses
import importlib.util
import inspect
import itertools
import json
import textwrap
import tomllib
from pathlib import Path

import jax
import numpy as np
import optax
import pytest
from brax.training.agents.ppo.losses import PPONetworkParams

from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation.metrics import Part
from mecanum_jax.task import EnvConfig
from train.cli import train as cli
from train.config import (
    TRAIN_CONFIG_DIR,
    PPOConfig,
    TrainConfig,
    load_train_config,
    parse_train_config,
)
from train.learner.periodic import COMPARED, Result, beats, compare
from train.learner.policy import load_policy, restore_policy
from train.learner.ppo import Learner, to_host
from train.learner.state import gradient_clip, make_optimizer
from train.loop.run import Run, RunDirError, TrainingDiverged
from train.store import checkpoint, leaves


def _final_train_state(run, learner):
    state, env_state = learner.init()
    host, _, meta = checkpoint.restore(
        run.dir, jax.tree.map(np.asarray, state), jax.tree.map(np.asarray, env_state)
    )
    return host, meta


def _trains_through_a_run(cfg, learner, run_dir, epochs):
    """A whole run through ``learner``: checkpoints, logs, evaluation, a finite end."""
    run = Run.create(cfg, run_dir)
    summary = run.train(learner=learner)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "finished"
    assert summary["epochs"] == epochs
    restored, _ = _final_train_state(run, learner)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(restored))


def _deterministic_policy(learner, state):
    """The deterministic policy of seed 0 (device 0) of a ``(D, S, ...)`` training state."""
    one = jax.tree.map(lambda x: x[0, 0], state)
    return learner.make_policy(
        (one.normalizer_params, one.params.policy, one.params.value), deterministic=True
    )


def _random_obs(learner, n, seed):
    rng = np.random.default_rng(seed)
    return {
        k: rng.normal(size=(n, *shape)).astype(np.float32)
        for k, shape in learner.env.observation_size.items()
    }


def test_learner_uses_both_devices(learner):
    assert learner.n_devices == 2
    assert learner.envs_per_device == 4
    assert learner.parallel == "pmap"  # "auto" on CPUs; "sharded" only for several GPUs


def test_full_run_writes_its_directory(full_run, tiny):
    run, summary = full_run
    d = run.dir
    assert json.loads((d / "status.json").read_text())["state"] == "finished"
    assert parse_train_config(json.loads((d / "config.json").read_text()), "saved") == tiny
    lines = [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]
    assert lines[-1]["env_steps"] == 3 * tiny.steps_per_iteration * tiny.run.epoch_iterations
    for key in (
        "reward/tracking_lin",
        "reward/tracking_ang",
        "reward/action_rate",
        "reward/energy",
    ):
        assert key in lines[0]["train"]
    assert {"randomized", "nominal"} <= set(lines[0]["eval"])
    assert lines[0]["baseline"] == lines[-1]["baseline"]  # fixed held-out episodes
    assert list((d / "tb" / "seed_0").iterdir())  # TensorBoard events
    assert checkpoint.latest_epoch(d) == 3
    assert summary["epochs"] == 3
    assert summary["seeds"][0]["eval"]["nominal"]["rmse_lin"] > 0
    # wall time (and "beat at") counts the whole session: set-up, compilation, baseline
    assert summary["walltime_s"] == pytest.approx(summary["session_s"], abs=0.5)
    assert 0 < lines[0]["walltime"] < lines[-1]["walltime"] <= summary["walltime_s"]


def test_interrupted_run_resumes_exactly(full_run, tiny, learner, tmp_path, monkeypatch):
    reference, _ = full_run
    run = Run.create(tiny, tmp_path / "run")
    calls = {"n": 0}
    real_epoch = learner.epoch

    def epoch_then_ctrl_c(*args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt  # Ctrl-C during the second epoch
        return real_epoch(*args)

    monkeypatch.setattr(learner, "epoch", epoch_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        run.train(learner=learner)
    monkeypatch.setattr(learner, "epoch", real_epoch)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "interrupted"
    assert checkpoint.latest_epoch(run.dir) == 1  # the last completed epoch was saved

    resumed = Run.resume(run.dir)
    resumed.train(learner=learner)
    a, meta_a = _final_train_state(reference, learner)
    b, meta_b = _final_train_state(resumed, learner)
    assert meta_a["env_steps"] == meta_b["env_steps"]
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)  # optimizer, params, normalizer, keys: identical
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1, 2, 3]


def test_metric_loggers_get_every_epoch_and_wandb_is_optional(tiny, learner, tmp_path, monkeypatch):
    """A user's logger and W&B (``run.wandb_project``) receive each epoch's numeric rows,
    the same figures as metrics.jsonl; without wandb installed the option fails early."""
    import sys
    import types

    class Recorder:
        def __init__(self):
            self.calls, self.closed = [], False

        def log(self, steps, rows):
            self.calls.append((steps, rows))

        def close(self):
            self.closed = True

    fake_runs = []

    def init(**kw):
        run = types.SimpleNamespace(kw=kw, logged=[], finished=False)
        run.log = lambda data, step: run.logged.append((step, data))
        run.finish = lambda: setattr(run, "finished", True)
        fake_runs.append(run)
        return run

    monkeypatch.setitem(sys.modules, "wandb", types.SimpleNamespace(init=init))
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *a: object())
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, wandb_project="mecanum"))
    user = Recorder()
    run = Run.create(cfg, tmp_path / "run", loggers=[user])
    run.train(learner=learner)
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [steps for steps, _ in user.calls] == [x["env_steps"] for x in lines]
    steps, rows = user.calls[-1]
    seed = tiny.run.seeds[0]
    last = {k: v for k, v in _flat(lines[-1]).items() if isinstance(v, float) and k != "walltime"}
    assert len(last) > 10
    key = next(k for k in last if "rmse" in k)  # an evaluation figure
    for k, v in last.items():
        assert rows[seed][k] == pytest.approx(v, rel=1e-6)
    assert user.closed
    (wb,) = fake_runs
    assert wb.kw["project"] == "mecanum"
    assert wb.kw["config"]["run"]["wandb_project"] == "mecanum"
    assert wb.finished
    assert wb.logged[-1][0] == steps
    assert wb.logged[-1][1][f"seed_{seed}/{key}"] == rows[seed][key]
    monkeypatch.undo()
    if importlib.util.find_spec("wandb") is None:
        with pytest.raises(ConfigError, match=r"run\.wandb_project = 'mecanum': needs the wandb"):
            cfg.validate()


def _flat(d, prefix=""):
    out = {}
    for k, v in d.items():
        key = f"{prefix}/{k}" if prefix else k
        out |= _flat(v, key) if isinstance(v, dict) else {key: v}
    return out


@pytest.mark.full
def test_sharded_parallel_trains_like_pmap(full_run, tiny, learner, tmp_path):
    """``run.parallel = "sharded"`` (jit over a device mesh, the workaround for pmap's
    compiler crash on 2 GPUs) computes Brax's pmap path's epoch, on both devices."""
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, parallel="sharded"))
    sharded = Learner(cfg)
    assert sharded.parallel == "sharded"
    host = to_host(learner.init())
    ts, es = sharded.place(*host)
    leaf = jax.tree.leaves(ts)[0]
    assert len(leaf.sharding.device_set) == 2
    assert leaf.sharding.spec[0] == "d"
    ref_ts, _, ref_m = learner.epoch(*learner.place(*host))
    got_ts, _, got_m = sharded.epoch(ts, es)
    # the same epoch up to the two compilations' rounding (~3e-7 after one iteration,
    # which the following iterations' rollouts amplify)
    for k, v in to_host(ref_m).items():
        np.testing.assert_allclose(to_host(got_m)[k], v, rtol=1e-4, atol=1e-6, err_msg=k)
    for x, y in zip(
        jax.tree.leaves(to_host(ref_ts)), jax.tree.leaves(to_host(got_ts)), strict=True
    ):
        if np.issubdtype(y.dtype, np.floating):  # (rng keys differ per device by design)
            np.testing.assert_array_equal(y[0], y[1])  # replicas agree: the all-reduce works
            np.testing.assert_allclose(y, x, rtol=1e-3, atol=1e-5)
        else:
            np.testing.assert_array_equal(y, x)
    # a whole run through it: checkpoints, logs, evaluation
    _trains_through_a_run(cfg, sharded, tmp_path / "sharded", full_run[1]["epochs"])


@pytest.mark.full
def test_split_parallel_trains_like_pmap(full_run, tiny, learner, tmp_path):
    """``run.parallel = "split"`` (each device's rollouts in a program of its own, the
    update over the mesh: train/learner/split_epoch.py) computes Brax's pmap path's epoch, with
    each device's robots stepped on that device, and a whole run goes through it."""
    cfg = dataclasses.replace(tiny, run=dataclasses.replace(tiny.run, parallel="split"))
    split = Learner(cfg)
    assert split.parallel == "split"
    with pytest.raises(ValueError, match="compiles its programs on first use"):
        split.compile_epoch(*split.init())
    host = to_host(learner.init())
    ts, es = split.place(*host)
    ref_ts, ref_es, ref_m = learner.epoch(*learner.place(*host))
    got_ts, got_es, got_m = split.epoch(ts, es)
    for tree in (got_ts, got_es):  # each device keeps its own slice
        for leaf in jax.tree.leaves(tree):
            assert [s.data.shape[0] for s in leaf.addressable_shards] == [1, 1]
            assert len(leaf.sharding.device_set) == 2
    for k, v in to_host(ref_m).items():
        np.testing.assert_allclose(to_host(got_m)[k], v, rtol=1e-4, atol=1e-6, err_msg=k)
    pairs = itertools.chain(
        zip(jax.tree.leaves(to_host(ref_ts)), jax.tree.leaves(to_host(got_ts)), strict=True),
        zip(jax.tree.leaves(to_host(ref_es)), jax.tree.leaves(to_host(got_es)), strict=True),
    )
    for x, y in pairs:
        assert x.shape == y.shape
        if np.issubdtype(y.dtype, np.floating):
            np.testing.assert_allclose(y, x, rtol=1e-3, atol=1e-5)
        else:
            np.testing.assert_array_equal(y, x)
    _trains_through_a_run(cfg, split, tmp_path / "split", full_run[1]["epochs"])


def test_nan_stops_and_keeps_last_good_checkpoint(tiny, learner, tmp_path, monkeypatch):
    run = Run.create(tiny, tmp_path / "nan")
    calls = {"n": 0}
    real_epoch = learner.epoch

    def poisoned(*args):
        calls["n"] += 1
        ts, es, metrics = real_epoch(*args)
        if calls["n"] == 2:
            ts = ts.replace(params=jax.tree.map(lambda x: x * np.nan, ts.params))
            metrics = dict(metrics, finite=metrics["finite"] * 0)
        return ts, es, metrics

    monkeypatch.setattr(learner, "epoch", poisoned)
    with pytest.raises(
        TrainingDiverged, match=r"non-finite .* epoch 2 .* last good checkpoint: epoch 1"
    ):
        run.train(learner=learner)
    assert json.loads((run.dir / "status.json").read_text())["state"] == "diverged"
    host, _ = _final_train_state(run, learner)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(host.params))


@pytest.mark.full  # compiles the learner's finiteness check on its own
def test_nan_check_detects_non_finite_params(learner):
    ts, env_state = learner.init()

    def poison(x):
        x = np.array(x)
        if x.dtype.kind == "f":
            x[0, 0] = np.nan
        return x

    ts = ts.replace(params=jax.tree.map(poison, ts.params))
    _, _, metrics = learner.epoch(ts, env_state)
    assert float(np.asarray(metrics["finite"])[0, 0]) == 0.0


def test_run_directory_is_never_overwritten(full_run, tiny):
    run, _ = full_run
    before = (run.dir / "metrics.jsonl").read_text()
    with pytest.raises(RunDirError, match="already exists"):
        Run.create(tiny, run.dir)
    assert cli.main(["--config", "tiny", "--run-dir", str(run.dir)]) == 2
    assert (run.dir / "metrics.jsonl").read_text() == before


def test_resume_refuses_changed_config(full_run, tiny):
    run, _ = full_run
    import dataclasses

    changed = dataclasses.replace(tiny, ppo=dataclasses.replace(tiny.ppo, learning_rate=1.0))
    with pytest.raises(ConfigError, match=r"ppo\.learning_rate: cannot change when resuming"):
        Run.resume(run.dir, overrides=changed)


def test_policy_loads_into_plain_inference_function(full_run, learner):
    run, _ = full_run
    act, meta = load_policy(run.dir)
    assert meta["epoch"] == 3
    assert meta["robot"] == "o_rectangle"
    assert meta["observation_layout"][0] == ["command", 3]
    host, _ = _final_train_state(run, learner)
    policy = _deterministic_policy(learner, host)
    obs = _random_obs(learner, 5, seed=0)
    a = np.asarray(act(obs))
    assert a.shape == (5, 4)
    assert np.all(np.abs(a) <= 1)
    np.testing.assert_allclose(
        a, np.asarray(policy(obs, jax.random.PRNGKey(1))[0]), rtol=1e-5, atol=1e-6
    )


def test_load_policy_errors(tmp_path):
    with pytest.raises(checkpoint.CheckpointError, match="no such directory"):
        load_policy(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(checkpoint.CheckpointError, match="no checkpoints"):
        load_policy(tmp_path / "empty")


def test_evaluation_is_paired_and_held_out(learner):
    ts, _ = learner.init_training()
    one = jax.tree.map(lambda x: x[0], ts)
    a = learner.evaluate_baseline(one)
    b = learner.evaluate_baseline(one)
    assert a.values == b.values  # same fixed episodes every time
    assert set(a.values) == {"randomized", "nominal"}
    assert learner.cfg.run.eval_seed not in learner.cfg.run.seeds
    batches = learner.evaluation.batches()
    assert len(batches["randomized"].keys) == learner.cfg.run.num_eval_envs
    # the nominal scenario: nominal physics, no noise or latency
    assert np.all(np.asarray(batches["nominal"].noise_std) == 0)
    assert np.all(np.asarray(batches["nominal"].latency) == 0)
    assert np.ptp(np.asarray(batches["randomized"].params.friction)) > 0


def _result(ss_lin, ss_wz):
    """A periodic-evaluation result with per-episode steady-state errors."""
    parts = {}
    for key, err in (("ss_lin", ss_lin), ("ss_wz", ss_wz)):
        parts[key] = Part(np.asarray(err, float) ** 2, np.ones(len(err)), "rms")
    for key in set(COMPARED) - set(parts):
        parts[key] = Part(np.ones(len(ss_lin)), np.ones(len(ss_lin)), "mean")
    return Result({"randomized": {}}, {"randomized": parts})


def test_beating_the_baseline_takes_a_paired_interval_below_one():
    rng = np.random.default_rng(0)
    base = rng.uniform(0.5, 1.5, 200)
    baseline = _result(base, base)
    assert beats(compare(_result(0.8 * base, 0.9 * base), baseline))  # both clearly lower
    assert not beats(compare(_result(0.8 * base, 1.1 * base), baseline))  # one worse
    noisy = base * rng.choice([0.7, 1.3], 200)  # lower or higher by episode: a tie
    assert not beats(compare(_result(noisy, 0.8 * base), baseline))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--ppo.num-envs", "7"], "ppo.num_envs = 7"),
        (["--ppo.learning-rate", "-1"], "ppo.learning_rate = -1.0"),
        (["--run.seeds", "1", "1"], "run.seeds"),
        (["--run.seeds", "4294967296"], "seeds must be < 2**32"),
        (["--env.randomization.friction", "0.5", "0.1"], "env.randomization.friction"),
        (["--run.progress-every-s", "0"], "run.progress_every_s = 0.0: must be > 0 seconds"),
        (["--run.progress-every-s", "inf"], "run.progress_every_s = inf: must be > 0 seconds"),
    ],
)
def test_cli_rejects_bad_overrides_before_compiling(args, message, tmp_path, capsys):
    code = cli.main(["--config", "tiny", "--run-dir", str(tmp_path / "r"), *args])
    assert code == 2
    assert message in capsys.readouterr().err.replace("\n", "")
    assert not (tmp_path / "r").exists()


def test_bad_config_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[ppo]\nnum_envz = 3\n')
    with pytest.raises(ConfigError, match=r"ppo\.num_envz = 3: unknown key"):
        load_train_config(bad)
    with pytest.raises(ConfigError, match="no such file"):
        load_train_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="no such built-in config; known"):
        load_train_config("no_such_config")
    assert TrainConfig().validate().num_iterations >= 1


def _nested_keys(cls, where=""):
    """Dotted paths of every leaf field of a config dataclass."""
    out = []
    for f in dataclasses.fields(cls):
        default = getattr(cls(), f.name)
        path = f"{where}.{f.name}" if where else f.name
        out += _nested_keys(type(default), path) if dataclasses.is_dataclass(default) else [path]
    return out


def test_shipped_configs_validate_and_spell_out_the_task():
    """Each shipped config states every task setting: the file a user reads is what runs."""
    task_keys = _nested_keys(EnvConfig)
    names = sorted(p.stem for p in TRAIN_CONFIG_DIR.glob("*.toml"))
    assert {"quick", "tiny", "gpu", "scratch"} <= set(names)
    for name in names:
        cfg = load_train_config(name)
        assert cfg.name == name
        raw = tomllib.loads((TRAIN_CONFIG_DIR / f"{name}.toml").read_text())
        for key in task_keys:
            table = raw["env"]
            for part in key.split("."):
                assert part in table, f"{name}.toml: env.{key} is not spelled out"
                table = table[part]


def _field_docs(cls):
    """Attribute docstrings of a dataclass's fields (what tyro shows in --help)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, nxt in itertools.pairwise(body):
        is_doc = isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
        if isinstance(node, ast.AnnAssign) and is_doc and isinstance(nxt.value.value, str):
            docs[node.target.id] = nxt.value.value
    return docs


def test_every_config_field_has_help_text(capsys):
    classes, todo = [], [TrainConfig]
    while todo:
        cls = todo.pop()
        classes.append(cls)
        for f in dataclasses.fields(cls):
            value = getattr(cls(), f.name)
            if dataclasses.is_dataclass(value):
                todo.append(type(value))
    # train, env (and its 5 sections), network, ppo (its smoothness, distill, anchor), run
    assert len(classes) == 13
    for cls in classes:
        missing = {f.name for f in dataclasses.fields(cls)} - set(_field_docs(cls))
        assert not missing, f"{cls.__name__}: fields without a docstring: {sorted(missing)}"
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    assert "Width of the linear tracking kernel" in capsys.readouterr().out


def test_saved_configs_with_the_retired_error_cap_still_load():
    data = TrainConfig().to_dict()
    data["env"]["reward"]["error_cap"] = 0.0
    assert parse_train_config(data, "old run") == TrainConfig()
    data["env"]["reward"]["error_cap"] = 2.0
    with pytest.raises(ConfigError, match=r"env\.reward\.error_cap = 2\.0: unknown key"):
        parse_train_config(data, "old run")


def test_untrained_policy_is_the_baseline(learner):
    """zero_init_mean + residual actions: the deterministic untrained policy outputs 0."""
    ts, _ = learner.init_training()
    policy = _deterministic_policy(learner, ts)
    obs = _random_obs(learner, 7, seed=1)
    with jax.numpy_rank_promotion("allow"):
        action = np.asarray(policy(obs, jax.random.PRNGKey(0))[0])
    np.testing.assert_array_equal(action, np.zeros((7, learner.env.action_size)))
    assert learner.cfg.env.residual


def test_untrained_policy_explores_with_the_configured_noise(learner):
    """network.init_noise_std sets the initial exploration std, the same in every state
    (Brax's tanh-normal policy alone ignores it and starts at softplus of random outputs)."""
    ts, _ = learner.init_training()
    one = jax.tree.map(lambda x: x[0, 0], ts)
    obs = _random_obs(learner, 16, seed=2)
    with jax.numpy_rank_promotion("allow"):
        logits = learner.networks.policy_network.apply(
            one.normalizer_params, one.params.policy, obs
        )
        dist = learner.networks.parametric_action_distribution.create_dist(logits)
    std = np.asarray(dist.scale)
    assert std.shape == (16, learner.env.action_size)
    np.testing.assert_allclose(std, learner.cfg.network.init_noise_std, rtol=1e-5)


@pytest.mark.parametrize("per_network", [True, False])
def test_gradient_clipping_per_network(per_network):
    """With ppo.clip_per_network a huge value gradient no longer shrinks the policy's step."""
    cfg = TrainConfig(ppo=PPOConfig(max_grad_norm=1.0, clip_per_network=per_network))
    clip = gradient_clip(cfg)
    zeros = {"w": np.zeros(2, np.float32)}
    grads = PPONetworkParams(
        policy={"w": np.array([0.3, 0.4], np.float32)},  # norm 0.5: under the limit
        value={"w": np.array([60.0, 80.0], np.float32)},  # norm 100
    )
    params = PPONetworkParams(policy=zeros, value=zeros)
    out, _ = clip.update(grads, clip.init(params), params)
    policy, value = np.asarray(out.policy["w"]), np.asarray(out.value["w"])
    if per_network:
        np.testing.assert_allclose(policy, [0.3, 0.4], rtol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(value), 1.0, rtol=1e-5)
    else:  # one global norm, about 100: both scaled by the same factor
        scale = 1.0 / np.linalg.norm([0.3, 0.4, 60.0, 80.0])
        np.testing.assert_allclose(policy, np.array([0.3, 0.4]) * scale, rtol=1e-5)
        np.testing.assert_allclose(value, np.array([60.0, 80.0]) * scale, rtol=1e-5)


def test_policy_warmup_ramps_only_the_policy():
    """ppo.policy_warmup_steps: the policy's steps grow linearly from zero over the warm-up
    (in environment steps, converted to gradient updates); the value function's do not."""
    base = TrainConfig(ppo=PPOConfig(num_envs=8, batch_size=8, num_minibatches=2))
    updates_per_iteration = base.ppo.num_minibatches * base.ppo.num_updates_per_batch  # 8
    cfg = dataclasses.replace(
        base, ppo=dataclasses.replace(base.ppo, policy_warmup_steps=base.steps_per_iteration)
    )  # one iteration of warm-up: 8 updates
    plain, warm = make_optimizer(base), make_optimizer(cfg)
    params = PPONetworkParams(
        policy={"w": np.zeros(2, np.float32)}, value={"w": np.zeros(2, np.float32)}
    )
    grads = PPONetworkParams(
        policy={"w": np.array([0.3, -0.4], np.float32)},
        value={"w": np.array([0.1, 0.2], np.float32)},
    )
    s_plain, s_warm = plain.init(params), warm.init(params)
    for k in range(updates_per_iteration + 2):
        ref, s_plain = plain.update(grads, s_plain, params)
        got, s_warm = warm.update(grads, s_warm, params)
        ramp = min(k / updates_per_iteration, 1.0)
        np.testing.assert_allclose(got.policy["w"], ramp * ref.policy["w"], rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(got.value["w"], ref.value["w"], rtol=1e-6)
    assert np.any(np.asarray(ref.policy["w"]) != 0)
    # no warm-up: the optimizer state's tree (in checkpoints) is the one it always was
    former = optax.chain(gradient_clip(base), optax.adam(base.ppo.learning_rate))
    assert jax.tree.structure(s_plain) == jax.tree.structure(former.init(params))
    with pytest.raises(ConfigError, match=r"ppo\.policy_warmup_steps"):
        dataclasses.replace(
            base, ppo=dataclasses.replace(base.ppo, policy_warmup_steps=-1)
        ).validate()


def test_restoring_a_policy_builds_no_learner(full_run, monkeypatch):
    """A checkpoint restores into a template built from shapes alone, not a Learner."""
    run, _ = full_run

    def no_learner(*args, **kwargs):
        raise AssertionError("restore_policy built a Learner")

    monkeypatch.setattr(Learner, "__init__", no_learner)
    restored = restore_policy(run.dir)
    assert restored.epoch == 3
    assert np.all(np.isfinite(np.asarray(jax.tree.leaves(restored.params)[0])))


def test_bench_variants_take_the_trainers_flags(capsys):
    from train.tools import bench

    with pytest.raises(SystemExit):
        bench.main(["--config", "tiny", "--variant", "x --ppo.num-envz 3"])
    assert "--ppo.num-envz" in capsys.readouterr().err
    assert bench.main(["--config", "tiny", "--variant", "x --ppo.num-envs 3"]) == 2
    assert "ppo.num_envs = 3: must divide" in capsys.readouterr().out


@pytest.mark.full
def test_cpu_trains_256_robots(tiny, tmp_path):
    """256 robots on CPU used to hang (jaxlib's batched LAPACK deadlock); chunked, they
    train. One epoch of the tiny config at 256 environments."""
    cfg = dataclasses.replace(
        tiny,
        ppo=dataclasses.replace(tiny.ppo, num_envs=256, batch_size=128, num_timesteps=2560),
        run=dataclasses.replace(tiny.run, epoch_iterations=1),
    )
    summary = Run.create(cfg, tmp_path / "r256").train()
    assert summary["epochs"] == 1
    assert summary["env_steps_per_seed"] == 2560


def test_checkpoints_hold_only_numpy_arrays(learner):
    """Orbax refuses process-local jax.Arrays in multi-process runs; some optimizer states
    rebuild their leaves as jax arrays, so the packing converts leaf by leaf."""
    state, env_state = learner.init()
    for tree in (to_host(state), to_host(env_state)):
        packed = leaves.pack(tree)
        assert packed
        assert all(isinstance(v, np.ndarray) for v in packed.values())


def test_the_epoch_a_time_limit_stops_at_is_evaluated_and_logged(
    tiny, learner, tmp_path, monkeypatch
):
    """Between periodic evaluations (here: none but the final one), a run stopped by its
    time limit evaluates the epoch it stops at, and logs it in metrics.jsonl as the
    summary has it."""
    monkeypatch.setattr("train.loop.session.Session.eval_due", lambda self, final: final)
    run = Run.create(tiny, tmp_path / "limited")
    summary = run.train(learner=learner, time_limit_s=0.0)
    lines = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    assert [x["epoch"] for x in lines] == [1]
    assert json.loads((run.dir / "status.json").read_text())["state"] == "stopped"
    (logged,) = [x for x in lines if "eval" in x]
    (seed,) = summary["seeds"]
    assert seed["eval"]
    for scenario, figures in seed["eval"].items():
        for k, v in figures.items():
            if isinstance(v, float):
                assert logged["eval"][scenario][k] == pytest.approx(v, rel=1e-6), (scenario, k)


@pytest.mark.parametrize(
    ("parallel", "impl", "alone"),
    [
        ("pmap", "jax", False),
        ("sharded", "jax", False),
        ("split", "warp", True),
        ("sharded", "warp", True),
        ("pmap", "warp", True),
    ],
)
def test_first_runs_alone_under_warp(parallel, impl, alone):
    """Under MuJoCo Warp (and on the split path) the baseline's first evaluation finishes
    before the first epoch starts: a program's first run captures Warp's CUDA graphs, and
    another thread's GPU work meanwhile breaks the capture (train/loop/run.py)."""
    from types import SimpleNamespace

    from train.loop.aot import first_runs_alone

    learner = SimpleNamespace(
        parallel=parallel, env=SimpleNamespace(robot=SimpleNamespace(impl=impl))
    )
    assert first_runs_alone(learner) is alone  # type: ignore[arg-type]


def test_each_session_evaluates_its_first_epoch():
    """A first figure soon after the start: the session's first epoch is evaluated, then
    every ``run.eval_every`` epochs and the last one (a resumed session's first too)."""
    from types import SimpleNamespace

    from train.loop.session import Session

    cfg = SimpleNamespace(run=SimpleNamespace(eval_every=8))
    loop = Session(cfg, Path(), True, None, 0.0, None, None)  # type: ignore[arg-type]

    def evaluated(epochs: range) -> list[int]:
        out = []
        for loop.epoch in epochs:
            if loop.eval_due(final=loop.epoch == epochs[-1]):
                out.append(loop.epoch)
        return out

    assert evaluated(range(1, 18)) == [1, 8, 16, 17]
    loop.first_epoch = 11  # resumed after epoch 10
    assert evaluated(range(11, 20)) == [11, 16, 19]


def test_the_fresh_state_program_is_fresh_state_for_any_valid_seed(learner):
    """Seeds past int32 (``run.seeds`` allows up to 2**32 - 1) give the eager state's keys."""
    from train.learner.state import fresh_state, fresh_state_program

    program = fresh_state_program(learner.cfg, learner.env, learner.networks, learner.optimizer)
    for seed in (3, 2**31, 2**32 - 1):
        state, k_env = program(np.uint32(seed))
        eager, k_eager = fresh_state(
            learner.cfg, learner.env, learner.networks, learner.optimizer, seed
        )
        assert np.array_equal(k_env, k_eager)
        assert np.array_equal(state.key, eager.key)
