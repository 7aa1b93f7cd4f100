"""mecanum-eval's scorecard: a win or a loss needs the interval on one side of 1 and a
mean difference above the metric's margin; anything else is a tie."""

from mecanum_jax.evaluation.compare import score
from train.cli.eval_output import scorecard_table


def _results(policy_ss_wz, verdict):
    cmp = {"ratio": 1.5, "lo": 1.2, "hi": 1.8, "verdict": verdict}
    return {
        "nominal": {
            "policy": {"ss_wz": policy_ss_wz, "ss_lin": 0.10},
            "analytic": {"ss_wz": 0.10, "ss_lin": 0.20},
            "compare": {
                "policy/analytic": {
                    "ss_wz": cmp,
                    "ss_lin": {"ratio": 0.5, "lo": 0.4, "hi": 0.6, "verdict": "better"},
                }
            },
        }
    }


def test_a_loss_needs_the_interval_and_the_margin():
    card = score(_results(0.15, "worse"), "policy/analytic")["nominal"]
    assert card == {"wins": ["ss_lin"], "ties": [], "losses": ["ss_wz"]}
    # worse, but by less than 0.02 rad/s: a tie
    card = score(_results(0.11, "worse"), "policy/analytic")["nominal"]
    assert card["losses"] == []
    assert card["ties"] == ["ss_wz"]
    # a large difference whose interval includes 1: a tie
    card = score(_results(0.30, "tie"), "policy/analytic")["nominal"]
    assert card["ties"] == ["ss_wz"]


def test_the_table_judges_against_every_reference_and_names_the_metrics_lost():
    results = _results(0.15, "worse")
    nominal = results["nominal"]
    nominal["feedback"] = {"ss_wz": 0.16, "ss_lin": 0.10}
    tie = {"ratio": 0.94, "lo": 0.9, "hi": 1.0, "verdict": "tie"}
    nominal["compare"]["policy/feedback"] = {"ss_wz": tie, "ss_lin": tie}
    table = scorecard_table(results, "policy", ["analytic", "feedback"])
    assert table.row_count == 1
    assert [c.header for c in table.columns] == [
        "scenario", "vs analytic", "vs feedback", "lost"
    ]  # fmt: skip
    cells = [next(iter(c.cells)) for c in table.columns]
    assert cells[1] == "1/0/[red]1[/]"  # a win (ss_lin), a loss (ss_wz) against analytic
    assert cells[2] == "0/2/0"  # two ties against feedback
    assert cells[3] == "analytic:ss_wz"
