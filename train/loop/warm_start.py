"""A warm start without tracing: the run's compiled programs kept on disk.

With JAX's persistent cache warm, a start still traces and lowers its three large
programs (the robots' reset, the epoch, the evaluation's rollout) to find them in the
cache: on the 2-core CPU 6.7 of the tiny config's 11 s, on an H200 10 s
(docs/benchmarks.md). :func:`attach` gives a learner's programs a store of their compiled
executables (``jax.experimental.serialize_executable``) in the compilation cache's
directory (``<dir>/mecanum-programs``), so a later start of the same run loads them
without tracing. A cold start compiles each as ``jit(...).lower(...).compile()`` would
and writes it; a warm one runs the executable it wrote, so the two give the same numbers
bit for bit.

Each entry is keyed by everything its program depends on (:func:`run_key`): the resolved
config, the robot, the versions of jax, jaxlib, MuJoCo, MJX, Warp, Brax, Flax and optax,
the devices, ``XLA_FLAGS``, JAX's numerics flags, a hash of the ``mecanum_jax`` and
``train`` sources, and the program's name and argument signature. A file is trusted only
if its checksum, its stored key and its deserialization all pass; else it is compiled
again and rewritten, with a log line.

Off (:func:`why_not`), with a log line, where the store cannot serve: no persistent
cache, several processes, several CPU devices, ``run.parallel = "split"``, or
``MECANUM_WARM_START=off``. Under MJX's Warp implementation, whose FFI targets exist only
once a call is traced, a stored program records the targets it calls and a warm start
makes them first (train/loop/warp_targets.py).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import pickle
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np
from jax.stages import Compiled, Wrapped
from jax.tree_util import PyTreeDef

import mecanum_jax
import train
from train.loop import warp_targets

if TYPE_CHECKING:
    from train.config import TrainConfig
    from train.learner.ppo import Learner

MAGIC = b"mecanum-jax executable 2\n"
SUFFIX = ".jaxexe"
SUBDIR = "mecanum-programs"
ENV_VAR = "MECANUM_WARM_START"
PACKAGES = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "warp-lang", "brax", "flax", "optax")
JAX_FLAGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_threefry_partitionable",
    "jax_default_prng_impl",
)
Log = Callable[[str], None]
Key = dict[str, object]
"""A program's key: JSON-ready values (:func:`run_key`, plus the program's own)."""
Aval = tuple[tuple[int, ...], str, bool]
"""An argument's shape, dtype and weak type (:func:`_aval`)."""
Signature = tuple[PyTreeDef, tuple[Aval, ...]]


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def code_hash() -> str:
    """sha256 of the ``mecanum_jax`` and ``train`` packages' ``.py`` files (paths and bytes)."""
    h = hashlib.sha256()
    for package in (mecanum_jax, train):
        root = Path(str(package.__file__)).parent
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode() + b"\0")
            h.update(path.read_bytes() + b"\0")
    return h.hexdigest()


def _digest(obj: object) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=repr).encode()).hexdigest()


def run_key(cfg: TrainConfig, devices: Sequence[jax.Device]) -> Key:
    """What a run's programs depend on, as JSON-ready values (see the module docstring)."""
    return {
        "config": _digest(cfg.to_dict()),
        "robot": _digest(repr(cfg.env.description())),
        "versions": {p: _version(p) for p in PACKAGES},
        "devices": [f"{d.platform}:{d.device_kind}:{d.id}" for d in devices],
        "backend_devices": jax.device_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "jax_flags": {f: str(getattr(jax.config, f, None)) for f in JAX_FLAGS},
        "code": code_hash(),
    }


class Store:
    """Compiled programs in a directory, each file keyed, checksummed and checked on load."""

    def __init__(
        self, directory: Path, key: Key, log: Log, tracers: Sequence[warp_targets.Tracer] = ()
    ):
        """``tracers``: where the programs call MuJoCo Warp, what makes its FFI targets in
        a fresh process (:func:`train.loop.warp_targets.register`)."""
        self.directory = directory
        self.key = key
        self.log = log
        self.tracers = tuple(tracers)
        self.loaded: list[str] = []
        self.written: list[str] = []

    def path(self, full_key: Key) -> Path:
        return self.directory / f"{_digest(full_key)[:40]}{SUFFIX}"

    def _payload(self, full_key: Key) -> bytes | None:
        """The payload kept under ``full_key`` (``None``: none); raises if the file is not
        this key's intact entry."""
        try:
            blob = self.path(full_key).read_bytes()
        except FileNotFoundError:
            return None
        header, payload = _unframe(blob)
        if header != json.loads(json.dumps(full_key, default=repr)):
            raise ValueError("its key differs (a stale entry)")
        return payload

    def _write(self, name: str, full_key: Key, payload: bytes) -> None:
        path = self.path(full_key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_bytes(_frame(full_key, payload))
        os.replace(tmp, path)  # atomically: never a partial file under the final name
        self.written.append(name)

    def _unusable(self, name: str, full_key: Key, err: Exception) -> None:
        path = self.path(full_key)
        self.log(f"warm start: {name}: {path.name} unusable ({err}); made again")
        path.unlink(missing_ok=True)

    def load(self, name: str, full_key: Key, read_back: bool = False) -> Compiled | None:
        """The program stored under ``full_key``, or ``None`` (absent, stale or corrupt:
        logged, and the file removed); ``read_back``: just written, not counted as loaded."""
        try:
            payload = self._payload(full_key)
            if payload is None:
                return None
            serialized, in_tree, out_tree, devices, targets = pickle.loads(payload)
            if targets and not warp_targets.register(targets, self.tracers):
                raise ValueError("its MuJoCo Warp FFI targets cannot be made here")
            compiled = _deserialize(serialized, in_tree, out_tree, devices)
        except Exception as err:  # anything wrong with the file: never trusted
            self._unusable(name, full_key, err)
            return None
        if not read_back:
            self.loaded.append(name)
        return compiled

    def save(self, name: str, full_key: Key, compiled: Any) -> None:
        """Write ``compiled`` (atomically); a program that cannot be serialized is logged."""
        from jax.experimental import serialize_executable

        try:
            devices = [d.id for d in compiled.runtime_executable().local_devices()]
            targets = warp_targets.used(compiled.as_text()) if self.tracers else []
            payload = pickle.dumps((*serialize_executable.serialize(compiled), devices, targets))
        except Exception as err:
            self.log(f"warm start: {name} cannot be stored ({err}); it compiles on each start")
            return
        self._write(name, full_key, payload)


def _deserialize(
    serialized: bytes, in_tree: PyTreeDef, out_tree: PyTreeDef, device_ids: list[int]
) -> Compiled:
    """The executable, loaded onto the devices it was compiled for."""
    from jax.experimental import serialize_executable

    by_id = {d.id: d for d in jax.local_devices()}
    devices = [by_id[i] for i in device_ids]
    return serialize_executable.deserialize_and_load(
        serialized, in_tree, out_tree, backend=devices[0].client, execution_devices=devices
    )


def _frame(key: Key, payload: bytes) -> bytes:
    header = json.dumps(key, sort_keys=True, default=repr).encode()
    body = len(header).to_bytes(8, "little") + header + payload
    return MAGIC + hashlib.sha256(body).digest() + body


def _unframe(blob: bytes) -> tuple[object, bytes]:
    if not blob.startswith(MAGIC):
        raise ValueError("not a stored program")
    digest, body = blob[len(MAGIC) : len(MAGIC) + 32], blob[len(MAGIC) + 32 :]
    if hashlib.sha256(body).digest() != digest:
        raise ValueError("checksum mismatch")
    n = int.from_bytes(body[:8], "little")
    return json.loads(body[8 : 8 + n]), body[8 + n :]


class Stored:
    """A jitted (or pmapped) function whose compiled programs come from a :class:`Store`:
    called, it runs the program for its arguments' signature, loaded, or compiled (and
    written) on first use; :meth:`lower` looks the program up first and traces only when
    it is not stored (``train.loop.aot`` compiles through it)."""

    def __init__(self, fn: Wrapped, name: str, store: Store):
        self.fn = fn
        self.name = name
        self.store = store
        self._programs: dict[Signature, Compiled] = {}
        self._checked: set[Signature] = set()
        self._lock = threading.Lock()  # (the baseline's evaluation runs in a thread)

    def lower(self, *args: Any) -> StoredLowering:
        return StoredLowering(self, args)

    def __call__(self, *args: Any) -> Any:
        sig = _signature(args)
        with self._lock:
            program = self._programs.get(sig)
            if program is None:
                program = self.load(sig) or self.adopt(sig, self.fn.lower(*args).compile())
            if sig not in self._checked:
                return self._first_run(program, args, sig)
        return program(*args)

    def full_key(self, sig: Signature) -> Key:
        return {**self.store.key, "program": self.name, "signature": repr(sig)}

    def load(self, sig: Signature) -> Compiled | None:
        """The stored program for ``sig`` (``None``: not stored, or unusable)."""
        program = self._programs.get(sig) or self.store.load(self.name, self.full_key(sig))
        if program is not None:
            self._programs[sig] = program
        return program

    def adopt(self, sig: Signature, compiled: Compiled) -> Compiled:
        """``compiled``, just compiled for ``sig``, written and read back, so a cold start
        runs what a warm one will."""
        full_key = self.full_key(sig)
        self.store.save(self.name, full_key, compiled)
        program = self.store.load(self.name, full_key, read_back=True) or compiled
        self._programs[sig] = program
        return program

    def _first_run(self, program: Compiled, args: tuple[Any, ...], sig: Signature) -> Any:
        """The program's first outputs, waited for. One that fails (XLA:CPU of jaxlib
        0.10.2 wrote an executable it had read from the persistent cache without all its
        functions) is dropped, the program compiled and run instead, and not stored."""
        try:
            out = jax.block_until_ready(program(*args))
        except Exception as err:  # the stored executable is broken: never used again
            self.store.log(f"warm start: {self.name} failed to run ({err}); compiled instead")
            self.store.path(self.full_key(sig)).unlink(missing_ok=True)
            program = self._programs[sig] = self.fn.lower(*args).compile()
            out = program(*args)
        self._checked.add(sig)
        return out


class StoredLowering:
    """What :meth:`Stored.lower` gives for arguments (arrays or ``ShapeDtypeStruct``s):
    the stored program where there is one, nothing traced; else the function traced and
    lowered now, on this thread (MuJoCo Warp numbers its calls in trace order). Its
    :meth:`compile` (on any thread) compiles and writes what is not stored, and returns
    the :class:`Stored` function, whose first call runs it, checked."""

    def __init__(self, stored: Stored, args: tuple[Any, ...]):
        self.stored = stored
        self.sig = _signature(args)
        self.lowered = None if stored.load(self.sig) else stored.fn.lower(*args)

    def compile(self) -> Stored:
        if self.lowered is not None:
            self.stored.adopt(self.sig, self.lowered.compile())
        return self.stored


def _signature(args: tuple[Any, ...]) -> Signature:
    leaves, tree = jax.tree.flatten(args)
    return tree, tuple(_aval(x) for x in leaves)


def _aval(x: Any) -> Aval:
    """Shape, dtype and weak type; not the placement, which the run's key (its config
    and devices) fixes, so a program lowered from shapes serves the placed arrays."""
    weak = bool(getattr(x, "weak_type", False))
    dtype = x.dtype if hasattr(x, "dtype") else np.result_type(x)
    return (np.shape(x), str(dtype), weak)


def why_not(learner: Learner, environ: Mapping[str, str] = os.environ) -> str | None:
    """Why the store cannot serve ``learner`` (``None``: it can)."""
    from train.loop import compilation_cache

    if environ.get(ENV_VAR, "").lower() in ("0", "off", "false", "no"):
        return f"{ENV_VAR}={environ[ENV_VAR]}"
    if compilation_cache.in_force() is None:
        return "the persistent compilation cache is off"
    if learner.n_processes > 1:
        return "several processes"
    if learner.n_devices > 1 and learner.devices[0].platform == "cpu":
        # XLA:CPU re-serializes a cache hit without all its functions: a stored program
        # that then fails on one device leaves the other waiting in a collective, and XLA
        # aborts the process after 40 s (seen in the full tier, jaxlib 0.10.2)
        return "several CPU devices"
    if learner.parallel == "split":
        return "run.parallel = 'split' compiles per GPU on first use"
    return None


def attach(learner: Any, log: Log = print) -> Any:
    """Serve ``learner``'s reset, epoch and evaluation rollout from a :class:`Store` in the
    compilation cache's directory (once per learner; :func:`store_of` gives it), unless
    :func:`why_not` (said in a log line). Returns ``learner``."""
    if store_of(learner) is not None:
        return learner
    reason = why_not(learner)
    if reason is not None:
        log(f"warm start off: {reason}; the programs are traced and compiled as usual")
        return learner
    from train.loop import compilation_cache

    directory = compilation_cache.in_force()
    assert directory is not None
    env = learner.env
    warp = env.robot.impl == "warp"
    tracers = [warp_targets.step_tracer(env.robot, env.substeps)] if warp else []
    store = Store(directory / SUBDIR, run_key(learner.cfg, learner.devices), log, tracers)
    # the learner's and the evaluator's jitted programs, wrapped in place (their calls
    # and lowerings go through the wrappers unchanged)
    learner._reset = Stored(learner._reset, "reset", store)
    learner._parallel_epoch = Stored(learner._parallel_epoch, "epoch", store)
    learner.evaluation.store_programs(lambda fn: Stored(fn, "rollout", store))
    learner.warm_store = store
    return learner


def store_of(learner: object) -> Store | None:
    """The store :func:`attach` gave ``learner`` (``None``: none)."""
    return getattr(learner, "warm_store", None)


__all__ = ["ENV_VAR", "Store", "Stored", "attach", "code_hash", "run_key", "store_of", "why_not"]
