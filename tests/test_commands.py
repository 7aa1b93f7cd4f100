"""The command process: mirrored commands (``env.commands.p_mirror``)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.sim.description import builtin_description
from mecanum_jax.task.commands import (
    MIRRORS,
    CommandConfig,
    command_schedule,
    next_command,
    sample_command,
)
from mecanum_jax.task.constants import robot_constants


@pytest.fixture(scope="module")
def robot():
    desc = builtin_description("o_rectangle")
    return robot_constants(desc, desc.build_geometry(), None)


def _draws(robot, c, previous, n=2000):
    keys = jax.random.split(jax.random.PRNGKey(3), n)
    nxt = jax.jit(jax.vmap(lambda k: next_command(robot, k, c, previous)))
    fresh = jax.jit(jax.vmap(lambda k: sample_command(robot, k, c)))
    return np.asarray(nxt(keys)), np.asarray(fresh(keys))


@pytest.mark.parametrize("p", [0.0, jnp.asarray(0.0)], ids=["static", "traced"])
def test_without_mirrors_the_next_command_is_the_fresh_draw_bit_for_bit(robot, p):
    # traced: as evaluation passes the mix, the mirror's draws run and must change nothing
    c = dataclasses.replace(CommandConfig(), p_mirror=p)
    new, fresh = _draws(robot, c, jnp.array([0.3, -0.2, 0.5]))
    np.testing.assert_array_equal(new, fresh)


def test_mirrored_commands_are_the_last_one_under_each_mirror(robot):
    previous = np.array([0.3, -0.2, 0.5], np.float32)
    c = dataclasses.replace(CommandConfig(), p_mirror=0.4)
    new, fresh = _draws(robot, c, jnp.asarray(previous))
    images = previous * np.asarray(MIRRORS, np.float32)  # (3, 3)
    which = [np.flatnonzero((row == images).all(-1)) for row in new]
    mirrored = np.array([len(w) == 1 for w in which])
    # every command is a fresh draw or exactly one mirror image of the last one
    assert np.all(mirrored | (new == fresh).all(-1))
    assert abs(mirrored.mean() - 0.4) < 0.04, mirrored.mean()
    counts = np.bincount([w[0] for w in which if len(w) == 1], minlength=3)
    assert counts.min() > 0.25 * counts.sum(), counts  # each mirror about a third


def test_a_stop_is_followed_by_a_fresh_draw(robot):
    c = dataclasses.replace(CommandConfig(), p_mirror=1.0)
    new, fresh = _draws(robot, c, jnp.zeros(3), n=200)
    np.testing.assert_array_equal(new, fresh)


def test_a_schedule_with_mirrors_reverses_its_commands(robot):
    c = CommandConfig(p_mirror=1.0, p_zero=0.0, resample_min_s=0.5, resample_max_s=1.0)
    cmds = np.asarray(command_schedule(robot, jax.random.PRNGKey(0), 500, c, 0.02))
    changes = np.flatnonzero((np.diff(cmds, axis=0) != 0).any(-1)) + 1
    assert len(changes) >= 5
    for t in changes:  # each new command is the one before, mirrored
        images = cmds[t - 1] * np.asarray(MIRRORS, np.float32)
        assert (np.isclose(images, cmds[t]).all(-1)).any(), (cmds[t - 1], cmds[t])
    assert np.allclose(np.abs(cmds), np.abs(cmds[0]))  # one magnitude, mirrored throughout


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_a_bad_mirror_chance_names_the_field(value):
    with pytest.raises(ConfigError, match=r"env\.commands\.p_mirror"):
        dataclasses.replace(CommandConfig(), p_mirror=value).validate()
