"""Render rollouts: video with MuJoCo's renderer, and a top-down trajectory plot.

Video backend: MuJoCo's offscreen renderer, headless through OSMesa or EGL (Mesa's EGL
renders on the CPU too). Choose with ``MUJOCO_GL`` before MuJoCo is imported;
:func:`ensure_gl_backend` picks whichever of the two is installed when no display is
present and nothing was chosen, and :func:`gl_unavailable_reason` says why rendering
cannot work on this machine.

Command (the six motion modes of seed 000, one after another):
``python -m mecanum_jax.sim.render --out runs/six_modes.mp4 [--fidelity reference]``
writes the video and ``six_modes_trajectory.png`` beside it.
"""

from __future__ import annotations

import os


def ensure_gl_backend() -> str:
    """Pick a headless GL backend for MuJoCo if the user has not (call before importing mujoco).

    With no display and no ``MUJOCO_GL``: OSMesa if its library is installed, else EGL if
    that is, else nothing (MuJoCo then imports fine and only rendering fails). Choosing a
    backend whose library is missing would break ``import mujoco`` itself.
    """
    if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
        import ctypes.util

        for backend, library in (("osmesa", "OSMesa"), ("egl", "EGL")):
            if ctypes.util.find_library(library):
                os.environ["MUJOCO_GL"] = backend
                os.environ.setdefault("PYOPENGL_PLATFORM", backend)
                break
    return os.environ.get("MUJOCO_GL", "")


def gl_unavailable_reason() -> str | None:
    """``None`` when MuJoCo can render offscreen here, else why not (naming the missing
    library). Picks a backend first (:func:`ensure_gl_backend`) and renders one tiny frame."""
    backend = ensure_gl_backend()
    if not backend and not os.environ.get("DISPLAY"):
        return (
            "no display and no headless GL library (libOSMesa or libEGL) found: install "
            "Debian's libosmesa6 or libegl1 to render videos"
        )
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_string(
            "<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>"
        )
        with mujoco.Renderer(model, 8, 8) as renderer:
            renderer.update_scene(mujoco.MjData(model))
            renderer.render()
    except Exception as err:  # MuJoCo raises several types for a missing GL context
        return f"MUJOCO_GL={backend or '(display)'}: cannot render: {type(err).__name__}: {err}"
    return None


import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def render_frames(
    mj_model: object,
    qpos_frames: np.ndarray,
    width: int = 640,
    height: int = 480,
    distance: float = 1.6,
) -> np.ndarray:
    """RGB frames (T, H, W, 3) uint8 of a model at the given configurations (T, nq).

    The camera follows the chassis from above and behind at ``distance`` m.
    """
    import mujoco

    model = mj_model
    assert isinstance(model, mujoco.MjModel)
    data = mujoco.MjData(model)
    camera = mujoco.MjvCamera()
    camera.distance = distance
    camera.elevation = -40.0
    camera.azimuth = 135.0
    frames = []
    with mujoco.Renderer(model, height, width) as renderer:
        for qpos in qpos_frames:
            data.qpos[:] = qpos
            mujoco.mj_forward(model, data)
            camera.lookat[:] = data.qpos[:3]
            renderer.update_scene(data, camera)
            frames.append(renderer.render().copy())
    return np.stack(frames)


def video_writer_missing(fmt: str) -> str | None:
    """``None`` where videos of format ``fmt`` ("mp4" or "gif") can be written, else what to
    install: mp4 goes through imageio-ffmpeg (the optional ``video`` extra, 165 MB with its
    ffmpeg binary); gif needs only imageio."""
    import importlib.util

    if fmt == "mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        return (
            "writing mp4 needs imageio-ffmpeg, the optional 'video' extra, which is not "
            "installed: pip install 'mecanum-jax[video]'"
        )
    return None


def write_video(frames: np.ndarray, path: Path, fps: int) -> Path:
    """Write frames to ``path`` (.mp4 via imageio-ffmpeg, .gif via Pillow), atomically."""
    import imageio.v3 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".partial" + path.suffix)
    if path.suffix == ".gif":
        iio.imwrite(tmp, frames, duration=1000 / fps, loop=0)
    else:
        iio.imwrite(tmp, frames, fps=fps, codec="libx264", macro_block_size=8)
    tmp.replace(path)
    return path


def plot_trajectories(
    paths: Sequence[np.ndarray], labels: Sequence[str], out: Path, title: str = ""
) -> Path:
    """Top-down plot of world trajectories (each (T, 3): x, y, yaw) with heading ticks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    for path, label in zip(paths, labels, strict=True):
        ax.plot(path[:, 0], path[:, 1], label=label)
        step = max(1, len(path) // 12)
        p = path[::step]
        ax.quiver(p[:, 0], p[:, 1], np.cos(p[:, 2]), np.sin(p[:, 2]),
                  angles="xy", scale=25, width=0.004, alpha=0.6)  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


def six_modes_rollout(
    fidelity: str = "fast", seconds_per_mode: float = 1.5, fps: int = 30
) -> tuple:
    """Simulate seed 000's six modes one after another.

    Returns (robot, qpos frames, poses, labels, frames per mode).
    """
    import jax
    import jax.numpy as jnp

    from mecanum_jax.kinematics import model as kinematics
    from mecanum_jax.kinematics.modes import SIX_MODES
    from mecanum_jax.sim import physics
    from mecanum_jax.sim.description import builtin_description

    robot = physics.Robot(builtin_description("o_rectangle"), fidelity)  # type: ignore[arg-type]
    params = robot.nominal_params(max_accel=40.0)
    substeps = max(1, round(1 / (fps * robot.dt)))
    frames_per_mode = round(seconds_per_mode * fps)
    labels = [label for label, _, _ in SIX_MODES.values()]
    twists = jnp.asarray(
        [[v * (1.0 if unit[2] != 0 else 0.4) for v in unit] for _, unit, _ in SIX_MODES.values()]
    )
    commands = kinematics.inverse(robot.geometry, twists)
    step = jax.jit(lambda s, c: robot.step(s, c, params, substeps))
    state = robot.reset(params)
    qpos, poses = [], []
    for cmd in commands:
        for _ in range(frames_per_mode):
            state = step(state, cmd)
            qpos.append(np.asarray(state.data.qpos))
            poses.append(np.asarray(robot.sensors(state).pose))
    return robot, np.stack(qpos), np.stack(poses), labels, frames_per_mode


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Render seed 000's six motion modes")
    parser.add_argument("--out", type=Path, default=Path("runs/six_modes.mp4"), help=".mp4 or .gif")
    parser.add_argument("--fidelity", choices=("fast", "reference"), default="fast")
    parser.add_argument("--seconds-per-mode", type=float, default=1.5)
    parser.add_argument("--fps", type=int, default=30)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    args = parser.parse_args(argv)
    if args.out.suffix not in (".mp4", ".gif"):
        parser.error(f"--out = {str(args.out)!r}: expected a .mp4 or .gif file")
    if missing := video_writer_missing(args.out.suffix[1:]):
        parser.error(f"--out = {str(args.out)!r}: {missing} (or write a .gif)")
    for name in ("seconds_per_mode", "fps", "width", "height"):
        if getattr(args, name) <= 0:
            parser.error(f"--{name.replace('_', '-')} = {getattr(args, name)}: must be > 0")
    ensure_gl_backend()
    robot, qpos, poses, labels, per_mode = six_modes_rollout(
        args.fidelity, args.seconds_per_mode, args.fps
    )
    frames = render_frames(robot.mj_model, qpos, args.width, args.height)
    video = write_video(frames, args.out, args.fps)
    segments = [poses[i * per_mode : (i + 1) * per_mode + 1] for i in range(len(labels))]
    plot_path = args.out.with_name(args.out.stem + "_trajectory.png")
    title = f"seed 000's six modes ({args.fidelity} fidelity)"
    plot = plot_trajectories(segments, labels, plot_path, title)
    print(f"wrote {video} ({len(frames)} frames) and {plot}")


if __name__ == "__main__":
    main()
