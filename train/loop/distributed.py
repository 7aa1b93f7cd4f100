"""Starting a multi-process (multi-host, or one process per GPU) run through ``jax.distributed``.

``jax.distributed.initialize()`` detects SLURM, Open MPI and Cloud TPU clusters by itself, and
reads ``JAX_COORDINATOR_ADDRESS`` and ``JAX_LOCAL_DEVICE_IDS``, but nothing tells it the process
count and id outside those clusters. :func:`init_distributed` also reads
``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``, so a hand-started run needs only environment
variables (here two processes on one host, one GPU each)::

    for i in 0 1; do
      JAX_COORDINATOR_ADDRESS=localhost:12355 JAX_NUM_PROCESSES=2 JAX_PROCESS_ID=$i \\
      JAX_LOCAL_DEVICE_IDS=$i mecanum-train --config gpu --distributed &
    done; wait

Each process also keeps what only it holds, its devices' loop keys and robots, beside
process 0's orbax checkpoint (:func:`save_process`, :func:`restore_process`).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Protocol, TypedDict, TypeVar

import jax
import numpy as np
import numpy.typing as npt

from mecanum_jax.config import ConfigError
from train.store.leaves import CheckpointError, corruption, pack, unpack

ENV_KEYS = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
Tree = TypeVar("Tree")


class DistributedArgs(TypedDict, total=False):
    """The ``jax.distributed.initialize`` keyword arguments the environment variables give."""

    coordinator_address: str
    num_processes: int
    process_id: int


def distributed_args(environ: Mapping[str, str]) -> DistributedArgs:
    """``jax.distributed.initialize`` keyword arguments from ``environ``; raises
    :class:`ConfigError` naming the variable and its value when one is malformed."""
    args: DistributedArgs = {}
    address = environ.get("JAX_COORDINATOR_ADDRESS")
    if address is not None:
        host, sep, port = address.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ConfigError(
                f"JAX_COORDINATOR_ADDRESS = {address!r}: expected host:port (port 1-65535)"
            )
        args["coordinator_address"] = address
    counts: dict[str, int] = {}
    for key, name in (("JAX_NUM_PROCESSES", "num_processes"), ("JAX_PROCESS_ID", "process_id")):
        raw = environ.get(key)
        if raw is None:
            continue
        try:
            counts[name] = int(raw)
        except ValueError:
            raise ConfigError(f"{key} = {raw!r}: expected an integer") from None
    n, pid = counts.get("num_processes"), counts.get("process_id")
    if n is not None and n < 1:
        raise ConfigError(f"JAX_NUM_PROCESSES = {n}: must be >= 1")
    if pid is not None and pid < 0:
        raise ConfigError(f"JAX_PROCESS_ID = {pid}: must be >= 0")
    if n is not None and pid is not None and pid >= n:
        raise ConfigError(f"JAX_PROCESS_ID = {pid}: must be < JAX_NUM_PROCESSES = {n}")
    if (n is None) != (pid is None):
        given, missing = ("JAX_NUM_PROCESSES", "JAX_PROCESS_ID")[:: 1 if pid is None else -1]
        raise ConfigError(f"{given} = {environ[given]!r} is set but {missing} is not")
    if n is not None and address is None:
        raise ConfigError(
            f"JAX_NUM_PROCESSES = {n}: JAX_COORDINATOR_ADDRESS (host:port of process 0) "
            "must be set too"
        )
    if n is not None and pid is not None:
        args["num_processes"], args["process_id"] = n, pid
    return args


def init_distributed(
    enabled: bool,
    environ: Mapping[str, str] | None = None,
    initialize: Callable[..., None] | None = None,
) -> DistributedArgs:
    """Join the ``jax.distributed`` run when ``enabled`` (``--distributed``): from the
    environment variables above, else from the cluster environment JAX detects. Returns the
    arguments it passed (empty when not enabled)."""
    if not enabled:
        return DistributedArgs()
    args = distributed_args(os.environ if environ is None else environ)
    if initialize is None:
        initialize = jax.distributed.initialize
    try:
        initialize(**args)
    except ValueError as err:  # JAX found no cluster and was not told the rest
        raise ConfigError(
            f"--distributed: {err} (no SLURM / Open MPI / Cloud TPU environment detected; "
            f"set {', '.join(ENV_KEYS)})"
        ) from err
    return args


_barriers = itertools.count()


def barrier(name: str, timeout_s: float = 1800.0) -> None:
    """Wait until every process of a ``jax.distributed`` run gets here (no-op for one).

    Through the coordination service, not a collective: CPU (gloo) collectives give up
    when a peer is 30 s late to their first use, and one process may still be compiling
    (a warm compilation cache serves processes unevenly). ``jax.distributed`` has no
    public barrier; this is the client orbax and JAX's own serialization use.
    """
    client = coordination_client() if jax.process_count() > 1 else None
    if client is None:
        return
    client.wait_at_barrier(f"mecanum/{name}/{next(_barriers)}", int(timeout_s * 1000))


class CoordinationClient(Protocol):
    """What this package uses of the ``jax.distributed`` coordination service's client."""

    def wait_at_barrier(self, barrier_id: str, timeout_in_ms: int, /) -> None: ...
    def key_value_set(self, key: str, value: str, /) -> None: ...
    def key_value_dir_get(self, key: str, /) -> list[tuple[str, str]]: ...
    def key_value_delete(self, key: str, /) -> None: ...


def coordination_client() -> CoordinationClient | None:
    """The ``jax.distributed`` coordination service's client (a key-value store and
    barriers), or ``None`` where this process joined none (several processes without
    jax.distributed: nothing to wait on)."""
    from jax._src import distributed as jax_distributed

    return jax_distributed.global_state.client


PROCESS_DIR = "process_state"


def _process_dir(run_dir: Path, index: int) -> Path:
    return run_dir / PROCESS_DIR / f"p{index}"


def save_process(run_dir: Path, epoch: int, keys: npt.ArrayLike, env: object, keep: int) -> Path:
    """What only this process holds in a multi-process run (process 0's orbax checkpoint has
    the replicated training state): its devices' loop keys and robots, as one ``.npz``
    written atomically; keeps the newest ``keep``."""
    folder = _process_dir(run_dir, jax.process_index())
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{epoch}.npz"
    tmp = folder / f".{epoch}.tmp.npz"
    arrays: dict[str, np.ndarray] = {f"env_{k}": v for k, v in pack(env).items()}
    arrays["key"] = np.asarray(keys)
    np.savez(tmp, allow_pickle=True, **arrays)  # numpy's default, named: all else is arrays
    os.replace(tmp, path)
    saved = sorted(int(f.stem) for f in folder.glob("*.npz") if f.stem.isdigit())
    for old in saved[:-keep] if keep > 0 else []:
        (folder / f"{old}.npz").unlink(missing_ok=True)
    return path


def restore_process(
    run_dir: Path, epoch: int, keys_like: npt.ArrayLike, env_like: Tree
) -> tuple[np.ndarray, Tree] | None:
    """This process's loop keys and robots of ``epoch`` (see :func:`save_process`), or
    ``None`` when it has none for that epoch."""
    path = _process_dir(run_dir, jax.process_index()) / f"{epoch}.npz"
    if not path.exists():
        return None
    with np.load(path) as f:
        keys = np.asarray(f["key"])
        env = {k.removeprefix("env_"): f[k] for k in f.files if k.startswith("env_")}
        if damage := corruption(env):
            raise CheckpointError(f"{str(path)!r}: {damage}")
        if keys.shape != np.shape(keys_like):
            raise CheckpointError(
                f"{str(path)!r}: key shape {keys.shape}, expected {np.shape(keys_like)}"
            )
        return keys.astype(np.asarray(keys_like).dtype), unpack(env_like, env)


__all__ = [
    "ENV_KEYS",
    "CoordinationClient",
    "DistributedArgs",
    "barrier",
    "coordination_client",
    "distributed_args",
    "init_distributed",
    "restore_process",
    "save_process",
]
