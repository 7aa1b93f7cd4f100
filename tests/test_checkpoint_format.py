"""The checkpoint format: leaves stored and restored by name, with checksums; the
leaf-index format of earlier versions still restores.

tests/data/checkpoints/ holds one training state of the tiny config in both formats,
written once (tests/data/write_checkpoints.py) and never rewritten: each must restore,
bit for bit, with the code of the day.
"""

import dataclasses
import shutil
import typing
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from mecanum_jax.task.env import MecanumEnv
from train.config_loading import parse_train_config, with_absent
from train.learner.state import state_template
from train.store import checkpoint, leaves

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data" / "checkpoints"
EPOCH = 1
# two leaves of one shape and different data: Adam's first and second moments
MU = ".optimizer_state[1][0].mu.policy['params']['hidden_0']['kernel']"
NU = ".optimizer_state[1][0].nu.policy['params']['hidden_0']['kernel']"


@pytest.fixture(scope="module")
def template():
    """Zeros shaped like the stored state, built by today's code from the stored config."""
    _, meta = checkpoint.read_meta(DATA / "named")
    cfg = parse_train_config(with_absent(meta["config"]), "tests/data checkpoint meta")
    env = MecanumEnv(dataclasses.replace(cfg.env, physics_impl="jax"))
    return state_template(cfg, env, int(meta["devices"]))


@pytest.fixture(scope="module")
def expected():
    with np.load(DATA / "expected.npz") as f:
        return {k: f[k] for k in f.files}


def raw_train(run_dir: Path) -> dict[str, np.ndarray]:
    """The ``train`` item as stored: ``{key: array}``."""
    _, items = checkpoint.read_checked(run_dir, EPOCH, ("train", "meta"))
    return {k: np.asarray(v) for k, v in items["train"].items()}


def write_raw(
    run_dir: Path, train: dict[str, np.ndarray], source: Path, damaged: bool = False
) -> Path:
    """A copy of ``source``'s checkpoint whose ``train`` item is ``train`` (keys as given):
    as another version would have written it (checksums of ``train`` as it is), or, if
    ``damaged``, with the checksums it holds (data that changed after they were taken)."""
    if not damaged and leaves.CHECKSUMS in train:
        train = leaves.with_checksums(train)
    _, meta = checkpoint.read_meta(source)
    mgr = checkpoint.manager(run_dir)
    args = ocp.args.Composite(train=ocp.args.StandardSave(train), meta=ocp.args.JsonSave(meta))
    mgr.save(EPOCH, args=args, force=True)
    mgr.wait_until_finished()
    mgr.close()
    return run_dir


@pytest.mark.parametrize("fmt", ["named", "index"])
def test_stored_checkpoints_restore_bit_identically(fmt, template, expected):
    assert leaves.is_index_format(raw_train(DATA / fmt)) == (fmt == "index")
    restored = checkpoint.read_train(DATA / fmt, EPOCH, template)
    got = dict(leaves.named_leaves(restored))
    assert sorted(got) == sorted(expected)
    for name, want in expected.items():
        assert got[name].dtype == want.dtype, name
        np.testing.assert_array_equal(got[name], want, err_msg=name)
    assert not np.array_equal(expected[MU], expected[NU])  # the swap below changes data


def test_swapped_leaves_are_refused_naming_both(template, tmp_path):
    """Two same-shape leaves stored under each other's names: the checksums catch it."""
    train = raw_train(DATA / "named")
    assert train[MU].shape == train[NU].shape
    train[MU], train[NU] = train[NU], train[MU]
    run = write_raw(tmp_path / "swapped", train, DATA / "named", damaged=True)
    with pytest.raises(checkpoint.CheckpointError) as err:
        checkpoint.read_train(run, EPOCH, template)
    message = str(err.value)
    assert f"{MU} (holds the data saved as {NU})" in message
    assert f"{NU} (holds the data saved as {MU})" in message
    assert "swapped or corrupt" in message


def test_changed_data_is_refused(template, tmp_path):
    train = raw_train(DATA / "named")
    train[MU] = train[MU] + np.float32(1e-3)
    run = write_raw(tmp_path / "changed", train, DATA / "named", damaged=True)
    with pytest.raises(checkpoint.CheckpointError, match=r"1 not holding the data .*mu\.policy"):
        checkpoint.read_train(run, EPOCH, template)


def test_renamed_and_misshaped_leaves_are_named(template, tmp_path):
    """What an upgrade that renames or reshapes leaves looks like: every one is named."""
    train = raw_train(DATA / "named")
    renamed = {MU.replace(".mu.", ".m."): train.pop(MU), NU.replace(".nu.", ".v."): train.pop(NU)}
    run = write_raw(tmp_path / "renamed", {**train, **renamed}, DATA / "named")
    with pytest.raises(checkpoint.CheckpointError) as err:
        checkpoint.read_train(run, EPOCH, template)
    message = str(err.value)
    assert f"2 missing from the checkpoint: {MU}, {NU}" in message
    assert "2 not in this state: " in message
    assert all(k in message for k in renamed)
    assert str(run / "checkpoints" / str(EPOCH)) in message

    train = raw_train(DATA / "named")
    train[MU] = train[MU][..., :3]
    run = write_raw(tmp_path / "misshaped", train, DATA / "named")
    with pytest.raises(checkpoint.CheckpointError, match=r"of another shape: .*mu\.policy.*"):
        checkpoint.read_train(run, EPOCH, template)


def test_the_index_format_restores_a_swap_silently(template, tmp_path):
    """Why leaves are named now: swapped same-shape leaves in the leaf-index format restore
    without a word, each into the other's slot."""
    train = raw_train(DATA / "index")
    names = [n for n, _ in leaves.named_leaves(template)]
    a, b = f"{names.index(MU):05d}", f"{names.index(NU):05d}"
    train[a], train[b] = train[b], train[a]
    run = write_raw(tmp_path / "swapped", train, DATA / "index")
    got = dict(leaves.named_leaves(checkpoint.read_train(run, EPOCH, template)))
    reference = dict(leaves.named_leaves(checkpoint.read_train(DATA / "index", EPOCH, template)))
    np.testing.assert_array_equal(got[MU], reference[NU])


class Moments(typing.NamedTuple):
    mu: np.ndarray
    nu: np.ndarray


class Reordered(typing.NamedTuple):  # an upgrade that declares the fields the other way
    nu: np.ndarray
    mu: np.ndarray


def test_a_reordered_tree_restores_by_name():
    tree = {"adam": Moments(mu=np.ones(3, np.float32), nu=np.full(3, 2.0, np.float32))}
    like = {"adam": Reordered(nu=np.zeros(3, np.float32), mu=np.zeros(3, np.float32))}
    back = leaves.unpack(like, leaves.pack(tree))
    np.testing.assert_array_equal(back["adam"].mu, tree["adam"].mu)
    np.testing.assert_array_equal(back["adam"].nu, tree["adam"].nu)
    # by index (the earlier format), the same checkpoint lands in the wrong slots
    by_index = {f"{i:05d}": x for i, x in enumerate((tree["adam"].mu, tree["adam"].nu))}
    wrong = leaves.unpack(like, by_index)
    np.testing.assert_array_equal(wrong["adam"].mu, tree["adam"].nu)


def test_zero_size_leaves_are_left_out_and_rebuilt():
    tree = {"a": np.arange(4.0), "empty": np.zeros((3, 0), np.float32), "n": np.int32(7)}
    packed = leaves.pack(tree)
    assert sorted(packed) == ["['a']", "['n']", leaves.CHECKSUMS]
    back = leaves.unpack(tree, packed)
    assert back["empty"].shape == (3, 0)
    assert back["empty"].dtype == np.float32
    np.testing.assert_array_equal(back["a"], tree["a"])
    assert back["n"] == 7
    with pytest.raises(leaves.CheckpointError, match=r"1 missing from the checkpoint: \['a'\]"):
        leaves.unpack(tree, {"['n']": np.int32(7)})


def test_index_format_errors_name_the_leaf():
    like = {"a": np.zeros(2), "b": np.zeros(3)}
    with pytest.raises(leaves.CheckpointError, match=r"leaf 00001 \(\['b'\]\): shape \(2,\)"):
        leaves.unpack(like, {"00000": np.zeros(2), "00001": np.zeros(2)})
    with pytest.raises(leaves.CheckpointError, match=r"leaf 00001 \(\['b'\]\): missing"):
        leaves.unpack(like, {"00000": np.zeros(2)})
    with pytest.raises(leaves.CheckpointError, match=r"leaves 00002: not in this state"):
        leaves.unpack(like, {"00000": np.zeros(2), "00001": np.zeros(3), "00002": np.zeros(1)})


def test_prune_and_graft_round_trip():
    f32 = np.float32
    tree = {
        "robots": np.ones((4, 2), f32),
        "empty": np.zeros((4, 0), f32),
        "buffer": np.ones(5, f32),
    }
    shared = {0: np.full(5, 9.0, f32)}  # leaves in key order: buffer, empty, robots
    pruned = leaves.prune(tree, shared)
    assert [np.shape(x) for x in jax.tree.leaves(pruned)] == [(4, 2)]
    back = leaves.graft(tree, pruned, shared)
    np.testing.assert_array_equal(back["buffer"], shared[0])
    assert back["empty"].shape == (4, 0)
    np.testing.assert_array_equal(back["robots"], tree["robots"])


def test_resuming_a_leaf_index_checkpoint_restores_train_and_env_by_index(tmp_path):
    """A run checkpointed by an earlier version resumes: both items by index, as before."""
    train = {"w": np.arange(6.0).reshape(2, 3), "key": np.array([1, 2], np.uint32)}
    env = {"qpos": np.ones((2, 7)), "step": np.array([3, 4], np.int32)}
    index = {f"{i:05d}": x for i, x in enumerate(jax.tree.leaves(train))}
    env_index = {f"{i:05d}": x for i, x in enumerate(jax.tree.leaves(env))}
    mgr = checkpoint.manager(tmp_path)
    args = ocp.args.Composite(
        train=ocp.args.StandardSave(index),
        env=ocp.args.StandardSave(env_index),
        meta=ocp.args.JsonSave({"epoch": 4}),
    )
    mgr.save(4, args=args, force=True)
    mgr.wait_until_finished()
    mgr.close()
    like = {k: np.zeros_like(v) for k, v in train.items()}
    env_like = {k: np.zeros_like(v) for k, v in env.items()}
    got_train, got_env, meta = checkpoint.restore(tmp_path, like, env_like)
    assert meta["epoch"] == 4
    for want, got in ((train, got_train), (env, got_env)):
        for k in want:
            np.testing.assert_array_equal(got[k], want[k])
    # and a checkpoint written now round-trips through the same call
    shutil.rmtree(tmp_path / checkpoint.CHECKPOINT_DIR)
    mgr = checkpoint.manager(tmp_path)
    checkpoint.save(mgr, 5, train, env, {"epoch": 5})
    mgr.close()
    got_train, got_env, _ = checkpoint.restore(tmp_path, like, env_like)
    np.testing.assert_array_equal(got_train["w"], train["w"])
    np.testing.assert_array_equal(got_env["qpos"], env["qpos"])
