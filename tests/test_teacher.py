"""The privileged teacher (network.teacher): a policy that reads the critic's observation
(the simulator's truth), trained and evaluated like any other, never exported."""

import json

import jax
import pytest

from mecanum_jax.task import EnvConfig, MecanumEnv
from train.cli import export
from train.config import NetworkConfig, TrainConfig
from train.learner.policy import restore_policy
from train.learner.state import make_networks
from train.store import checkpoint


@pytest.mark.parametrize(("teacher", "key"), [(False, "state"), (True, "privileged_state")])
def test_the_teachers_policy_reads_the_privileged_observation(teacher, key):
    env = MecanumEnv(EnvConfig())
    networks = make_networks(env, TrainConfig(network=NetworkConfig(teacher=teacher)))
    params = networks.policy_network.init(jax.random.PRNGKey(0))
    first = params["params"]["hidden_0"]["kernel"]
    assert first.shape[0] == env.observation_size[key][0]
    sizes = {k: v[0] for k, v in env.observation_size.items()}
    assert sizes["privileged_state"] > sizes["state"]


def test_a_teacher_is_never_exported(tmp_path):
    class Restored:  # what check_exportable reads of a restored policy
        run_dir = tmp_path / "teacher-run"
        cfg = TrainConfig(network=NetworkConfig(teacher=True))

    with pytest.raises(checkpoint.CheckpointError, match=r"network\.teacher = true"):
        export.check_exportable(Restored())  # type: ignore[arg-type]
    Restored.cfg = TrainConfig()
    export.check_exportable(Restored())  # type: ignore[arg-type]


@pytest.mark.full  # a tiny training run and an evaluation rollout: a minute on 2 cores
def test_a_teacher_trains_evaluates_and_refuses_export(tiny, tmp_path, capsys):
    from train.cli.evaluate import main as eval_main
    from train.cli.export import main as export_main
    from train.cli.train import main as train_main

    run = tmp_path / "teacher"
    assert train_main(["--config", "tiny", "--network.teacher", "True", "--run-dir", str(run)]) == 0
    restored = restore_policy(run)
    assert restored.cfg.network.teacher
    out = tmp_path / "eval"
    args = [str(run), "--only", "nominal", "--episodes", "2", "--seconds", "2", "--no-plots"]
    assert eval_main([*args, "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["teacher"] is True
    assert "a privileged teacher" in report["label"]
    capsys.readouterr()
    assert eval_main([*args, "--out", str(tmp_path / "e2"), "--export"]) == 2
    assert "--export: the target is a teacher" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "e2").exists()
    assert export_main([str(run), str(tmp_path / "p.npz")]) == 2
    assert "network.teacher = true" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "p.npz").exists()
    # a model directory (what the device runner's ab and seeds tasks package) keeps the
    # teacher's checkpoint for evaluation, without an export
    model = tmp_path / "model"
    assert export_main([str(run), str(model), "--model"]) == 0
    assert not (model / "policy.npz").exists()
    assert json.loads((model / "provenance.json").read_text())["teacher"] is True
    assert restore_policy(model).cfg.network.teacher
