"""The teacher of ``ppo.distill``: a trained policy's action on a student's observations,
the target of the imitation term (train/learner/losses.py).

A privileged teacher (``network.teacher = true``) reads ``obs["privileged_state"]``: the
sensors and the truth no robot measures (friction, payload, radii, motor gains, latency).
Its student trains the same task with ``network.teacher = false``, usually observing
0.5 to 1 s of earlier sensor frames (``env.obs_history``) from which to infer that truth.
The student's observations hold every entry of the teacher's, by name (the history is
one more entry), so the teacher's observation is gathered from the student's rollouts
entry by entry, and its action is computed there: the student learns the teacher's
action in the states it visits itself.

Usage (the teacher first, then its student on the same task)::

    mecanum-train --config gpu --network.teacher True --run-dir runs/teacher
    mecanum-train --config gpu --env.obs-history 25 --ppo.distill.teacher runs/teacher \\
        --run-dir runs/student
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mecanum_jax.config import ConfigError
from mecanum_jax.task import observations as obs_
from mecanum_jax.task.env import MecanumEnv
from train.config import TrainConfig, config_diff
from train.learner.policy import restore_policy
from train.store.leaves import CheckpointError

WHERE = "ppo.distill.teacher"
FREE = ("env.obs_history", "env.physics_impl")
"""Task fields in which a student may differ from its teacher."""

TeacherAction = Callable[[dict[str, jax.Array]], jax.Array]


@dataclasses.dataclass(frozen=True)
class Teacher:
    """A restored teacher: its action on a student's (batched) observation dict, and
    where it came from."""

    action: TeacherAction
    run_dir: Path
    epoch: int
    seed: int
    privileged: bool

    def describe(self) -> str:
        kind = "a privileged teacher" if self.privileged else "a policy"
        return f"{self.run_dir} (epoch {self.epoch}, seed {self.seed}, {kind})"


def gather_indices(student: obs_.Layout, teacher: obs_.Layout, what: str) -> np.ndarray:
    """Positions in a student's observation of each entry of the teacher's, in the
    teacher's order; a :class:`ConfigError` naming :data:`WHERE` for an entry the student
    lacks or holds at another size."""
    where: dict[str, tuple[int, int]] = {}
    offset = 0
    for name, size in student:
        where[name] = (offset, int(size))
        offset += int(size)
    picked: list[int] = []
    for name, size in teacher:
        if name not in where or where[name][1] != int(size):
            got = "none" if name not in where else f"size {where[name][1]}"
            raise ConfigError(
                f"{WHERE}: the teacher's {what} entry {name!r} (size {size}) is not in this "
                f"run's observation ({got})"
            )
        start = where[name][0]
        picked.extend(range(start, start + int(size)))
    return np.asarray(picked, np.int32)


def load_teacher(cfg: TrainConfig, env: MecanumEnv) -> Teacher:
    """The teacher ``cfg.ppo.distill.teacher`` names, for a student training ``env``'s
    task; a :class:`ConfigError` naming the field if it cannot teach this run."""
    path = cfg.ppo.distill.teacher
    try:
        restored = restore_policy(path)
    except CheckpointError as err:
        raise ConfigError(f"{WHERE} = {path!r}: {err}") from None
    tcfg = restored.cfg
    differs = [f for f in config_diff(tcfg.env, cfg.env, "env") if f not in FREE]
    if differs:
        raise ConfigError(
            f"{WHERE} = {path!r}: the teacher trained another task; it differs from this run "
            f"in {differs}"
        )
    # the teacher's layout as its checkpoint records it (restore_policy checked it against
    # the teacher's config); the same robot, so the same privileged entries follow it
    layout = tuple((str(name), int(size)) for name, size in restored.meta["observation_layout"])
    state = gather_indices(env.layout, layout, "policy observation")
    privileged = gather_indices(
        env.privileged_layout,
        obs_.privileged_layout(layout, env.n_wheels),
        "privileged observation",
    )
    params = jax.tree.map(jnp.asarray, (restored.normalizer, restored.params))
    apply = restored.apply

    def action(obs: dict[str, jax.Array]) -> jax.Array:
        seen = {
            "state": jnp.take(obs["state"], state, axis=-1),
            "privileged_state": jnp.take(obs["privileged_state"], privileged, axis=-1),
        }
        return apply(params, seen)

    return Teacher(action, restored.run_dir, restored.epoch, restored.seed, tcfg.network.teacher)


__all__ = ["FREE", "WHERE", "Teacher", "gather_indices", "load_teacher"]
