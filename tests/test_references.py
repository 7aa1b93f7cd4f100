"""The reference controllers, and the shipped model directory."""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tasks import PLAIN_FEEDBACK, WHEEL

from mecanum_jax.evaluation import episodes, metrics, scenarios
from mecanum_jax.evaluation import rollout as evaluation
from mecanum_jax.evaluation.traces import trace_parts
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.task import REFERENCES, EnvConfig, FeedbackConfig, MecanumEnv, references
from train.cli.evaluate import main as eval_main
from train.learner.policy import PROVENANCE, restore_policy

pytestmark = pytest.mark.full

MODEL = "models/o_rectangle"
PLAIN = EnvConfig(**WHEEL, feedback=FeedbackConfig(**PLAIN_FEEDBACK))  # quick.toml's task


def test_reference_rates_select_the_named_controller():
    env = MecanumEnv(PLAIN.nominal())
    s = env.set_command(env.reset(jax.random.PRNGKey(0)), jnp.asarray([0.3, 0.1, 0.5]))
    fb = env.config.feedback
    traced = [
        np.asarray(
            references.reference_rates(env.constants, jnp.asarray(i), s.info, fb, env.control)
        )
        for i in range(3)
    ]
    for i in range(len(REFERENCES)):
        one = references.reference_rates(env.constants, i, s.info, fb, env.control)
        np.testing.assert_allclose(traced[i], one, atol=1e-5)
    base = references.baseline_rates(env.constants, s.info["command"])
    np.testing.assert_allclose(traced[0], base, atol=1e-5)
    # at rest, the feedback's integrator grows by ki·e·dt with e the whole yaw command
    ki = env.config.feedback.ki
    after = env.step(s, jnp.zeros(env.action_size), jnp.asarray(2))
    assert float(after.info["feedback_integral"]) == pytest.approx(ki * 0.5 * 0.02, rel=1e-4)


SLIP = """
[defaults]
episodes = 4
seconds = 4.0
seed = 3

[scenarios.slip]
commands = { kind = "sequence", units = "si", sequence = [[0.0, 0.0, 2.0, 4.0]] }
randomization = { friction = [0.5, 0.5], radius_scale = [0.93, 0.93], wheel_radius_spread = 0.0 }
"""


def test_feedback_removes_the_steady_yaw_error_of_a_slipping_spin(tmp_path):
    """Wheels 7% smaller than the inverse model believes, on a half-friction floor: the
    robot spins slower than commanded; the integral on the gyro makes that up, the open
    loop cannot (the target is the true robot's feasible twist, still 2 rad/s)."""
    (tmp_path / "slip.toml").write_text(SLIP)
    sset = scenarios.load_scenarios(tmp_path / "slip.toml")
    env = MecanumEnv(episodes.eval_env_config(PLAIN, sset))
    batch = episodes.prepare(env, sset.scenarios[0])
    ev = evaluation.Evaluator(env)
    jac = kinematics.jacobian(env.geometry)
    dt = env.config.control_dt
    traces = ev.run_many([(batch, "analytic"), (batch, "feedback")])
    a, f = (trace_parts(t, jac, dt)["ss_wz"] for t in traces)
    assert a.value() > 0.05  # the open loop leaves a steady error
    c = metrics.paired_ratio(f, a, n_boot=500)
    assert c is not None
    assert metrics.verdict(c) == "better", c


def test_shipped_model_loads_evaluates_and_exports(tmp_path):
    prov = json.loads((Path(MODEL) / PROVENANCE).read_text())
    assert {"command", "commit", "device", "env_steps", "walltime_s"} <= set(prov)
    restored = restore_policy(MODEL)
    out = tmp_path / "ev"
    argv = [MODEL, "--only", "nominal", "--episodes", "2", "--seconds", "1", "--out", str(out)]
    argv += ["--no-plots", "--references", "analytic"]
    assert eval_main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["epoch"] == restored.epoch
    assert report["scenarios"]["nominal"]["policy"]["rmse_wz"] is not None
    # the NumPy export shipped beside it is this policy
    from mecanum_jax.deploy import policy as deploy

    policy = deploy.load(Path(MODEL) / "policy.npz")
    env = MecanumEnv(dataclasses.replace(restored.cfg.env, physics_impl="jax"))
    s = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 16))
    params = (restored.normalizer, restored.params)
    step = jax.jit(jax.vmap(env.step))
    try:
        import onnxruntime as ort

        onnx_path = str(Path(MODEL) / "policy.onnx")
        session = ort.InferenceSession(onnx_path, providers=["CPUExecutionProvider"])
    except ImportError:
        ort = None
    for _ in range(3):  # after a step, last_action (the action filter's state) is not zero
        with jax.numpy_rank_promotion("allow"):
            raw = restored.apply(params, s.obs)
        obs = np.asarray(s.obs["state"])
        age = np.asarray(s.info["command_age"]) if "command_age" in s.info else None
        got = policy.action(obs, age)
        command = np.asarray(s.info["command"])
        setpoints = policy.wheel_setpoints(command, got, obs)
        integral = policy.feedback_integral_step(obs, age) if policy.feedback_base else None
        before = s
        s = step(s, raw)
        # NumPy returns the action the environment applies (low-passed, if trained so)
        np.testing.assert_allclose(got, np.asarray(s.info["last_action"]), atol=1e-4)
        # ... and the setpoints and the feedback integrator it applies
        applied = jax.vmap(env.wheel_setpoints)(before.info["command"], s.info["last_action"],
                                                before.info)  # fmt: skip
        np.testing.assert_allclose(setpoints, np.asarray(applied), atol=2e-3)
        if integral is not None:
            np.testing.assert_allclose(integral, s.info["feedback_integral"], atol=1e-5)
        if ort is not None:  # the ONNX graph shipped beside it does the same
            ages = np.zeros((len(obs), 1), np.float32) if age is None else age[:, None]
            feeds = {"observation": obs, "command_age": ages.astype(np.float32)}
            onnx_action, onnx_setpoints, *rest = session.run(None, feeds)
            np.testing.assert_allclose(onnx_action, got, atol=1e-4)
            np.testing.assert_allclose(onnx_setpoints, setpoints, atol=2e-3)
            if integral is not None:  # the graph holds it too, from the command's age
                np.testing.assert_allclose(rest[0][:, 0], integral, atol=1e-5)
