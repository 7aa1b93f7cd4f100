"""What every ``mecanum-bench`` report shares: the JSON's header and its atomic write."""

from __future__ import annotations

import dataclasses
import datetime
import json
from pathlib import Path
from typing import Any

import jax
from rich.console import Console


def header(benchmark: str, args: Any) -> dict[str, Any]:
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


def write_json(result: dict[str, Any], path: Path | None, console: Console) -> None:
    """Write ``result`` to ``path`` (none: nothing), never leaving a half-written file."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(path)  # never leaves a half-written file
    console.print(f"wrote {path}")


__all__ = ["header", "write_json"]
