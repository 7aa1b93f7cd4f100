"""The install's optional parts: mp4 videos need the ``video`` extra, and are refused with
the advice to install it before any rollout where it is missing; the licence is declared."""

import hashlib
import sys
import tomllib
from pathlib import Path

import pytest

from train import evaluate

ROOT = Path(__file__).resolve().parent.parent


def test_mp4_without_ffmpeg_is_refused_before_any_rollout(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    out = tmp_path / "ev"
    assert evaluate.main(["baseline", "--only", "nominal", "--video", "--out", str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "--video (--video-format mp4)" in err
    assert "pip install 'mecanum-jax[video]'" in err
    assert not out.exists()
    assert not (tmp_path / "ev.partial").exists()
    # gif needs no ffmpeg; without --video nothing is asked
    for argv in (["--video", "--video-format", "gif"], []):
        evaluate._check_args(evaluate._parse(["baseline", *argv], "p", evaluate.EvalArgs))


def test_mp4_passes_the_check_where_ffmpeg_is_installed():
    pytest.importorskip("imageio_ffmpeg")
    evaluate._check_args(evaluate._parse(["baseline", "--video"], "p", evaluate.EvalArgs))


def test_video_extra_and_licence_are_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert extras["video"] == ["imageio-ffmpeg>=0.5"]
    assert not any(d.startswith("imageio-ffmpeg") for d in project["dependencies"])
    assert project["license"] == "Apache-2.0"
    assert project["license-files"] == ["LICENSE"]
    # the full text, as the Apache Software Foundation publishes it (and Debian ships it in
    # /usr/share/common-licenses/Apache-2.0)
    digest = hashlib.sha256((ROOT / "LICENSE").read_bytes()).hexdigest()
    assert digest == "cfc7749b96f63bd31c3c42b5c471bf756814053e847c10f3eb003417bc523d30"


def test_the_render_command_refuses_mp4_without_ffmpeg(monkeypatch, tmp_path, capsys):
    from mecanum_jax.sim import render

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(SystemExit) as exit_:
        render.main(["--out", str(tmp_path / "six.mp4")])
    assert exit_.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "--out = " in err
    assert "pip install 'mecanum-jax[video]'" in err
    assert not list(tmp_path.iterdir())
