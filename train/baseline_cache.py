"""The analytic baseline's evaluation (:meth:`train.ppo.Learner.evaluate_baseline`), kept
on disk: it depends on the task, the evaluation's settings and physics, the code, the
packages and the device, never on the policy, so a start that shares them all with an
earlier one reads it back. One ``<key>.npz`` in ``mecanum-baselines/`` in JAX's compilation
cache directory (:mod:`train.compilation_cache`) while that cache is on and one process
runs; the key is a SHA-256 of :func:`key_inputs`. A file that is unreadable, or not one
:func:`store` wrote, is computed anew and replaced; an unwritable one only warns: the cache
never stops a run. Deleting the directory clears it."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import sys
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import numpy as np

import mecanum_jax
from mecanum_jax.config import CONFIG_DIR
from mecanum_jax.evaluation.metrics import Part
from train import compilation_cache
from train.periodic import Result

if TYPE_CHECKING:
    from train.ppo import Learner

SUBDIR = "mecanum-baselines"
FORMAT = 1  # of the files; part of the key
PACKAGES = ["jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "warp-lang", "brax", "flax"]
PACKAGES += [f"jax-cuda{v}-{p}" for v in (12, 13) for p in ("plugin", "pjrt")]


class Entry(NamedTuple):
    """A baseline's file (``None``: no cache), its key, and what it held (``None``: a miss)."""

    path: Path | None
    key: str = ""
    result: Result | None = None

    @property
    def origin(self) -> str:
        """``"cache"``, ``"computed"`` (then stored) or ``"off"`` (computed; no cache)."""
        return "cache" if self.result is not None else "off" if self.path is None else "computed"


def directory() -> Path | None:
    """``mecanum-baselines/`` in JAX's compilation cache directory; ``None`` where that
    cache is off or several processes run (each would compute and write the same)."""
    where = compilation_cache.in_force()
    return None if where is None or jax.process_count() > 1 else where / SUBDIR


def source_roots() -> list[tuple[str, Path]]:
    """The code and data the result comes from: the library (every file; its configs too
    where it is installed as a wheel), the robot descriptions (``configs/robots/``), and
    the trainer's files that choose, play and store the evaluation."""
    train = Path(__file__).resolve().parent
    return [
        ("mecanum_jax", Path(mecanum_jax.__file__).resolve().parent),
        ("robots", CONFIG_DIR / "robots"),
        *((f"train/{f}", train / f) for f in ("periodic.py", "ppo.py", Path(__file__).name)),
    ]


def source_hash(roots: Iterable[tuple[str, Path]] | None = None) -> str:
    """SHA-256 of the names and contents of every file under ``roots`` (default
    :func:`source_roots`), sorted; the bytecode Python writes as it imports left out."""
    digest = hashlib.sha256()
    for label, root in source_roots() if roots is None else roots:
        for f in sorted(root.rglob("*")) if root.is_dir() else [root]:
            if "__pycache__" in f.parts or f.suffix in (".pyc", ".pyo") or not f.is_file():
                continue
            name = f"{label}/{f.relative_to(root).as_posix()}" if root.is_dir() else label
            content = f.read_bytes()
            digest.update(f"{name}\0{len(content)}\0".encode() + content)
    return digest.hexdigest()


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def key_inputs(learner: Learner) -> dict[str, Any]:
    """Everything the baseline's result depends on, as plain data. The policy network is
    in: the evaluation's program runs it too (its actions masked out for the baseline)."""
    cfg, ev = learner.cfg, learner.evaluation
    r, p, robot, device = cfg.run, cfg.ppo, ev.env.robot, jax.devices()[0]
    run_fields = ("eval_seed", "num_eval_envs", "eval_episode_length", "eval_fidelity")
    return {
        "format": FORMAT,
        "env": dataclasses.asdict(cfg.env),
        "run": {f: getattr(r, f) for f in (*run_fields, "matmul_precision")}
        | {"seeds": len(r.seeds)},
        "evaluation": {
            "env": dataclasses.asdict(ev.env.config),
            "robot": dataclasses.asdict(ev.env.desc),
            "physics": [robot.impl, robot.robots, robot.fidelity, robot.servo],
            "max_batch": ev.evaluator.max_batch,
            "scenarios": [dataclasses.asdict(s) for s in ev.scenarios.scenarios],
        },
        "policy": [dataclasses.asdict(cfg.network), p.normalize_observations, p.clip_observations],
        "device": [device.platform, device.device_kind],
        "float64": str(jax.dtypes.canonicalize_dtype(np.float64)),  # float32 unless x64
        "xla_flags": os.environ.get("XLA_FLAGS"),
        "versions": {p: _version(p) for p in PACKAGES},
        "source": source_hash(),
    }


def key(inputs: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON of ``inputs`` (sorted keys, tuples as lists)."""
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()


def _warn(message: str, err: Exception) -> None:
    why = getattr(err, "strerror", None) or err
    print(f"warning: baseline cache: {message} ({type(err).__name__}: {why})", file=sys.stderr)


def store(path: Path, digest: str, result: Result) -> bool:
    """Write ``result`` under ``digest`` atomically (a file beside ``path``, renamed);
    ``False``, with a warning, where it cannot."""
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        arrays: dict[str, Any] = {}
        entries: list[list[str]] = []
        for scenario, parts in result.parts.items():
            for metric, part in parts.items():
                arrays[f"num{len(entries)}"], arrays[f"den{len(entries)}"] = part.num, part.den
                entries.append([scenario, metric, part.kind])
        meta = {"format": FORMAT, "key": digest, "values": result.values, "parts": entries}
        arrays["meta"] = np.array(json.dumps(meta))
        path.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
        return True
    except Exception as err:  # the cache never stops a run
        _warn(f"cannot write {str(path)!r}", err)
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        return False


def load(path: Path, digest: str) -> Result | None:
    """The result :func:`store` wrote to ``path`` under ``digest``; ``None`` where there
    is none, or (with a warning) where the file is unreadable or not what it wrote."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"][()]))
            if meta["format"] != FORMAT or meta["key"] != digest:
                raise ValueError("another format or key")
            parts: dict[str, dict[str, Part]] = {}
            for i, (scenario, metric, kind) in enumerate(meta["parts"]):
                num, den = z[f"num{i}"], z[f"den{i}"]
                if kind not in ("rms", "mean") or num.ndim != 1 or num.shape != den.shape:
                    raise ValueError(f"part {scenario}/{metric}")
                parts.setdefault(scenario, {})[metric] = Part(num, den, kind)
        values = meta["values"]
        numbers = [v for scenario in values.values() for v in scenario.values()]
        if set(values) != set(parts) or not all(isinstance(v, float | int | None) for v in numbers):
            raise ValueError("values")
        return Result(values, parts)
    except Exception as err:  # whatever is wrong with the file, the result is computed anew
        _warn(f"ignoring {str(path)!r}, to be computed anew", err)
        return None


def lookup(learner: Learner, enabled: bool = True) -> Entry:
    """The learner's :class:`Entry` (off where ``enabled`` is false)."""
    where = directory() if enabled else None
    if where is None:
        return Entry(None)
    try:
        digest = key(key_inputs(learner))
    except Exception as err:  # (a source file that cannot be read)
        _warn("off: no key", err)
        return Entry(None)
    path = where / f"{digest[:24]}.npz"
    return Entry(path, digest, load(path, digest))


def compute(learner: Learner, ts_first_device: Any, entry: Entry) -> Result:
    """Evaluate the baseline (:meth:`Learner.evaluate_baseline`) and store it as ``entry`` says."""
    result = learner.evaluate_baseline(ts_first_device)
    if entry.path is not None:
        store(entry.path, entry.key, result)
    return result


def trace_in_place(learner: Learner, ts_first_device: Any) -> list[Any]:
    """Trace and lower the evaluation program the baseline would have run, running nothing;
    the lowered programs (``PeriodicEvaluation.trace``). Where
    the baseline runs first (``train.aot.first_runs_alone``: under MuJoCo Warp), a start
    that reads it back must still trace that program at the same point: Warp numbers its
    FFI calls in trace order and the compilation cache's keys hold those numbers, so a
    start that traced the epoch first missed the cache for the epoch and the evaluation
    that an earlier start had compiled (an H200, 2026-11-27; docs/benchmarks.md)."""
    params = (ts_first_device.normalizer_params, ts_first_device.params.policy)
    return learner.evaluation.trace("analytic", jax.tree.map(lambda x: x[0], params))


def _look_up_in_place(learner: Learner, ts_first_device: Any, enabled: bool, first: bool) -> Entry:
    """:func:`lookup`; on a hit where the baseline runs before the first epoch
    (``first``), its program traced all the same (:func:`trace_in_place`)."""
    entry = lookup(learner, enabled)
    if entry.result is not None and first:
        trace_in_place(learner, ts_first_device)
    return entry


def baseline(
    learner: Learner, ts_first_device: Any, enabled: bool = True, first: bool = False
) -> tuple[Result, str]:
    """The baseline's result, read back or computed (and stored), and its ``origin``;
    ``first``: it runs before the first epoch (read back, it is traced then all the same:
    :func:`trace_in_place`)."""
    entry = _look_up_in_place(learner, ts_first_device, enabled, first)
    if entry.result is None:
        return compute(learner, ts_first_device, entry), entry.origin
    return entry.result, entry.origin


def start(
    learner: Learner,
    ts_first_device: Any,
    enabled: bool,
    log: Callable[[str], None],
    first: bool = False,
) -> tuple[Future[Result], str]:
    """``mecanum-train``'s baseline and its ``origin``: read back (a finished future;
    ``log`` says from where; ``first``: traced all the same, :func:`trace_in_place`), or
    evaluated and stored in a thread of its own."""
    entry = _look_up_in_place(learner, ts_first_device, enabled, first)
    if entry.result is None:
        pool = ThreadPoolExecutor(1, thread_name_prefix="baseline-eval")
        job = pool.submit(compute, learner, ts_first_device, entry)
        pool.shutdown(wait=False)
        return job, entry.origin
    done: Future[Result] = Future()
    done.set_result(entry.result)
    home, path = str(Path.home()), str(entry.path)
    shown = "~" + path[len(home) :] if path.startswith(home + os.sep) else path
    log(f"baseline read back from {shown}")
    return done, "cache"


__all__ = ["Entry", "baseline", "compute", "directory", "key", "key_inputs", "load", "lookup"]
__all__ += ["source_hash", "source_roots", "start", "store", "trace_in_place"]
