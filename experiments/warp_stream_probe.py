"""Is Warp's "unknown stream" a garbage-collected stream wrapper, and does pinning cure it?

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
- ``--gc on``: nothing changed;
- ``--pin off``: without the product's cure (``mecanum_jax.sim.warp_streams``, which
  keeps external streams registered for the process; ``on``, the default, keeps it);

If the hypothesis holds, a failing process under ``--gc trace --pin off`` logs a
``__del__`` during a collection just before the error, and ``--pin on`` does not fail.
On the GPU machine, twice in a row per mode (the first process on a machine has not
failed):

    bash scripts/device/run.sh --warp experiment warp_stream_probe.py --gc trace --pin off \
        -- --config gpu --env.physics-impl warp --compilation-cache off
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


_live: dict[int, int] = {}  # external handle -> wrappers alive
_events = {"del": 0, "del_in_gc": 0, "erased_live": 0, "erased_live_in_gc": 0}
_trace_file: Any = sys.stderr


def trace_stream_deletions() -> bool:
    """Count every ``wp.Stream.__del__``; log to ``_trace_file`` those run by the
    garbage collector or that erase the entry of a wrapper still alive. False where
    Warp is not installed."""
    try:
        import warp as wp
    except ImportError:
        return False
    stream_class: Any = wp.Stream
    original_init, original_del = stream_class.__init__, stream_class.__del__

    def counted_init(self: Any, *args: Any, **kwargs: Any) -> None:
        original_init(self, *args, **kwargs)
        if kwargs.get("cuda_stream"):
            _live[kwargs["cuda_stream"]] = _live.get(kwargs["cuda_stream"], 0) + 1

    def logged(self: Any) -> None:
        handle = getattr(self, "cuda_stream", None)
        external = bool(handle) and not getattr(self, "owner", False)
        others = 0
        if external and isinstance(handle, int):
            _live[handle] = _live.get(handle, 1) - 1
            others = _live[handle]
        _events["del"] += 1
        _events["del_in_gc"] += _collecting
        _events["erased_live"] += others > 0
        _events["erased_live_in_gc"] += others > 0 and _collecting
        if not (_collecting or others > 0):
            original_del(self)  # the usual end of a call's wrapper: counted, not logged
            return
        print(
            f"{time.monotonic():.3f} Stream.__del__ stream="
            f"{hex(handle) if isinstance(handle, int) else handle} external={external} "
            f"others_alive={others} thread={threading.current_thread().name} "
            f"in_gc={_collecting}",
            file=_trace_file,
            flush=True,
        )
        original_del(self)

    stream_class.__init__ = counted_init
    stream_class.__del__ = logged
    gc.callbacks.append(_on_gc)
    return True


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, rest = _split(argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gc", choices=("on", "off", "trace"), default="trace")
    ap.add_argument(
        "--pin",
        choices=("on", "off"),
        default="on",
        help="on: the product's cure (mecanum_jax.sim.warp_streams); off: Warp as shipped",
    )
    ap.add_argument("--trace-file", help="where --gc trace writes its lines (default stderr)")
    args = ap.parse_args(ours)
    global _trace_file
    if args.trace_file:
        _trace_file = open(args.trace_file, "w")  # noqa: SIM115 (open for the process)

    from mecanum_jax.sim import physics

    if args.pin == "off":
        physics.pin_external_streams = lambda: False
    if args.gc == "off":
        gc.disable()
    elif args.gc == "trace" and not trace_stream_deletions():
        print("warp_stream_probe: warp is not installed; nothing to trace", file=sys.stderr)
    print(
        f"[warp_stream_probe] gc={args.gc} pin={args.pin}",
        file=sys.stderr,
        flush=True,
    )
    from train import coldstart

    try:
        return coldstart.main(rest)
    finally:
        if args.gc == "trace":
            print(f"[warp_stream_probe] Stream.__del__ counts: {_events}", file=sys.stderr)


def _split(argv: list[str]) -> tuple[list[str], list[str]]:
    """The probe's own arguments, and ``train.coldstart``'s after ``--``."""
    if "--" in argv:
        i = argv.index("--")
        return argv[:i], argv[i + 1 :]
    return argv, []


if __name__ == "__main__":
    sys.exit(main())
