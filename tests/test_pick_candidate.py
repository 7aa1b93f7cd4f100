"""scripts/pick_candidate.py: the fixed rule that chooses among candidates on tuning episodes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scripts.pick_candidate import AIMS, FIGURES, ROLLER_SCENARIOS, main, rank_key

SCENARIOS = sorted({s for s, _ in FIGURES})


def report(
    target: str, ratio: float, lost_key: str | None = None, against: str = "analytic"
) -> dict:
    """A tuning report whose policy reads ``ratio`` x analytic (and x feedback, which reads
    as analytic) on every figure; where ``lost_key`` is given, that metric of the training
    mix is lost (worse by 0.1) against ``against``."""
    scenarios = {}
    for name in SCENARIOS:
        base = {k: 1.0 for _, k in FIGURES} | {"ss_lin": 1.0, "settle_lin_s": 1.0}
        policy = {k: v * ratio for k, v in base.items()}
        compare = {
            k: {"ratio": ratio, "lo": ratio - 0.01, "hi": ratio + 0.01, "verdict": "tie"}
            for k in base
        }
        compared = {"analytic": compare, "feedback": dict(compare)}
        if lost_key and name == "tuning_randomized":
            policy[lost_key] = base[lost_key] + 0.1
            lost = {"ratio": 1.1, "lo": 1.05, "hi": 1.15, "verdict": "worse"}
            compared[against] = compared[against] | {lost_key: lost}
        scenarios[name] = {
            "policy": policy,
            "analytic": base,
            "feedback": base,
            "compare": {f"policy/{ref}": c for ref, c in compared.items()},
        }
    return {"target": target, "scenarios": scenarios}


def test_fewer_losses_beat_a_lower_mean(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = []
    for name, rep in {
        "tune_a_1.json": report("A", 0.8, lost_key="ss_wz"),  # better on average, one loss
        "tune_b_2.json": report("B", 0.95),
        "tune_c_3.json": report("C", 0.97),
        "tune_shipped.json": report("S", 0.5),  # shown, never chosen
    }.items():
        (tmp_path / name).write_text(json.dumps(rep))
        files.append(str(tmp_path / name))
    assert main(files) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == "B"
    assert any("(not a candidate)" in line for line in out)


def aims_only(rep: dict, ratio: float, hi: float) -> dict:
    """``rep`` with each of :data:`AIMS` read as ``ratio`` x feedback, interval up to ``hi``."""
    for scenario, key, _ in AIMS:
        rep["scenarios"][scenario]["compare"]["policy/feedback"][key] = {
            "ratio": ratio, "lo": ratio - 0.01, "hi": hi, "verdict": "better"
        }  # fmt: skip
    return rep


def test_the_steady_aims_rank_after_the_losses_and_before_the_mean(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """B meets every aim (0.80x feedback, interval below 1), C one (0.95x: within the ss v
    aim only, and its interval reaches 0.96) with the lower mean: B is chosen. A meets every
    aim with the lowest mean, but has a loss: fewer losses still come first."""
    reports = {
        "tune_a_0.json": report("A", 0.70, lost_key="ss_wz"),
        "tune_b_1.json": report("B", 0.80),
        "tune_c_2.json": aims_only(report("C", 0.79), 0.95, 0.96),
    }
    for name, rep in reports.items():
        (tmp_path / name).write_text(json.dumps(rep))
    assert main([str(tmp_path / name) for name in reports]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == "B"
    rows = {line.split()[0]: line for line in out if line.startswith("tune_") and "[" in line}
    assert rows["tune_b_1.json"].count(" met") == len(AIMS)
    assert rows["tune_c_2.json"].count(" met") == 1  # 0.95 <= 0.96 with its interval below 1
    ranked = [line.split()[0] for line in out if line.startswith("tune_") and "[" not in line]
    assert ranked == ["tune_b_1.json", "tune_c_2.json", "tune_a_0.json"]


def test_an_aim_whose_interval_reaches_1_is_not_met(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """B is within every aim by its ratio (0.80x) but each interval reaches 1: none is met,
    so C, which meets them all, is chosen over B's lower mean."""
    reports = {
        "tune_b_1.json": aims_only(report("B", 0.78), 0.80, 1.0),
        "tune_c_2.json": report("C", 0.79),
    }
    for name, rep in reports.items():
        (tmp_path / name).write_text(json.dumps(rep))
    assert main([str(tmp_path / name) for name in reports]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == "C"


def test_the_geometric_mean_is_over_every_figure() -> None:
    losses, gmean, ratios = rank_key(report("X", 0.9))
    assert losses == 0
    assert len(ratios) == len(FIGURES)
    assert gmean == pytest.approx(0.9)
    assert rank_key(report("Y", 0.9, lost_key="ss_wz"))[0] == 1


def test_a_loss_against_feedback_counts_as_one_against_analytic_does() -> None:
    assert rank_key(report("Z", 0.9, lost_key="ss_lin", against="feedback"))[0] == 1


def test_a_report_without_the_tuning_scenarios_is_refused() -> None:
    rep = report("X", 0.9)
    del rep["scenarios"]["tuning_nominal"]
    with pytest.raises(ValueError, match="tuning_nominal"):
        rank_key(rep)


def test_the_command_names_a_report_it_cannot_rank(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rep = report("X", 0.9)
    del rep["scenarios"]["tuning_path"]
    bad = tmp_path / "tune_x.json"
    bad.write_text(json.dumps(rep))
    assert main([str(bad)]) == 2
    assert "tune_x.json" in capsys.readouterr().err


def test_the_bundle_holds_every_report_without_its_episodes(tmp_path: Path) -> None:
    files = []
    for name, ratio in (("tune_a_1", 0.9), ("tune_shipped", 0.95)):
        rep = report(name.upper(), ratio)
        rep["scenarios"]["tuning_path"]["per_episode"] = {"drift_m": [0.1] * 32}
        rep["scenarios"]["tuning_nominal"]["per_episode"] = {"ss_wz": [0.1] * 32}
        (tmp_path / f"{name}.json").write_text(json.dumps(rep))
        files.append(str(tmp_path / f"{name}.json"))
    out = tmp_path / "tuning.json"
    assert main([*files, "--bundle", str(out)]) == 0
    bundle = json.loads(out.read_text())
    assert sorted(bundle) == ["tune_a_1", "tune_shipped"]
    assert bundle["tune_a_1"]["target"] == "TUNE_A_1"
    path = bundle["tune_a_1"]["scenarios"]["tuning_path"]
    assert "per_episode" not in path
    # kept where a CPU rerun checks the GPU's table (scripts/eval_agreement.py)
    assert bundle["tune_a_1"]["scenarios"]["tuning_nominal"]["per_episode"]["ss_wz"][0] == 0.1
    assert path["policy"]["drift_m"] == pytest.approx(0.9)


def test_every_figure_of_the_rule_is_a_scenario_of_the_tuning_file() -> None:
    from mecanum_jax.evaluation.scenarios import load_scenarios

    tuning = load_scenarios("tuning")
    assert set(SCENARIOS) <= set(tuning.names), sorted(set(SCENARIOS) - set(tuning.names))
    scripted = {s.name for s in tuning.scenarios if s.commands.kind != "random"}
    drifts = {name for name, key in FIGURES if key == "drift_m"}  # a scripted path's end
    assert {"tuning_path", "tuning_modes", "tuning_slalom", "tuning_stop_go"} <= drifts
    assert drifts <= scripted, sorted(drifts - scripted)


def roller_report(target: str, lost: bool = False, fidelity: str = "reference") -> dict:
    """A report of configs/eval/dashes.toml: the training mix's figures of :func:`report`
    under each dash's name (``lost``: ss_wz lost against feedback)."""
    mix = report(target, 1.0, "ss_wz" if lost else None, "feedback")["scenarios"]
    scenarios = {name: mix["tuning_randomized"] for name in ROLLER_SCENARIOS}
    return {"target": target, "fidelity": fidelity, "scenarios": scenarios}


def _write(tmp_path: Path, reports: dict[str, dict]) -> list[str]:
    for name, rep in reports.items():
        (tmp_path / name).write_text(json.dumps(rep))
    return [str(tmp_path / name) for name in reports]


def test_a_loss_in_the_roller_model_counts_with_the_tuning_losses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tuning = _write(
        tmp_path, {"tune_a_1.json": report("A", 0.9), "tune_b_2.json": report("B", 0.95)}
    )
    rollers = {
        "roller_a_1.json": roller_report("A", lost=True),
        "roller_b_2.json": roller_report("B"),
    }
    assert main(tuning) == 0  # the fast model alone: A, lower on average
    assert capsys.readouterr().out.strip().splitlines()[-1] == "A"
    assert main([*tuning, "--roller", *_write(tmp_path, rollers)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == "B"
    row = next(line.split() for line in out if line.startswith("tune_a_1.json"))
    assert row[1:3] == ["3", "3"]  # losses in all (one a dash), of them in the roller model


@pytest.mark.parametrize(
    ("rollers", "message"),
    [
        ({"roller_b_2.json": roller_report("B")}, "tune_a_1.json has no roller report"),
        (
            {
                "roller_a_1.json": roller_report("A", fidelity="fast"),
                "roller_b_2.json": roller_report("B"),
            },
            "fidelity = 'fast', expected 'reference'",
        ),
    ],
)
def test_a_candidate_without_its_roller_report_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], rollers: dict, message: str
) -> None:
    tuning = _write(
        tmp_path, {"tune_a_1.json": report("A", 0.9), "tune_b_2.json": report("B", 0.95)}
    )
    assert main([*tuning, "--roller", *_write(tmp_path, rollers)]) == 2
    assert message in capsys.readouterr().err


def test_the_roller_scenarios_are_those_of_the_dashes_file() -> None:
    from mecanum_jax.evaluation.scenarios import load_scenarios

    assert set(ROLLER_SCENARIOS) == set(load_scenarios("dashes").names)
