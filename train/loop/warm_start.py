"""A warm start without tracing: the run's compiled programs kept on disk.

With JAX's persistent cache warm, a start still traces and lowers its three large
programs (the robots' reset, the epoch, the evaluation's rollout) to find them in the
cache: on the 2-core CPU 6.7 of the tiny config's 11 s, on an H200 10 s
(docs/profiling.md). :func:`attach` gives a learner's programs a store of their compiled
executables (``jax.experimental.serialize_executable``) in the compilation cache's
directory (``<dir>/mecanum-programs``), so a later start of the same run loads them
without tracing. A cold start compiles each as ``jit(...).lower(...).compile()`` would
and writes it; a warm one runs the executable it wrote, so the two give the same numbers
bit for bit.

Two kinds of file. An executable is keyed by what compiles it: a hash of the lowered
program's text, its argument signature, the versions of jax, jaxlib, MuJoCo, MJX, Warp,
Brax, Flax and optax, the devices, ``XLA_FLAGS`` and JAX's numerics flags. An index entry
maps a run's program to its executable's key, keyed by everything the program depends on
(:func:`run_key`): the resolved config, the robot, those versions, devices and flags, a
hash of the ``mecanum_jax`` and ``train`` sources, and the program's name and argument
signature. A warm start reads the index and loads, tracing nothing; after an edit of the
sources or the config the index misses, the program is traced and lowered, and where the
lowered text is unchanged its executable loads without compiling (and the index learns
the new key). On the CPU the store's programs compile outside JAX's persistent cache:
XLA:CPU of jaxlib 0.10.2 re-serializes an executable it read from that cache without all
its functions, which left every start after an edit tracing again. A file is trusted only if
its checksum, its stored key and its deserialization all pass; else it is compiled again
and rewritten, with a log line.

The evaluation's episodes and the baseline's first figures on them, which the run's key
fixes too, are kept beside them (train/loop/stored_baseline.py). On one CPU device the
stored programs load on a thread from the moment the config is known, while the trainer
imports and the learner is built (:func:`begin_loading`, :func:`load_ahead`: loading the
epoch's executable is most of a warm start there, and XLA releases Python's lock while it
loads); this module imports no trainer module, so it can begin before them.

Off (:func:`why_not`), with a log line, where the store cannot serve: no persistent
cache, several processes, several CPU devices, ``run.parallel = "split"``, or
``MECANUM_WARM_START=off``. Under MJX's Warp implementation, whose FFI targets exist only
once a call is traced, a stored program records the targets it calls and a warm start
makes them first (train/loop/warp_targets.py).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import os
import threading
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np
from jax.stages import Compiled, Wrapped
from jax.tree_util import PyTreeDef

import mecanum_jax
import train
from mecanum_jax.tracing import GPU_THREEFRY_FLAG, prepare_tracing
from train.loop import warp_targets
from train.loop.program_store import INDEX_SUFFIX, SUFFIX, Ahead, Key, Log, Store, digest

if TYPE_CHECKING:
    from train.config import TrainConfig
    from train.learner.ppo import Learner

SUBDIR = "mecanum-programs"
ENV_VAR = "MECANUM_WARM_START"
PACKAGES = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "warp-lang", "brax", "flax", "optax")
JAX_FLAGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_threefry_partitionable",
    "jax_default_prng_impl",
    GPU_THREEFRY_FLAG,
)
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


def run_key(cfg: TrainConfig, devices: Sequence[jax.Device]) -> Key:
    """What a run's programs depend on, as JSON-ready values (see the module docstring)."""
    return {
        "config": digest(cfg.to_dict()),
        "robot": digest(repr(cfg.env.description())),
        "versions": {p: _version(p) for p in PACKAGES},
        "devices": [f"{d.platform}:{d.device_kind}:{d.id}" for d in devices],
        "backend_devices": jax.device_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "jax_flags": {f: str(getattr(jax.config, f, None)) for f in JAX_FLAGS},
        "code": code_hash(),
    }


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
        self._keys: dict[Signature, Key] = {}  # each program's executable's key
        self._checked: set[Signature] = set()
        self._lock = threading.Lock()  # (the baseline's evaluation runs in a thread)

    def lower(self, *args: Any) -> StoredLowering:
        return StoredLowering(self, args)

    def __call__(self, *args: Any) -> Any:
        sig = _signature(args)
        with self._lock:
            program = self._programs.get(sig)
            if program is None:
                program = self.load(sig) or self.adopt(sig, self.fn.lower(*args))
            if sig not in self._checked:
                return self._first_run(program, args, sig)
        return program(*args)

    def full_key(self, sig: Signature) -> Key:
        return {**self.store.key, "program": self.name, "signature": repr(sig)}

    def load(self, sig: Signature) -> Compiled | None:
        """The stored program for ``sig``, found through the index, nothing traced
        (``None``: not stored, or unusable)."""
        program = self._programs.get(sig)
        if program is None:
            program_key = self.store.indexed(self.name, self.full_key(sig))
            if program_key is not None:
                program = self.store.load(self.name, program_key)
                self._keys[sig] = program_key
        if program is not None:
            self._programs[sig] = program
        return program

    def adopt(self, sig: Signature, lowered: Any) -> Compiled:
        """The program ``lowered`` for ``sig``: the executable kept for the same lowered
        text, else compiled now outside the persistent cache, written and read back, so a
        cold start runs what a warm one will; the index then points at it."""
        program_key = self._keys[sig] = self.store.program_key(lowered.as_text(), sig)
        program = self.store.load(self.name, program_key)
        if program is None:
            with _outside_persistent_cache(self.store.fresh):
                compiled = lowered.compile()
            self.store.save(self.name, program_key, compiled)
            program = self.store.load(self.name, program_key, read_back=True) or compiled
        if self.store.path(program_key).exists():
            self.store.index(self.full_key(sig), program_key)
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
            if sig in self._keys:
                self.store.path(self._keys[sig]).unlink(missing_ok=True)
            program = self._programs[sig] = self.fn.lower(*args).compile()
            out = program(*args)
        self._checked.add(sig)
        return out


@contextlib.contextmanager
def _outside_persistent_cache(on: bool) -> Iterator[None]:
    """With ``on``, this thread's compilations kept out of JAX's persistent cache: keyed
    apart from its entries (with the metadata) and never written there. JAX decides once
    per process whether the cache is used, so its on-switch cannot do this; these settings
    have no public context manager, and where one is missing nothing changes for it."""
    from jax._src import config as jax_config

    with contextlib.ExitStack() as stack:
        for name, value in (
            ("compilation_cache_include_metadata_in_key", True),
            ("persistent_cache_min_compile_time_secs", float("inf")),
        ):
            state = getattr(jax_config, name, None)
            if on and callable(state):
                stack.enter_context(state(value))
        yield


class StoredLowering:
    """What :meth:`Stored.lower` gives for arguments (arrays or ``ShapeDtypeStruct``s):
    the stored program where there is one, nothing traced; else the function traced and
    lowered now, on this thread (MuJoCo Warp numbers its calls in trace order). Its
    :meth:`compile` (on any thread) loads the executable of the same lowered text or
    compiles and writes it, and returns the :class:`Stored` function, whose first call
    runs it, checked."""

    def __init__(self, stored: Stored, args: tuple[Any, ...]):
        self.stored = stored
        self.sig = _signature(args)
        self.lowered = None if stored.load(self.sig) else stored.fn.lower(*args)

    def compile(self) -> Stored:
        if self.lowered is not None:
            self.stored.adopt(self.sig, self.lowered)
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


def _switched_off(environ: Mapping[str, str]) -> bool:
    return environ.get(ENV_VAR, "").lower() in ("0", "off", "false", "no")


def why_not(learner: Learner, environ: Mapping[str, str] = os.environ) -> str | None:
    """Why the store cannot serve ``learner`` (``None``: it can)."""
    from train.loop import compilation_cache

    if _switched_off(environ):
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


_begun: Ahead | None = None
"""The loading :func:`begin_loading` began, until :func:`load_ahead` takes it."""


def load_ahead(cfg: TrainConfig) -> Ahead | None:
    """Start loading ``cfg``'s stored programs on a background thread, before its learner
    is built (:class:`~train.loop.program_store.Ahead`; :func:`attach` takes them), or
    the loading :func:`begin_loading` began for the same run: on one CPU device, where the
    store serves (``None`` elsewhere; on a GPU the executables load when first called)."""
    from train.loop import compilation_cache

    directory = compilation_cache.in_force()
    local = jax.local_devices()
    if _switched_off(os.environ) or directory is None or jax.process_count() > 1:
        return None
    if len(local) != 1 or local[0].platform != "cpu":
        return None
    global _begun
    key = run_key(cfg, local)
    begun, _begun = _begun, None
    if begun is not None and begun.key == key:  # this run's
        return begun
    return Ahead(directory / SUBDIR, key, ("fresh", "reset", "epoch", "rollout"))


def begin_loading(cfg: TrainConfig) -> None:
    """:func:`load_ahead` now, before the trainer's modules are imported (this module
    imports none of them): the executables load on a thread while the run imports and
    builds, and the run's own :func:`load_ahead` takes them. Sets what the run sets before
    it traces (``prepare_tracing``: the run's key holds those flags)."""
    global _begun
    prepare_tracing(cfg.run.matmul_precision)
    _begun = load_ahead(cfg)


def attach(learner: Any, log: Log = print, ahead: Ahead | None = None) -> Any:
    """Serve ``learner``'s reset, epoch and evaluation rollout, and the evaluation's
    episodes and the baseline's figures (train/loop/stored_baseline.py), from a
    :class:`Store` in the compilation cache's directory (once per learner; :func:`store_of`
    gives it), with the programs ``ahead`` loaded (:func:`load_ahead`), unless
    :func:`why_not` (said in a log line). Returns ``learner``."""
    if store_of(learner) is not None:
        return learner
    reason = why_not(learner)
    if reason is not None:
        log(f"warm start off: {reason}; the programs are traced and compiled as usual")
        return learner
    from train.loop import compilation_cache
    from train.loop.stored_baseline import StoredBaseline, stored_episodes  # (imports MJX)

    directory = compilation_cache.in_force()
    assert directory is not None
    env = learner.env
    warp = env.robot.impl == "warp"
    tracers = [warp_targets.step_tracer(env.robot, env.substeps)] if warp else []
    key = run_key(learner.cfg, learner.devices)
    # on a GPU an executable read from JAX's persistent cache serializes whole
    fresh = learner.devices[0].platform == "cpu"
    store = Store(directory / SUBDIR, key, log, tracers, fresh)
    store.ahead = ahead
    # the learner's and the evaluator's jitted programs, wrapped in place (their calls
    # and lowerings go through the wrappers unchanged)
    if fresh:  # a seed's fresh training state, made on the host: on a GPU run not stored
        learner._fresh = Stored(learner._fresh, "fresh", store)
    learner._reset = Stored(learner._reset, "reset", store)
    learner._parallel_epoch = Stored(learner._parallel_epoch, "epoch", store)
    learner.evaluation.store_programs(lambda fn: Stored(fn, "rollout", store))
    learner.evaluation.draw = stored_episodes(learner.evaluation.draw, store)
    learner.evaluate_baseline = StoredBaseline(learner.evaluate_baseline, store)
    learner.warm_store = store
    return learner


def store_of(learner: object) -> Store | None:
    """The store :func:`attach` gave ``learner`` (``None``: none)."""
    return getattr(learner, "warm_store", None)


__all__ = [
    "ENV_VAR",
    "INDEX_SUFFIX",
    "SUFFIX",
    "Store",
    "Stored",
    "attach",
    "begin_loading",
    "code_hash",
    "load_ahead",
    "run_key",
    "store_of",
    "why_not",
]
