"""The training configs: validation, help texts and the saved form."""

import ast
import dataclasses
import inspect
import itertools
import json
import re
import textwrap
import tomllib

import pytest

from mecanum_jax.config import ConfigError, validated_once
from train import config as train_config
from train.cli import train as cli
from train.config import TrainConfig
from train.config_loading import TRAIN_CONFIG_DIR, load_train_config
from train.learner.ppo import Learner
from train.loop.run import Run


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


def test_a_bad_file_is_named_with_flags_too(tmp_path):
    """Flags are applied before the file's values are checked; an error in a value of the
    file's own still names the file, one in a flag's does not."""
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[ppo]\nlearning_rate = -1.0\n')
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(bad))}: ppo\.learning_rate = -1\.0"):
        load_train_config(bad, ["--ppo.num-timesteps", "1000"])
    with pytest.raises(ConfigError, match=r"^ppo\.num_envs = 7: must divide"):
        load_train_config("tiny", ["--ppo.num-envs", "7"])
    assert load_train_config(bad, ["--ppo.learning-rate", "1e-3"]).ppo.learning_rate == 1e-3


def test_a_config_is_checked_once_however_many_ask(monkeypatch):
    """Asked again, a config that passed is returned at once (validated_once)."""
    checks = []
    monkeypatch.setattr(train_config, "check_wandb", checks.append)  # once per check
    cfg = load_train_config("tiny")
    assert cfg.validate() is cfg.validate() is cfg
    assert len(checks) == 1


class _SetUpError(Exception):
    """Stops mecanum-train once its run and learner are set up."""


def test_mecanum_train_validates_its_config_once(tmp_path, monkeypatch):
    """A new run (with and without a flag) and a resumption each check the config once:
    the file's values after the flags; the run directory and the learner ask again and
    get it at once."""
    checked = []
    body = getattr(TrainConfig.validate, "__wrapped__", TrainConfig.validate)  # the checks

    def counted(cfg):
        checked.append(cfg)
        return body(cfg)

    def set_up_only(run, **_):
        try:
            Learner(run.cfg)
        finally:
            run.close()
        raise _SetUpError

    monkeypatch.setattr(TrainConfig, "validate", validated_once(counted))
    monkeypatch.setattr(Run, "train", set_up_only)
    run_dir = str(tmp_path / "run")
    for argv in (
        ["--config", "tiny", "--run-dir", str(tmp_path / "plain")],
        ["--config", "tiny", "--ppo.learning-rate", "1e-3", "--run-dir", run_dir],
        ["--resume", run_dir, "--ppo.num-timesteps", "8000"],
    ):
        checked.clear()
        with pytest.raises(_SetUpError):
            cli.main(argv)
        assert len(checked) == 1, f"{argv}: validated {len(checked)} times"


def _leaves(table, prefix=""):
    for key, value in table.items():
        if isinstance(value, dict):
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def _default(dotted):
    value = TrainConfig()
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def test_shipped_configs_state_only_what_they_change():
    """The defaults are the shipped recipe: gpu.toml names it and sets only the path
    integrator its policy was trained with and the mirror average (which a default would
    refuse on every layout without mirrors); every config states a key only where it
    differs from the default (a key stated at its default would hide what the file changes)."""
    names = sorted(p.stem for p in TRAIN_CONFIG_DIR.glob("*.toml"))
    assert {"quick", "tiny", "gpu", "scratch"} <= set(names)
    for name in names:
        cfg = load_train_config(name)
        assert cfg.name == name
        raw = tomllib.loads((TRAIN_CONFIG_DIR / f"{name}.toml").read_text())
        for key, value in _leaves(raw):
            if key != "name":
                same = tuple(value) if isinstance(value, list) else value
                assert same != _default(key), f"{name}.toml: {key} = {value!r} is the default"
    gpu = tomllib.loads((TRAIN_CONFIG_DIR / "gpu.toml").read_text())
    assert dict(_leaves(gpu)) == {
        "name": "gpu",
        "env.path_integrator": "euler",
        "env.symmetric": True,
    }


def test_the_shipped_model_was_trained_with_the_gpu_config():
    """gpu.toml is the shipped policy's recipe: models/o_rectangle's config.json states the
    same task, network and PPO settings, but for the physics flag its run passed and the
    run's own bookkeeping (seeds, checkpoints, evaluation batch)."""
    model = TRAIN_CONFIG_DIR.parents[1] / "models" / "o_rectangle" / "config.json"
    shipped = json.loads(model.read_text())
    gpu = json.loads(json.dumps(dataclasses.asdict(load_train_config("gpu"))))
    assert {**shipped["env"], "physics_impl": gpu["env"]["physics_impl"]} == gpu["env"]
    assert shipped["network"] == gpu["network"]
    assert shipped["ppo"] == gpu["ppo"]


def test_a_saved_config_without_a_field_runs_as_it_was_saved():
    """A run's config.json or checkpoint meta written before a field existed ran with the
    field off; with_absent fills it so, not with today's default (the shipped recipe), and
    leaves every field a file states alone. Each filled field exists and differs from its
    default (else the entry would be dead)."""
    from train.config_loading import SAVED_ABSENT, parse_train_config, with_absent

    for key, value in _leaves(SAVED_ABSENT):
        assert value != _default(key), key
    full = json.loads(json.dumps(dataclasses.asdict(load_train_config("gpu"))))
    assert with_absent(full) == full
    older = {k: v for k, v in full.items() if k != "network"}
    older["ppo"] = {k: v for k, v in full["ppo"].items() if k != "anchor"}
    cfg = parse_train_config(with_absent(older), "old config.json")
    assert cfg.ppo.anchor.weight == 0.0
    assert cfg.network.init_noise_std == 0.5
    assert cfg.ppo.smoothness.temporal == 1.0  # stated in the file: kept


def test_a_saved_config_with_a_removed_option_off_loads_and_with_it_on_is_refused(tmp_path):
    """A run saved before an option was removed states it: at its off value (how the run
    ran, and how the code now runs) the key is dropped; at another value the run used what
    is gone, and loading names the file, the field and the value. A TOML file gets no such
    leave. Each retired field is gone from today's config (else the entry would hide it)."""
    from train.config_loading import SAVED_RETIRED

    for key, _ in _leaves(SAVED_RETIRED):
        with pytest.raises(AttributeError):
            _default(key)
    saved = json.loads(json.dumps(dataclasses.asdict(load_train_config("gpu"))))
    saved["env"]["commands"]["p_mirror"] = 0.0  # as runs saved while the option existed state it
    path = tmp_path / "config.json"
    path.write_text(json.dumps(saved))
    assert load_train_config(str(path)) == load_train_config("gpu")
    saved["env"]["commands"]["p_mirror"] = 0.3
    path.write_text(json.dumps(saved))
    with pytest.raises(
        ConfigError, match=r"config\.json: env\.commands\.p_mirror = 0\.3: .*removed"
    ):
        load_train_config(str(path))
    toml = tmp_path / "old.toml"
    toml.write_text("[env.commands]\np_mirror = 0.0\n")
    with pytest.raises(ConfigError, match=r"p_mirror = 0\.0: unknown key"):
        load_train_config(str(toml))


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
    # train, env (and its 5 sections), network, ppo (its smoothness, anchor), run
    assert len(classes) == 12
    for cls in classes:
        missing = {f.name for f in dataclasses.fields(cls)} - set(_field_docs(cls))
        assert not missing, f"{cls.__name__}: fields without a docstring: {sorted(missing)}"
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    assert "Width of the linear tracking kernel" in capsys.readouterr().out
