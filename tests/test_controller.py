"""The one controller (mecanum_jax.control) on its three backends: JAX, NumPy and the ONNX
graph traced from the same code give the same actions, setpoints and integrator; a
symmetric policy is exactly equivariant (the model folder: test_robot_archive.py)."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.control.spec import policy_layout
from mecanum_jax.control.symmetry import mirrors
from mecanum_jax.deploy.policy import NumpyPolicy, load, outputs

MODEL = Path(__file__).resolve().parents[1] / "models" / "o_rectangle"


def _observations(policy: NumpyPolicy, n: int, seed: int = 0) -> np.ndarray:
    """Random observations in the ranges the robot sees: actions in [-1, 1], some stops."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(scale=0.6, size=(n, policy.observation_size)).astype(np.float32)
    last = policy.entry("last_action")
    obs[:, last] = rng.uniform(-1, 1, size=(n, last.stop - last.start))
    obs[::10, :3] = 0.0  # stops
    return obs


OPTIONS = {
    "shipped": {},
    "shipped_symmetric": {"symmetric": True},
    "wheel_analytic_yaw_integral": {
        "residual_space": "wheel", "residual_base": "analytic", "yaw_integral_tau": 1.0,
        "residual_at_stop": False, "action_filter": 0.0, "residual_deadband": 0.0,
    },
    "direct_rates": {"residual": False, "action_filter": 0.0, "residual_deadband": 0.0},
    "path_ramp_history": {"path_tau": 3.0, "residual_ramp_s": 0.5, "obs_history": 2},
    "feedback_margin": {"feedback": {"margin": 0.1}},
}  # fmt: skip
"""Controller options as the configs use them, each on the shipped robot's export."""


def _policy(overrides: dict, seed: int = 0) -> NumpyPolicy:
    """The shipped export's controller with ``overrides``; the shipped weights where the
    layout is the shipped one, random ones (of the shipped scale) elsewhere."""
    shipped = load(MODEL / "policy.npz")
    meta = {**shipped.meta, **{k: {**shipped.meta[k], **v} if isinstance(v, dict) else v
                               for k, v in overrides.items()}}  # fmt: skip
    twist = meta["residual"] and meta["residual_space"] == "twist"
    n = len(shipped.max_rates)
    meta["action_size"] = 3 if twist else n
    feedback = meta["residual"] and meta["residual_base"] == "feedback"
    layout = policy_layout(n, meta["action_size"], meta["yaw_integral_tau"] > 0, feedback,
                           meta["obs_history"], meta.get("path_tau", 0) > 0)  # fmt: skip
    meta["observation_layout"] = [list(x) for x in layout]
    size = sum(k for _, k in layout)
    if size == shipped.observation_size and meta["action_size"] == shipped.action_size:
        return NumpyPolicy(shipped.layers, shipped.mean, shipped.std, meta)
    rng = np.random.default_rng(seed)
    sizes = [size, 64, 64, 2 * meta["action_size"]]
    layers = [(rng.normal(0, 1 / np.sqrt(a), (a, b)).astype(np.float32), np.zeros(b, np.float32))
              for a, b in itertools.pairwise(sizes)]  # fmt: skip
    return NumpyPolicy(layers, np.zeros(size, np.float32), np.ones(size, np.float32), meta)


@pytest.mark.parametrize("name", list(OPTIONS))
def test_jax_numpy_and_onnx_agree_on_1000_random_steps(name):
    """The action, the setpoints and the integrator of 1000 random steps (observations in
    the ranges the robot sees, command ages from 0 to 40 periods) on the three backends."""
    ort = pytest.importorskip("onnxruntime")
    from mecanum_jax.deploy.onnx import to_onnx

    policy = _policy(OPTIONS[name])
    obs = _observations(policy, 1000)
    age = np.random.default_rng(1).integers(0, 40, (1000, 1)).astype(np.float32)
    want = outputs(policy, obs, age, np)
    with jax.numpy_rank_promotion("allow"):
        fn = jax.jit(lambda o, a: outputs(policy, o, a, jnp))
        got_jax = fn(jnp.asarray(obs), jnp.asarray(age))
    session = ort.InferenceSession(to_onnx(policy).SerializeToString(),
                                   providers=["CPUExecutionProvider"])  # fmt: skip
    names = ["action", "wheel_setpoints", "feedback_integral"][: len(want)]
    got_onnx = session.run(names, {"observation": obs, "command_age": age})
    assert np.abs(want[1]).max() > 1.0  # the wheels are driven
    for what, w, j, o in zip(names, want, got_jax, got_onnx, strict=True):
        scale = 1.0 if what != "wheel_setpoints" else float(np.max(policy.max_rates))
        np.testing.assert_allclose(np.asarray(j), w, atol=1e-5 * scale, err_msg=f"jax {what}")
        np.testing.assert_allclose(o, w, atol=1e-5 * scale, err_msg=f"onnx {what}")


def test_a_symmetric_policy_is_exactly_equivariant():
    """f(g·o) = g·f(o) for every mirror, whatever the weights (the shipped ones here)."""
    shipped = load(MODEL / "policy.npz")
    policy = NumpyPolicy(
        shipped.layers, shipped.mean, shipped.std, dict(shipped.meta, symmetric=True)
    )
    obs = _observations(policy, 200, seed=1)
    base = policy.network(obs)
    for (oi, os), (ai, sign) in mirrors(policy.spec):
        mirrored = policy.network(obs[:, oi] * os)
        np.testing.assert_allclose(mirrored, base[:, ai] * sign, atol=2e-6)
    plain = NumpyPolicy(
        shipped.layers, shipped.mean, shipped.std, dict(shipped.meta, symmetric=False)
    )
    (oi, os), (ai, sign) = mirrors(plain.spec)[0]
    gap = np.abs(plain.network(obs[:, oi] * os) - plain.network(obs)[:, ai] * sign).max()
    assert gap > 1e-3  # the unsymmetrized network is not: the check can fail


def test_an_asymmetric_robot_is_refused_for_a_symmetric_policy():
    from mecanum_jax.control.symmetry import AsymmetricRobotError

    shipped = load(MODEL / "policy.npz")
    spec = dataclasses.replace(
        shipped.spec,
        # one wheel set further from the centre: its ωz column no longer matches a mirror's
        jacobian=shipped.spec.jacobian
        + np.asarray([[0, 0, 0.3], [0, 0, 0], [0, 0, 0], [0, 0, 0]], np.float32),
    )
    with pytest.raises(AsymmetricRobotError, match="not mirror-symmetric"):
        mirrors(spec)


def test_a_rank_deficient_layout_observes_finite_odometry():
    """x_square's Jacobian has rank 2: its controller reads the task's pseudo-inverse
    forward model, so the odometry it observes is finite (NaN made the first epoch of a
    training run diverge)."""
    import warnings

    from mecanum_jax.control import step as ctl
    from mecanum_jax.task import EnvConfig, MecanumEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the layout's SingularLayoutWarning
        env = MecanumEnv(EnvConfig(robot="x_square"))
    spec = env.control
    assert np.all(np.isfinite(spec.forward_matrix))
    np.testing.assert_allclose(spec.forward_matrix, np.asarray(env.constants.forward_matrix))
    rates = np.asarray([3.0, -1.0, 2.0, 0.5], np.float32)
    frame = ctl.frame(spec, rates, np.zeros(1, np.float32), np.zeros(3, np.float32), np)
    assert np.all(np.isfinite(frame))


@pytest.mark.parametrize("spin", [2.0, 11.0])
def test_the_exact_path_integrator_stays_within_the_leaks_bound(spin):
    """A robot that lags a held command by a constant 0.1 m/s and 0.1 rad/s for 8 s: the
    exact integrator's path error settles within the leak's bound (error rate · τ), at any
    commanded yaw rate; the shipped policy's first-order one does too at 2 rad/s, but at 11
    rad/s (the robot's ωz reach; ωz·dt = 0.22) it outgrows the leak."""
    from mecanum_jax.control import step as ctl

    base = dataclasses.replace(load(MODEL / "policy.npz").spec, path_tau=3.0)
    command = np.asarray([0.5, 0.0, spin], np.float32)
    twist = command - np.asarray([0.1, 0.0, 0.1], np.float32)
    bound = np.hypot(0.1, 0.1 * 3.0) * 3.0 + 0.1 * 3.0  # |v error| with the heading's part

    def held(integrator):
        spec = dataclasses.replace(base, path_integrator=integrator)
        error = np.zeros(3, np.float32)
        for _ in range(400):
            error = ctl.path_step(spec, error, twist, command, np)
        return float(np.linalg.norm(error[:2])), float(error[2])

    exact, heading = held("exact")
    assert exact < bound
    a = np.exp(-0.02 / 3.0)  # the heading's leaky sum of -0.1 rad/s over 400 periods
    assert heading == pytest.approx(-0.1 * 0.02 * a * (1 - a**400) / (1 - a), rel=1e-4)
    euler, _ = held("euler")
    assert (euler < bound) if spin == 2.0 else (euler > 5 * bound)
