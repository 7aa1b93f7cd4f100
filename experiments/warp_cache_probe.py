"""Does MuJoCo Warp survive JAX's persistent compilation cache when XLA's command buffers
are off? (GPU only; docs/benchmarks.md, "Compiling ahead under Warp fails".)

The product leaves the cache in any process that builds Warp physics
(``mecanum_jax.sim.warp_cache``): a program read back from it failed on an H100 with
``Warp error: unknown stream``. The untried remedy is ``XLA_FLAGS=
--xla_gpu_enable_command_buffer=``: with XLA's CUDA-graph capture off, Warp's FFI
handler never starts an *external* capture on XLA's stream. This probe keeps the cache
on (the product's guard patched out, in this process only) and runs ``train.coldstart``
with the flags it is given, so two calls with one cache directory are a cold and a warm
start::

    XLA_FLAGS=--xla_gpu_enable_command_buffer= python experiments/warp_cache_probe.py \
        --env.physics-impl warp --compilation-cache /tmp/probe-cache --json-out cold.json

It prints the XLA flags in force and exits with train.coldstart's code; a Warp error in
the warm call is the answer "no".
"""

from __future__ import annotations

import os
import sys

import mecanum_jax.sim.physics as physics


def main(argv: list[str]) -> int:
    print(f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}; the persistent cache is kept")
    physics.leave_the_persistent_cache = lambda: False  # type: ignore[assignment]
    from train.coldstart import main as coldstart

    return coldstart(["--config", "gpu", *argv])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
