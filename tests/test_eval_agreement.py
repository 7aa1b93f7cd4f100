"""scripts/eval_agreement.py: when two devices' reports of the same episodes agree."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from scripts.eval_agreement import agreement, main

EPISODES = 32


def report(ss_wz: np.ndarray, device: str = "cpu:0") -> dict:
    """A one-scenario, one-controller report whose pooled ss ωz comes from ``ss_wz``."""
    count = np.full(len(ss_wz), 200.0)
    pooled = float(np.sqrt(np.sum(count * ss_wz**2) / np.sum(count)))
    episodes = {
        "ss_wz": ss_wz.tolist(),
        "ss_lin": [0.1] * len(ss_wz),
        "steady_steps": count.tolist(),
    }
    return {
        "device": device,
        "scenarios": {
            "nominal": {
                "analytic": {"ss_wz": pooled, "ss_lin": 0.1},
                "per_episode": {"analytic": episodes},
            }
        },
    }


def base() -> np.ndarray:
    return np.random.default_rng(0).uniform(0.05, 0.3, EPISODES)


def test_identical_reports_agree():
    lines, ok = agreement(report(base()), report(base()), 0.01)
    assert ok
    assert not any("DISAGREE" in line for line in lines)


def test_a_device_wide_bias_disagrees():
    """TF32-like: every episode 3% off. No episode agrees, so nothing excuses it."""
    lines, ok = agreement(report(base() * 1.03), report(base()), 0.01)
    assert not ok
    assert any("DISAGREE" in line for line in lines)


def test_one_chaotic_episode_is_named_not_failed():
    """One episode of 32 parted (its figure halves): the pooled figure moves by more than
    1%, but the other 31 agree and the move is inside the figure's sampling interval."""
    b = base()
    a = b.copy()
    a[5] *= 0.5
    x = report(a)["scenarios"]["nominal"]["analytic"]["ss_wz"]
    y = report(b)["scenarios"]["nominal"]["analytic"]["ss_wz"]
    assert abs(x - y) / y > 0.01  # the plain rule alone would fail it
    lines, ok = agreement(report(a), report(b), 0.01)
    assert ok
    assert any("diverged: 1 of 32 episodes" in line for line in lines)


def test_many_parted_episodes_disagree():
    """A fifth of the episodes parted: more than chaos explains (the 15% default)."""
    b = base()
    a = b.copy()
    a[:7] *= 1.5
    _, ok = agreement(report(a), report(b), 0.01)
    assert not ok
    _, ok_loose = agreement(report(a), report(b), 0.01, max_diverged=0.25)
    assert ok_loose  # the share is what refuses it: the move is within sampling noise


def test_a_small_bias_besides_a_parted_episode_disagrees():
    """The other episodes must agree too: 3% on all but one is not chaos."""
    b = base()
    a = b * 1.03
    a[5] = b[5] * 0.9
    lines, ok = agreement(report(a), report(b), 0.01)
    assert not ok
    assert any("DISAGREE" in line for line in lines)


def test_reports_without_episode_figures_use_the_plain_rule():
    a, b = report(base()), report(base())
    a["scenarios"]["nominal"]["analytic"]["ss_wz"] *= 1.05
    for r in (a, b):
        del r["scenarios"]["nominal"]["per_episode"]
    _, ok = agreement(a, b, 0.01)
    assert not ok


def test_main_rejects_bad_tolerances_and_reports_exit_codes(tmp_path: Path, capsys):
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(report(base() * 1.03, "cuda:0")))
    pb.write_text(json.dumps(report(base())))
    assert main([str(pa), str(pb)]) == 1
    assert main([str(pb), str(pb)]) == 0
    assert main([str(pa), str(pb), "--max-diverged", "1.5"]) == 2
    assert "--max-diverged must be in [0, 1), got 1.5" in capsys.readouterr().err
