"""The trainer's configuration: frozen dataclasses read from ``configs/train/*.toml``.

Every key is validated (type by :func:`mecanum_jax.config.from_mapping`, value by
:meth:`TrainConfig.validate`) and unknown keys are rejected, all before anything compiles.
Command-line overrides are tyro flags over the same dataclasses (``--ppo.learning-rate``),
applied before the values are checked (:func:`load_train_config`); each config is checked
once, however many layers ask (:func:`mecanum_jax.config.validated_once`).
The resolved configuration is saved as ``config.json`` in each run directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

from mecanum_jax.config import (
    CONFIG_DIR,
    ConfigError,
    find_config,
    from_mapping,
    invalid,
    load_toml,
    require,
    validated_once,
)
from mecanum_jax.task import EnvConfig
from mecanum_jax.task.fidelity import check_task
from train.loss_config import AnchorConfig, SmoothnessConfig

TRAIN_CONFIG_DIR = CONFIG_DIR / "train"


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Policy and value MLPs (Brax's make_ppo_networks), swish activations; the value
    function also sees the true twist and the randomized parameters (the privileged
    critic), and the policy's mean output starts at 0 (with residual actions: exactly the
    base)."""

    policy_hidden: tuple[int, ...] = (128, 128, 128)
    """Hidden layer sizes of the policy MLP (at least one, each >= 1)."""
    value_hidden: tuple[int, ...] = (256, 256, 256)
    """Hidden layer sizes of the value MLP (at least one, each >= 1)."""
    init_noise_std: float = 0.5
    """Initial exploration standard deviation of the policy's actions (> 0)."""


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters with Brax's meanings.

    One training iteration collects batch_size · num_minibatches trajectories of
    unroll_length steps from num_envs environments, then runs
    num_updates_per_batch passes of num_minibatches gradient steps.
    """

    num_timesteps: int = 400_000
    """Environment steps to train for, over all environments (>= 1)."""
    num_envs: int = 64
    """Parallel environments (>= 1; divides batch_size · num_minibatches)."""
    unroll_length: int = 20
    """Control steps per collected trajectory (>= 1)."""
    batch_size: int = 64
    """Trajectories per minibatch (>= 1)."""
    num_minibatches: int = 4
    """Minibatches per pass over the collected data (>= 1)."""
    num_updates_per_batch: int = 4
    """Passes over the collected data per iteration (>= 1)."""
    learning_rate: float = 3e-4
    """Adam learning rate (> 0)."""
    learning_rate_final: float = 1.0
    """The learning rate at num_timesteps, as a fraction of learning_rate, reached by a
    cosine decay over the run's updates (in [0, 1]; 1: constant)."""
    entropy_cost: float = 1e-3
    """Weight of the policy entropy bonus (>= 0)."""
    discounting: float = 0.97
    """Discount factor per control step, in (0, 1]."""
    gae_lambda: float = 0.95
    """GAE λ, in (0, 1]."""
    clipping_epsilon: float = 0.2
    """PPO ratio clip (> 0)."""
    max_grad_norm: float = 1.0
    """Gradient norm clip, of the policy's and the value function's gradients apart (> 0)."""
    reward_scaling: float = 1.0
    """Multiplies rewards before the loss (> 0)."""
    clip_observations: float = 5.0
    """Clip the observations, normalized by their running mean and standard deviation, to
    ± this many standard deviations (>= 0; 0: off)."""
    update_precision: Literal["run", "default", "high", "highest"] = "run"
    """Matmul precision of the update's forward and backward passes (train/learner/losses.py
    at_precision): run keeps run.matmul_precision; default lets an
    NVIDIA GPU use TF32 there. Rollouts and evaluations keep the run's precision."""
    smoothness: SmoothnessConfig = SmoothnessConfig()
    """CAPS-style smoothness terms in the policy loss (train/learner/losses.py; off by default)."""
    anchor: AnchorConfig = AnchorConfig()
    """No yaw correction where the base controller is exact (train/learner/losses.py; off by
    default; needs env.residual_space = "twist")."""


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Seeds, evaluation, checkpoints, devices.

    seeds are trained side by side, vectorized in one program (jax.vmap).
    parallel spreads that program over the devices: "pmap" (Brax's path) or
    "sharded" (jit with the device axis sharded over a mesh; the collectives are
    those of a named vmap). With jax 0.11.2 on 2 GPUs, pmap (and shard_map)
    of any MJX step crashes XLA's compiler, while sharded jit compiles; "auto"
    picks "sharded" for several GPUs or several processes (--distributed),
    "pmap" otherwise, except "split" for MuJoCo Warp on several GPUs of one
    process: each device's rollouts in a program of its own and only the update over the
    mesh, since the mesh cannot split Warp's step (train/learner/parallel.py,
    train/learner/split_epoch.py).
    epoch_iterations training iterations run per compiled call; logging, the NaN
    check and Ctrl-C checkpoints happen between calls.
    """

    seeds: tuple[int, ...] = (0,)
    """Training seeds, trained side by side in one program (distinct, 0 <= seed < 2**32)."""
    epoch_iterations: int = 10
    """Training iterations per compiled call; logging happens between calls (>= 1)."""
    eval_every: int = 1
    """Evaluate every this many epochs, and at the end (>= 1)."""
    checkpoint_every: int = 1
    """Checkpoint every this many epochs, and at the end (>= 1)."""
    max_checkpoints: int = 3
    """Checkpoints kept in the run directory (>= 1)."""
    eval_seed: int = 20_261_122
    """Seed of the held-out evaluation episodes (not one of the training seeds)."""
    num_eval_envs: int = 32
    """Episodes per periodic evaluation scenario (>= 1)."""
    eval_fidelity: Literal["fast", "reference"] = "fast"
    """Physics model of the periodic evaluation: "fast" (the training model) or "reference"
    (the roller model at its own timestep; slower, docs/evaluation.md)."""
    eval_episode_length: int = 250
    """Control steps per evaluation episode (>= 1)."""
    max_devices: int = 0
    """Use at most this many local devices (>= 0; 0: all, but one GPU under MuJoCo Warp on
    the "sharded" path: train/learner/parallel.py)."""
    matmul_precision: Literal["default", "high", "highest"] = "highest"
    """jax's default matmul precision for the run."""
    parallel: Literal["auto", "pmap", "sharded", "split"] = "auto"
    """How the program spreads over devices: "pmap", "sharded", "split", or "auto"."""
    wandb_project: str = ""
    """Also log to this Weights & Biases project (needs pip install wandb; empty: off)."""
    progress_every_s: float = 30.0
    """Where the log stream is not a terminal (> log 2>&1, nohup, SLURM): a plain
    progress line every this many seconds, and one at each evaluation (> 0)."""


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """A whole training run."""

    name: str = "run"
    """The run's name: its directory under runs/ (no slashes or spaces)."""
    env: EnvConfig = EnvConfig()
    """The task."""
    network: NetworkConfig = NetworkConfig()
    """The networks."""
    ppo: PPOConfig = PPOConfig()
    """PPO."""
    run: RunConfig = RunConfig()
    """Seeds, evaluation, checkpoints, devices."""

    @validated_once  # each config once, however many layers ask
    def validate(self) -> TrainConfig:
        """Value checks (types were checked on load); raise :class:`ConfigError`."""
        if not self.name or any(c in self.name for c in "/\\ \t\n"):
            raise invalid("name", self.name, "must be a non-empty name without slashes or spaces")
        self.env.validate("env")
        n = self.network
        for field in ("policy_hidden", "value_hidden"):
            sizes = getattr(n, field)
            if not sizes or any(s < 1 for s in sizes):
                raise invalid(
                    f"network.{field}", list(sizes), "need at least one layer, sizes >= 1"
                )
        require(n, "network", ("init_noise_std",), lambda v: v > 0, "must be > 0")
        p = self.ppo
        counts = (
            "num_timesteps",
            "num_envs",
            "unroll_length",
            "batch_size",
            "num_minibatches",
            "num_updates_per_batch",
        )
        require(p, "ppo", counts, lambda v: v >= 1, "must be >= 1")
        require(
            p,
            "ppo",
            ("learning_rate", "max_grad_norm", "reward_scaling", "clipping_epsilon"),
            lambda v: v > 0,
            "must be > 0",
        )
        require(p, "ppo", ("entropy_cost",), lambda v: v >= 0, "must be >= 0")
        require(p, "ppo", ("learning_rate_final",), lambda v: 0 <= v <= 1, "must be in [0, 1]")
        require(p, "ppo", ("clip_observations",), lambda v: v >= 0, "must be >= 0 (0: off)")
        p.smoothness.validate("ppo.smoothness")
        p.anchor.validate("ppo.anchor")
        twist = self.env.residual and self.env.residual_space == "twist"
        if p.anchor.enabled and not twist:
            raise invalid(
                "ppo.anchor.weight",
                p.anchor.weight,
                "needs a twist-space residual (env.residual = true, env.residual_space = "
                '"twist"): it penalizes parts of the twist correction',
            )
        rand = self.env.randomization
        if p.anchor.enabled and rand.enabled and rand.nominal_share == 0:
            raise invalid(
                "ppo.anchor.weight",
                p.anchor.weight,
                "acts on nominal robots only, and env.randomization.nominal_share = 0 trains "
                "none: give it a share (gpu.toml: 0.25) or set the weight to 0",
            )
        require(p, "ppo", ("discounting", "gae_lambda"), lambda v: 0 < v <= 1, "must be in (0, 1]")
        if (p.batch_size * p.num_minibatches) % p.num_envs:
            raise invalid(
                "ppo.num_envs",
                p.num_envs,
                f"must divide batch_size * num_minibatches = {p.batch_size * p.num_minibatches}",
            )
        r = self.run
        check_wandb(r.wandb_project)
        if not r.seeds:
            raise invalid("run.seeds", [], "need at least one seed")
        if len(set(r.seeds)) != len(r.seeds):
            raise invalid("run.seeds", list(r.seeds), "seeds must be distinct")
        if any(s < 0 for s in r.seeds):
            raise invalid("run.seeds", list(r.seeds), "seeds must be >= 0")
        if any(s >= 2**32 for s in r.seeds):  # JAX's key of a larger one wraps onto another
            raise invalid("run.seeds", list(r.seeds), "seeds must be < 2**32")
        if r.eval_seed in r.seeds:
            raise invalid("run.eval_seed", r.eval_seed, "must differ from the training seeds")
        cadences = (
            "epoch_iterations",
            "eval_every",
            "checkpoint_every",
            "max_checkpoints",
            "num_eval_envs",
            "eval_episode_length",
        )
        require(r, "run", cadences, lambda v: v >= 1, "must be >= 1")
        require(r, "run", ("max_devices",), lambda v: v >= 0, "must be >= 0 (0: all local devices)")
        require(r, "run", ("progress_every_s",), _positive_finite, "must be > 0 seconds")
        check_task(self.env, r.eval_fidelity, "run.eval_fidelity")
        return self

    def check_devices(self, device_count: int) -> None:
        """Checks that depend on how many devices train (before compiling)."""
        p = self.ppo
        if p.num_envs % device_count:
            raise ConfigError(
                f"ppo.num_envs = {p.num_envs}: must be a multiple of the {device_count} devices"
            )
        if p.batch_size % device_count:
            raise ConfigError(
                f"ppo.batch_size = {p.batch_size}: must be a multiple of the {device_count} devices"
            )

    @property
    def steps_per_iteration(self) -> int:
        p = self.ppo
        return p.batch_size * p.num_minibatches * p.unroll_length

    @property
    def num_iterations(self) -> int:
        """Training iterations: enough to reach ``ppo.num_timesteps``."""
        return -(-self.ppo.num_timesteps // self.steps_per_iteration)

    @property
    def num_epochs(self) -> int:
        return -(-self.num_iterations // self.run.epoch_iterations)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _positive_finite(v: float) -> bool:
    return 0 < v < math.inf


def check_wandb(project: str) -> None:
    """Fail before training when ``run.wandb_project`` is set and wandb is missing."""
    if project and importlib.util.find_spec("wandb") is None:
        raise ConfigError(
            f"run.wandb_project = {project!r}: needs the wandb package (pip install wandb); "
            "leave it empty to log to metrics.jsonl and TensorBoard only"
        )


def parse_train_config(data: Any, source: str, validate: bool = True) -> TrainConfig:
    """The config of the mapping ``data``; errors name ``source``. ``validate=False``: the
    types checked, the values left to :func:`apply_flags` (given ``source``)."""
    with _named(source):
        cfg = from_mapping(TrainConfig, data)
        return cfg.validate() if validate else cfg


@contextlib.contextmanager
def _named(source: str) -> Iterator[None]:
    """A :class:`ConfigError` raised inside, named with ``source``, the values' file."""
    try:
        yield
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None


def load_train_config(
    path: str | Path,
    flags: list[str] | None = None,
    prog: str = "mecanum-train",
    description: str = "",
) -> TrainConfig:
    """Load a training config from TOML, or from a run directory's ``config.json``.

    A bare name (``quick``) means ``configs/train/<name>.toml``. ``flags``: command-line
    flags over its fields (:func:`apply_flags`), its values checked once, after them.
    """
    p = find_config(path, TRAIN_CONFIG_DIR, "config", "built-in config")
    try:
        data = json.loads(p.read_text()) if p.suffix == ".json" else load_toml(p)
    except json.JSONDecodeError as err:
        raise ConfigError(f"config file {str(p)!r}: invalid JSON: {err}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"config file {str(p)!r}: not a text file (UTF-8)") from None
    except OSError as err:
        raise ConfigError(f"config file {str(p)!r}: unreadable: {err.strerror}") from None
    if flags is None:
        return parse_train_config(data, str(p))
    base = parse_train_config(data, str(p), validate=False)
    return apply_flags(base, flags, prog, description, source=str(p))


def apply_flags(
    base: TrainConfig,
    flags: list[str],
    prog: str = "mecanum-train",
    description: str = "",
    source: str = "",
) -> TrainConfig:
    """``base`` with command-line flags over its fields (``--ppo.learning-rate 1e-3``),
    parsed by tyro as ``mecanum-train`` parses them, then validated (``base`` itself where
    they change nothing). ``source``: the file of a ``base`` not yet validated; an error
    in a value of its own names the file, as :func:`parse_train_config` does."""
    import tyro

    cfg = tyro.cli(
        TrainConfig,
        default=base,
        args=flags,
        prog=prog,
        description=description,
        config=(tyro.conf.FlagConversionOff,),
    )
    if cfg == base:
        cfg = base  # checked once, whichever layer asks first
    try:
        return cfg.validate()
    except ConfigError:
        if source:  # the file's own error first, named with the file
            with _named(source):
                base.validate()
        raise


def config_diff(a: Any, b: Any, where: str = "") -> list[str]:
    """Dotted paths of the fields that differ between two configs."""
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        out = []
        for f in dataclasses.fields(a):
            path = f"{where}.{f.name}" if where else f.name
            out += config_diff(getattr(a, f.name), getattr(b, f.name), path)
        return out
    return [] if a == b else [where]


__all__ = [
    "TRAIN_CONFIG_DIR",
    "NetworkConfig",
    "PPOConfig",
    "RunConfig",
    "TrainConfig",
    "apply_flags",
    "config_diff",
    "load_train_config",
    "parse_train_config",
]
