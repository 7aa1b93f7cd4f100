"""scripts/eval_tables.py: the docs' tables, and another policy's rows beside the shipped one."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scripts.eval_tables import main

COMPARE = {"ss_wz": {"ratio": 0.5, "lo": 0.4, "hi": 0.6, "verdict": "better"}}


def report(policy_ss_wz: float, scenario: str = "nominal", seed: int = 7, fidelity: str = "fast"):
    """A one-scenario report of a policy and ``analytic`` on the same episodes."""
    figures = {"ss_lin": 0.1, "ss_wz": policy_ss_wz}
    return {
        "fidelity": fidelity,
        "scenarios": {
            scenario: {
                "episodes": 32,
                "seconds": 10.0,
                "seed": seed,
                "policy": figures,
                "analytic": {"ss_lin": 0.1, "ss_wz": 0.2},
                "compare": {"policy/analytic": COMPARE},
            }
        },
    }


def write(tmp_path: Path, name: str, data: dict) -> str:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return str(path)


def test_also_adds_the_other_policys_rows_and_its_ratio(tmp_path, capsys):
    shipped = write(tmp_path, "shipped.json", report(0.123))
    candidate = write(tmp_path, "candidate.json", report(0.077))
    assert main([shipped, "--also", f"candidate={candidate}"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("|")]
    assert any("| policy | 0.100 | 0.123 |" in r for r in rows)
    assert any("| candidate | 0.100 | 0.077 |" in r for r in rows)
    ratio_rows = [r for r in rows if "0.50 [0.40, 0.60] ✓" in r]
    assert [r.split("|")[2].strip() for r in ratio_rows] == ["analytic", "analytic (candidate)"]


def test_one_name_takes_reports_of_several_scenarios(tmp_path, capsys):
    a = write(tmp_path, "a.json", report(0.1, "nominal"))
    b = write(tmp_path, "b.json", report(0.1, "randomized"))
    ta = write(tmp_path, "ta.json", report(0.05, "nominal"))
    tb = write(tmp_path, "tb.json", report(0.06, "randomized"))
    assert main([a, b, "--also", f"candidate={ta}", "--also", f"candidate={tb}"]) == 0
    out = capsys.readouterr().out
    assert "| candidate | 0.100 | 0.050 |" in out
    assert "| candidate | 0.100 | 0.060 |" in out


@pytest.mark.parametrize(
    ("other", "spec", "message"),
    [
        (report(0.1, seed=8), "candidate={}", "scenario 'nominal': seed = 8, the tables' 7"),
        (report(0.1, fidelity="reference"), "candidate={}", "fidelity 'reference'"),
        (report(0.1), "analytic={}", "the name 'analytic' is taken"),
        (report(0.1), "candidate{}", "is not NAME=REPORT"),
        ({"not": "a report"}, "candidate={}", "is not a mecanum-eval report"),
    ],
)
def test_bad_also_is_rejected_naming_the_value(tmp_path, capsys, other, spec, message):
    shipped = write(tmp_path, "shipped.json", report(0.1))
    path = write(tmp_path, "other.json", other)
    assert main([shipped, "--also", spec.format(path)]) == 2
    captured = capsys.readouterr()
    assert message in captured.err
    assert captured.out == ""


def test_the_same_name_twice_on_one_scenario_is_rejected(tmp_path, capsys):
    shipped = write(tmp_path, "shipped.json", report(0.1))
    t1 = write(tmp_path, "t1.json", report(0.05))
    assert main([shipped, "--also", f"candidate={t1}", "--also", f"candidate={t1}"]) == 2
    assert "has 'candidate' already" in capsys.readouterr().err
