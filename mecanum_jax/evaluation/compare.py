"""One controller against another on the same episodes: the ratios with their paired
intervals (:func:`ratios`), and a scorecard of wins, ties and losses (:func:`score`).

``mecanum-eval`` compares the policy with each reference controller over :data:`COMPARED`
(``report.json``'s ``compare``), the trainer's periodic evaluation compares each seed's
policy with the baseline over :data:`TRAINING_COMPARED`, both through :func:`ratios`. A
ratio is ``a``'s pooled metric over ``b``'s, with the percentile bootstrap interval of
:func:`~mecanum_jax.evaluation.metrics.paired_ratio` (episodes resampled, the same draw for
both) and its :func:`~mecanum_jax.evaluation.metrics.verdict`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mecanum_jax.evaluation import metrics

COMPARED = (
    "rmse_lin",
    "rmse_wz",
    "ss_lin",
    "ss_wz",
    "settle_lin_s",
    "settle_wz_s",
    "drift_m",
    "heading_drift_rad",
    "energy_j",
    "energy_per_m",
)
"""Metrics ``mecanum-eval`` compares pairwise (policy against each reference)."""

TRAINING_COMPARED = ("rmse_lin", "rmse_wz", "ss_lin", "ss_wz", "settle_wz_s", "energy_j")
"""Metrics the trainer's periodic evaluation logs as policy / baseline ratios."""

LOSS_MARGIN = {
    "ss_lin": 0.01,
    "rmse_lin": 0.01,
    "ss_wz": 0.02,
    "rmse_wz": 0.02,
    "drift_m": 0.05,
    "settle_lin_s": 0.05,
    "settle_wz_s": 0.05,
}
"""The tracking metrics a scorecard counts, and the excess (m/s, rad/s, m, s) below which
a difference whose interval lies on one side is still called a tie."""


def ratios(
    a: Mapping[str, metrics.Part],
    b: Mapping[str, metrics.Part],
    keys: Sequence[str] = COMPARED,
    n_boot: int = 2000,
) -> dict[str, dict[str, float | str]]:
    """``a``'s metrics over ``b``'s, both per-episode parts of the same episodes: for each
    of ``keys`` that ``a`` has, the ratio, its paired bootstrap interval (``n_boot``
    resamples, one draw for every metric) and the verdict; a ratio undefined on either
    side (no steps counted, a zero reference) is left out."""
    present = [k for k in keys if k in a]
    if not present:
        return {}
    weights = metrics.bootstrap_weights(len(a[present[0]].num), n_boot)
    out: dict[str, dict[str, float | str]] = {}
    for key in present:
        c = metrics.paired_ratio(a[key], b[key], weights=weights)
        if c is not None:
            out[key] = c.as_dict()
    return out


def score(results: Mapping[str, Any], pair: str) -> dict[str, dict[str, list[str]]]:
    """Per scenario of ``results`` (``report.json``'s ``scenarios``), ``pair``'s
    (``who/ref``) tracking metrics (:data:`LOSS_MARGIN`) as wins, ties and losses: a win or
    a loss needs the paired 95% interval on one side of 1 *and* a mean difference above
    the metric's margin; anything else is a tie."""
    who, ref = pair.split("/")
    out: dict[str, dict[str, list[str]]] = {}
    for name, r in results.items():
        cmp = r.get("compare", {}).get(pair)
        if cmp is None:
            continue
        card: dict[str, list[str]] = {"wins": [], "ties": [], "losses": []}
        for key, margin in LOSS_MARGIN.items():
            c, a, b = cmp.get(key), r[who].get(key), r[ref].get(key)
            if c is None or a is None or b is None:
                continue
            kind = "ties"
            if c["verdict"] == "worse" and a - b > margin:
                kind = "losses"
            elif c["verdict"] == "better" and b - a > margin:
                kind = "wins"
            card[kind].append(key)
        out[name] = card
    return out


__all__ = ["COMPARED", "LOSS_MARGIN", "TRAINING_COMPARED", "ratios", "score"]
