"""Write tests/data/checkpoints/: one training state in both checkpoint formats.

    .venv/bin/python tests/data/write_checkpoints.py

The state is configs/train/tiny.toml's after one epoch (seed 0, one CPU device): its
optimizer moments are non-zero, so no two of its same-shape leaves are alike. It is
written, as a model directory holds it (``train`` and ``meta``, no environment state), as

- ``named/``: the current format (leaves by name, with checksums; ``train.store.leaves.pack``);
- ``index/``: the leaf-index format of earlier versions (``{"00000": leaf 0, ...}``), as
  ``train.store.checkpoint`` wrote it until named leaves replaced it;
- ``expected.npz``: every leaf by name, what both must restore to, bit for bit.

The committed files are never rewritten: tests/test_checkpoint_format.py checks that the
code of the day still restores what earlier code wrote.
"""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

HERE = Path(__file__).resolve().parent / "checkpoints"


def index_pack(tree: Any) -> dict[str, np.ndarray]:
    """The leaf-index format, as ``train.store.checkpoint.pack`` wrote it before."""
    leaves = jax.tree.leaves(tree)
    return {f"{i:05d}": np.asarray(x) for i, x in enumerate(leaves) if math.prod(np.shape(x))}


def write(folder: Path, train: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    options = ocp.CheckpointManagerOptions(create=True)
    mgr = ocp.CheckpointManager((folder / "checkpoints").absolute(), options=options)
    mgr.save(
        1,
        args=ocp.args.Composite(train=ocp.args.StandardSave(train), meta=ocp.args.JsonSave(meta)),
        force=True,
    )
    mgr.wait_until_finished()
    mgr.close()


def main() -> int:
    sys.path.insert(0, str(HERE.parent.parent.parent))
    from train.config_loading import load_train_config
    from train.learner.ppo import Learner
    from train.learner.transfer import to_host
    from train.store.leaves import named_leaves, pack

    if HERE.exists():
        print(f"{HERE} exists: the committed fixtures are never rewritten", file=sys.stderr)
        return 1
    cfg = load_train_config("tiny")
    learner = Learner(cfg)
    state, env_state = learner.init()
    state, _, _ = learner.epoch(state, env_state)
    host = to_host(state)
    meta = {"config": cfg.to_dict(), "devices": learner.n_devices, "epoch": 1}
    try:
        write(HERE / "named", pack(host), meta)
        write(HERE / "index", index_pack(host), meta)
        np.savez(HERE / "expected.npz", **{n: np.asarray(x) for n, x in named_leaves(host)})
    except BaseException:
        shutil.rmtree(HERE, ignore_errors=True)
        raise
    print(f"wrote {HERE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
