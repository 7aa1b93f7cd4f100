"""``mecanum-eval``'s arguments (:class:`EvalArgs`) and their checks, made before any
checkpoint is read or rollout compiled."""

from __future__ import annotations

from mecanum_jax.sim.render import ensure_gl_backend, video_writer_missing

ensure_gl_backend()  # before MuJoCo is imported (by the task): OSMesa when there is no display

import dataclasses  # noqa: E402
import tomllib  # noqa: E402
from typing import Annotated, Literal  # noqa: E402

import tyro  # noqa: E402

from mecanum_jax.config import ConfigError  # noqa: E402
from mecanum_jax.task.references import REFERENCES  # noqa: E402

MIN_SECONDS = 0.1
"""The shortest episode ``--seconds`` accepts, s."""


@dataclasses.dataclass
class EvalArgs:
    """Evaluate a policy against the reference controllers on named scenarios."""

    target: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="TARGET")]
    """baseline, a run directory (latest checkpoint), or <run>/checkpoints/<epoch>."""
    scenarios: str = "default"
    """Scenario file: a name in configs/eval/ or a path to a .toml file."""
    only: tuple[str, ...] = ()
    """Evaluate only these scenarios (names from the file), in this order."""
    episodes: int | None = None
    """Override every scenario's number of episodes (e.g. fewer, for a quick look)."""
    seconds: float | None = None
    """Override every scenario's episode length."""
    seed: int | None = None
    """Which of the run's training seeds (default: the first)."""
    epoch: int | None = None
    """Which checkpoint (default: the latest)."""
    robot: str | None = None
    """baseline only: robot description (built-in name or TOML path)."""
    config: str | None = None
    """baseline only: train config whose [env] defines the task (default: quick)."""
    out: str | None = None
    """Output directory (default: <run>/eval/epoch<k>-<time>, or runs/eval-baseline-<time>)."""
    plots: bool = True
    """Write the PNG plots."""
    video: bool = False
    """Render the --video-scenarios (episode --video-episode): policy and baseline side by
    side."""
    video_scenarios: tuple[str, ...] = ()
    """Scenarios to render (default: six_modes if evaluated, else the first)."""
    video_episode: int = 0
    """Which episode of each rendered scenario."""
    video_size: tuple[int, int] = (320, 240)
    """Width and height of each policy's view, pixels."""
    fps: int = 25
    """Video frame rate (frames are taken from the 50 Hz control steps)."""
    video_format: Literal["mp4", "gif"] = "mp4"
    """mp4 (H.264 through imageio-ffmpeg: pip install 'mecanum-jax[video]') or gif (Pillow)."""
    max_batch: int | None = None
    """Robots per compiled rollout (default: 64 on CPU, the fastest, each with 8 guard rows;
    from 256 rows jaxlib 0.10.2 deadlocks, so at most 247; 16384 on GPU, so a whole
    evaluation is one rollout)."""
    physics_impl: str = ""
    """MJX implementation to simulate with: "jax", "warp" (the warp extra), or "" (the
    task's own, except that a Warp task evaluates under JAX on the CPU, where Warp's kernels
    are about 30x slower). Both simulate the same robot (docs/benchmarks.md)."""
    fidelity: str = "fast"
    """Physics model: "fast" (the training model) or "reference" (the roller model at its own
    timestep, same control period; docs/evaluation.md)."""
    references: tuple[str, ...] = REFERENCES
    """Reference controllers to run on the same episodes (analytic, analytic_nearest,
    feedback)."""
    play: tuple[str, ...] = ()
    """A probe: FIELD=VALUE changes of the task's [env] at play time (FIELD or
    SECTION.FIELD, VALUE as in a TOML file, e.g. residual_deadband=0.01
    feedback.margin=0.05), for the policy and the references alike. It says whether a lever
    is worth training, never what a policy trained so would do."""
    settle_s: float = 0.5
    """Steady-state error counts control steps at least this long after a command change, s."""
    bootstrap: int = 2000
    """Bootstrap resamples of the paired intervals."""
    export: bool = False
    """Also write the deployable policy (policy.npz + mecanum_robot.zip) to the output."""
    matmul_precision: Literal["default", "high", "highest"] | None = None
    """jax's matmul precision for the evaluation (default: the run's run.matmul_precision,
    highest unless the run chose otherwise). default is TF32 on A100/H100 GPUs and
    makes the figures depend on the device (mecanum_jax.precision)."""
    progress_every_s: float = 30.0
    """Where stderr is not a terminal: a plain progress line of the rollouts every this many
    seconds, and one per finished chunk (> 0)."""


def check_args(args: EvalArgs) -> None:
    """Raise :class:`ConfigError` naming the first bad argument (before anything runs)."""
    w, h = args.video_size
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise ConfigError(f"--video-size = {w} {h}: each in [16, 4096] pixels")
    if not 1 <= args.fps <= 50:
        raise ConfigError(f"--fps = {args.fps}: must be in [1, 50] (the control rate)")
    if args.video_episode < 0:
        raise ConfigError(f"--video-episode = {args.video_episode}: must be >= 0")
    if args.max_batch is not None and args.max_batch < 1:
        raise ConfigError(f"--max-batch = {args.max_batch}: must be >= 1")
    if args.video_scenarios and not args.video:
        raise ConfigError("--video-scenarios: needs --video")
    if args.video and (missing := video_writer_missing(args.video_format)):
        raise ConfigError(f"--video (--video-format {args.video_format}): {missing}, or use gif")
    unknown = [r for r in args.references if r not in REFERENCES]
    if unknown or not args.references:
        raise ConfigError(f"--references = {list(args.references)}: expected some of {REFERENCES}")
    if not args.settle_s >= 0:
        raise ConfigError(f"--settle-s = {args.settle_s}: must be >= 0")
    if not 0 < args.progress_every_s < float("inf"):
        raise ConfigError(f"--progress-every-s = {args.progress_every_s}: must be > 0 seconds")
    if args.seconds is not None and args.seconds < MIN_SECONDS:
        raise ConfigError(
            f"--seconds = {args.seconds}: an episode must last at least {MIN_SECONDS} s "
            "(5 control steps at 50 Hz); shorter episodes measure no tracking"
        )
    if args.bootstrap < 100:
        raise ConfigError(f"--bootstrap = {args.bootstrap}: must be >= 100")
    if args.export and args.target == "baseline":
        raise ConfigError("--export: the baseline has no weights to export; give a checkpoint")
    if args.export and args.play:
        raise ConfigError(f"--play {' '.join(args.play)}: a probe, not a policy to export")
    play_changes(args.play)


def play_changes(items: tuple[str, ...]) -> dict[str, object]:
    """``--play``'s FIELD=VALUE items as ``{FIELD: value}``, each value read as TOML reads
    it; the fields themselves are checked against the task (task.config.changed_env)."""
    changes: dict[str, object] = {}
    for item in items:
        name, eq, text = item.partition("=")
        if not eq or not name or not text:
            raise ConfigError(f"--play {item!r}: expected FIELD=VALUE, e.g. residual_deadband=0.01")
        try:
            changes[name] = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            raise ConfigError(
                f"--play {item!r}: {text!r} is not a TOML value (a number, true or false, "
                'or a "quoted string")'
            ) from None
    return changes


__all__ = ["MIN_SECONDS", "EvalArgs", "check_args", "play_changes"]
