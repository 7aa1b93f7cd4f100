"""Two evaluations of the same episodes compared episode by episode
(mecanum_jax/evaluation/paired.py, scripts/compare_policies.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from mecanum_jax.evaluation import metrics, paired

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location(
        "compare_policies", ROOT / "scripts/compare_policies.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _parts(policy_scale: float, analytic_shift: float = 0.0, episodes: int = 32) -> paired.Parts:
    rng = np.random.default_rng(0)  # the same "episodes" in every call
    err = rng.uniform(0.01, 0.05, episodes)
    steps = np.full(episodes, 400.0)
    noise = rng.normal(1.0, 0.05, episodes)
    ana = {"ss_wz": metrics.Part(err * steps * (1 + analytic_shift), steps, "rms"),
           "energy_j": metrics.Part(70 + 10 * err, np.ones(episodes), "mean")}  # fmt: skip
    pol = {"ss_wz": metrics.Part(policy_scale**2 * err * steps * noise, steps, "rms"),
           "energy_j": metrics.Part(70 + 10 * err, np.ones(episodes), "mean")}  # fmt: skip
    return {"nominal": {"policy": pol, "analytic": ana}}


def test_parts_survive_the_file(tmp_path):
    parts = _parts(0.5)
    paired.save_parts(tmp_path / paired.PARTS_FILE, parts)
    back = paired.load_parts(tmp_path)  # a directory reads its parts.npz
    for who in ("policy", "analytic"):
        for m, p in parts["nominal"][who].items():
            q = back["nominal"][who][m]
            np.testing.assert_array_equal(q.num, p.num)
            np.testing.assert_array_equal(q.den, p.den)
            assert q.kind == p.kind
    with pytest.raises(FileNotFoundError, match=r"parts\.npz"):
        paired.load_parts(tmp_path / "missing")


def test_the_pair_is_paired_and_says_which_is_better():
    better = paired.pair(_parts(0.5), _parts(1.0))["nominal"]
    c = better["ss_wz"]
    assert c.ratio == pytest.approx(0.5, rel=0.01)
    assert c.hi < 1  # the whole interval below 1: the first is better
    same = paired.pair(_parts(1.0), _parts(1.0))["nominal"]["energy_j"]
    assert (same.ratio, same.lo, same.hi) == (1.0, 1.0, 1.0)


def test_other_episodes_are_refused_by_name():
    with pytest.raises(paired.EpisodesDifferError, match="nominal: analytic ss_wz"):
        paired.pair(_parts(0.5), _parts(1.0, analytic_shift=0.1))
    with pytest.raises(paired.EpisodesDifferError, match="16 episodes against 32"):
        paired.pair(_parts(0.5, episodes=16), _parts(1.0))
    # within the tolerance (a GPU's non-deterministic contact solve): accepted
    paired.pair(_parts(0.5), _parts(1.0, analytic_shift=0.005))


def test_the_script_prints_the_table_and_refuses_bad_input(tmp_path, capsys):
    main = _script().main
    for name, parts in (("new", _parts(0.5)), ("old", _parts(1.0)),
                        ("other", _parts(1.0, analytic_shift=0.2))):  # fmt: skip
        (tmp_path / name).mkdir()
        paired.save_parts(tmp_path / name / paired.PARTS_FILE, parts)
    assert main([str(tmp_path / "new"), str(tmp_path / "old")]) == 0
    out = capsys.readouterr().out
    assert "| nominal | ss ωz |" in out
    assert "✓" in out
    assert main([str(tmp_path / "new"), str(tmp_path / "other")]) == 2
    assert "not the same episodes" in capsys.readouterr().err
    assert main([str(tmp_path / "new"), str(tmp_path / "nowhere")]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert main([str(tmp_path / "new"), str(tmp_path / "old"), "--tolerance", "2"]) == 2
    assert "--tolerance 2.0" in capsys.readouterr().err


def test_the_script_compares_the_policy_against_a_reference_of_the_second(tmp_path, capsys):
    """--against: the first's policy against the second's `feedback` (a reference played
    under another config), not against the second's policy."""
    main = _script().main
    first = _parts(0.5)
    second = _parts(1.0)
    second["nominal"]["feedback"] = _parts(0.25)["nominal"]["policy"]  # better than both
    for name, parts in (("new", first), ("base", second)):
        (tmp_path / name).mkdir()
        paired.save_parts(tmp_path / name / paired.PARTS_FILE, parts)
    args = [str(tmp_path / "new"), str(tmp_path / "base")]
    assert main(args) == 0
    assert "✓" in capsys.readouterr().out  # the policy against the second's policy: better
    assert main([*args, "--against", "feedback"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if "| ss ωz |" in line)
    assert "| 2.0" in row  # against that feedback: twice as large,
    assert "✗" in row  # and worse
    assert main([*args, "--against", "nobody"]) == 2
    assert "'nobody' in the second" in capsys.readouterr().err
