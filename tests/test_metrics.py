"""The tracking metrics on synthetic traces with known answers, and the interval rule."""

import numpy as np
import pytest

from mecanum_jax.evaluation import metrics
from mecanum_jax.kinematics.geometry import o_rectangle
from mecanum_jax.kinematics.model import jacobian

DT = 0.02
J = np.asarray(jacobian(o_rectangle(radius=0.05, half_wheelbase=0.10, half_track=0.125)))


def _parts(command, target, twist, torque=None, rate=None, cfg=None):
    E, T = command.shape[:2]
    pose = np.zeros((E, T, 3))
    pose[..., 0] = np.cumsum(twist[..., 0], axis=1) * DT  # straight along x
    zeros = np.zeros((E, T))
    torque = np.zeros((E, T, 4)) if torque is None else torque
    rate = np.zeros((E, T, 4)) if rate is None else rate
    energy = np.sum(np.abs(torque * rate), axis=-1) * DT
    return metrics.episode_parts(
        command, target, twist, pose, np.zeros((E, 3)), energy, zeros, torque, rate, J, DT, cfg
    )


def test_step_response_has_its_known_settling_time_and_steady_state_error():
    """vx steps 0 → 1 m/s at t = 0 and the robot reaches it linearly in 0.3 s, then holds
    it with an offset of 0.02 m/s: settling 0.3 s, steady-state error 0.02."""
    T = 100
    command = np.zeros((1, T, 3))
    command[..., 0] = 1.0
    twist = np.zeros((1, T, 3))
    ramp = np.minimum(np.arange(1, T + 1) * DT / 0.3, 1.0)
    twist[0, :, 0] = ramp - 0.02 * (ramp >= 1.0)
    p = _parts(command, command, twist)
    # band: max(0.1 · 1 m/s, 0.05) = 0.1; the ramp enters it at 0.9 m/s, t = 0.27 s
    assert p["settle_lin_s"].value() == pytest.approx(0.28, abs=1e-9)
    assert p["ss_vx"].value() == pytest.approx(0.02, rel=1e-6)  # after 0.5 s: only the offset
    assert p["ss_wz"].value() == pytest.approx(0.0)
    assert p["rmse_vx"].value() > 0.1  # the raw figure is dominated by the step
    assert p["settle_wz_s"].value() is None  # no ω step happened


def test_a_segment_that_never_settles_counts_its_whole_length():
    T = 50
    command = np.zeros((1, T, 3))
    command[..., 2] = 2.0
    twist = np.zeros((1, T, 3))  # never moves
    p = _parts(command, command, twist)
    assert p["settle_wz_s"].value() == pytest.approx(T * DT)


def test_unreachable_command_is_judged_against_its_feasible_target():
    """Commanded 3 m/s, reachable 1 m/s, achieved 1 m/s: no steady-state error, raw 2 m/s."""
    T = 80
    command = np.zeros((1, T, 3))
    command[..., 0] = 3.0
    target = np.zeros_like(command)
    target[..., 0] = 1.0
    twist = target.copy()
    p = _parts(command, target, twist)
    assert p["ss_lin"].value() == pytest.approx(0.0)
    assert p["rmse_vx"].value() == pytest.approx(2.0)


def test_null_space_wheel_pattern_is_all_null_energy():
    """Torques along the null space of Jᵀ (wheels squeezing each other) move nothing."""
    null = np.linalg.svd(J.T)[2][-1]  # the one torque pattern with Jᵀ τ = 0
    assert np.allclose(J.T @ null, 0, atol=1e-9)
    T = 10
    torque = np.broadcast_to(null, (1, T, 4)).copy()
    rate = np.broadcast_to(np.sign(null) * 5.0, (1, T, 4)).copy()
    zeros = np.zeros((1, T, 3))
    p = _parts(zeros, zeros, zeros, torque, rate)
    assert p["null_energy_j"].value() == pytest.approx(p["energy_j"].value(), rel=1e-9)
    # a pure forward drive has no null-space part
    fwd = J @ np.array([1.0, 0.0, 0.0])
    torque = np.broadcast_to(fwd, (1, T, 4)).copy()
    p = _parts(zeros, zeros, zeros, torque, rate)
    assert p["null_energy_j"].value() == pytest.approx(0.0, abs=1e-9)
    assert p["energy_j"].value() > 0


def test_steps_since_change_and_segments():
    c = np.zeros((1, 6, 3))
    c[0, 2:, 0] = 1.0
    c[0, 5:, 2] = 1.0
    assert metrics.steps_since_change(c).tolist() == [[0, 1, 0, 1, 2, 0]]
    assert metrics.segment_ids(c).tolist() == [[0, 0, 1, 1, 1, 2]]


def _part(values):
    values = np.asarray(values, float)
    return metrics.Part(values**2, np.ones_like(values), "rms")


def test_interval_rule_win_loss_and_tie():
    rng = np.random.default_rng(1)
    base = rng.uniform(0.5, 1.5, 256)
    win = metrics.paired_ratio(_part(0.7 * base), _part(base))
    loss = metrics.paired_ratio(_part(1.3 * base), _part(base))
    noisy = base * rng.choice([0.6, 1.4], 256)  # as often better as worse
    tie = metrics.paired_ratio(_part(noisy), _part(base))
    assert win is not None
    assert loss is not None
    assert tie is not None
    assert win.ratio == pytest.approx(0.7)
    assert win.hi < 1
    assert metrics.verdict(win) == "better"
    assert loss.lo > 1
    assert metrics.verdict(loss) == "worse"
    assert tie.lo < 1 < tie.hi
    assert metrics.verdict(tie) == "tie"


def test_pairing_narrows_the_interval():
    """Episodes differ a lot, the controllers by a steady 5%: paired resampling sees it."""
    rng = np.random.default_rng(2)
    base = rng.uniform(0.1, 3.0, 128)
    c = metrics.paired_ratio(_part(0.95 * base), _part(base))
    assert c is not None
    assert 0.9 < c.lo <= c.hi < 1


def test_undefined_ratios_and_bad_inputs():
    zero = metrics.Part(np.zeros(3), np.zeros(3), "rms")
    assert metrics.paired_ratio(zero, zero) is None
    assert metrics.verdict(None) == "n/a"
    with pytest.raises(ValueError, match="3 episodes against 2"):
        metrics.paired_ratio(_part([1, 2, 3]), _part([1, 2]))
    with pytest.raises(ValueError, match=r"metrics.settle_s = -1"):
        metrics.MetricConfig(settle_s=-1).validate()


def test_bootstrap_interval_of_one_controller():
    """The interval of a pooled metric over resampled episodes: it holds the pooled value,
    is a point where every episode agrees, widens with the spread, and is undefined
    where no step counts."""
    rng = np.random.default_rng(3)
    spread = metrics.Part(rng.uniform(0, 2, 40), np.ones(40), "rms")
    lo, hi = metrics.bootstrap_interval(spread)
    assert lo < spread.value() < hi
    same = metrics.Part(np.full(40, 0.25), np.ones(40), "rms")
    assert metrics.bootstrap_interval(same) == pytest.approx((0.5, 0.5))
    wider = metrics.Part(rng.uniform(0, 8, 40), np.ones(40), "rms")
    lo_w, hi_w = metrics.bootstrap_interval(wider)
    assert hi_w - lo_w > hi - lo
    assert metrics.bootstrap_interval(metrics.Part(np.zeros(5), np.zeros(5), "rms")) is None


def test_flicker_is_the_mean_action_step():
    from mecanum_jax.evaluation.metrics import flicker_part

    still = np.zeros((2, 5, 3))
    assert flicker_part(still).value() == 0.0
    alternating = np.zeros((2, 5, 3))
    alternating[:, 1::2] = 0.1  # every step changes each entry by 0.1
    assert flicker_part(alternating).value() == pytest.approx(0.1)
    ramp = np.cumsum(np.full((1, 5, 1), 0.02), axis=1)  # a steady slope: 0.02 a step
    assert flicker_part(ramp).value() == pytest.approx(0.02)
