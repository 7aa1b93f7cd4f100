"""No command line overwrites what is already there: each writing CLI, pointed at an
existing target, refuses with exit code 2 and one line naming it, and the files in the
target survive byte for byte. All refuse before anything compiles."""

from pathlib import Path

import pytest

from mecanum_jax.deploy import ros2
from train.cli import deploy_sim, evaluate, export, train
from train.cli.paths import shipped_dir
from train.loop.run import Run

MODEL = shipped_dir() / "o_rectangle"


def _snapshot(path: Path) -> dict[str, bytes]:
    if path.is_file():
        return {"": path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in path.rglob("*") if p.is_file()}


@pytest.fixture
def earlier(tmp_path, monkeypatch):
    """An earlier result in the CWD: a folder with a summary.json and a report file."""
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "earlier"
    folder.mkdir()
    (folder / "summary.json").write_text('{"earlier": true}\n')
    (tmp_path / "earlier.json").write_text('{"earlier": true}\n')
    (tmp_path / "earlier.npz").write_bytes(b"earlier")
    (tmp_path / "earlier.toml").write_text("# earlier\n")
    return tmp_path


def _ros_params(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> str:
    assert ros2.main(["o_rectangle", "--to-ros"]) == 0
    path = tmp_path / "params.yaml"
    path.write_text(capsys.readouterr().out)
    return str(path)


CASES = {
    "mecanum-train": (train.main, ["--config", "tiny", "--run-dir", "earlier"], "earlier"),
    "mecanum-train-batch": (
        train.batch_main,
        ["--configs", "tiny", "--out", "earlier"],
        "earlier",
    ),
    "mecanum-eval --out": (
        evaluate.main,
        ["baseline", "--only", "nominal", "--episodes", "1", "--out", "earlier"],
        "earlier",
    ),
    "mecanum-export": (export.main, [str(MODEL), "earlier.npz"], "earlier.npz"),
    "mecanum-export --model": (export.main, [str(MODEL), "earlier", "--model"], "earlier"),
    "mecanum-deploy-sim --out": (
        deploy_sim.main,
        [str(MODEL), "--out", "earlier.json"],
        "earlier.json",
    ),
    "mecanum-ros2": (ros2.main, ["PARAMS", "earlier.toml"], "earlier.toml"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_an_existing_target_is_refused_and_kept(name, earlier, capsys):
    main, argv, target = CASES[name]
    argv = [_ros_params(earlier, capsys) if a == "PARAMS" else a for a in argv]
    before = _snapshot(earlier / target)
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    assert repr(target) in err[0], err
    assert "never overwritten" in err[0], err
    assert _snapshot(earlier / target) == before
    assert not list(earlier.glob("*.partial"))


def test_an_empty_folder_may_take_a_batch(earlier, monkeypatch):
    """An existing but empty --out is used (as an empty --run-dir is): nothing to lose."""
    (earlier / "empty").mkdir()
    created = []
    monkeypatch.setattr(Run, "create", lambda cfg, d, **kw: created.append(d) or 1 / 0)
    with pytest.raises(ZeroDivisionError):
        train.batch_main(["--configs", "tiny", "--out", "empty"])
    assert created == [Path("empty") / "tiny"]
