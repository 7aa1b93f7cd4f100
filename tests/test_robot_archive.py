"""The export's robot-side archive (``mecanum_robot.zip``): the shipped model holds what the
export writes today, the same bytes for the same sources, and the archive runs on its own
(NumPy only), as a library on ``sys.path`` and as its self-check."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

MODEL = Path(__file__).resolve().parents[1] / "models" / "o_rectangle"


def test_the_model_folder_holds_what_the_export_writes_today():
    from mecanum_jax.deploy.write import ARCHIVE, robot_archive, robot_side_files

    assert (MODEL / ARCHIVE).read_bytes() == robot_archive()
    with zipfile.ZipFile(MODEL / ARCHIVE) as archive:
        assert archive.namelist() == sorted(robot_side_files())
    assert not list(MODEL.rglob("*.py"))  # no stale loose copy beside it either


def test_the_robot_archive_is_the_same_bytes_for_the_same_sources(tmp_path):
    from mecanum_jax.deploy import write

    first = write.robot_archive()
    assert write.robot_archive() == first
    edited = tmp_path / "loop.py"
    edited.write_bytes(write.robot_side_files()["mecanum_loop.py"].read_bytes() + b"# edit\n")
    files = dict(write.robot_side_files(), **{"mecanum_loop.py": edited})
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(write, "robot_side_files", lambda: files)
        assert write.robot_archive() != first  # an edited source is seen: the test can fail


def test_the_copied_loop_runs_beside_the_export_without_jax(tmp_path):
    """What mecanum-export writes beside policy.npz runs on its own: NumPy only."""
    from mecanum_jax.deploy.write import ARCHIVE, robot_archive

    shutil.copy(MODEL / "policy.npz", tmp_path)
    (tmp_path / ARCHIVE).write_bytes(robot_archive())
    script = (
        f"import sys; sys.path.insert(0, {ARCHIVE!r}); from mecanum_loop import Controller\n"
        "c = Controller.load('policy.npz'); c.reset()\n"
        "for _ in range(3): s, a = c.step([0.3, 0, 0.5], [0, 0, 0, 0], 0.0, [0, 0, 9.81])\n"
        "heavy = sorted(m for m in ('jax', 'mujoco', 'brax', 'mecanum_jax') if m in sys.modules)\n"
        "print(list(map(float, s)), heavy)"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    setpoints, heavy = done.stdout.strip().rsplit(" ", 1)
    assert heavy == "[]"
    assert max(abs(x) for x in json.loads(setpoints)) > 1


def test_the_archive_checks_itself_on_the_robot(tmp_path):
    """``python mecanum_robot.zip`` beside the export ticks its loop and times the tick; a
    file that is not there is named, with exit code 2."""
    from mecanum_jax.deploy.write import ARCHIVE, robot_archive

    shutil.copy(MODEL / "policy.npz", tmp_path)
    (tmp_path / ARCHIVE).write_bytes(robot_archive())
    done = subprocess.run(
        [sys.executable, ARCHIVE], cwd=tmp_path, capture_output=True, text=True, check=True
    )
    assert "policy.npz (numpy): setpoints [" in done.stdout
    assert "ms a tick of the 20 ms control period" in done.stdout
    bad = subprocess.run(
        [sys.executable, ARCHIVE, "missing.npz"], cwd=tmp_path, capture_output=True, text=True
    )
    assert bad.returncode == 2
    assert "'missing.npz': no such file" in bad.stderr
