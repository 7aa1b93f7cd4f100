"""Two evaluations of the same episodes, compared episode by episode.

``mecanum-eval`` writes, beside ``report.json``, every controller's per-episode metric
parts (:class:`~mecanum_jax.evaluation.metrics.Part`: a numerator and a denominator per
episode) to ``parts.npz`` (:func:`save_parts`). The episodes of a scenario depend only on
the scenario file and its seed (robots, commands, sensor noise), so two policies
evaluated apart, on any machine, play the same ones; :func:`pair` then gives each
metric's ratio of the first policy to the second with the paired bootstrap interval of
:func:`~mecanum_jax.evaluation.metrics.paired_ratio`, the comparison a choice between two
policies needs (their ratios to `analytic` alone are two separate intervals).

Before pairing, :func:`pair` checks that a reference controller both evaluations played
(``analytic`` by default: it depends on no policy and no config) reads the same on each
scenario, to ``tolerance``; different episodes (another scenario file, seed or episode
count) or another physics raise :class:`EpisodesDifferError` naming the scenario and figure.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mecanum_jax.evaluation import metrics

PARTS_FILE = "parts.npz"
"""The file name of the parts beside an evaluation's ``report.json``."""

Parts = dict[str, dict[str, dict[str, metrics.Part]]]
"""``parts[scenario][controller][metric]``."""


class EpisodesDifferError(ValueError):
    """Two evaluations did not play the same episodes."""


def save_parts(path: str | Path, parts: Parts) -> None:
    """Write ``parts`` to ``path`` (a compressed ``.npz``)."""
    arrays: dict[str, np.ndarray] = {}
    kinds: dict[str, str] = {}
    for scenario, by_who in parts.items():
        for who, by_metric in by_who.items():
            for metric, p in by_metric.items():
                key = f"{scenario}/{who}/{metric}"
                arrays[f"{key}/num"] = np.asarray(p.num, np.float64)
                arrays[f"{key}/den"] = np.asarray(p.den, np.float64)
                kinds[key] = p.kind
    arrays["kinds"] = np.asarray(json.dumps(kinds))
    with open(path, "wb") as f:
        np.savez_compressed(f, allow_pickle=True, **arrays)  # numpy's default, named


def load_parts(path: str | Path) -> Parts:
    """The parts :func:`save_parts` wrote to ``path`` (a file or an evaluation's directory);
    ``FileNotFoundError`` naming the path if there is none."""
    path = Path(path)
    if path.is_dir():
        path = path / PARTS_FILE
    if not path.is_file():
        raise FileNotFoundError(
            f"{str(path)!r}: no such file (mecanum-eval writes {PARTS_FILE} beside report.json)"
        )
    out: Parts = {}
    with np.load(path) as z:
        kinds = json.loads(str(z["kinds"]))
        for key, kind in kinds.items():
            scenario, who, metric = key.split("/")
            part = metrics.Part(z[f"{key}/num"], z[f"{key}/den"], kind)
            out.setdefault(scenario, {}).setdefault(who, {})[metric] = part
    return out


def check_same_episodes(
    a: Parts, b: Parts, scenario: str, reference: str = "analytic", tolerance: float = 0.01
) -> None:
    """Raise :class:`EpisodesDifferError` unless ``scenario`` has as many episodes in ``a`` as in
    ``b`` and ``reference`` reads the same in both, every metric within ``tolerance``
    (relative)."""
    ra, rb = a[scenario].get(reference), b[scenario].get(reference)
    if ra is None or rb is None:
        raise EpisodesDifferError(f"{scenario}: {reference!r} was not played in both evaluations")
    for metric in sorted(set(ra) & set(rb)):
        pa, pb = ra[metric], rb[metric]
        if len(pa.num) != len(pb.num):
            raise EpisodesDifferError(f"{scenario}: {len(pa.num)} episodes against {len(pb.num)}")
        va, vb = pa.value(), pb.value()
        if (va is None) != (vb is None) or (
            va is not None and vb is not None and abs(va - vb) > tolerance * max(abs(vb), 1e-9)
        ):
            raise EpisodesDifferError(
                f"{scenario}: {reference} {metric} reads {va} in one evaluation and {vb} in "
                f"the other (more than {tolerance:.0%} apart): not the same episodes or physics"
            )


def pair(
    a: Parts,
    b: Parts,
    who_a: str = "policy",
    who_b: str = "policy",
    reference: str = "analytic",
    tolerance: float = 0.01,
) -> dict[str, dict[str, metrics.Comparison]]:
    """Per scenario both evaluations hold (in ``a``'s order), each metric's ratio of
    ``a[who_a]`` to ``b[who_b]`` on the same episodes, with its paired interval (checked
    first with :func:`check_same_episodes`). Metrics undefined on either side are left out."""
    out: dict[str, dict[str, metrics.Comparison]] = {}
    for scenario in [s for s in a if s in b]:
        check_same_episodes(a, b, scenario, reference, tolerance)
        pa, pb = a[scenario].get(who_a), b[scenario].get(who_b)
        if pa is None or pb is None:
            raise EpisodesDifferError(
                f"{scenario}: no {who_a!r} in the first or {who_b!r} in the second"
            )
        weights = metrics.bootstrap_weights(len(next(iter(pa.values())).num))
        row: dict[str, metrics.Comparison] = {}
        for metric in [m for m in pa if m in pb]:
            c = metrics.paired_ratio(pa[metric], pb[metric], weights=weights)
            if c is not None:
                row[metric] = c
        out[scenario] = row
    return out


__all__ = [
    "PARTS_FILE",
    "EpisodesDifferError",
    "Parts",
    "check_same_episodes",
    "load_parts",
    "pair",
    "save_parts",
]
