"""The sections of a training config (:class:`train.config.TrainConfig`): the networks,
PPO's hyper-parameters, and the run's seeds, cadences and devices, as frozen dataclasses
whose fields document every key of the ``[network]``, ``[ppo]`` and ``[run]`` tables of
``configs/train/*.toml``. :meth:`train.config.TrainConfig.validate` checks their values.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from train.loss_config import AnchorConfig, SmoothnessConfig


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
    init_noise_std: float = 0.075
    """Initial exploration standard deviation of the policy's actions (> 0)."""


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters with Brax's meanings.

    One training iteration collects batch_size · num_minibatches trajectories of
    unroll_length steps from num_envs environments, then runs
    num_updates_per_batch passes of num_minibatches gradient steps.
    """

    num_timesteps: int = 85_000_000
    """Environment steps to train for, over all environments (>= 1)."""
    num_envs: int = 32_768
    """Parallel environments (>= 1; divides batch_size · num_minibatches)."""
    unroll_length: int = 20
    """Control steps per collected trajectory (>= 1)."""
    batch_size: int = 4096
    """Trajectories per minibatch (>= 1)."""
    num_minibatches: int = 16
    """Minibatches per pass over the collected data (>= 1)."""
    num_updates_per_batch: int = 4
    """Passes over the collected data per iteration (>= 1)."""
    learning_rate: float = 1e-3
    """Adam learning rate (> 0)."""
    learning_rate_final: float = 0.1
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
    update_precision: Literal["run", "default", "high", "highest"] = "default"
    """Matmul precision of the update's forward and backward passes (train/learner/losses.py
    at_precision): run keeps run.matmul_precision; default lets an
    NVIDIA GPU use TF32 there. Rollouts and evaluations keep the run's precision."""
    smoothness: SmoothnessConfig = SmoothnessConfig()
    """CAPS-style smoothness terms in the policy loss (train/learner/losses.py)."""
    anchor: AnchorConfig = AnchorConfig()
    """No correction where the base controller is exact (train/learner/losses.py; needs
    env.residual_space = "twist": a direct-rate config sets weight = 0)."""


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
    epoch_iterations: int = 5
    """Training iterations per compiled call; logging happens between calls (>= 1)."""
    eval_every: int = 8
    """Evaluate every this many epochs, and at the end (>= 1)."""
    checkpoint_every: int = 10
    """Checkpoint every this many epochs, and at the end (>= 1)."""
    max_checkpoints: int = 3
    """Checkpoints kept in the run directory (>= 1)."""
    eval_seed: int = 20_261_122
    """Seed of the held-out evaluation episodes (not one of the training seeds)."""
    num_eval_envs: int = 2048
    """Episodes per periodic evaluation scenario (>= 1)."""
    eval_fidelity: Literal["fast", "reference"] = "fast"
    """Physics model of the periodic evaluation: "fast" (the training model) or "reference"
    (the roller model at its own timestep; slower, docs/evaluation.md)."""
    eval_episode_length: int = 500
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


__all__ = ["NetworkConfig", "PPOConfig", "RunConfig"]
