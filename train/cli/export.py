"""``mecanum-export``: write a trained policy for deployment.

Examples::

    mecanum-export runs/gpu-... policy.npz                  # weights + normalizer, for NumPy
    mecanum-export runs/gpu-.../checkpoints/40 policy.npz --seed 1
    mecanum-export models/o_rectangle policy.onnx --format onnx  # one ONNX graph
    mecanum-export runs/gpu-... models/mine --model         # a model directory, like a run

``policy.npz`` holds the policy network's weights, the observation normalizer and the
control loop's constants; ``mecanum_policy.py`` (NumPy inference,
``mecanum_jax.deploy.policy``) is copied beside it. ``--format onnx`` writes one ONNX graph
from raw observations to actions and wheel-rate setpoints (``mecanum_jax.deploy.onnx``).
``--model`` packs one checkpoint as a model directory that ``mecanum-eval`` and
``mecanum-export`` read like a run directory (:func:`train.learner.policy.package_model`).
``mecanum-eval ... --export`` writes the same ``policy.npz`` beside its report.

An existing output is never overwritten. Exit code 2: bad input (arguments, checkpoint).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro
from rich.console import Console

from mecanum_jax import atomic
from mecanum_jax._checks import require_platform
from mecanum_jax.config import ConfigError
from mecanum_jax.deploy import policy as deploy
from mecanum_jax.deploy.write import save
from mecanum_jax.task import MecanumEnv
from mecanum_jax.task.controller import controller_meta
from train.cli.paths import check_output, resolve_model
from train.learner.policy import RestoredPolicy, package_model, restore_policy, split_target
from train.loop.progress import print_error
from train.store import checkpoint

console = Console(stderr=True)


@dataclasses.dataclass
class ExportArgs:
    """Write a trained policy: a small NumPy file (weights + observation normalizer), or a
    model directory (--model) that mecanum-eval and mecanum-export read like a run."""

    run: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """A run directory (latest checkpoint) or <run>/checkpoints/<epoch>."""
    out: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="OUT")]
    """The file to write: .npz (mecanum_policy.py, NumPy inference, is copied beside
    it) or, with --format onnx, .onnx; with --model, the directory to create."""
    format: Literal["npz", "onnx"] = "npz"
    """npz: weights and normalizer for the NumPy module; onnx: one ONNX graph from
    raw observations to actions and wheel-rate setpoints (normalizer, clip and the
    baseline inside; needs the onnx extra)."""
    seed: int | None = None
    """Which of the run's training seeds (default: the first)."""
    epoch: int | None = None
    """Which checkpoint (default: the latest)."""
    model: bool = False
    """Write a model directory: the policy's checkpoint (no optimizer-free copy is made:
    the training state of that epoch, without the environment state), the resolved config,
    provenance.json and the NumPy export."""
    provenance: tuple[str, ...] = ()
    """--model: KEY=VALUE pairs for provenance.json (e.g. command=..., device=...)."""


def main(argv: list[str] | None = None) -> int:
    """``mecanum-export RUN OUT``: see the module docstring."""
    checkpoint.quiet_closed_loop_noise()
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(ExportArgs, args=argv, prog="mecanum-export")
    try:
        require_platform()  # JAX_PLATFORMS names a backend that exists (mecanum_jax._checks)
        suffix = "." + args.format
        if args.model and args.format != "npz":
            raise ConfigError(f"--format = {args.format!r}: --model writes its own npz export")
        if not args.model and not args.out.endswith(suffix):
            raise ConfigError(
                f"out = {args.out!r}: expected a {suffix} file name for --format {args.format}"
                + (" (or --model)" if args.format == "npz" else "")
            )
        check_output(args.out, "out")
        extra = {}
        for item in args.provenance:
            key, sep, value = item.partition("=")
            if not sep or not key:
                raise ConfigError(f"--provenance {item!r}: expected KEY=VALUE")
            extra[key] = value
        run_dir, epoch = split_target(resolve_model(args.run))
        restored = restore_policy(run_dir, args.seed, epoch or args.epoch)
    except (ConfigError, checkpoint.CheckpointError, OSError) as err:
        _error(err)
        return 2
    try:
        return _write(args, restored, extra)
    except OSError as err:  # the disk filled, or the folder went away, while writing
        _error(atomic.explain(err, args.out))  # (what it wrote is gone: mecanum_jax.atomic)
        return 2


def _write(args: ExportArgs, restored: RestoredPolicy, extra: dict[str, Any]) -> int:
    if args.model:
        fill = lambda folder: export_policy(restored, folder / "policy.npz")  # noqa: E731
        out = package_model(restored, Path(args.out), extra, fill)
        console.log(f"wrote model directory {out}")
        return 0
    if args.format == "onnx":
        try:
            path = export_onnx(restored, Path(args.out))
        except ImportError as err:
            _error(
                ConfigError(
                    f"--format onnx: {err}; install the extra: pip install 'mecanum-jax[onnx]'"
                )
            )
            return 2
        console.log(f"wrote {path}")
        return 0
    path = export_policy(restored, Path(args.out))
    modules = sorted({name.split("/")[0] for name in robot_side_files()})  # the package once
    beside = ", ".join(str(path.with_name(m)) for m in modules)
    console.log(f"wrote {path} and beside it {beside}")
    return 0


def robot_side_files() -> dict[str, Path]:
    """What the robot needs beside ``policy.npz``, by its name there: the NumPy policy, the
    control loop and the controller package (``mecanum_control/``), from the library."""
    from mecanum_jax import control

    source = Path(deploy.__file__)
    files = {"mecanum_policy.py": source, "mecanum_loop.py": source.with_name("loop.py")}
    package = Path(control.__file__).parent
    for src in sorted(package.glob("*.py")):
        files[f"mecanum_control/{src.name}"] = src
    return files


def export_policy(restored: RestoredPolicy, path: Path) -> Path:
    """Write ``policy.npz`` (weights, normalizer, control-loop constants) and copy the
    NumPy inference module beside it as ``mecanum_policy.py``. Each file atomically; on an
    error, those it had written are removed again."""
    modules = robot_side_files()
    new = [p for p in (path, *(path.parent / n for n in modules)) if not p.exists()]
    try:
        save(path, *_policy_arrays(restored))
        for name, src in modules.items():
            (path.parent / name).parent.mkdir(exist_ok=True)
            atomic.copy_file(src, path.parent / name)
    except BaseException:
        for p in new:
            p.unlink(missing_ok=True)
        raise
    return path


def export_onnx(restored: RestoredPolicy, path: Path) -> Path:
    """Write the policy and its control loop as one ONNX graph (``mecanum_jax.deploy.onnx``)."""
    from mecanum_jax.deploy import onnx as onnx_export

    return onnx_export.write_onnx(deploy.NumpyPolicy(*_policy_arrays(restored)), path)


def task_meta(env: MecanumEnv) -> dict[str, Any]:
    """What an exported policy's control loop needs of ``env``'s task
    (:func:`mecanum_jax.task.controller.controller_meta`)."""
    return controller_meta(env.config, env.desc, env.constants)


def _policy_arrays(
    restored: RestoredPolicy,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray, dict[str, Any]]:
    """The exported policy's layers, normalizer mean and std, and metadata."""
    cfg = restored.cfg
    env = MecanumEnv(dataclasses.replace(cfg.env, physics_impl="jax"))  # shapes only
    layers_tree = restored.params["params"]
    names = sorted(layers_tree, key=lambda n: int(n.rsplit("_", 1)[-1]))
    layers = [
        (np.asarray(layers_tree[n]["kernel"]), np.asarray(layers_tree[n]["bias"])) for n in names
    ]
    mean = np.asarray(restored.normalizer.mean["state"])
    std = np.asarray(restored.normalizer.std["state"])
    meta = {
        **task_meta(env),
        "activation": "swish",  # the trainer's (train/learner/state.py)
        "clip_observations": cfg.ppo.clip_observations,
        "source": {"run": str(restored.run_dir), "epoch": restored.epoch, "seed": restored.seed},
    }
    return layers, mean, std, meta


def _error(err: BaseException) -> None:
    print_error(console, err)


export_main = main
"""``main`` under the name the device runner's ``package`` step imports."""

__all__ = ["ExportArgs", "export_main", "export_onnx", "export_policy", "main", "task_meta"]


if __name__ == "__main__":
    sys.exit(main())
