"""mecanum_jax.sim.warp_streams on a stand-in of warp-lang 1.18's ``Stream`` (Warp's own
class needs a CUDA device): external streams stay in the table; Warp's own streams are
created and destroyed as before."""

from __future__ import annotations

import gc
import sys
import types
from typing import Any

import pytest

from mecanum_jax.sim import warp_streams


def _fake_warp(name: str) -> tuple[type, list[tuple[str, int]], set[int]]:
    """A module ``name`` with ``runtime`` and a ``Stream`` whose ``__init__`` and
    ``__del__`` follow warp-lang 1.18's (context.py): an external ``cuda_stream``
    registers, and any wrapper's ``__del__`` unregisters it."""
    calls: list[tuple[str, int]] = []
    table: set[int] = set()
    module = types.ModuleType(name)

    class Device:
        context = 0xC0
        is_cuda = True

    class Runtime:
        def get_device(self, device: object) -> Device:
            return device if isinstance(device, Device) else Device()

    class Stream:
        def __new__(cls, *args: object, **kwargs: object) -> Stream:
            instance = super().__new__(cls)
            instance.cuda_stream = None
            instance.owner = False
            return instance

        def __init__(self, device: object = None, priority: int = 0, **kwargs: Any) -> None:
            self._cached_event = None
            self.device = module.runtime.get_device(device)
            if "cuda_stream" in kwargs:
                self.cuda_stream = kwargs["cuda_stream"]
                self._is_blocking = None
                calls.append(("register", self.cuda_stream))
                table.add(self.cuda_stream)
            else:
                self.cuda_stream = 0x5000 + len(calls)
                self._is_blocking = True
                calls.append(("create", self.cuda_stream))
                table.add(self.cuda_stream)
                self.owner = True

        def __del__(self) -> None:
            if not self.cuda_stream:
                return
            calls.append(("destroy" if self.owner else "unregister", self.cuda_stream))
            table.discard(self.cuda_stream)

    Stream.__module__ = name
    module.runtime = Runtime()  # type: ignore[attr-defined]
    module.Stream = Stream  # type: ignore[attr-defined]
    sys.modules[name] = module
    return Stream, calls, table


@pytest.fixture
def fake(request: pytest.FixtureRequest):
    name = f"fake_warp_context_{request.node.name}"
    yield _fake_warp(name)
    sys.modules.pop(name, None)


def test_unpatched_stand_in_shows_the_failure(fake) -> None:
    """The stand-in reproduces Warp's rule: a stale wrapper's ``__del__`` erases the
    entry a live wrapper of the same stream needs."""
    Stream, _, table = fake
    live = Stream(cuda_stream=0xAB)
    stale = Stream(cuda_stream=0xAB)
    del stale
    gc.collect()
    assert live.cuda_stream == 0xAB
    assert 0xAB not in table


def test_external_stream_stays_registered(fake) -> None:
    Stream, calls, table = fake
    assert warp_streams.pin_stream_class(Stream)
    live = Stream(cuda_stream=0xAB)
    stale = Stream(cuda_stream=0xAB)
    assert stale.cuda_stream == 0xAB
    assert stale._is_blocking is None
    assert stale.device.context == 0xC0
    assert not stale.owner
    del stale
    gc.collect()
    assert 0xAB in table, "a stale wrapper erased the live one's entry"
    del live
    gc.collect()
    assert 0xAB in table
    # registered once, never unregistered: no event created per call
    assert [c for c in calls if c[1] == 0xAB] == [("register", 0xAB)]


def test_wrapper_in_a_collected_cycle(fake) -> None:
    """The suspected trigger: an old call's wrapper in a reference cycle, freed by the
    cyclic collector while a new call's wrapper is live."""
    Stream, calls, table = fake
    warp_streams.pin_stream_class(Stream)
    old = Stream(cuda_stream=0xCD)
    holder: dict[str, object] = {"stream": old}
    holder["self"] = holder  # a cycle
    del old
    new = Stream(cuda_stream=0xCD)
    del holder
    gc.collect()
    assert 0xCD in table
    assert new.cuda_stream == 0xCD
    assert ("unregister", 0xCD) not in calls


def test_own_streams_unchanged(fake) -> None:
    Stream, calls, table = fake
    warp_streams.pin_stream_class(Stream)
    own = Stream()
    handle = own.cuda_stream
    assert own.owner
    assert handle in table
    del own
    gc.collect()
    assert ("destroy", handle) in calls
    assert handle not in table


def test_patch_once(fake) -> None:
    Stream, calls, _ = fake
    assert warp_streams.pin_stream_class(Stream)
    init = Stream.__init__
    assert not warp_streams.pin_stream_class(Stream)
    assert Stream.__init__ is init
    Stream(cuda_stream=0xEF)
    assert calls == [("register", 0xEF)]
