"""Is Warp's "unknown stream" a garbage-collected stream wrapper? (an open question)

A second ``train.coldstart`` process under MuJoCo Warp on the same GPU machine fails in
its policy evaluation with ``FFI callback error: RuntimeError: Warp error: unknown
stream`` (docs/benchmarks.md, 2026-11-27). Read in warp-lang 1.18's source: each FFI call
wraps XLA's stream in a ``wp.Stream``, which registers it in Warp's process-wide stream
table, then begins Warp's own graph capture on it; the table has no reference counts, and
the ``__del__`` of any wrapper of the same stream erases its entry. The hypothesis: a
wrapper of an earlier call, kept alive by a reference cycle, is collected between another
call's registration and its capture.

This runs ``train.coldstart`` (its arguments after ``--``) once, with

- ``--gc trace``: every ``wp.Stream.__del__`` logged (stream handle, thread, and whether
  the cyclic garbage collector is running; ``gc.callbacks``), then the start as usual;
- ``--gc off``: the cyclic garbage collector disabled for the whole process (reference
  counting still frees what it can), the candidate cure at its bluntest;
- ``--gc on``: nothing changed (the control).

If the hypothesis holds, a failing process under ``trace`` logs a ``__del__`` during a
collection just before the error, and ``off`` does not fail. On the GPU machine, twice in
a row per mode (the first process on a machine has not failed):

    bash scripts/device/run.sh --warp experiment warp_stream_probe.py --gc trace -- \
        --config gpu --env.physics-impl warp --compilation-cache off
"""

from __future__ import annotations

import argparse
import gc
import sys
import threading
import time
from typing import Any

_collecting = False


def _on_gc(phase: str, info: dict) -> None:
    global _collecting
    _collecting = phase == "start"


def trace_stream_deletions() -> bool:
    """Log every ``wp.Stream.__del__``; False where Warp is not installed."""
    try:
        import warp as wp
    except ImportError:
        return False
    original = wp.Stream.__del__

    def logged(self: Any) -> None:
        handle = getattr(self, "cuda_stream", None)
        print(
            f"[warp_stream_probe] {time.monotonic():.3f} Stream.__del__ stream="
            f"{hex(handle) if isinstance(handle, int) else handle} owner="
            f"{getattr(self, 'owner', '?')} thread={threading.current_thread().name} "
            f"in_gc={_collecting}",
            file=sys.stderr,
            flush=True,
        )
        original(self)

    stream_class: Any = wp.Stream
    stream_class.__del__ = logged
    gc.callbacks.append(_on_gc)
    return True


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, rest = _split(argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gc", choices=("on", "off", "trace"), default="trace")
    args = ap.parse_args(ours)
    if args.gc == "off":
        gc.disable()
    elif args.gc == "trace" and not trace_stream_deletions():
        print("warp_stream_probe: warp is not installed; nothing to trace", file=sys.stderr)
    print(f"[warp_stream_probe] gc={args.gc}", file=sys.stderr, flush=True)
    from train import coldstart

    return coldstart.main(rest)


def _split(argv: list[str]) -> tuple[list[str], list[str]]:
    """The probe's own arguments, and ``train.coldstart``'s after ``--``."""
    if "--" in argv:
        i = argv.index("--")
        return argv[:i], argv[i + 1 :]
    return argv, []


if __name__ == "__main__":
    sys.exit(main())
