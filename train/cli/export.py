"""``mecanum-export``: write a trained policy for deployment.

Examples::

    mecanum-export runs/gpu-... policy.npz                  # weights + normalizer, for NumPy
    mecanum-export runs/gpu-.../checkpoints/40 policy.npz --seed 1
    mecanum-export models/o_rectangle policy.onnx --format onnx  # one ONNX graph
    mecanum-export runs/gpu-... models/mine --model         # a model directory, like a run

``policy.npz`` holds the policy network's weights, the observation normalizer and the
control loop's constants; ``mecanum_robot.zip`` beside it the robot-side code (NumPy
inference and the control loop, ``mecanum_jax.deploy.write.robot_archive``).
``--format onnx`` writes one ONNX graph from raw observations to actions and wheel-rate
setpoints (``mecanum_jax.deploy.onnx``).
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

import tyro
from rich.console import Console

from mecanum_jax import atomic
from mecanum_jax._checks import require_platform
from mecanum_jax.config import ConfigError
from mecanum_jax.deploy.write import ARCHIVE, export_onnx, export_policy
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
    """The file to write: .npz (the robot-side code, NumPy inference and the control loop,
    is written beside it as mecanum_robot.zip) or, with --format onnx, .onnx; with --model,
    the directory to create."""
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
        arrays = restored.export_arrays()
        fill = lambda folder: export_policy(*arrays, folder / "policy.npz")  # noqa: E731
        out = package_model(restored, Path(args.out), extra, fill)
        console.log(f"wrote model directory {out}")
        return 0
    if args.format == "onnx":
        try:
            path = export_onnx(*restored.export_arrays(), Path(args.out))
        except ImportError as err:
            _error(
                ConfigError(
                    f"--format onnx: {err}; install the extra: pip install 'mecanum-jax[onnx]'"
                )
            )
            return 2
        console.log(f"wrote {path}")
        return 0
    path = export_policy(*restored.export_arrays(), Path(args.out))
    console.log(
        f"wrote {path} and beside it {path.with_name(ARCHIVE)} (mecanum_loop.py, "
        "mecanum_policy.py and mecanum_control/: put it on sys.path; run it to check the "
        "export on the robot)"
    )
    return 0


def _error(err: BaseException) -> None:
    print_error(console, err)


export_main = main
"""``main`` under the name the device runner's ``package`` step imports."""

__all__ = ["ExportArgs", "export_main", "main"]


if __name__ == "__main__":
    sys.exit(main())
