"""How one epoch's program spreads over the devices (``run.parallel``).

The program is ``fn`` of one seed's states, vmapped over the seeds; its collectives
(gradients, normalizer statistics, metrics) are named :data:`AXIS`. Over the device axis:

- ``"pmap"``: Brax's path, ``jax.pmap``.
- ``"sharded"``: a named ``vmap`` over the devices, jitted with that axis sharded over a
  mesh of all processes' devices; XLA's SPMD partitioner splits the program. With jax
  0.11.2 on 2 GPUs it compiles where ``pmap`` of an MJX step crashes XLA's compiler.
- ``"split"``: each device rolls out its robots in a program of its own, and only the
  update is one program over the mesh (train/learner/split_epoch.py). One process.

The partitioner cannot split a custom call it knows nothing of, such as the FFI call of
MuJoCo Warp's step: on the ``"sharded"`` path it gathers the whole batch onto every
device, so under Warp each GPU simulates every robot (2 H200s: 1.01x one), and
``jax.shard_map`` of the step crashed. ``"split"`` has no program that both holds the
physics and spans devices (2 H200s: 1.96x one; docs/benchmarks.md), so ``"auto"`` takes it
for a Warp run on several GPUs of one process (:func:`choose`). For the same reason a
program that spans several devices draws its random numbers as JAX's unrolled threefry,
not through the GPUs' threefry kernel, another custom call (:func:`partitionable_draws`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jax.stages import Wrapped

from mecanum_jax.tracing import threefry_kernel_on_gpus

if TYPE_CHECKING:
    from train.config import TrainConfig

AXIS = "devices"
"""Name of the device axis in the program's collectives (``jax.lax.pmean``)."""
MESH_AXIS = "d"
"""The device mesh's axis under ``run.parallel = "sharded"`` or ``"split"``."""


def _several_gpus(devices: Sequence[jax.Device]) -> bool:
    return len(devices) > 1 and all(d.platform == "gpu" for d in devices)


def _warp_on_gpus(cfg: TrainConfig, devices: Sequence[jax.Device]) -> bool:
    return cfg.env.description().sim.impl == "warp" and _several_gpus(devices)


def devices_for(cfg: TrainConfig) -> list[jax.Device]:
    """The local devices a run trains on: ``run.max_devices`` of them (0: all), except that
    a Warp run on the ``"sharded"`` path left at 0 on several GPUs takes the first only,
    and says so on stderr: the others would only repeat its physics (see the module)."""
    local = jax.local_devices()
    if cfg.run.max_devices:
        return local[: cfg.run.max_devices]
    if cfg.run.parallel == "sharded" and _warp_on_gpus(cfg, local):
        print(
            f"note: training on 1 of {len(local)} GPUs: under MuJoCo Warp the sharded "
            "path splits no physics, so more GPUs only repeat it (docs/benchmarks.md); "
            "--run.parallel split (or auto) uses them all, --run.max-devices N takes N",
            file=sys.stderr,
        )
        return local[:1]
    return local


def choose(cfg: TrainConfig, devices: Sequence[jax.Device], processes: int) -> str:
    """``run.parallel``, with ``"auto"`` resolved: ``"split"`` for a Warp run on several
    GPUs of one process, ``"sharded"`` for any other run on several GPUs or processes,
    else ``"pmap"``."""
    if cfg.run.parallel != "auto":
        return cfg.run.parallel
    if processes == 1 and _warp_on_gpus(cfg, devices):
        return "split"
    return "sharded" if _several_gpus(devices) or processes > 1 else "pmap"


def partitionable_draws(how: str, devices: Sequence[jax.Device]) -> bool:
    """Where a program spans several ``devices`` (``"sharded"``, and ``"split"``'s update),
    the GPUs' threefry kernel turned off for JAX's unrolled hash, which the partitioner can
    split (:func:`mecanum_jax.tracing.threefry_kernel_on_gpus`); returns whether it was."""
    if how == "pmap" or len(devices) < 2:
        return False
    threefry_kernel_on_gpus(on=False)
    return True


def mesh_sharding(parallel: str, devices: Sequence[jax.Device]) -> NamedSharding | None:
    """The sharding of the ``(D, ...)`` states over a mesh of ``devices`` (``None``: pmap)."""
    if parallel == "pmap":
        return None
    return NamedSharding(Mesh(np.array(devices), (MESH_AXIS,)), PartitionSpec(MESH_AXIS))


def spread(
    fn: Callable[..., object],
    parallel: str,
    devices: Sequence[jax.Device],
    sharding: NamedSharding | None,
) -> Wrapped:
    """``fn`` of one seed's states as one program over seeds and devices (see the module)."""
    if sharding is None:
        return jax.pmap(jax.vmap(fn), axis_name=AXIS, devices=devices)
    return jax.jit(
        jax.vmap(jax.vmap(fn), axis_name=AXIS, spmd_axis_name=MESH_AXIS),
        in_shardings=sharding,
        out_shardings=sharding,
    )


__all__ = [
    "AXIS",
    "MESH_AXIS",
    "choose",
    "devices_for",
    "mesh_sharding",
    "partitionable_draws",
    "spread",
]
