"""What JAX compiles, program by program, from ``jax.monitoring``'s events
(:class:`CompileLog`): each program's tracing, lowering and XLA compilation times, whether
the persistent compilation cache served it, and the phase it compiled in (train/tools/
coldstart.py's tables)."""

from __future__ import annotations

import re
import threading
from typing import NotRequired, TypedDict

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
CACHE_EVENTS = {
    "/jax/compilation_cache/cache_hits": "hit",
    "/jax/compilation_cache/cache_misses": "miss",
}


class Event(TypedDict):
    """One traced, lowered or compiled program as ``jax.monitoring`` reports it."""

    event: str  # trace_s, lower_s or compile_s
    name: str
    s: float
    phase: str
    cache: NotRequired[str | None]  # compile_s: hit or miss (None: no persistent cache)


class Program(TypedDict):
    """One XLA compilation, with the tracing and lowering of the same name before it."""

    name: str
    phase: str
    trace_s: float | None
    lower_s: float | None
    compile_s: float
    cache: str | None


class CompileLog:
    """Listens to ``jax.monitoring``: one record per traced, lowered or compiled program."""

    def __init__(self) -> None:
        self.phase = "start"
        self.events: list[Event] = []
        self._current = threading.local()

    def on_duration(self, event: str, duration_secs: float, **kwargs: str | int) -> None:
        if event in EVENTS:
            name = str(kwargs.get("fun_name", "?"))
            record: Event = {
                "event": EVENTS[event],
                "name": name,
                "s": duration_secs,
                "phase": self.phase,
            }
            if event == COMPILE_EVENT:
                record["cache"] = getattr(self._current, "cache", None)
                self._current.cache = None
            self.events.append(record)

    def on_scalar(self, event: str, value: float | int, **kwargs: str | int) -> None:
        if event == COMPILE_EVENT:  # a compilation starts
            self._current.cache = None

    def on_event(self, event: str, **kwargs: str | int) -> None:
        if event in CACHE_EVENTS:
            self._current.cache = CACHE_EVENTS[event]

    def __enter__(self) -> CompileLog:
        import jax.monitoring as mon

        mon.register_event_duration_secs_listener(self.on_duration)
        mon.register_scalar_listener(self.on_scalar)
        mon.register_event_listener(self.on_event)
        return self

    def __exit__(self, *exc: object) -> None:
        import jax.monitoring as mon

        for name, listener in (
            ("unregister_event_duration_listener", self.on_duration),
            ("unregister_scalar_listener", self.on_scalar),
            ("unregister_event_listener", self.on_event),
        ):
            unregister = getattr(mon, name, None)  # (a JAX without it keeps the listener)
            if unregister is not None:
                unregister(listener)

    def programs(self) -> list[Program]:
        """Each XLA compilation, with the tracing and lowering of the same name before it."""
        out: list[Program] = []
        pending: dict[str, dict[str, float]] = {}
        for e in self.events:
            key = _base_name(e["name"])
            if e["event"] != "compile_s":
                slot = pending.setdefault(key, {})
                slot[e["event"]] = slot.get(e["event"], 0.0) + e["s"]
                continue
            before = pending.pop(key, {})
            out.append(
                {
                    "name": e["name"],
                    "phase": e["phase"],
                    "trace_s": before.get("trace_s"),
                    "lower_s": before.get("lower_s"),
                    "compile_s": e["s"],
                    "cache": e["cache"],
                }
            )
        return out


def _base_name(name: str) -> str:
    """``jit(_epoch)`` (lowering, compilation) -> ``_epoch`` (tracing)."""
    match = re.fullmatch(r"(?:jit|pmap)\((.*)\)", name)
    return match.group(1) if match else name


__all__ = ["CompileLog", "Event", "Program"]
