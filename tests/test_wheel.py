"""The built wheel works outside the clone: its robots, run configs and scenarios ship
inside the package, and so does the shipped policy (models/o_rectangle as
mecanum_jax/shipped/o_rectangle); a user's own ``train.py`` in the working folder does
not shadow the trainer (full tier: builds a wheel and a fresh environment)."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.full


def _uv() -> str:
    for candidate in (ROOT / ".tools" / "bin" / "uv", shutil.which("uv")):
        if candidate and Path(candidate).exists():
            return str(candidate)
    pytest.skip("uv not found (./dev bootstraps it into .tools/)")


def test_wheel_installs_and_runs_from_outside_the_clone(tmp_path):
    uv = _uv()
    dist = tmp_path / "dist"
    subprocess.run([uv, "build", "--wheel", "-q", "-o", str(dist), str(ROOT)], check=True)
    (wheel,) = dist.glob("mecanum_jax-*.whl")
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
        metadata = whl.read(next(n for n in names if n.endswith(".dist-info/METADATA")))
    assert b"License-Expression: Apache-2.0" in metadata
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), names
    shipped = "mecanum_jax/shipped/o_rectangle/"
    epoch = json.loads((ROOT / "models" / "o_rectangle" / "provenance.json").read_text())["epoch"]
    meta = f"checkpoints/{epoch}/meta/metadata"  # the shipped checkpoint's
    for name in ("config.json", "policy.npz", "provenance.json", meta):
        assert shipped + name in names, name
    for kind in ("robots/o_rectangle", "eval/default", "train/tiny"):
        assert f"mecanum_jax/configs/{kind}.toml" in names, kind
    # the locked versions of the runtime dependencies (from uv's cache, no resolution)
    reqs = tmp_path / "requirements.txt"
    subprocess.run(
        [uv, "export", "--frozen", "--no-dev", "--no-emit-project", "--no-hashes", "-q",
         "-o", str(reqs)],
        check=True, cwd=ROOT,
    )  # fmt: skip
    venv = tmp_path / "venv"
    subprocess.run([uv, "venv", "-q", "-p", sys.executable, str(venv)], check=True)
    py = str(venv / "bin" / "python")
    install = [uv, "pip", "install", "-q", "-p", py]
    subprocess.run([*install, "-r", str(reqs)], check=True)
    subprocess.run([*install, "--no-deps", str(wheel)], check=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    # a user's own script named like the trainer's package: console scripts do not put the
    # working folder on sys.path, so it is never imported in place of the package
    (work / "train.py").write_text("raise SystemExit('the user train.py was imported')\n")
    script = textwrap.dedent(
        """
        import jax.numpy as jnp
        import mecanum_jax
        from mecanum_jax import builtin_description
        from mecanum_jax.kinematics import model as kinematics
        assert "site-packages" in mecanum_jax.__file__, mecanum_jax.__file__
        geom = builtin_description("o_rectangle").build_geometry()
        rates = kinematics.inverse(geom, jnp.array([0.5, 0.0, 0.0]))
        assert abs(float(rates[0]) - 10.0) < 1e-4, rates
        print("kinematics ok")
        """
    )
    # as a user's shell has it: no XLA_FLAGS of the suite's (the commands add their own)
    drop = ("PYTHONPATH", "VIRTUAL_ENV", "XLA_FLAGS")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["JAX_PLATFORMS"] = "cpu"

    def run(*argv: str) -> str:
        proc = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return proc.stdout + proc.stderr

    assert "kinematics ok" in run(py, "-c", script)
    bin_dir = venv / "bin"
    run(str(bin_dir / "mecanum-eval"), "baseline", "--only", "nominal", "--episodes", "2",
        "--seconds", "0.2", "--no-plots", "--out", "ev")  # fmt: skip
    assert (work / "ev" / "report.json").exists()
    run(str(bin_dir / "mecanum-train"), "--config", "tiny", "--ppo.num-timesteps", "1",
        "--run-dir", "r")  # fmt: skip
    assert (work / "r" / "summary.json").exists()
    # the default install has no ffmpeg: mp4 is refused, naming the extra, before a rollout
    eval_mp4 = [str(bin_dir / "mecanum-eval"), "baseline", "--video", "--out", "v"]
    proc = subprocess.run(eval_mp4, cwd=work, env=env, capture_output=True, text=True)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "pip install 'mecanum-jax[video]'" in " ".join(proc.stderr.split())
    assert not (work / "v").exists()
    # the shipped policy, found inside the package from a folder without models/
    run(str(bin_dir / "mecanum-eval"), "models/o_rectangle", "--only", "nominal",
        "--episodes", "2", "--seconds", "0.2", "--no-plots", "--out", "ev_shipped")  # fmt: skip
    assert "o_rectangle" in (work / "ev_shipped" / "report.json").read_text()
    run(str(bin_dir / "mecanum-deploy-sim"), "--episodes", "1", "--seconds", "0.2",
        "--out", "ds.json")  # fmt: skip
    assert (work / "ds.json").exists()
    (installed,) = venv.glob("lib/python*/site-packages/mecanum_jax/shipped/o_rectangle")
    packed = {n[len(shipped) :].split("/")[0] for n in names if n.startswith(shipped)}
    assert {p.name for p in installed.iterdir()} == packed  # nothing written beside it
