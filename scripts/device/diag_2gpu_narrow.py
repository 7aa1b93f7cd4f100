"""Which multi-device constructs crash XLA's GPU compiler (jax 0.11.2, 2 H200s)?

Sessions 3-8 saw ``pmap`` of the PPO epoch, and of the MJX reset alone, segfault inside
``backend_compile_and_load`` on ``nvidia-h200-x2``, while one device compiles. Each case
here runs in its own process (a segfault ends only that case) and prints ``ok`` or dies:

- ``pmap_mjx_box``: ``pmap`` of ``mjx.step`` of a free box on a plane (no project code);
- ``pmap_reset``: ``pmap`` of the environment's reset (the known crash);
- ``shard_map_reset``: the same through ``shard_map`` over a 2-device mesh;
- ``jit_sharded_reset``: plain ``jit`` with the keys sharded over the devices (GSPMD);
- ``jit_sharded_step``: plain ``jit`` of the environment step on sharded states.

    python3 scripts/device/diag_2gpu_narrow.py            # all cases, one process each
    python3 scripts/device/diag_2gpu_narrow.py CASE       # one case
"""

from __future__ import annotations

import subprocess
import sys
import time

CASES = ("pmap_mjx_box", "pmap_reset", "shard_map_reset", "jit_sharded_reset", "jit_sharded_step")
BOX = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/>
<body pos="0 0 .3"><freejoint/><geom type="box" size=".1 .1 .1"/></body></worldbody></mujoco>"""


def run_case(name: str) -> None:
    import jax
    import jax.numpy as jnp
    import mujoco
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec
    from mujoco import mjx

    n = jax.device_count()
    per = 4
    keys = jax.random.split(jax.random.PRNGKey(0), n * per)
    if name == "pmap_mjx_box":
        m = mjx.put_model(mujoco.MjModel.from_xml_string(BOX))
        d = jax.vmap(lambda _: mjx.make_data(m))(jnp.arange(per))
        d = jax.tree.map(lambda x: np.stack([np.asarray(x)] * n), d)  # uncommitted
        out = jax.pmap(jax.vmap(lambda x: mjx.step(m, x)))(d)
        jax.block_until_ready(out.qpos)
    else:
        from mecanum_jax.env import EnvConfig, MecanumEnv, TrainingEnv

        env = TrainingEnv(MecanumEnv(EnvConfig()))
        if name == "pmap_reset":
            out = jax.pmap(env.reset)(keys.reshape(n, per, 2))
        else:
            mesh = Mesh(jax.devices(), ("d",))
            if name == "shard_map_reset":
                f = jax.shard_map(
                    env.reset,
                    mesh=mesh,
                    in_specs=PartitionSpec("d"),
                    out_specs=PartitionSpec("d"),
                )
                out = jax.jit(f)(keys)
            else:
                sharded = jax.device_put(keys, NamedSharding(mesh, PartitionSpec("d")))
                out = jax.jit(env.reset)(sharded)
                if name == "jit_sharded_step":
                    act = jnp.zeros((n * per, env.action_size))
                    act = jax.device_put(act, NamedSharding(mesh, PartitionSpec("d")))
                    out = jax.jit(env.step)(out, act)
        jax.block_until_ready(out.obs)
    print(f"{name}: ok on {n} devices")


def main() -> None:
    if len(sys.argv) > 1:
        if sys.argv[1] not in CASES:
            sys.exit(f"case {sys.argv[1]!r}: expected one of {', '.join(CASES)}")
        run_case(sys.argv[1])
        return
    for name in CASES:
        t = time.time()
        res = subprocess.run(
            [sys.executable, "-X", "faulthandler", __file__, name],
            capture_output=True,
            text=True,
            timeout=300,
        )
        last = [x for x in (res.stdout + res.stderr).splitlines() if "warp" not in x.lower()]
        verdict = (
            last[-1]
            if res.returncode == 0
            else f"rc {res.returncode}: "
            + " | ".join(x for x in last if "Fatal" in x or "Error" in x)[:300]
        )
        print(f"{name:20s} {time.time() - t:5.1f} s  {verdict}", flush=True)


if __name__ == "__main__":
    main()
