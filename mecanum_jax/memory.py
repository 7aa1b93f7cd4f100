"""Memory guards: refuse a job whose estimated footprint exceeds the memory there is,
before anything is built (an allocation that fails half an hour in, or a machine that
swaps, is worse than a line saying what to change).

:func:`available_bytes` is what the device can still hold: a GPU's free memory where the
backend reports it, else the host's available memory (``/proc/meminfo``'s MemAvailable),
capped by the process's address-space limit (``ulimit -v``). The estimates are linear in
the batch, with constants from the peak resident memory of small CPU runs and the
simulator state's size (each constant's docstring gives its measurement). They are rough
(tens of percent): meant to refuse a batch that cannot fit, not to tune one that nearly does.
"""

from __future__ import annotations

import os
import resource

import jax

from mecanum_jax.config import ConfigError

BASE_BYTES = 2_560 * 2**20
"""What a training or evaluation process holds besides its batch: Python, JAX, MuJoCo and
XLA compiling the programs. Measured (2-core CPU, jax 0.10.2, ``/usr/bin/time -v``): the
tiny config's peak RSS was 2.44-2.54 GiB with 256 or 2048 environments at unroll 10, so
this constant is the larger and the environments' share is below that spread."""
TRAIN_ENV_BYTES = 40 * 2**10
"""Per training (or evaluation) environment: its simulator state, 9.9 KB (``jax.eval_shape``
of the tiny task's reset), times four for the physics step's temporaries. The runs above
bound it: 1792 more environments raised the peak by less than the 0.1 GiB noise, i.e.
less than ~56 KB each."""
TRAIN_STEP_BYTES = 10 * 2**10
"""Per collected transition (trajectories × unroll length): the rollout and its gradient
passes. Measured: 256 environments at unroll 80 peaked 0.17 GiB above unroll 10 (17,920
more transitions, ~10 KB each)."""
EVAL_STEP_BYTES = 512
"""Per robot, controller and control step of an evaluation: the recorded traces (about 30
float32: twist, command, wheel rates, pose, power) with room for the metrics' copies."""
FRACTION = 0.9
"""The share of the available memory an estimate may take."""


def available_bytes() -> int:
    """Bytes the first device can still allocate (see the module docstring)."""
    dev = jax.devices()[0]
    try:
        stats = dev.memory_stats()
    except Exception:
        stats = None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    free = _meminfo_available()
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        free = min(free, max(0, soft - _virtual_bytes()))
    return free


def _meminfo_available() -> int:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES"))


def _virtual_bytes() -> int:
    """The process's address space now (what ``ulimit -v`` limits)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


def training_bytes(num_envs: int, trajectories: int, unroll_length: int) -> int:
    """The estimated peak memory of training ``num_envs`` environments that collect
    ``trajectories`` × ``unroll_length`` transitions per iteration (all seeds together);
    its periodic evaluation is :func:`evaluation_bytes`."""
    return BASE_BYTES + num_envs * TRAIN_ENV_BYTES + trajectories * unroll_length * TRAIN_STEP_BYTES


def evaluation_bytes(robots: int, steps: int, players: int) -> int:
    """The estimated peak memory of one evaluation rollout of ``robots`` robots over
    ``steps`` control steps, played by ``players`` controllers (policy and references)."""
    return BASE_BYTES + robots * players * (TRAIN_ENV_BYTES + steps * EVAL_STEP_BYTES)


def require_memory(need: int, what: str, fix: str) -> None:
    """Raise :class:`ConfigError` in one line when ``need`` bytes (an estimate) exceed
    :data:`FRACTION` of :func:`available_bytes`; ``what`` names the job, ``fix`` the way
    to make it smaller."""
    have = available_bytes()
    if need > FRACTION * have:
        dev = jax.devices()[0]
        raise ConfigError(
            f"{what}: needs about {_gib(need)} (estimated before building anything), more "
            f"than {FRACTION:.0%} of the {_gib(have)} available on {dev.platform} "
            f"({dev.device_kind}); {fix}"
        )


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB"


__all__ = ["BASE_BYTES", "available_bytes", "evaluation_bytes", "require_memory", "training_bytes"]
