"""What every ``mecanum-bench`` report shares: the JSON's header and its atomic write."""

from __future__ import annotations

import dataclasses
import datetime
import json
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import jax
from rich.console import Console

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


def header(benchmark: str, args: DataclassInstance) -> dict[str, object]:
    """What every benchmark's JSON starts with: the date, the device and the arguments."""
    device = jax.devices()[0]
    return {
        "benchmark": benchmark,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "device": f"{device.platform}: {device.device_kind}",
        "jax": jax.__version__,
        "config": {
            k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(args).items()
        },
    }


SPREAD_WARN = 0.2
"""Repeats whose spread (max − min over the median) passes this disagree: a warning."""


def median_spread(samples: Sequence[float]) -> tuple[float, float]:
    """The median of timed repeats and their spread, (max − min) / median (0 for one)."""
    median = statistics.median(samples)
    return median, (max(samples) - min(samples)) / median if median > 0 else 0.0


def warn_spread(console: Console, what: str, spread: float) -> None:
    """Print one warning line when a figure's repeats disagree by more than SPREAD_WARN."""
    if spread > SPREAD_WARN:
        console.print(
            f"[yellow]warning[/]: {what}: repeats disagree by {100 * spread:.0f}% (max − min "
            f"over the median; > {100 * SPREAD_WARN:.0f}%): a busy machine? more --repeats"
        )


def write_json(result: Mapping[str, object], path: Path | None, console: Console) -> None:
    """Write ``result`` to ``path`` (none: nothing), never leaving a half-written file."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(path)  # never leaves a half-written file
    console.print(f"wrote {path}")


__all__ = ["SPREAD_WARN", "header", "median_spread", "warn_spread", "write_json"]
