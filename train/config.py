"""The trainer's configuration: a whole run's :class:`TrainConfig` and its value checks.

Its sections' fields are in :mod:`train.config_sections`; :mod:`train.config_loading`
reads it from ``configs/train/*.toml`` or a run's ``config.json``, with command-line flags
over it. Every key is validated (type by :func:`mecanum_jax.config.from_mapping` on load,
value by :meth:`TrainConfig.validate`) and unknown keys are rejected, all before anything
compiles; each config is checked once, however many layers ask
(:func:`mecanum_jax.config.validated_once`). The resolved configuration is saved as
``config.json`` in each run directory.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from typing import Any

from mecanum_jax.config import ConfigError, invalid, require, validated_once
from mecanum_jax.task import EnvConfig
from mecanum_jax.task.fidelity import check_task
from train.config_sections import NetworkConfig, PPOConfig, RunConfig


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


__all__ = ["TrainConfig"]
