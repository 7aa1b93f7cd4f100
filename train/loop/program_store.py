"""The warm-start store's files (train/loop/warm_start.py): compiled programs and the
index that points a run's programs at them, each keyed, checksummed and checked on load;
written atomically, so a killed writer leaves nothing partial under a final name."""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import jax
from jax.stages import Compiled
from jax.tree_util import PyTreeDef

from train.loop import warp_targets

MAGIC = b"mecanum-jax executable 3\n"
SUFFIX = ".jaxexe"
INDEX_SUFFIX = ".index"
Log = Callable[[str], None]
Key = dict[str, object]
"""A program's key: JSON-ready values (warm_start.run_key, plus the program's own)."""
COMPILER_FIELDS = ("versions", "devices", "backend_devices", "xla_flags", "jax_flags")
"""The fields of a run's key that an executable's key holds too: what compiles it."""
T = TypeVar("T")


def digest(obj: object) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=repr).encode()).hexdigest()


class Store:
    """Compiled programs in a directory, each file keyed, checksummed and checked on load."""

    def __init__(
        self,
        directory: Path,
        key: Key,
        log: Log,
        tracers: Sequence[warp_targets.Tracer] = (),
        fresh: bool = True,
    ):
        """``tracers``: where the programs call MuJoCo Warp, what makes its FFI targets in
        a fresh process (:func:`train.loop.warp_targets.register`); ``fresh``: compile
        outside JAX's persistent cache (XLA:CPU serializes its hits broken)."""
        self.directory = directory
        self.key = key
        self.log = log
        self.tracers = tuple(tracers)
        self.fresh = fresh
        self.loaded: list[str] = []
        self.written: list[str] = []
        self.ahead: Ahead | None = None
        """Programs loaded ahead, while the run was being built (:class:`Ahead`)."""
        self.loaded_ahead: list[str] = []
        self.load_s: dict[str, dict[str, float]] = {}
        """Seconds each loaded program took: its file read and checked (``read``), its
        Warp targets made (``targets``), the executable loaded onto the devices
        (``deserialize``)."""

    def path(self, full_key: Key, suffix: str = SUFFIX) -> Path:
        return _path(self.directory, full_key, suffix)

    def program_key(self, lowered_text: str, sig: object) -> Key:
        """An executable's key: the lowered program and what compiles it."""
        compiler = {f: self.key[f] for f in COMPILER_FIELDS if f in self.key}
        text = hashlib.sha256(lowered_text.encode()).hexdigest()
        return {**compiler, "lowered": text, "signature": repr(sig)}

    def _payload(self, full_key: Key, suffix: str = SUFFIX) -> bytes | None:
        return _payload(self.directory, full_key, suffix)

    def read(self, name: str, full_key: Key, suffix: str, parse: Callable[[bytes], T]) -> T | None:
        """``parse`` of the payload kept under ``full_key`` (``None``: none); a file that is
        not this key's intact entry, or that ``parse`` refuses, is logged and removed, and
        ``None`` returned: never trusted."""
        try:
            payload = self._payload(full_key, suffix)
            return None if payload is None else parse(payload)
        except Exception as err:  # anything wrong with the file
            self._unusable(name, full_key, err, suffix)
            return None

    def write(self, full_key: Key, payload: bytes, suffix: str = SUFFIX) -> None:
        """Keep ``payload`` under ``full_key``, framed with its key and checksum."""
        path = self.path(full_key, suffix)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_bytes(frame(full_key, payload))
        os.replace(tmp, path)  # atomically: never a partial file under the final name

    def _unusable(self, name: str, full_key: Key, err: Exception, suffix: str = SUFFIX) -> None:
        path = self.path(full_key, suffix)
        self.log(f"warm start: {name}: {path.name} unusable ({err}); made again")
        path.unlink(missing_ok=True)

    def indexed(self, name: str, full_key: Key) -> Key | None:
        """The executable's key the index keeps for a run's program (``None``: none, or
        an unusable entry: logged, and removed)."""

        def parse(payload: bytes) -> Key | None:
            found = json.loads(payload)
            if found is not None and not isinstance(found, dict):
                raise ValueError("not an executable's key")
            return found

        return self.read(name, full_key, INDEX_SUFFIX, parse)

    def index(self, full_key: Key, program_key: Key) -> None:
        """Point a run's program at its executable."""
        self.write(full_key, json.dumps(program_key, sort_keys=True).encode(), INDEX_SUFFIX)

    def load(self, name: str, full_key: Key, read_back: bool = False) -> Compiled | None:
        """The program stored under ``full_key``, or ``None`` (absent, stale or corrupt:
        logged, and the file removed); ``read_back``: just written, not counted as loaded."""

        t0 = time.perf_counter()
        times: dict[str, float] = {}

        def parse(payload: bytes) -> Compiled:
            return _parse(payload, t0, times, self.tracers)

        loaded = self.ahead.take(full_key) if self.ahead is not None else None
        compiled: Compiled | None
        if loaded is not None:
            compiled, times = loaded
            self.loaded_ahead.append(name)
        else:
            compiled = self.read(name, full_key, SUFFIX, parse)
        if compiled is None:
            return None
        if not read_back:
            self.loaded.append(name)
            self.load_s[name] = times
        return compiled

    def save(self, name: str, full_key: Key, compiled: Any) -> None:
        """Write ``compiled`` (atomically); a program that cannot be serialized is logged."""
        from jax.experimental import serialize_executable

        try:
            devices = [d.id for d in compiled.runtime_executable().local_devices()]
            targets = warp_targets.used(compiled.as_text()) if self.tracers else []
            serialized, in_tree, out_tree = serialize_executable.serialize(compiled)
            # the pytrees apart: reading them imports the trainer's modules (see Ahead)
            trees = pickle.dumps((in_tree, out_tree))
            payload = pickle.dumps((serialized, trees, devices, targets))
        except Exception as err:
            self.log(f"warm start: {name} cannot be stored ({err}); it compiles on each start")
            return
        self.write(full_key, payload)
        self.written.append(name)


class Ahead:
    """A run's stored programs loaded ahead on a background thread, while the run imports
    the trainer and builds its model and environment (the executable's load releases
    Python's lock; the pytrees, whose classes need the trainer's modules, are read by
    :meth:`take`, on the run's thread): every index
    entry under the run's ``key`` whose program is named in ``order``, in that order, read,
    checked and deserialized as :meth:`Store.load` does. :meth:`take` hands over what it
    loaded; an entry it could not load (stale, corrupt, or calling MuJoCo Warp, whose
    targets the store makes on the run's own thread) is left to :meth:`Store.load`, which
    checks it again, logs it and makes it anew."""

    def __init__(self, directory: Path, key: Key, order: Sequence[str]):
        self.key = key
        run = _as_read(key)
        found: list[tuple[int, Key]] = []
        for path in directory.glob(f"*{INDEX_SUFFIX}"):
            try:
                header, payload = unframe(path.read_bytes())
                assert isinstance(header, dict)
                name = header.pop("program", None)
                header.pop("signature", None)
                if header == run and name in order and (program := json.loads(payload)):
                    found.append((order.index(name), program))
            except Exception:  # not this run's intact entry: Store.load judges it
                continue
        pool = ThreadPoolExecutor(1, thread_name_prefix="mecanum-ahead")
        self._loads: dict[str, Future[_Half | None]] = {
            digest(program): pool.submit(_load_ahead, directory, program)
            for _, program in sorted(found, key=lambda f: f[0])
        }
        pool.shutdown(wait=False)

    def take(self, program_key: Key) -> tuple[Compiled, dict[str, float]] | None:
        """The executable stored under ``program_key`` and its load's times, if loaded
        ahead (waiting for it where it is still loading); else ``None``."""
        future = self._loads.pop(digest(program_key), None)
        try:
            half = None if future is None else future.result()
            return None if half is None else _finish(half)
        except Exception:  # Store.load reads the file again and logs what is wrong
            return None


class _Half(NamedTuple):
    """An executable loaded ahead, its pytrees still pickled (:meth:`Ahead.take` ends it)."""

    unloaded: Any
    args_flat: list[Any]
    no_kwargs: bool
    trees: bytes
    times: dict[str, float]


def _load_ahead(directory: Path, program_key: Key) -> _Half | None:
    """The heavy half of ``deserialize_and_load`` (XLA's load, which needs no module of
    the trainer), with that function's own steps as jax 0.10.2 takes them (its private
    unpickler); a failure here, as on a jax whose steps differ, leaves the program to
    :meth:`Store.load`, which reads it through the public function."""
    from jax.experimental import serialize_executable

    t0 = time.perf_counter()
    payload = _payload(directory, program_key, SUFFIX)
    if payload is None:
        return None
    serialized, trees, device_ids, targets = pickle.loads(payload)
    if targets:
        raise ValueError("it calls MuJoCo Warp: its targets are made on the run's thread")
    t1 = time.perf_counter()
    devices = _local_devices(device_ids)
    unpickler = serialize_executable._JaxPjrtUnpickler(
        io.BytesIO(serialized), devices[0].client, devices
    )
    unloaded, args_flat, no_kwargs = unpickler.load()
    times = {"read": t1 - t0, "targets": 0.0, "deserialize": time.perf_counter() - t1}
    return _Half(unloaded, args_flat, no_kwargs, trees, times)


def _finish(half: _Half) -> tuple[Compiled, dict[str, float]]:
    """:func:`_load_ahead`'s executable as a ``Compiled``, its pytrees read (on the run's
    thread, whose imports they need)."""
    in_tree, out_tree = pickle.loads(half.trees)
    args_info = in_tree.unflatten(half.args_flat)
    compiled = Compiled(half.unloaded.load(), [], args_info, out_tree, no_kwargs=half.no_kwargs)
    return compiled, half.times


def _path(directory: Path, full_key: Key, suffix: str) -> Path:
    return directory / f"{digest(full_key)[:40]}{suffix}"


def _as_read(key: Key) -> object:
    """``key`` as a file's header reads back (JSON, values it cannot hold as their repr)."""
    return json.loads(json.dumps(key, default=repr))


def _payload(directory: Path, full_key: Key, suffix: str) -> bytes | None:
    """The payload kept under ``full_key`` (``None``: none); raises if the file is not
    this key's intact entry."""
    try:
        blob = _path(directory, full_key, suffix).read_bytes()
    except FileNotFoundError:
        return None
    header, payload = unframe(blob)
    if header != _as_read(full_key):
        raise ValueError("its key differs (a stale entry)")
    return payload


def _parse(
    payload: bytes,
    t0: float,
    times: dict[str, float],
    tracers: Sequence[warp_targets.Tracer] | None,
) -> Compiled:
    """A stored program's executable, loaded; ``times`` gets its phases' seconds from
    ``t0``. ``tracers``: what makes its MuJoCo Warp targets (``None``: refuse a program
    that calls them)."""
    t1 = time.perf_counter()
    times["read"] = t1 - t0
    serialized, trees, devices, targets = pickle.loads(payload)
    in_tree, out_tree = pickle.loads(trees)
    if targets and (tracers is None or not warp_targets.register(targets, tracers)):
        raise ValueError("its MuJoCo Warp FFI targets cannot be made here")
    t2 = time.perf_counter()
    times["targets"] = t2 - t1
    compiled = _deserialize(serialized, in_tree, out_tree, devices)
    times["deserialize"] = time.perf_counter() - t2
    return compiled


def _local_devices(device_ids: list[int]) -> list[jax.Device]:
    """This process's devices of those ids, in their order (a missing one raises)."""
    by_id = {d.id: d for d in jax.local_devices()}
    return [by_id[i] for i in device_ids]


def _deserialize(
    serialized: bytes, in_tree: PyTreeDef, out_tree: PyTreeDef, device_ids: list[int]
) -> Compiled:
    """The executable, loaded onto the devices it was compiled for."""
    from jax.experimental import serialize_executable

    devices = _local_devices(device_ids)
    return serialize_executable.deserialize_and_load(
        serialized, in_tree, out_tree, backend=devices[0].client, execution_devices=devices
    )


def frame(key: Key, payload: bytes) -> bytes:
    header = json.dumps(key, sort_keys=True, default=repr).encode()
    body = len(header).to_bytes(8, "little") + header + payload
    return MAGIC + hashlib.sha256(body).digest() + body


def unframe(blob: bytes) -> tuple[object, bytes]:
    if not blob.startswith(MAGIC):
        raise ValueError("not a stored program")
    digest, body = blob[len(MAGIC) : len(MAGIC) + 32], blob[len(MAGIC) + 32 :]
    if hashlib.sha256(body).digest() != digest:
        raise ValueError("checksum mismatch")
    n = int.from_bytes(body[:8], "little")
    return json.loads(body[8 : 8 + n]), body[8 + n :]
