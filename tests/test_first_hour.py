"""What a new user meets first: quiet imports, an 80-column progress line, a finished run
resumed, and resume past a corrupt or truncated newest checkpoint."""

import ast
import shutil
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from train.cli.train import main as train_main
from train.learner.policy import restore_policy
from train.loop.progress import count as _si
from train.store import checkpoint, leaves


def test_importing_the_task_prints_nothing(fresh_imports):
    """MJX's optional Warp probe prints 'Failed to import warp' where warp is absent
    (a fresh interpreter imports the task and the trainer: ``fresh_imports`` in
    conftest.py)."""
    out, _ = fresh_imports
    assert out.returncode == 0, out.stderr
    assert "warp" not in out.stdout + out.stderr, out.stdout + out.stderr


def test_importing_the_library_and_trainer_leaves_jax_untouched(fresh_imports):
    """``import mecanum_jax`` (its physics, task and evaluation modules) and ``import train``
    change no attribute of the ``jax`` module (in a fresh interpreter: ``fresh_imports`` in
    conftest.py)."""
    proc, findings = fresh_imports
    assert proc.returncode == 0, proc.stderr
    assert findings["changed"] == []


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


def _data_files(ckpt):
    """Every file of the item's OCDBT stores: values and B-tree nodes. Damaging only some
    is not a sure test: which file holds what varies from run to run, and a damaged byte
    range that no live entry points at is, rightly, not an error."""
    files = [f for f in ckpt.rglob("d/*") if f.is_file()]
    assert files, f"no data file under {ckpt}"
    return files


def _corrupt(run_dir):
    for path in _data_files(run_dir / "checkpoints" / "3" / "train"):
        data = bytearray(path.read_bytes())
        data[4:] = bytes(len(data) - 4)  # magic kept, headers and blocks zeroed
        path.write_bytes(bytes(data))


def _truncate(run_dir):
    for path in _data_files(run_dir / "checkpoints" / "3" / "train"):
        path.write_bytes(path.read_bytes()[:16])  # cut short mid-write, just after it began


def _bit_rot(run_dir):
    """Decodes cleanly, but one leaf no longer holds what its checksum was taken of."""
    _, items = checkpoint.read_checked(run_dir, 3, ("train", "env", "meta"))
    train = {k: np.array(v) for k, v in items["train"].items()}
    name = next(k for k, v in train.items() if k != leaves.CHECKSUMS and v.dtype == np.float32)
    train[name].reshape(-1)[0] += np.float32(1.0)
    shutil.rmtree(run_dir / "checkpoints" / "3")
    mgr = checkpoint.manager(run_dir)
    mgr.save(
        3,
        args=ocp.args.Composite(
            train=ocp.args.StandardSave(train),
            env=ocp.args.StandardSave(dict(items["env"])),
            meta=ocp.args.JsonSave(dict(items["meta"])),
        ),
        force=True,
    )
    mgr.wait_until_finished()
    mgr.close()


@pytest.mark.parametrize("damage", [_corrupt, _truncate, _bit_rot])
def test_resume_falls_back_past_a_damaged_newest_checkpoint(full_run, learner, tmp_path, damage):
    run, _ = full_run
    copy = tmp_path / "run"
    shutil.copytree(run.dir, copy)
    assert checkpoint.latest_epoch(copy) == 3
    damage(copy)
    state, env_state = learner.init()
    messages: list[str] = []
    host, _, meta = checkpoint.restore(
        copy,
        jax.tree.map(np.asarray, state),
        jax.tree.map(np.asarray, env_state),
        log=messages.append,
    )
    assert meta["epoch"] == 2, messages
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


def test_error_messages_print_their_brackets():
    """A checkpoint error names leaves such as ``.policy['params']``; rich must not read
    the brackets as markup (and drop them, or fail on ``[/x]``)."""
    from rich.console import Console

    from train.loop.progress import print_error

    console = Console(record=True, width=200, color_system=None)
    message = "2 missing: .policy['params'][bold] and [/x] .nu"
    print_error(console, ValueError(message), "run [a]: diverged")
    assert console.export_text().strip() == f"run [a]: diverged: {message}"


def test_an_empty_newest_checkpoint_is_passed_over_with_a_warning(full_run, tmp_path):
    """A run directory with an empty ``checkpoints/<n>`` (a save cut off before its first
    file, or a stray mkdir) still evaluates: its newest clean checkpoint, named."""
    run, _ = full_run
    copy = tmp_path / "run"
    shutil.copytree(run.dir, copy)
    (copy / "checkpoints" / "4").mkdir()
    assert checkpoint.latest_epoch(copy) == 4
    with pytest.warns(checkpoint.SkippedCheckpointWarning, match=r"checkpoints/4'.*using epoch 3"):
        restored = restore_policy(copy)
    assert restored.epoch == 3
    with pytest.raises(checkpoint.CheckpointError, match=r"checkpoints/4' \("):
        restore_policy(copy, epoch=4)  # an epoch asked for by name is not replaced


def _imports_of(node: ast.AST) -> Iterator[tuple[int, str]]:
    """``(line, module)`` of every import under ``node`` outside ``if TYPE_CHECKING:``."""
    if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
        return
    if isinstance(node, ast.Import):
        yield from ((node.lineno, a.name) for a in node.names)
    elif isinstance(node, ast.ImportFrom) and node.module:
        names = [f"{node.module}.{a.name}" for a in node.names]
        yield from ((node.lineno, n) for n in (node.module, *names))
    for child in ast.iter_child_nodes(node):
        yield from _imports_of(child)


def test_every_module_importing_mjx_or_brax_quiets_the_warp_probe_first():
    """The probe prints in whichever module imports MJX first (Brax imports it): each such
    module imports ``mecanum_jax._quiet_mjx`` above it, so no entry point's import order
    lets the lines through (``mecanum-deploy-sim`` once printed them, by way of the
    evaluation's rollout)."""
    root = Path(__file__).resolve().parent.parent
    loud = ("brax", "mujoco.mjx")
    offenders = []
    for path in sorted([*root.glob("mecanum_jax/**/*.py"), *root.glob("train/**/*.py")]):
        if path.name == "_quiet_mjx.py":
            continue
        found = sorted(_imports_of(ast.parse(path.read_text())))
        first = [line for line, name in found if name.startswith(loud)]
        quiet = [line for line, name in found if name == "mecanum_jax._quiet_mjx"]
        if first and not (quiet and quiet[0] < first[0]):
            offenders.append(f"{path.relative_to(root)}:{first[0]}")
    assert not offenders, offenders
