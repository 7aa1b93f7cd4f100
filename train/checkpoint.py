"""Checkpoints (orbax): full training state for resume, and a plain inference function.

A checkpoint at ``<run>/checkpoints/<epoch>/`` holds three items:

- ``train``: the :class:`~train.state.TrainingState` of every seed and device (optimizer
  state, parameters, observation normalizer, rng keys);
- ``env``: the environment state of every robot (so resuming continues the same episodes);
- ``meta``: JSON — epoch, environment steps, wall time, the resolved config, the robot
  and the observation layout (so a checkpoint from another robot or layout is refused).

``train`` and ``env`` are stored as flat dicts of named leaves with checksums, and
restored by name (:mod:`train.leaves`); the leaf-index format of earlier versions
(the shipped model's among them) is recognised and restored by index.

:func:`load_policy` restores only ``train`` and ``meta`` and returns a jitted
deterministic ``obs -> action`` function for evaluation and deployment.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from mecanum_jax.config import ConfigError
from train.leaves import CheckpointError, corruption, pack, unpack

if TYPE_CHECKING:
    import orbax.checkpoint as ocp

CHECKPOINT_DIR = "checkpoints"


def quiet_closed_loop_noise() -> None:
    """Drop the "Event loop is closed" tracebacks that orbax's reader threads leave behind
    after a failed read (Python reports them as unraisable exceptions at exit); every other
    unraisable exception is reported as before. Called by the command lines."""
    if getattr(sys.unraisablehook, "_mecanum_quiet", False):
        return
    previous = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        exc = unraisable.exc_value
        if isinstance(exc, RuntimeError) and str(exc) == "Event loop is closed":
            return
        previous(unraisable)

    hook._mecanum_quiet = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


def _orbax() -> Any:
    """orbax.checkpoint, imported on first use: about 0.6 s that a run's start need not
    wait for (its first checkpoint comes epochs later; docs/benchmarks.md)."""
    import orbax.checkpoint

    return orbax.checkpoint


def manager(run_dir: Path, max_to_keep: int = 3, create: bool = True) -> ocp.CheckpointManager:
    ocp = _orbax()
    root = (run_dir / CHECKPOINT_DIR).absolute()
    extra: dict[str, Any] = {}
    if jax.process_count() > 1:
        # process-local: process 0 alone writes its host copies; orbax's default would
        # wait at barriers for every process of a jax.distributed run (and with a process
        # subset it leaves creating the root to the caller)
        me = jax.process_index()
        extra["multiprocessing_options"] = ocp.options.MultiprocessingOptions(
            primary_host=me, active_processes={me}
        )
        if create:
            root.mkdir(parents=True, exist_ok=True)
        create = False
    options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=create, **extra)
    return ocp.CheckpointManager(root, options=options)


def save(
    mgr: ocp.CheckpointManager, epoch: int, train: Any, env: Any, meta: dict[str, Any]
) -> None:
    """Save host (numpy) trees; blocks until written so a crash cannot leave it half done."""
    ocp = _orbax()
    mgr.save(
        epoch,
        args=ocp.args.Composite(
            train=ocp.args.StandardSave(pack(train)),
            env=ocp.args.StandardSave(pack(env)),
            meta=ocp.args.JsonSave(meta),
        ),
        force=True,
    )
    mgr.wait_until_finished()


def latest_epoch(run_dir: Path) -> int | None:
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        return None
    mgr = manager(run_dir, create=False)
    try:
        return mgr.latest_step()
    finally:
        mgr.close()


def _checkpoint_path(run_dir: Path, epoch: int) -> Path:
    return run_dir / CHECKPOINT_DIR / str(epoch)


def _read_items(mgr: ocp.CheckpointManager, epoch: int, items: tuple[str, ...]) -> dict[str, Any]:
    """The named items of checkpoint ``epoch`` as they were saved (no template: a file that
    does not decode is corruption, not a shape mismatch); ``meta`` is JSON, others arrays."""
    ocp = _orbax()
    args = {k: ocp.args.JsonRestore() if k == "meta" else ocp.args.StandardRestore() for k in items}
    out = dict(mgr.restore(epoch, args=ocp.args.Composite(**args)))
    for k in items:
        damage = "" if k == "meta" else corruption(out[k])
        if damage:  # decoded, but not the bytes that were saved
            raise CheckpointError(f"{k}: {damage}")
    return out


class SkippedCheckpointWarning(UserWarning):
    """The newest checkpoint of a run did not read (empty, corrupt or cut short); an older
    one was used."""


def _newest_clean(
    run_dir: Path, epoch: int | None, items: tuple[str, ...], skip: Callable[[int, str], None]
) -> tuple[int, dict[str, Any]]:
    """``(epoch, items)`` of checkpoint ``epoch``, or without one of the newest checkpoint
    whose items read cleanly, calling ``skip(epoch, reason)`` for each newer one that did
    not (empty, corrupt or cut short). Raises :class:`CheckpointError` naming every failure."""
    mgr = manager(run_dir, create=False)
    try:
        epochs = sorted(mgr.all_steps(), reverse=True) if epoch is None else [epoch]
        if not epochs:
            raise CheckpointError(f"{str(run_dir)!r}: no checkpoints in {CHECKPOINT_DIR}/")
        bad = []
        for ep in epochs:
            try:
                return ep, _read_items(mgr, ep, items)
            except Exception as err:  # orbax raises many types for unreadable files
                text = str(err) if epoch is not None else (str(err).splitlines() or [""])[0]
                reason = f"{type(err).__name__}: {text}"
                bad.append(f"{str(_checkpoint_path(run_dir, ep))!r} ({reason})")
                if epoch is None:
                    skip(ep, reason)
        if epoch is not None:
            raise CheckpointError(f"checkpoint {bad[0]} is corrupt or incomplete")
        raise CheckpointError(
            f"{str(run_dir)!r}: no checkpoint reads cleanly; each is corrupt or incomplete: "
            + "; ".join(bad)
        )
    finally:
        mgr.close()


def _read_checked(run_dir: Path, epoch: int | None, items: tuple[str, ...]) -> tuple[int, dict]:
    """:func:`_newest_clean`, with a :class:`SkippedCheckpointWarning` naming each newer
    checkpoint that did not read, once one did."""
    bad: list[str] = []

    def skip(ep: int, reason: str) -> None:
        bad.append(f"checkpoint {str(_checkpoint_path(run_dir, ep))!r} ({reason})")

    ep, out = _newest_clean(run_dir, epoch, items, skip)
    if bad:
        warnings.warn(
            f"{'; '.join(bad)}: corrupt or incomplete; using epoch {ep}, the newest that "
            "reads cleanly",
            SkippedCheckpointWarning,
            stacklevel=3,
        )
    return ep, out


def restore(
    run_dir: Path,
    train_like: Any,
    env_like: Any,
    epoch: int | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[Any, Any, dict[str, Any]]:
    """Restore the full state of ``epoch`` into trees shaped like the given.

    Without ``epoch``: the newest checkpoint that reads cleanly. A newer one that is
    corrupt or was cut short mid-write is renamed ``<epoch>.corrupt`` (kept for inspection,
    out of the way of the next save) and reported through ``log``. A checkpoint that reads
    but has another shape (an older version's training state) is an error, not skipped.
    """
    say = log or (lambda _: None)
    moved: list[int] = []

    def set_aside(ep: int, reason: str) -> None:
        moved.append(ep)
        path = _checkpoint_path(run_dir, ep)
        aside = path.with_name(f"{ep}.corrupt")
        path.rename(aside)
        say(
            f"checkpoint {str(path)!r} is corrupt or incomplete ({reason}); "
            f"moved to {str(aside)!r} for inspection; trying the previous one"
        )

    ep, out = _newest_clean(run_dir, epoch, ("train", "env", "meta"), set_aside)
    path = _checkpoint_path(run_dir, ep)
    try:
        train = unpack(train_like, out["train"])
        env = unpack(env_like, out["env"])
    except (CheckpointError, KeyError) as err:
        raise CheckpointError(
            f"checkpoint {str(path)!r} reads, but does not fit this run's state: "
            f"{err}. A checkpoint written by an older version of mecanum_jax, whose "
            "training state had another shape, can still be evaluated (mecanum-eval) "
            "but not resumed"
        ) from err
    if moved:
        say(f"resuming from checkpoint {str(path)!r}, the newest that reads cleanly")
    return train, env, dict(out["meta"])


def read_meta(run_dir: Path, epoch: int | None = None) -> tuple[int, dict[str, Any]]:
    epoch, out = _read_checked(run_dir, epoch, ("meta",))
    return epoch, dict(out["meta"])


def read_train(run_dir: Path, epoch: int, train_like: Any) -> Any:
    """The training state of checkpoint ``epoch``, shaped like ``train_like`` (matched by
    leaf name; by index in the leaf-index format); a mismatch names the checkpoint."""
    _, saved = _read_checked(run_dir, epoch, ("train",))
    return _unpack_train(run_dir, epoch, train_like, saved)


def _unpack_train(run_dir: Path, epoch: int, train_like: Any, saved: dict[str, Any]) -> Any:
    try:
        return unpack(train_like, saved["train"])
    except CheckpointError as err:
        where = str(_checkpoint_path(run_dir, epoch))
        raise CheckpointError(f"checkpoint {where!r}: {err}") from err


@dataclasses.dataclass(frozen=True)
class RestoredPolicy:
    """One seed's policy from a checkpoint: config, networks and host parameters."""

    run_dir: Path
    epoch: int
    seed: int
    cfg: Any  # train.config.TrainConfig
    networks: Any  # brax PPONetworks
    normalizer: Any  # running statistics (host arrays)
    params: Any  # policy network parameters (host arrays)
    meta: dict[str, Any]

    def apply(self, params: Any, obs: dict[str, Any]) -> jax.Array:
        """The deterministic action for ``params = (normalizer, policy params)``."""
        from train.periodic import deterministic_apply

        return deterministic_apply(self.networks)(params, obs)


def split_target(path: str | Path) -> tuple[Path, int | None]:
    """A run directory, or one checkpoint ``<run>/checkpoints/<epoch>``: ``(run_dir, epoch)``."""
    path = Path(path)
    if path.parent.name == CHECKPOINT_DIR and path.name.isdigit():
        return path.parent.parent, int(path.name)
    return path, None


def restore_policy(
    run_dir: str | Path, seed: int | None = None, epoch: int | None = None
) -> RestoredPolicy:
    """Restore one seed's policy (not the optimizer or environment) from a run's checkpoint.

    Raises :class:`CheckpointError` naming what is missing, corrupt or mismatched: no
    run directory or checkpoint, unreadable files, a seed the run did not train, or a
    checkpoint whose robot description or observation layout differs from what this code
    builds from the checkpoint's own config (e.g. the robot's TOML file changed since).
    """
    from train.config import parse_train_config

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise CheckpointError(f"run directory {str(run_dir)!r}: no such directory")
    packaged = _provenance(run_dir)
    if epoch is None and packaged.get("epoch") is not None:
        # a model directory evaluates the epoch it was packaged from, not a newer
        # checkpoint that landed beside it (e.g. a model unpacked over another)
        epoch = int(packaged["epoch"])
        if not _checkpoint_path(run_dir, epoch).is_dir():
            raise CheckpointError(
                f"model {str(run_dir)!r}: {PROVENANCE} names epoch {epoch}, which "
                f"{CHECKPOINT_DIR}/ lacks"
            )
    epoch, items = _read_checked(run_dir, epoch, ("train", "meta"))
    meta = dict(items["meta"])
    try:
        cfg = parse_train_config(meta["config"], f"{run_dir}/checkpoint meta")
    except (KeyError, ConfigError) as err:
        raise CheckpointError(
            f"checkpoint {str(run_dir)!r}: bad config in metadata: {err}"
        ) from err
    seeds = list(cfg.run.seeds)
    if seed is None:  # a model directory evaluates the seed it was packaged from
        seed = packaged.get("seed")
    seed = seeds[0] if seed is None else int(seed)
    if seed not in seeds:
        raise CheckpointError(f"seed = {seed}: this run trained seeds {seeds}")
    from mecanum_jax.task.env import MecanumEnv
    from train.state import make_networks, state_template

    # the networks need the task's shapes only: whichever MJX implementation trained it,
    # restoring needs no Warp
    env = MecanumEnv(dataclasses.replace(cfg.env, physics_impl="jax"))
    networks = make_networks(env, cfg)
    check_compatible(meta, env, f"checkpoint {str(run_dir / CHECKPOINT_DIR / str(epoch))!r}")
    train = _unpack_train(run_dir, epoch, state_template(cfg, env, int(meta["devices"])), items)
    one = jax.tree.map(lambda x: x[0, seeds.index(seed)], train)
    return RestoredPolicy(
        run_dir=run_dir,
        epoch=epoch,
        seed=seed,
        cfg=cfg,
        networks=networks,
        normalizer=one.normalizer_params,
        params=one.params.policy,
        meta=meta,
    )


PROVENANCE = "provenance.json"


def _provenance(run_dir: Path) -> dict[str, Any]:
    """A model directory's ``provenance.json`` (empty for a run directory)."""
    path = run_dir / PROVENANCE
    if not path.exists():
        return {}
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError) as err:
        raise CheckpointError(f"{str(path)!r}: unreadable: {err}") from err


def package_model(restored: RestoredPolicy, out: Path, provenance: dict[str, Any]) -> Path:
    """A self-contained model directory from one checkpoint of a run: ``config.json``,
    ``checkpoints/<epoch>/`` with the training state and metadata but not the environment
    state (the robots of every training slot), and ``provenance.json`` (the run, epoch,
    seed, wall time and env steps from the checkpoint, plus ``provenance``). mecanum-eval
    and mecanum-export read it as they read a run directory. Written atomically."""
    src = _checkpoint_path(restored.run_dir, restored.epoch)
    tmp = out.with_name(out.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    dst = tmp / CHECKPOINT_DIR / str(restored.epoch)
    dst.mkdir(parents=True)
    for item in ("train", "meta"):
        shutil.copytree(src / item, dst / item)
    for name in ("_CHECKPOINT_METADATA", "commit_success.txt"):
        if (src / name).exists():
            shutil.copyfile(src / name, dst / name)
    config = restored.run_dir / "config.json"
    if config.exists():
        shutil.copyfile(config, tmp / "config.json")
    meta = restored.meta
    record = {
        "source_run": str(restored.run_dir),
        "epoch": restored.epoch,
        "seed": restored.seed,
        "env_steps": meta.get("env_steps"),
        "walltime_s": meta.get("walltime"),
        "robot": meta.get("robot"),
        "devices": meta.get("devices"),
        **provenance,
    }
    (tmp / PROVENANCE).write_text(json.dumps(record, indent=2) + "\n")
    tmp.rename(out)
    return out


def check_compatible(meta: dict[str, Any], env: Any, what: str) -> None:
    """Refuse a checkpoint whose robot or observation layout differs from ``env``'s."""
    from mecanum_jax.sim.description import fingerprint

    robot = env.desc.robot.name
    if meta.get("robot") not in (None, robot):
        raise CheckpointError(f"{what}: trained on robot {meta.get('robot')!r}, expected {robot!r}")
    saved = meta.get("robot_fingerprint")
    if saved is not None and saved != fingerprint(env.desc):
        raise CheckpointError(
            f"{what}: robot {robot!r} has changed since training (description fingerprint "
            f"{saved}, this code builds {fingerprint(env.desc)}); evaluate with the "
            "description it was trained on"
        )
    layout = [list(x) for x in env.layout]
    if meta.get("observation_layout") != layout:
        raise CheckpointError(
            f"{what}: observation layout {meta.get('observation_layout')}, expected {layout}"
        )
    if int(meta.get("action_size", env.action_size)) != env.action_size:
        raise CheckpointError(
            f"{what}: action size {meta.get('action_size')}, expected {env.action_size}"
        )


def load_policy(
    run_dir: str | Path, seed: int | None = None, epoch: int | None = None
) -> tuple[Callable[[dict[str, Any]], jax.Array], dict[str, Any]]:
    """A deterministic ``policy(obs) -> action`` from a run's checkpoint.

    Args:
      run_dir: the run directory (holding ``checkpoints/``).
      seed: which of the run's seeds (default: the first).
      epoch: which checkpoint (default: the latest; a model directory's packaged one).

    Returns:
      ``(policy, meta)``; ``meta["policy_params"]`` holds the host arrays
      ``(normalizer, policy_params)`` for export.
    """
    from train.state import allow_rank_promotion

    restored = restore_policy(run_dir, seed, epoch)
    params = (restored.normalizer, restored.params)

    @jax.jit
    @allow_rank_promotion
    def act(obs: dict[str, Any]) -> jax.Array:
        return restored.apply(params, obs)

    meta = dict(restored.meta, epoch=restored.epoch, seed=restored.seed, policy_params=params)
    return act, meta


__all__ = [
    "CheckpointError",
    "RestoredPolicy",
    "check_compatible",
    "latest_epoch",
    "load_policy",
    "manager",
    "package_model",
    "read_meta",
    "read_train",
    "restore",
    "restore_policy",
    "save",
    "split_target",
]
