"""PPO throughput against the number of robots: ``python -m train.tools.bench`` JSON to a PNG.

    python scripts/plot_scaling.py e1024.json e4096.json ... --out scaling.png \\
        [--json-out scaling.json]

Reads the results of one or more ``train.tools.bench --json-out`` files (``run.sh scaling``
writes one per robot count), plots env steps/s (and the physics steps/s they imply)
against ``num_envs`` on a log axis, and optionally writes the results merged into one
JSON file, sorted by robot count.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

REQUIRED = ("num_envs", "steps_per_s_median", "physics_steps_per_s_median")


def load(paths: list[str]) -> dict[str, Any]:
    """The files' results merged (sorted by robot count) with the first file's header."""
    head: dict[str, Any] = {}
    results: list[dict[str, Any]] = []
    for path in paths:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise SystemExit(f"{path}: cannot read a train.tools.bench JSON file: {err}") from None
        if not isinstance(data, dict) or not isinstance(data.get("results"), list):
            raise SystemExit(f"{path}: no 'results' list (not a train.tools.bench JSON file)")
        for r in data["results"]:
            missing = [k for k in REQUIRED if k not in r]
            if missing:
                raise SystemExit(f"{path}: a result lacks {missing}")
            results.append(r)
        head = head or {k: v for k, v in data.items() if k != "results"}
    if not results:
        raise SystemExit("no results in " + ", ".join(paths))
    return {**head, "results": sorted(results, key=lambda r: r["num_envs"])}


def plot(merged: dict[str, Any], out: Path) -> None:
    results = merged["results"]
    robots = [r["num_envs"] for r in results]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(robots, [r["steps_per_s_median"] / 1e6 for r in results], "o-", label="env steps/s")
    ax.plot(
        robots,
        [r["physics_steps_per_s_median"] / 1e6 for r in results],
        "s--",
        label="physics steps/s (env steps × substeps)",
    )
    for x, r in zip(robots, results, strict=True):
        ax.annotate(f"{r['steps_per_s_median'] / 1e6:.3g}", (x, r["steps_per_s_median"] / 1e6),
                    textcoords="offset points", xytext=(0, 6), ha="center", fontsize=8)  # fmt: skip
    ax.set_xscale("log", base=2)
    ax.set_xticks(robots, [f"{n // 1024}k" if n % 1024 == 0 else str(n) for n in robots])
    ax.set_xlabel("robots (ppo.num_envs)")
    ax.set_ylabel("million steps per second")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title(
        f"PPO training throughput, {merged.get('config', '?')} config, "
        f"{merged.get('device', '?')} ({merged.get('date', '?')})",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("inputs", nargs="+", help="train.tools.bench --json-out files")
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--json-out", default=None, help="also write the merged results")
    args = parser.parse_args(argv)
    merged = load(args.inputs)
    plot(merged, Path(args.out))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(merged, indent=2) + "\n")
    for r in merged["results"]:
        print(f"{r['num_envs']:>8} robots: {r['steps_per_s_median']:>12,.0f} env steps/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
