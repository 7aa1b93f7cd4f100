"""Choose among trained candidates on the tuning episodes, by a rule fixed before the runs.

Reads ``mecanum-eval`` reports of ``configs/eval/tuning.toml`` (``run.sh tune`` writes
them as ``/tmp/tune-reports/tune_NAME.json``) and ranks every candidate against
``analytic`` on the same episodes:

1. fewest **losses** against ``analytic`` and against ``feedback`` together
   (``mecanum_jax.evaluation.compare.score``: the paired 95% interval on the worse side and
   an excess above the metric's margin) over the tuning scenarios;
2. then the most **steady-state aims met** (:data:`AIMS`: the project's targets for the
   steady gain, each a ratio to ``feedback`` within its aim and the interval below 1);
3. then the lowest **geometric mean of the ratios** to ``analytic`` over the figures the
   product is judged on: the training mix's ss v, ss ωz, settling of v and ωz and energy;
   the nominal robot's ss ωz and settling of ωz; the translations' ss ωz and energy; the
   closed path's ss ωz and final drift; the spins' ss ωz and energy; the motion modes' ss ωz
   and final drift; the slippery floors' ss ωz and settling of ωz; the settling of v and ωz
   with noisy sensors; the transients' final drift, the slalom's RMSE ωz, the bursts' and
   stop-and-go's ss v, the zigzag's RMSE v and the weave's RMSE ωz.

With ``--roller R...`` (``run.sh tune`` passes them), each candidate's losses also count
those of its report of ``configs/eval/dashes.toml`` in the reference roller model
(``roller_NAME.json`` for ``tune_NAME.json``): dashes near the reach yaw there as they
never do in the fast model, and a correction the fast model keeps inside its deadband can
turn that yaw into heading (docs/evaluation.md). A candidate without such a report is
refused, so every candidate is judged by the same rule.

Prints one row per candidate, then each one's steady-state aims against ``feedback`` and,
last, the path of the chosen one's model (the report's
``target``), so that a device call can evaluate it on held-out scenarios next::

    python scripts/pick_candidate.py tune_s0_1.json tune_s1_2.json ... [--exclude shipped]
        [--roller roller_s0_1.json roller_s1_2.json ...]

``--bundle FILE`` also writes every report into one JSON keyed by file name (their
per-episode data left out, but for ``tuning_nominal``'s), which is how ``run.sh tune``
sends any number of candidates back from the GPU machine as one file. Held-out scenarios
never enter the choice.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, NamedTuple

from mecanum_jax.evaluation.compare import score

JUDGED_AGAINST = ("analytic", "feedback")
"""The references a loss counts against (a report without one counts none against it)."""

FIGURES = (
    ("tuning_randomized", "ss_lin"),
    ("tuning_randomized", "ss_wz"),
    ("tuning_randomized", "settle_lin_s"),
    ("tuning_randomized", "settle_wz_s"),
    ("tuning_randomized", "energy_j"),
    ("tuning_nominal", "ss_wz"),
    ("tuning_nominal", "settle_wz_s"),
    ("tuning_translations", "ss_wz"),
    ("tuning_translations", "energy_j"),
    ("tuning_path", "ss_wz"),
    ("tuning_path", "drift_m"),
    ("tuning_spins", "ss_wz"),
    ("tuning_spins", "energy_j"),
    ("tuning_modes", "ss_wz"),
    ("tuning_modes", "drift_m"),
    ("tuning_slippery", "ss_wz"),
    ("tuning_slippery", "settle_wz_s"),
    ("tuning_noisy", "settle_lin_s"),
    ("tuning_noisy", "settle_wz_s"),
    ("tuning_slalom", "drift_m"),
    ("tuning_slalom", "rmse_wz"),
    ("tuning_bursts", "drift_m"),
    ("tuning_bursts", "ss_lin"),
    ("tuning_zigzag", "rmse_lin"),
    ("tuning_zigzag", "drift_m"),
    ("tuning_weave", "rmse_wz"),
    ("tuning_weave", "drift_m"),
    ("tuning_stop_go", "drift_m"),
    ("tuning_stop_go", "ss_lin"),
)
"""(scenario, metric) pairs whose ratios to ``analytic`` the geometric mean takes."""


AIMS = (
    ("tuning_randomized", "ss_lin", 0.96),
    ("tuning_randomized", "ss_wz", 0.87),
    ("tuning_slippery", "ss_wz", 0.86),
)
"""The steady-state wins a policy is to keep, as the largest ratio to ``feedback`` (docs/
controller.md): ranked after the losses and before the geometric mean, whose figures are
mostly transients' (a drift already far below both references' would otherwise outweigh
them)."""


def aims_of(scenarios: dict[str, Any]) -> tuple[int, list[str]]:
    """How many of :data:`AIMS` are met (the policy's ratio to ``feedback`` within the aim
    and its 95% interval below 1), and each as that ratio and interval, marked ``met``."""
    cells, met = [], 0
    for name, key, aim in AIMS:
        c = scenarios[name]["compare"]["policy/feedback"][key]
        ok = c["ratio"] <= aim and c["hi"] < 1
        met += ok
        cells.append(f"{c['ratio']:.2f} [{c['lo']:.2f}, {c['hi']:.2f}]{' met' if ok else ''}")
    return met, cells


ROLLER_SCENARIOS = ("tuning_dash", "tuning_dash_side", "tuning_cruise")
"""The scenarios of ``configs/eval/dashes.toml``, which a roller report must hold."""


def losses_of(scenarios: dict[str, Any]) -> int:
    """The losses in a report's ``scenarios`` against :data:`JUDGED_AGAINST` together."""
    return sum(
        len(card["losses"])
        for ref in JUDGED_AGAINST
        for card in score(scenarios, f"policy/{ref}").values()
    )


def roller_losses(report: dict[str, Any]) -> int:
    """The losses of a report of ``configs/eval/dashes.toml`` in the reference roller model;
    a report of another physics or without those scenarios is refused."""
    if report.get("fidelity") != "reference":
        raise ValueError(
            f"roller report of {report.get('target')!r}: fidelity = {report.get('fidelity')!r},"
            " expected 'reference' (mecanum-eval --fidelity reference)"
        )
    missing = [s for s in ROLLER_SCENARIOS if s not in report["scenarios"]]
    if missing:
        raise ValueError(f"roller report of {report.get('target')!r} lacks scenarios {missing}")
    return losses_of(report["scenarios"])


def candidate_name(path: Path) -> str:
    """``NAME`` of ``tune_NAME.json`` or ``roller_NAME.json``: how the two are matched."""
    return path.stem.split("_", 1)[-1]


def rank_key(report: dict[str, Any]) -> tuple[int, float, dict[str, float]]:
    """(losses, geometric mean of :data:`FIGURES`' ratios, the ratios) of one report."""
    scenarios = report["scenarios"]
    missing = [s for s, _ in FIGURES if s not in scenarios]
    if missing:
        raise ValueError(f"report of {report.get('target')!r} lacks scenarios {missing}")
    losses = losses_of(scenarios)
    ratios = {}
    for name, key in FIGURES:
        a, b = scenarios[name]["policy"].get(key), scenarios[name]["analytic"].get(key)
        if a is None or b is None or b <= 0:
            raise ValueError(f"{name}.{key} is undefined in the report of {report['target']}")
        ratios[f"{name.removeprefix('tuning_')}.{key}"] = a / b
    gmean = math.exp(sum(math.log(r) for r in ratios.values()) / len(ratios))
    return losses, gmean, ratios


KEPT_EPISODES = ("tuning_nominal",)
"""Scenarios whose per-episode data the bundle keeps: a CPU rerun of one of them checks the
GPU's table (``scripts/eval_agreement.py``, which needs them to tell a chaotic episode)."""


def without_episodes(report: dict[str, Any]) -> dict[str, Any]:
    """``report`` less each scenario's ``per_episode`` data (most of its size), but for
    :data:`KEPT_EPISODES`'."""
    scenarios = {
        name: {k: v for k, v in sc.items() if k != "per_episode" or name in KEPT_EPISODES}
        for name, sc in report["scenarios"].items()
    }
    return {**report, "scenarios": scenarios}


class Row(NamedTuple):
    """One candidate's line: its losses (with the roller model's), the aims it meets and the
    geometric mean, which break ties in that order, and what the tables print."""

    losses: int
    aims_met: int
    gmean: float
    name: str
    target: str
    ratios: dict[str, float]
    eligible: bool
    on_rollers: int
    aims: list[str]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="+", type=Path, help="tuning reports (report.json)")
    ap.add_argument(
        "--exclude", nargs="*", default=["shipped"],
        help="report file names containing any of these are shown but not chosen",
    )  # fmt: skip
    ap.add_argument(
        "--bundle", type=Path, default=None,
        help="also write every report, most per-episode data left out, into this one JSON file",
    )  # fmt: skip
    ap.add_argument(
        "--roller", nargs="*", type=Path, default=None,
        help="each candidate's report of configs/eval/dashes.toml in the reference roller "
        "model, roller_NAME.json for tune_NAME.json: its losses count too",
    )  # fmt: skip
    args = ap.parse_args(argv)
    rows: list[Row] = []
    bundle: dict[str, Any] = {}
    roller: dict[str, int] = {}
    for path in args.roller or []:
        try:
            report = json.loads(path.read_text())
            roller[candidate_name(path)] = roller_losses(report)
        except (OSError, ValueError, KeyError) as e:
            print(f"pick_candidate: cannot read roller report {path}: {e}", file=sys.stderr)
            return 2
        bundle[path.stem] = without_episodes(report)
    for path in args.reports:
        try:
            report = json.loads(path.read_text())
            losses, gmean, ratios = rank_key(report)
        except (OSError, ValueError, KeyError) as e:
            print(f"pick_candidate: cannot rank {path}: {e}", file=sys.stderr)
            return 2
        on_rollers, name = 0, candidate_name(path)
        if args.roller is not None:
            if name not in roller:
                missing = f"{path} has no roller report (roller_{name}.json)"
                print(f"pick_candidate: {missing}", file=sys.stderr)
                return 2
            on_rollers = roller[name]
        bundle[path.stem] = without_episodes(report)
        eligible = not any(x in path.name for x in args.exclude)
        total = losses + on_rollers
        met, aims = aims_of(report["scenarios"])
        row = Row(
            total, met, gmean, path.name, report["target"], ratios, eligible, on_rollers, aims
        )
        rows.append(row)
    if args.bundle is not None:
        args.bundle.write_text(json.dumps(bundle, indent=1))
    rows.sort(key=lambda r: (r.losses, -r.aims_met, r.gmean))
    names = list(rows[0].ratios)
    print("candidate".ljust(28), "losses", "roller", "aims", "gmean", *names)
    for row in rows:
        mark = "" if row.eligible else " (not a candidate)"
        cells = " ".join(f"{row.ratios[k]:.3f}" for k in names)
        print(
            f"{row.name + mark:28s} {row.losses:6d} {row.on_rollers:6d} {row.aims_met:4d}"
            f" {row.gmean:.3f} {cells}"
        )
    heads = [f"{s.removeprefix('tuning_')}.{k} <= {a}" for s, k, a in AIMS]
    print("aims, x feedback".ljust(36), *(h.ljust(22) for h in heads))
    for row in rows:
        print(f"{row.name:36s}", *(c.ljust(22) for c in row.aims))
    chosen = [r for r in rows if r.eligible]
    if not chosen:
        print("pick_candidate: no eligible candidate", file=sys.stderr)
        return 2
    print(chosen[0].target)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
