"""The first day's set-up: which path ``./dev`` takes (an NVIDIA GPU or the CPU), what it
says of the shipped policy, and the optional extras (``video``, ``cuda``) and licence.

``./dev which`` prints what ``./dev main`` would install and run, installing and running
nothing, so these tests need no GPU and leave the environment alone. A fake ``nvidia-smi``
on ``PATH`` stands in for a GPU machine."""

import hashlib
import json
import os
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from train.cli import eval_args, evaluate

ROOT = Path(__file__).resolve().parent.parent
H100 = "GPU 0: NVIDIA H100 80GB HBM3 (UUID: GPU-0f1e2d3c)"


def _path(tmp_path: Path, nvidia_smi: str | None = None, status: int = 0) -> str:
    """A PATH holding only what ``./dev which`` runs (so the test means the same on a GPU
    machine) and, given its output, a fake ``nvidia-smi``."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("bash", "date", "dirname"):
        (bin_dir / tool).symlink_to(shutil.which(tool) or pytest.fail(f"no {tool}"))
    (bin_dir / "python3").symlink_to(Path(sys.executable).resolve())
    if nvidia_smi is not None:
        lines = "".join(f"printf '%s\\n' {shlex.quote(x)}\n" for x in nvidia_smi.splitlines())
        (bin_dir / "nvidia-smi").write_text(f"#!/bin/sh\n{lines}exit {status}\n")
        (bin_dir / "nvidia-smi").chmod(0o755)
    return str(bin_dir)


def _which(path: str, *args: str, dev: Path = ROOT / "dev") -> dict[str, str]:
    env = {**os.environ, "PATH": path}
    out = subprocess.run(
        [f"{path}/bash", str(dev), "which", *args],
        capture_output=True, text=True, env=env, check=True,
    ).stdout  # fmt: skip
    return dict(line.split(": ", 1) for line in out.splitlines())


def test_a_gpu_gets_the_cuda_environment_and_the_gpu_run(tmp_path):
    plan = _which(_path(tmp_path, H100))
    assert plan["device"] == "NVIDIA H100 80GB HBM3"
    assert plan["sync"] == ".tools/bin/uv sync --frozen --quiet --extra cuda --extra warp"
    train = plan["train"].split()
    assert train[0] == ".venv/bin/mecanum-train"
    assert " --config gpu --env.physics-impl warp --max-minutes " in plan["train"]
    run = train[train.index("--run-dir") + 1]
    assert run.startswith("runs/gpu-")
    assert plan["evaluate"].split()[:2] == [".venv/bin/mecanum-eval", run]  # the run just trained


def test_without_a_gpu_the_cpu_path_is_as_before(tmp_path):
    plan = _which(_path(tmp_path), "--ppo.num-envs", "64")
    assert plan["device"].startswith("cpu")
    assert plan["sync"] == ".tools/bin/uv sync --frozen --quiet"  # no extra
    train = plan["train"].split()
    assert train[:2] == [".venv/bin/mecanum-train", "--run-dir"]
    assert train[2].startswith("runs/quick-")
    assert train[3:] == ["--ppo.num-envs", "64"]  # the quick config, the user's flags
    assert plan["evaluate"].split() == [
        ".venv/bin/mecanum-eval", train[2], "--episodes", "8", "--references", "analytic",
        "--no-plots",
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("output", "status"),
    [
        # the tool is installed but the driver is not loaded
        ("NVIDIA-SMI has failed because it couldn't communicate with the NVIDIA driver.", 9),
        ("No devices found.", 6),
        ("", 0),  # succeeds and lists no GPU
    ],
)
def test_an_nvidia_smi_that_lists_no_gpu_means_the_cpu(tmp_path, output, status):
    plan = _which(_path(tmp_path, output, status))
    assert plan["device"].startswith("cpu")
    assert "--extra" not in plan["sync"]


def test_cpu_flag_forces_the_cpu_path_on_a_gpu(tmp_path):
    path = _path(tmp_path, H100 + "\n" + H100.replace("GPU 0", "GPU 1"))
    assert _which(path)["device"] == "2 x NVIDIA H100 80GB HBM3"
    plan = _which(path, "--cpu")
    assert plan["device"] == "cpu (--cpu)"
    assert plan["sync"] == ".tools/bin/uv sync --frozen --quiet"
    assert "--config" not in plan["train"]
    assert "--cpu" not in plan["train"]


def test_the_shipped_policy_message_comes_from_its_provenance(tmp_path):
    recorded = json.loads((ROOT / "models" / "o_rectangle" / "provenance.json").read_text())
    shipped = _which(_path(tmp_path))["shipped"]
    assert shipped.startswith("models/o_rectangle: trained ")
    assert f"{recorded['walltime_s'] / 60:.1f} min" in shipped
    assert recorded["device"] in shipped
    assert f"{recorded['env_steps']:,} env steps" in shipped


@pytest.mark.parametrize(
    ("provenance", "expected"),
    [
        ({"device": "NVIDIA H200", "date": "2026-12-01"}, "trained on NVIDIA H200, 2026-12-01"),
        (
            {"walltime_s": 600, "devices": 2, "device": "NVIDIA H200", "env_steps": 1234567},
            "trained 10.0 min on 2 x NVIDIA H200, 1,234,567 env steps",
        ),
        ({"env_steps": 5}, "5 env steps"),
        ({}, "provenance.json records no training details"),
        ("[1, 2", "provenance.json unreadable (JSONDecodeError)"),
        (None, "provenance.json unreadable (FileNotFoundError)"),
    ],
)
def test_the_message_says_what_the_provenance_records(tmp_path, provenance, expected):
    """A copy of ./dev beside a models/o_rectangle of the test's own."""
    path = _path(tmp_path)
    clone = tmp_path / "clone"
    clone.mkdir()
    dev = clone / "dev"
    shutil.copy(ROOT / "dev", dev)
    model = clone / "models" / "o_rectangle"
    model.mkdir(parents=True)
    if provenance is not None:
        text = provenance if isinstance(provenance, str) else json.dumps(provenance)
        (model / "provenance.json").write_text(text)
    assert _which(path, dev=dev)["shipped"] == f"models/o_rectangle: {expected}"
    assert sorted(p.name for p in clone.iterdir()) == ["dev", "models"]  # nothing installed


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
        eval_args.check_args(evaluate._parse(["baseline", *argv], "p", evaluate.EvalArgs))


def test_mp4_passes_the_check_where_ffmpeg_is_installed():
    pytest.importorskip("imageio_ffmpeg")
    eval_args.check_args(evaluate._parse(["baseline", "--video"], "p", evaluate.EvalArgs))


def test_extras_and_licence_are_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    assert extras["video"] == ["imageio-ffmpeg>=0.5"]
    assert not any(d.startswith("imageio-ffmpeg") for d in project["dependencies"])
    assert any(d.startswith("jax[cuda12]") for d in extras["cuda"])
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
