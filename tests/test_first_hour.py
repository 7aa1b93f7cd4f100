"""What a new user meets first: quiet imports, an 80-column progress line, a finished run
resumed, and resume past a corrupt or truncated newest checkpoint."""

import shutil
import subprocess
import sys

import jax
import numpy as np
import pytest

from train import checkpoint
from train.cli import main as train_main
from train.run import _si


def test_importing_the_task_prints_nothing():
    """MJX's optional Warp probe prints 'Failed to import warp' where warp is absent."""
    code = "import mecanum_jax.task.env, train.ppo"
    env = {k: v for k, v in __import__("os").environ.items() if k != "MJX_WARP_ENABLED"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert "warp" not in out.stdout + out.stderr, out.stdout + out.stderr


@pytest.mark.parametrize(
    ("x", "text"), [(0, "0"), (960, "960"), (614_400, "614k"), (1_190_000, "1.19M")]
)
def test_progress_counts_are_short(x, text):
    assert _si(x) == text


def test_resuming_a_finished_run_says_so(full_run, capsys):
    run, _ = full_run
    assert train_main(["--resume", str(run.dir)]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "already finished: epoch 3 of 3" in err
    assert "summary.json" in err


def _compressed_chunks(ckpt):
    chunks = [f for f in ckpt.rglob("d/*") if f.read_bytes()[:4] == bytes.fromhex("28b52ffd")]
    assert chunks, f"no compressed chunk under {ckpt}"
    return chunks


def _corrupt(path):
    data = bytearray(path.read_bytes())
    half = len(data) // 2
    data[4:half] = bytes(half - 4)  # a zeroed frame header and first blocks
    path.write_bytes(bytes(data))


def _truncate(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # cut short mid-write


@pytest.mark.parametrize("damage", [_corrupt, _truncate])
def test_resume_falls_back_past_a_damaged_newest_checkpoint(full_run, learner, tmp_path, damage):
    run, _ = full_run
    copy = tmp_path / "run"
    shutil.copytree(run.dir, copy)
    assert checkpoint.latest_epoch(copy) == 3
    for chunk in _compressed_chunks(copy / "checkpoints" / "3" / "train"):
        damage(chunk)
    state, env_state = learner.init()
    messages: list[str] = []
    host, _, meta = checkpoint.restore(
        copy,
        jax.tree.map(np.asarray, state),
        jax.tree.map(np.asarray, env_state),
        log=messages.append,
    )
    assert meta["epoch"] == 2
    assert "checkpoints/3' is corrupt or incomplete" in messages[0]
    assert "3.corrupt" in messages[0]  # kept for inspection
    assert "checkpoints/2', the newest that reads cleanly" in messages[-1]
    assert (copy / "checkpoints" / "3.corrupt").is_dir()
    assert checkpoint.latest_epoch(copy) == 2
    good, _, _ = checkpoint.restore(
        run.dir, jax.tree.map(np.asarray, state), jax.tree.map(np.asarray, env_state), epoch=2
    )
    for a, b in zip(jax.tree.leaves(host), jax.tree.leaves(good), strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_checkpoint_of_another_shape_is_not_skipped(full_run, learner, tmp_path):
    """Only unreadable checkpoints are skipped; one that reads but does not fit is an error."""
    run, _ = full_run
    state, env_state = learner.init()
    wrong = jax.tree.map(lambda x: np.zeros((*np.shape(x), 2), np.asarray(x).dtype), state)
    with pytest.raises(checkpoint.CheckpointError, match="does not fit this run's state"):
        checkpoint.restore(run.dir, wrong, jax.tree.map(np.asarray, env_state))
    assert checkpoint.latest_epoch(run.dir) == 3  # nothing moved
