"""What ``mecanum-eval`` evaluates (:class:`Target`): the reference controllers alone
(``baseline``), or a checkpoint's policy beside them, in the environment and physics they
are played in; and where its report goes by default (:func:`default_out`)."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import jax
from rich.console import Console

from mecanum_jax import memory
from mecanum_jax.config import ConfigError
from mecanum_jax.evaluation import episodes, scenarios
from mecanum_jax.evaluation import rollout as ev
from mecanum_jax.task import MecanumEnv
from mecanum_jax.task import fidelity as fid
from mecanum_jax.task.config import changed_env
from mecanum_jax.tracing import prepare_tracing
from train.cli.eval_args import EvalArgs, play_changes
from train.config_loading import config_diff, config_value, load_train_config
from train.learner.policy import PROVENANCE, RestoredPolicy, restore_policy, split_target
from train.store import inputs

if TYPE_CHECKING:
    from brax.training.types import PolicyParams

console = Console(stderr=True)


def default_impl(trained: str) -> str:
    """The MJX implementation to evaluate a task trained under ``trained`` with, when
    ``--physics-impl`` is not given: "" (the task's own), or "jax" for a Warp task where
    the warp extra is absent or the backend is the CPU. Both simulate the same robot
    (docs/benchmarks.md), and on the CPU Warp's kernels run about 30x slower than JAX's."""
    if trained != "warp":
        return ""
    if importlib.util.find_spec("warp") is None or jax.default_backend() == "cpu":
        return "jax"
    return ""


class Target:
    """What is evaluated: the environment, and the learned policy if any."""

    def __init__(self, args: EvalArgs, scenario_set: scenarios.ScenarioSet):
        self.restored: RestoredPolicy | None = None
        play = play_changes(args.play)
        if args.target == "baseline":
            base = load_train_config(args.config or "quick").env
            if args.robot is not None:
                base = dataclasses.replace(base, robot=args.robot)
            if play:
                base = changed_env(base, play, "--play")
            for name in ("seed", "epoch"):
                if getattr(args, name) is not None:
                    raise ConfigError(f"--{name} = {getattr(args, name)}: only for a checkpoint")
            self.label = "references"
            precision = load_train_config(args.config or "quick").run.matmul_precision
        else:
            for name in ("robot", "config"):
                if getattr(args, name) is not None:
                    raise ConfigError(
                        f"--{name} = {getattr(args, name)!r}: a checkpoint evaluates on the "
                        "task it was trained on; --robot/--config are for `baseline`"
                    )
            run_dir, epoch = split_target(args.target)
            if epoch is not None and args.epoch is not None and epoch != args.epoch:
                raise ConfigError(f"--epoch = {args.epoch}: the target names epoch {epoch}")
            self.restored = restore_policy(run_dir, args.seed, epoch or args.epoch, play)
            check_config_task(self.restored, ignore=tuple(play))
            base = self.restored.cfg.env
            precision = self.restored.cfg.run.matmul_precision
            r = self.restored
            self.label = f"{run_dir} (epoch {r.epoch}, seed {r.seed})"
        if play:
            self.label += f" played with {' '.join(args.play)}"
        # before anything is traced: one number on every device (mecanum_jax.precision)
        self.precision = args.matmul_precision or precision
        prepare_tracing(self.precision, "--matmul-precision")
        fidelity = fid.check_fidelity(args.fidelity, "--fidelity")
        max_batch = fid.eval_batch(fidelity, args.max_batch, "--max-batch", 16384)
        impl = args.physics_impl or default_impl(base.physics_impl)
        if impl and not args.physics_impl:  # chosen here, not asked for: say so
            console.log(
                f"trained under MJX's {base.physics_impl} implementation; evaluating under its "
                f"{impl} one, the same robot (--physics-impl to choose)"
            )
        if impl:
            base = dataclasses.replace(base, physics_impl=impl)
        eval_cfg = episodes.eval_env_config(base.validate("env"), scenario_set)
        fid.check_task(eval_cfg, fidelity, "--fidelity")
        _require_memory(args, scenario_set, max_batch, eval_cfg.control_dt, self.restored)
        self.env = MecanumEnv(eval_cfg, robots=max_batch, fidelity=fidelity)
        self.label += "" if fidelity == "fast" else f" in the {fidelity} model"
        apply = None
        if self.restored is not None:
            apply = self.restored.apply
        self.evaluator = ev.Evaluator(self.env, apply, max_batch)

    @property
    def params(self) -> PolicyParams | None:
        r = self.restored
        return None if r is None else (r.normalizer, r.params)


def _require_memory(
    args: EvalArgs,
    scenario_set: scenarios.ScenarioSet,
    max_batch: int,
    control_dt: float,
    restored: RestoredPolicy | None,
) -> None:
    """Refuse an evaluation whose largest rollout would not fit (mecanum_jax.memory)."""
    robots = min(max_batch, sum(s.episodes for s in scenario_set.scenarios))
    steps = max(round(s.seconds / control_dt) for s in scenario_set.scenarios)
    players = len(args.references) + (restored is not None)
    need = memory.evaluation_bytes(robots, steps, players)
    memory.require_memory(
        need,
        f"evaluation of {robots} robots at once × {steps} steps × {players} controllers",
        "use a smaller --max-batch, fewer --episodes or shorter --seconds",
    )


def check_config_task(restored: RestoredPolicy, ignore: tuple[str, ...] = ()) -> None:
    """Refuse a model whose config.json states another task (``[env]``) than its
    checkpoint was trained on (an edit by hand): the checkpoint's config decides, so the
    edit would be ignored silently here, while deploy-sim and a resumed run read it.
    ``ignore``: env fields changed at play time (``--play``)."""
    path = restored.run_dir / "config.json"
    try:
        given = json.loads(path.read_text())["env"]["robot"]
        trained = restored.meta["config"]["env"]["robot"]
    except (OSError, ValueError, KeyError, TypeError):  # none, or check_saved_config's to report
        return
    if given != trained:
        raise ConfigError(
            f"{path}: env.robot = {given!r}, but the checkpoint was trained on robot "
            f"{trained!r}; a policy plays the robot it was trained on (config.json does not "
            f"change it): set env.robot back to {trained!r}, or train on {given!r}"
        )
    try:
        stated = inputs.load_saved_config(restored.run_dir, warn=False)
    except ValueError:  # check_saved_config's to report
        return
    differ = config_diff(stated, restored.cfg)
    skip = {"env.robot", *(f"env.{f}" for f in ignore)}
    if fields := [f for f in differ if f.startswith("env.") and f not in skip]:
        pairs = ", ".join(
            f"{f} = {config_value(stated, f)!r} (trained: {config_value(restored.cfg, f)!r})"
            for f in fields
        )
        raise ConfigError(
            f"{path}: {pairs}; a policy plays the task it was trained on: set config.json "
            "back to the checkpoint's task, or train with it"
        )


def default_out(args: EvalArgs, target: Target) -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    if target.restored is None:
        return Path(f"runs/eval-references-{stamp}")
    run_dir = target.restored.run_dir
    if (run_dir / PROVENANCE).exists():  # a shipped model: not a place to write
        return Path(f"runs/eval-{run_dir.name}-{stamp}")
    return run_dir / "eval" / f"epoch{target.restored.epoch}-{stamp}"


__all__ = ["Target", "check_config_task", "default_impl", "default_out"]
