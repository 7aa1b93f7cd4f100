"""One seed's policy from a checkpoint, and the model directory that packages it.

:func:`restore_policy` reads only a checkpoint's ``train`` and ``meta`` items
(:mod:`train.store.checkpoint`) into one seed's networks and parameters, refusing a
checkpoint of another robot or observation layout (:func:`check_compatible`);
:func:`load_policy` makes of it a jitted deterministic ``obs -> action`` function for
evaluation and deployment. :func:`package_model` writes a self-contained model directory
(one checkpoint, the config and ``provenance.json``), which both read as a run directory;
a model's ``played_with`` there sets play-time fields (``PLAYED_FIELDS``) over the
checkpoint's config, which keeps what the policy was trained with.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from mecanum_jax import atomic
from mecanum_jax.config import ConfigError
from train.store import inputs
from train.store.checkpoint import CHECKPOINT_DIR, checkpoint_path, read_checked, unpack_train
from train.store.leaves import CheckpointError

if TYPE_CHECKING:
    import numpy as np
    from brax.training.acme.running_statistics import RunningStatisticsState
    from brax.training.agents.ppo.networks import PPONetworks
    from brax.training.types import Params, PolicyParams
    from jax.typing import ArrayLike

    from mecanum_jax.task.shapes import Shaped, TaskShapes
    from train.config import TrainConfig


@dataclasses.dataclass(frozen=True)
class RestoredPolicy:
    """One seed's policy from a checkpoint: config, networks and host parameters."""

    run_dir: Path
    epoch: int
    seed: int
    cfg: TrainConfig
    networks: PPONetworks
    normalizer: RunningStatisticsState  # (host arrays)
    params: Params  # policy network parameters (host arrays)
    meta: dict[str, Any]
    shapes: TaskShapes  # the task's, from its config and robot description (no MJX model)

    def apply(self, params: PolicyParams, obs: dict[str, jax.Array]) -> jax.Array:
        """The deterministic action for ``params = (normalizer, policy params)``."""
        from train.learner.periodic import deterministic_apply

        return deterministic_apply(self.networks)(params, obs)

    def export_arrays(
        self,
    ) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray, dict[str, Any]]:
        """The policy as an export holds it (:mod:`mecanum_jax.deploy.write`): the layers in
        order (Flax's ``hidden_K``), the normalizer's mean and std, and the metadata."""
        import numpy as np

        from mecanum_jax.deploy.write import task_meta

        tree = self.params["params"]
        names = sorted(tree, key=lambda n: int(n.rsplit("_", 1)[-1]))
        layers = [(np.asarray(tree[n]["kernel"]), np.asarray(tree[n]["bias"])) for n in names]
        meta = {
            **task_meta(self.shapes),
            "activation": "swish",  # the trainer's (train/learner/state.py)
            "clip_observations": self.cfg.ppo.clip_observations,
            "source": {"run": str(self.run_dir), "epoch": self.epoch, "seed": self.seed},
        }
        mean = np.asarray(self.normalizer.mean["state"])
        return layers, mean, np.asarray(self.normalizer.std["state"]), meta


def split_target(path: str | Path) -> tuple[Path, int | None]:
    """A run directory, or one checkpoint ``<run>/checkpoints/<epoch>``: ``(run_dir, epoch)``."""
    path = Path(path)
    if path.parent.name == CHECKPOINT_DIR and path.name.isdigit():
        return path.parent.parent, int(path.name)
    return path, None


def restore_policy(
    run_dir: str | Path,
    seed: int | None = None,
    epoch: int | None = None,
    play: dict[str, object] | None = None,
) -> RestoredPolicy:
    """Restore one seed's policy (not the optimizer or environment) from a run's checkpoint;
    ``play``: fields of its task changed at play time (``mecanum-eval --play``), on top of
    a model's own ``played_with``.

    Builds no environment: the shapes and the checks come from the checkpoint's config and
    robot description (:func:`~mecanum_jax.task.shapes.task_shapes`).

    Raises :class:`CheckpointError` naming what is missing, corrupt or mismatched: no
    run directory or checkpoint, unreadable files, a seed the run did not train, or a
    checkpoint whose robot description or observation layout differs from what this code
    builds from the checkpoint's own config (e.g. the robot's TOML file changed since).
    """
    from train.config_loading import parse_train_config, saved_config

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        what = "not a directory" if run_dir.exists() else "no such directory"
        raise CheckpointError(f"run directory {str(run_dir)!r}: {what}")
    check_saved_config(run_dir)
    packaged = _provenance(run_dir)
    if epoch is None and packaged.get("epoch") is not None:
        # a model directory evaluates the epoch it was packaged from, not a newer
        # checkpoint that landed beside it (e.g. a model unpacked over another)
        epoch = int(packaged["epoch"])
        if not checkpoint_path(run_dir, epoch).is_dir():
            raise CheckpointError(
                f"model {str(run_dir)!r}: {PROVENANCE} names epoch {epoch}, which "
                f"{CHECKPOINT_DIR}/ lacks"
            )
    epoch, items = read_checked(run_dir, epoch, ("train", "meta"))
    meta = dict(items["meta"])
    try:
        saved = inputs.use_copies(
            saved_config(meta["config"], f"{run_dir}/checkpoint meta"), run_dir
        )  # the robot it trained on, if copied
        cfg = parse_train_config(saved, f"{run_dir}/checkpoint meta")
    except (KeyError, ConfigError) as err:
        raise CheckpointError(
            f"checkpoint {str(run_dir)!r}: bad config in metadata: {err}"
        ) from err
    if "played_with" in packaged:  # a model played with a controller setting of its own
        from mecanum_jax.task.config import played_with

        where = f"{run_dir / PROVENANCE} played_with"
        try:
            cfg = dataclasses.replace(cfg, env=played_with(cfg.env, packaged["played_with"], where))
        except ConfigError as err:
            raise CheckpointError(str(err)) from None
    if play:  # a probe: refused where it changes what the networks see (check_compatible)
        from mecanum_jax.task.config import changed_env

        cfg = dataclasses.replace(cfg, env=changed_env(cfg.env, play, "--play"))
    seeds = list(cfg.run.seeds)
    if seed is None:  # a model directory evaluates the seed it was packaged from
        seed = packaged.get("seed")
    seed = seeds[0] if seed is None else int(seed)
    if seed not in seeds:
        raise CheckpointError(f"seed = {seed}: this run trained seeds {seeds}")
    from mecanum_jax.task.shapes import task_shapes
    from train.learner.state import make_networks, state_template

    # the networks and the checks need the task's shapes only, from its config and robot
    # description: no MJCF or MJX model is built (nor Warp needed)
    shapes = task_shapes(cfg.env)
    networks = make_networks(shapes, cfg)
    where = f"checkpoint {str(run_dir / CHECKPOINT_DIR / str(epoch))!r}"
    try:
        check_compatible(meta, shapes, where)
    except CheckpointError as err:
        if not play:
            raise
        given = " ".join(f"{k}={v}" for k, v in play.items())
        raise CheckpointError(f"--play {given}: not a play-time change here: {err}") from None
    train = unpack_train(run_dir, epoch, state_template(cfg, shapes, int(meta["devices"])), items)
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
        shapes=shapes,
    )


PROVENANCE = "provenance.json"


def check_saved_config(run_dir: Path) -> None:
    """Refuse a run or model directory whose ``config.json`` is unreadable or invalid
    (truncated, say): it is the task deploy-sim and a resumed run read, and a model
    directory packed from the run would carry it."""
    path = run_dir / "config.json"
    if path.exists() or path.is_symlink():
        try:
            inputs.load_saved_config(run_dir, warn=False)  # the robot: the run's copy
        except ConfigError as err:  # names the file
            raise CheckpointError(str(err)) from None


def _provenance(run_dir: Path) -> dict[str, Any]:
    """A model directory's ``provenance.json`` (empty for a run directory)."""
    path = run_dir / PROVENANCE
    if not path.exists():
        return {}
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError) as err:
        raise CheckpointError(f"{str(path)!r}: unreadable: {err}") from err


def package_model(
    restored: RestoredPolicy,
    out: Path,
    provenance: Mapping[str, object],
    fill: Callable[[Path], object] | None = None,
) -> Path:
    """A self-contained model directory from one checkpoint of a run: ``config.json``,
    ``checkpoints/<epoch>/`` with the training state and metadata but not the environment
    state (the robots of every training slot), and ``provenance.json`` (the run, epoch,
    seed, wall time and env steps from the checkpoint, plus ``provenance``). mecanum-eval
    and mecanum-export read it as they read a run directory. ``fill(folder)`` adds files
    (an export). Written atomically (:func:`mecanum_jax.atomic.directory`): on any error no
    ``out``, and no ``.partial``, remains."""
    with atomic.directory(out) as tmp:
        _pack(restored, tmp, provenance)
        if fill is not None:
            fill(tmp)
    return out


def _pack(restored: RestoredPolicy, tmp: Path, provenance: Mapping[str, object]) -> None:
    src = checkpoint_path(restored.run_dir, restored.epoch)
    dst = tmp / CHECKPOINT_DIR / str(restored.epoch)
    for item in ("train", "meta"):
        atomic.copy_tree(src / item, dst / item)
    for name in ("_CHECKPOINT_METADATA", "commit_success.txt"):
        if (src / name).exists():
            shutil.copyfile(src / name, dst / name)
    config = restored.run_dir / "config.json"
    if config.exists():
        check_saved_config(restored.run_dir)  # never a broken config.json into a model
        shutil.copyfile(config, tmp / "config.json")
    inputs.copy_inputs(restored.run_dir, tmp)
    meta = restored.meta
    # a model packed again keeps how it is played: config.json states the task as played
    played = _provenance(restored.run_dir).get("played_with")
    record = {
        "source_run": str(restored.run_dir),
        "epoch": restored.epoch,
        "seed": restored.seed,
        "env_steps": meta.get("env_steps"),
        "walltime_s": meta.get("walltime"),
        "robot": meta.get("robot"),
        "devices": meta.get("devices"),
        **({} if played is None else {"played_with": played}),
        **provenance,
    }
    (tmp / PROVENANCE).write_text(json.dumps(record, indent=2) + "\n")


def check_compatible(meta: dict[str, Any], env: Shaped, what: str) -> None:
    """Refuse a checkpoint whose robot or observation layout differs from ``env``'s (an
    environment's, or the :class:`~mecanum_jax.task.shapes.TaskShapes` of its config)."""
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
) -> tuple[Callable[[Mapping[str, ArrayLike]], jax.Array], dict[str, Any]]:
    """A deterministic ``policy(obs) -> action`` from a run's checkpoint.

    Args:
      run_dir: the run directory (holding ``checkpoints/``).
      seed: which of the run's seeds (default: the first).
      epoch: which checkpoint (default: the latest; a model directory's packaged one).

    Returns:
      ``(policy, meta)``; ``meta["policy_params"]`` holds the host arrays
      ``(normalizer, policy_params)`` for export.
    """
    from mecanum_jax.task.controller import allow_rank_promotion

    restored = restore_policy(run_dir, seed, epoch)
    params = (restored.normalizer, restored.params)

    @jax.jit
    @allow_rank_promotion
    def act(obs: dict[str, jax.Array]) -> jax.Array:
        return restored.apply(params, obs)

    meta = dict(restored.meta, epoch=restored.epoch, seed=restored.seed, policy_params=params)
    return act, meta


__all__ = [
    "PROVENANCE",
    "RestoredPolicy",
    "check_compatible",
    "load_policy",
    "package_model",
    "restore_policy",
    "split_target",
]
