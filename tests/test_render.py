"""Rendering: a rollout becomes a video (OSMesa on CPU) and a trajectory plot."""

import os

from mecanum_jax.sim.render import ensure_gl_backend

ensure_gl_backend()

import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from mecanum_jax.sim import render  # noqa: E402


@pytest.mark.full
@pytest.mark.render
def test_six_modes_video_and_plot(tmp_path):
    out = tmp_path / "six.gif"
    render.main(["--out", str(out), "--seconds-per-mode", "0.2", "--fps", "10", "--width", "160",
                 "--height", "120"])  # fmt: skip
    frames = iio.imread(out)
    assert frames.shape[0] == 12  # 6 modes × 2 frames
    assert frames.shape[1:3] == (120, 160)
    assert frames.std() > 5  # a scene, not a blank image
    assert not np.array_equal(frames[0], frames[-1])  # the robot moved
    assert (tmp_path / "six_trajectory.png").stat().st_size > 1000
    assert not list(tmp_path.glob("*.partial*"))


def test_render_rejects_bad_arguments(tmp_path):
    with pytest.raises(SystemExit):
        render.main(["--out", str(tmp_path / "x.avi")])
    with pytest.raises(SystemExit):
        render.main(["--out", str(tmp_path / "x.gif"), "--fps", "0"])


@pytest.mark.parametrize(
    ("found", "expected"),
    [({"OSMesa", "EGL"}, "osmesa"), ({"EGL"}, "egl"), (set(), "")],
)
def test_gl_backend_is_only_chosen_when_its_library_exists(found, expected, monkeypatch):
    """Setting MUJOCO_GL to a backend whose library is missing breaks ``import mujoco``
    (seen on the GPU machine without OSMesa): no display and nothing installed → unset."""
    import ctypes.util

    from mecanum_jax.sim import render

    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: name if name in found else None)
    assert render.ensure_gl_backend() == expected
    assert os.environ.get("MUJOCO_GL", "") == expected
