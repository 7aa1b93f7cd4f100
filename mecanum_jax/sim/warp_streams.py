"""Keep XLA's CUDA streams in Warp's stream table for the life of the process.

MJX calls MuJoCo Warp through Warp's JAX FFI handler (warp-lang 1.18,
``warp/_src/jax/ffi.py``). Under ``GraphMode.WARP`` each call that does not replay a
cached graph wraps XLA's stream in a new ``wp.Stream(device, cuda_stream=...)``, which
*registers* the stream in Warp's process-wide table (``g_streams`` in ``warp.cu``), and
then begins Warp's own graph capture on it, which looks the stream up there. The table
has no reference counts: the ``__del__`` of **any** wrapper of that stream *unregisters*
it. A wrapper from an earlier call that a reference cycle kept alive, collected by the
garbage collector between another call's registration and its capture, so erases the
entry the live call needs, and that call fails with ``Warp error: unknown stream``. That
happened to a second ``train.tools.coldstart`` process on a GPU machine, to an epoch compiled
on another thread, and with JAX's persistent compilation cache on (docs/profiling.md):
each changes when the collector runs, not what Warp does.

:func:`pin_external_streams` makes the registration of a stream Warp does not own (an
external handle, such as XLA's) last for the process: the first wrapper of a handle
registers it, later wrappers reuse that entry, and no wrapper's ``__del__`` erases it.
XLA creates its streams once per process and keeps them, so an entry never outlives the
stream it names while a program can still run on it. Streams Warp creates itself are
untouched (created, registered and destroyed as before).
"""

from __future__ import annotations

import sys
import threading
from typing import Any, Protocol

_PINNED: set[tuple[int, int]] = set()
_LOCK = threading.Lock()
_MARK = "_mecanum_pins_external_streams"


class _Stream(Protocol):
    """What :func:`_adopt` sets of a Warp ``Stream`` (or of a stand-in with its interface)."""

    device: object
    cuda_stream: int
    _cached_event: object
    _is_blocking: bool | None


def _key(device: object, handle: int) -> tuple[int, int]:
    context = getattr(device, "context", None)
    return (int(context or 0), int(handle))


def pin_stream_class(stream_class: Any) -> bool:
    """Patch ``stream_class`` (Warp's ``Stream``, or a stand-in with its interface) so
    that external streams stay registered (module docstring). Returns False where it
    was already patched."""
    with _LOCK:
        if getattr(stream_class, _MARK, False):
            return False
        original_init = stream_class.__init__
        original_del = stream_class.__del__

        def init(
            self: _Stream, device: object = None, priority: int = 0, **kwargs: int | None
        ) -> None:
            handle = kwargs.get("cuda_stream")
            if not handle:  # Warp's own stream, or CUDA's default stream: Warp's rule
                original_init(self, device, priority, **kwargs)
                return
            resolved = _resolve(stream_class, device)
            key = _key(resolved, handle)
            if key in _PINNED:
                _adopt(self, resolved, handle)
            else:
                original_init(self, device, priority, **kwargs)
                _PINNED.add(key)

        def delete(self: object) -> None:
            if not getattr(self, "owner", False) and getattr(self, "cuda_stream", None):
                return  # an external stream: its entry stays (module docstring)
            original_del(self)

        stream_class.__init__ = init
        stream_class.__del__ = delete
        setattr(stream_class, _MARK, True)
        return True


def _resolve(stream_class: type, device: object) -> object:
    """``device`` as Warp's ``__init__`` resolves it, through the ``runtime`` of the module
    that defines ``stream_class`` (Warp's ``context``)."""
    runtime = getattr(sys.modules.get(stream_class.__module__), "runtime", None)
    return runtime.get_device(device) if runtime is not None else device


def _adopt(stream: _Stream, device: object, handle: int) -> None:
    """Warp's ``__init__`` for an external handle, less the registration that the first
    wrapper of that handle made."""
    stream._cached_event = None
    stream.device = device
    stream.cuda_stream = handle
    stream._is_blocking = None


def pin_external_streams() -> bool:
    """Apply :func:`pin_stream_class` to Warp's ``Stream``; False where Warp is not
    installed or it was patched before."""
    try:
        import warp
    except ImportError:
        return False
    return pin_stream_class(warp.Stream)


__all__ = ["pin_external_streams", "pin_stream_class"]
