"""``ppo.distill``: a student imitates a privileged teacher on its own rollouts."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from train.config import NetworkConfig, PPOConfig, TrainConfig
from train.learner import distill
from train.learner.losses import imitation_loss
from train.loss_config import DistillConfig


def test_bad_distill_settings_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match=r"ppo\.distill\.weight.*0"):
        TrainConfig(ppo=PPOConfig(distill=DistillConfig(teacher="t", weight=0.0))).validate()
    cfg = TrainConfig(
        network=NetworkConfig(teacher=True), ppo=PPOConfig(distill=DistillConfig(teacher="t"))
    )
    with pytest.raises(ConfigError, match=r"ppo\.distill\.teacher = 't'.*network\.teacher"):
        cfg.validate()
    missing = str(tmp_path / "nowhere")
    student = TrainConfig(ppo=PPOConfig(distill=DistillConfig(teacher=missing)))
    with pytest.raises(ConfigError, match=rf"ppo\.distill\.teacher = '{missing}'.*no such"):
        distill.load_teacher(student, None)  # type: ignore[arg-type]


def test_the_teachers_observation_is_gathered_by_entry_name():
    student = (("command", 3), ("gyro_z", 1), ("sensor_history", 4), ("true_twist", 3))
    teacher = (("command", 3), ("gyro_z", 1), ("true_twist", 3))
    idx = distill.gather_indices(student, teacher, "privileged observation")
    np.testing.assert_array_equal(idx, [0, 1, 2, 3, 8, 9, 10])
    with pytest.raises(ConfigError, match=r"ppo\.distill\.teacher.*'friction' \(size 4\)"):
        distill.gather_indices(student, (*teacher, ("friction", 4)), "privileged observation")
    with pytest.raises(ConfigError, match=r"'gyro_z' \(size 2\).*\(size 1\)"):
        distill.gather_indices(student, (("gyro_z", 2),), "policy observation")


def test_the_imitation_term_is_zero_on_the_teacher_and_moves_only_the_student():
    obs = {"state": jax.random.normal(jax.random.PRNGKey(0), (16, 5))}
    w_teacher = jax.random.normal(jax.random.PRNGKey(1), (5, 3))

    def teacher(o):
        return jnp.tanh(o["state"] @ w_teacher)

    def student(w):
        return lambda o: jnp.tanh(o["state"] @ w)

    assert float(imitation_loss(student(w_teacher), teacher, obs)) == pytest.approx(0.0)
    zero = jnp.zeros((5, 3))
    loss = imitation_loss(student(zero), teacher, obs)
    expected = np.mean(np.sum(np.asarray(teacher(obs)) ** 2, axis=-1))
    assert float(loss) == pytest.approx(float(expected), rel=1e-5)
    grad = jax.grad(lambda w: imitation_loss(student(w), teacher, obs))(zero)
    assert float(jnp.max(jnp.abs(grad))) > 0  # the student moves towards the teacher


@pytest.mark.full  # two tiny training runs: a couple of minutes on 2 cores
def test_a_student_with_history_learns_its_teachers_actions(tmp_path, capsys):
    """A tiny teacher, then its student with 5 earlier sensor frames: the run logs the
    teacher, the imitation error falls as the student trains, and the student exports
    with the history its control loop keeps."""
    from train.cli.export import main as export_main
    from train.cli.train import main as train_main

    teacher = tmp_path / "teacher"
    args = ["--config", "tiny", "--compilation-cache", "off"]
    # a teacher whose actions are far from the student's zero start (its random initial
    # network) and that reads only what the student reads: the student can match it, so
    # the imitation error must fall (a privileged teacher's gathering: the test above)
    tflags = ["--network.zero-init-mean", "False"]
    assert train_main([*args, *tflags, "--run-dir", str(teacher)]) == 0
    student = tmp_path / "student"
    flags = ["--env.obs-history", "5", "--ppo.distill.teacher", str(teacher)]
    flags += ["--ppo.distill.weight", "20", "--ppo.num-timesteps", "9600", "--run.eval-every", "30"]
    flags += ["--ppo.learning-rate", "1e-3"]
    capsys.readouterr()
    assert train_main([*args, *flags, "--run-dir", str(student)]) == 0
    log = " ".join(capsys.readouterr().err.split())
    assert "imitating" in log
    assert "seed 0, a policy)" in log
    rows = [json.loads(x) for x in (student / "metrics.jsonl").read_text().splitlines()]
    errors = [r["train"]["loss/imitation"] for r in rows]
    assert len(errors) >= 10
    assert np.mean(errors[:2]) > 0.05, errors  # the zero start is far from the teacher
    assert np.mean(errors[-3:]) < 0.3 * np.mean(errors[:2]), errors
    assert export_main([str(student), str(tmp_path / "s.npz")]) == 0
    from mecanum_jax.deploy.policy import load

    policy = load(tmp_path / "s.npz")
    assert policy.obs_history == 5
    assert policy.meta["observation_layout"][-1][0] == "sensor_history"


@pytest.mark.full  # a tiny training run and two resets: about a minute on 2 cores
def test_a_privileged_teachers_action_on_a_students_observation(tmp_path):
    """The teacher's action computed from a student's observation (history inserted, in
    the policy's and the privileged observation) is its action on its own observation of
    the same state."""
    import dataclasses

    from mecanum_jax.task.env import MecanumEnv
    from train.cli.train import main as train_main
    from train.config import load_train_config
    from train.learner.policy import restore_policy

    teacher = tmp_path / "teacher"
    flags = ["--network.teacher", "True", "--network.zero-init-mean", "False"]
    flags += ["--ppo.num-timesteps", "320", "--compilation-cache", "off"]
    assert train_main(["--config", "tiny", *flags, "--run-dir", str(teacher)]) == 0
    tiny = load_train_config("tiny")
    student = dataclasses.replace(
        tiny,
        env=dataclasses.replace(tiny.env, obs_history=4),
        ppo=dataclasses.replace(tiny.ppo, distill=DistillConfig(teacher=str(teacher))),
    ).validate()
    student_env = MecanumEnv(student.env)
    got = distill.load_teacher(student, student_env)
    assert got.privileged
    restored = restore_policy(teacher)
    key = jax.random.PRNGKey(7)
    mine = jax.jit(student_env.reset)(key).obs
    own = jax.jit(MecanumEnv(restored.cfg.env).reset)(key).obs
    assert mine["state"].shape[-1] == own["state"].shape[-1] + 4 * student_env.sensor_size
    want = restored.apply((restored.normalizer, restored.params), own)
    np.testing.assert_allclose(got.action(mine), want, rtol=1e-5, atol=1e-6)
    assert float(jnp.max(jnp.abs(want))) > 0.01  # a teacher that acts
    # a teacher of another task is refused, naming the differing field
    other = dataclasses.replace(student, env=dataclasses.replace(student.env, action_filter=0.5))
    with pytest.raises(ConfigError, match=r"ppo\.distill\.teacher.*env\.action_filter"):
        distill.load_teacher(other, student_env)
