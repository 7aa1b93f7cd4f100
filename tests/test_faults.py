"""No fault loses work (mecanum_jax/atomic.py, train/loop/run_dir.py): a full or read-only
disk and a second writer of a run.

Each command line meets a disk that fails (``os.fsync`` or a copy raising ENOSPC, as a full
disk does at the end of a write; EROFS or a chmod for a read-only one) with exit code 2 and
one line naming the path, leaves none of its own files, and the files already there keep
their bytes. A run directory has one writer: a second one is refused before it writes. The
``full`` tests train: a checkpoint that fails on a full disk stops the run resumably, and a
run killed (SIGKILL) in a checkpoint's save resumes while a second resume is refused.
"""

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mecanum_jax import atomic
from train.cli import deploy_sim, evaluate, export, train
from train.cli.paths import shipped_dir
from train.loop.run import Run
from train.store import checkpoint, lock

MODEL = shipped_dir() / "o_rectangle"
FULL = r"no space left on device writing '{}' \([\d.]+ MB free on /[^)]*\); free space and re-run"


def _snapshot(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` (or ``path`` itself) and its bytes."""
    if path.is_file():
        return {"": path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in path.rglob("*") if p.is_file()}


def _error_line(capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line a failed command printed to stderr (besides its progress log),
    without its ``error: ``."""
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if "error" in line.lower()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    return lines[0].removeprefix("error: ")


def _disk_full(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every fsync fails as on a full disk: each atomic write's bytes are in its temporary
    file when it fails."""

    def fsync(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", fsync)


def _debris(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial" in p.name or "-tmp" in p.name]


def test_an_atomic_write_keeps_the_old_bytes_on_a_full_disk(tmp_path, monkeypatch):
    path = tmp_path / "status.json"
    atomic.write_json(path, {"state": "running"})
    before = path.read_bytes()
    _disk_full(monkeypatch)
    for write in (
        lambda: atomic.write_json(path, {"state": "finished"}),
        lambda: atomic.copy_file(MODEL / "config.json", path),
        lambda: atomic.append_text(path, "more\n"),
    ):
        with pytest.raises(atomic.DiskError, match=FULL.format(path)):
            write()
        assert path.read_bytes() == before
    with pytest.raises(atomic.DiskError), atomic.directory(tmp_path / "model") as tmp:
        atomic.write_text(tmp / "a.txt", "a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["status.json"]
    err = atomic.explain(ValueError("Failed to write 10 bytes: No space left on device"), path)
    assert isinstance(err, atomic.DiskError)
    assert err.no_space


EXPORTS = {
    "npz": ["p.npz"],
    "onnx": ["p.onnx", "--format", "onnx"],
}


@pytest.mark.parametrize("kind", list(EXPORTS))
def test_an_export_on_a_full_disk_leaves_nothing_and_the_retry_works(
    kind, tmp_path, monkeypatch, capsys
):
    """Before, a full disk left a 0-byte p.onnx that the retry refused as existing."""
    if kind == "onnx":
        pytest.importorskip("onnx")
    monkeypatch.chdir(tmp_path)
    argv = [str(MODEL), *EXPORTS[kind]]
    with monkeypatch.context() as m:
        _disk_full(m)
        assert export.main(argv) == 2
    assert _error_line(capsys).startswith(f"no space left on device writing '{argv[1]}' (")
    assert list(tmp_path.iterdir()) == []
    assert export.main(argv) == 0
    assert (tmp_path / argv[1]).stat().st_size > 1000


def test_a_model_export_on_a_full_disk_is_one_line_and_leaves_no_partial(
    tmp_path, monkeypatch, capsys
):
    """Before, a shutil.Error listing every file's failure (5 KB) and a 3 MB .partial."""
    monkeypatch.chdir(tmp_path)
    real, calls = shutil.copyfile, []

    def copyfile(src, dst, **kw):  # the disk fills up in the third file: half of it written
        calls.append(dst)
        if len(calls) >= 3:
            Path(dst).write_bytes(Path(src).read_bytes()[: Path(src).stat().st_size // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))
        return real(src, dst, **kw)

    monkeypatch.setattr(shutil, "copyfile", copyfile)
    assert export.main([str(MODEL), "m", "--model"]) == 2
    line = _error_line(capsys)
    assert line.startswith(f"no space left on device writing '{calls[2]}' (")
    assert len(line) < 300
    assert list(tmp_path.iterdir()) == []


def test_an_evaluation_on_a_full_disk_leaves_no_partial(tmp_path, monkeypatch, capsys):
    def evaluate_into(partial, *args):  # the parts written, then the report meets a full disk
        (partial / "parts.npz").write_bytes(b"\0" * 4096)
        _disk_full(monkeypatch)
        atomic.write_json(partial / "report.json", {})

    monkeypatch.setattr(evaluate, "_evaluate_into", evaluate_into)
    out = tmp_path / "ev"
    argv = ["baseline", "--only", "nominal", "--episodes", "1", "--out", str(out)]
    assert evaluate.main(argv) == 2
    assert _error_line(capsys).startswith(f"no space left on device writing '{out}.partial/")
    assert list(tmp_path.iterdir()) == []


def test_a_deploy_rehearsal_on_a_full_disk_leaves_nothing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "figures.json"
    original = deploy_sim.report

    def report(*args):  # the loop has run: its figures meet a full disk
        _disk_full(monkeypatch)
        return original(*args)

    monkeypatch.setattr(deploy_sim, "report", report)
    argv = [str(MODEL), "--command", "0.2", "0", "0", "--seconds", "0.2", "--out", str(out)]
    assert deploy_sim.main(argv) == 2
    assert _error_line(capsys).startswith(f"no space left on device writing '{out}' (")
    assert list(tmp_path.iterdir()) == []


def test_a_new_run_on_a_full_disk_leaves_no_run_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _disk_full(monkeypatch)
    assert train.main(["--config", "tiny", "--run-dir", "run"]) == 2
    line = _error_line(capsys)
    assert line.startswith("no space left on device writing 'run/config.json' (")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def made(tiny, tmp_path):
    """A run directory as Run.create leaves it (no epoch trained), its lock given back, with
    a metrics row and a TensorBoard folder to be kept byte for byte."""
    run = Run.create(tiny, tmp_path / "run")
    run.close()
    (run.dir / "metrics.jsonl").write_text('{"epoch": 1}\n')
    (run.dir / "tb").mkdir()
    return run.dir


HOLD = (
    "import sys; from train.store import lock; lock.acquire(sys.argv[1]); "
    "print(1, flush=True); input()"
)


def test_a_second_writer_is_refused_at_once_and_a_killed_one_frees_the_run(made, capsys):
    """A process that holds the run (here one that took the lock) makes a second
    ``--resume`` exit 2 with one line naming it, writing nothing; killed with SIGKILL, it
    leaves the run free (the OS drops the lock)."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(made)], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    try:
        assert holder.stdout is not None
        assert holder.stdout.readline().strip() == b"1"
        before = _snapshot(made)
        assert train.main(["--resume", str(made)]) == 2
        assert _error_line(capsys) == (
            f"run directory {str(made)!r} is in use by another process (pid {holder.pid}); "
            f"wait for it to end or stop it, then resume with --resume {made}"
        )
        assert _snapshot(made) == before
        assert not lock.holds(made)
    finally:
        holder.kill()
        holder.wait()
    Run.resume(made).close()  # free again


def test_a_read_only_run_directory_is_refused_in_one_line(made, monkeypatch, capsys):
    before = _snapshot(made)
    made.chmod(0o555)
    try:
        if os.access(made, os.W_OK):  # root: the mode does not stop writes; the mount would
            real = os.open

            def read_only(path, flags, *args):
                if str(path).startswith(str(made)) and flags & (os.O_WRONLY | os.O_RDWR):
                    raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
                return real(path, flags, *args)

            monkeypatch.setattr(os, "open", read_only)
        assert train.main(["--resume", str(made)]) == 2
        line = _error_line(capsys)
    finally:
        made.chmod(0o755)
    assert line.startswith(f"{os.strerror(errno.EROFS).lower()} writing '{made}/.lock' (on /")
    assert line.endswith("make it writable or write elsewhere, and re-run")
    assert _snapshot(made) == before


def _epochs(run_dir: Path) -> list[int]:
    return [json.loads(x)["epoch"] for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.full  # trains the tiny run: tens of seconds on 2 cores
def test_a_checkpoint_on_a_full_disk_stops_the_run_resumably(tiny, learner, tmp_path, monkeypatch):
    import orbax.checkpoint as ocp

    real = ocp.CheckpointManager.save

    def save(self, step, *args, **kw):  # orbax's error, after a part of the save was written
        if step < 2:
            return real(self, step, *args, **kw)
        tmp = Path(self.directory) / f"{step}.orbax-checkpoint-tmp"
        (tmp / "train").mkdir(parents=True)
        (tmp / "train" / "d").write_bytes(b"\0" * 1000)
        raise ValueError(
            f'RESOURCE_EXHAUSTED: Failed writing: "{tmp}/train/d": Failed to write 506353 '
            "bytes to file 17: No space left on device [os_error_code='28']"
        )

    run = Run.create(tiny, tmp_path / "run")
    with monkeypatch.context() as m:
        m.setattr(ocp.CheckpointManager, "save", save)
        with pytest.raises(atomic.DiskError, match=FULL.format(f"{tmp_path}/run/checkpoints/2")):
            run.train(learner=learner)
    status = json.loads((run.dir / "status.json").read_text())
    assert status["state"] == "failed: no space"
    assert status["last_checkpoint"]["epoch"] == 1
    assert status["error"].startswith("no space left on device writing")
    assert _debris(run.dir) == []
    assert checkpoint.latest_epoch(run.dir) == 1
    Run.resume(run.dir).train(learner=learner)  # the disk has room again
    assert _epochs(run.dir) == [1, 2, 3]
    assert json.loads((run.dir / "status.json").read_text())["state"] == "finished"


KILLED_IN_SAVE = textwrap.dedent(
    """
    import os, signal, sys
    from orbax.checkpoint._src.path import atomicity  # where orbax renames a save complete
    from train.cli import train
    Rename = atomicity.AtomicRenameTemporaryPath
    real = Rename.finalize
    async def finalize(self, *args, **kw):  # checkpoint 2 written, not yet renamed: killed
        if self.get_final().name == "2":
            os.kill(os.getpid(), signal.SIGKILL)
        return await real(self, *args, **kw)
    Rename.finalize = finalize
    sys.exit(train.main(sys.argv[1:]))
    """
)


def _train_cli(*args: str, script: str | None = None) -> subprocess.Popen:
    cmd = [sys.executable, *(["-c", script] if script else ["-m", "train.cli.train"]), *args]
    env = {**os.environ, "COLUMNS": "200", "TTY_COMPATIBLE": "0"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.full  # two command-line runs: minutes on 2 cores
def test_killed_in_a_checkpoint_resumes_and_a_second_resume_is_refused(tmp_path, capsys):
    run_dir = tmp_path / "run"
    killed = _train_cli("--config", "tiny", "--run-dir", str(run_dir), script=KILLED_IN_SAVE)
    _, err = killed.communicate(timeout=900)
    assert killed.returncode == -signal.SIGKILL, err[-3000:]
    assert checkpoint.latest_epoch(run_dir) == 1
    assert [p.name for p in _debris(run_dir)] == ["2.orbax-checkpoint-tmp"]
    resumed = _train_cli("--resume", str(run_dir))
    try:
        end = time.monotonic() + 300
        while (run_dir / ".lock").read_text().strip() != str(resumed.pid):
            assert resumed.poll() is None
            assert time.monotonic() < end
            time.sleep(0.05)
        before = _snapshot(run_dir / "metrics.jsonl")
        assert train.main(["--resume", str(run_dir)]) == 2  # while the first compiles
        assert f"is in use by another process (pid {resumed.pid})" in _error_line(capsys)
        assert _snapshot(run_dir / "metrics.jsonl") == before
        _, err = resumed.communicate(timeout=900)
    finally:
        resumed.kill()
    assert resumed.returncode == 0, err[-3000:]
    assert "removed a checkpoint cut short" in err
    assert _epochs(run_dir) == [1, 2, 3]  # each epoch once
    assert _debris(run_dir) == []
    assert checkpoint.latest_epoch(run_dir) == 3


REAL_DISK = """
mount -t tmpfs -o size=1m tmpfs {mnt} || exit 99
head -c 950000 /dev/zero > {mnt}/filler
for out in "p.onnx --format onnx" "m --model"; do
  {python} -m train.cli.export {model} {mnt}/$out; echo "rc=$?"; ls -A {mnt}
done
"""


@pytest.mark.full  # two exports in fresh interpreters: tens of seconds
def test_exports_into_a_really_full_disk(tmp_path):
    """A 1 MB tmpfs, 0.1 MB of it free, in a user and mount namespace of its own (where
    the kernel lets an unprivileged user make one): the ONNX export and the model
    directory (3 MB) each exit 2 with one line and leave only the filler."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1): cannot mount a small tmpfs")
    script = REAL_DISK.format(mnt=mnt, python=sys.executable, model=MODEL)
    env = {**os.environ, "COLUMNS": "300", "TTY_COMPATIBLE": "0"}
    proc = subprocess.run(
        ["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True, env=env, timeout=600
    )
    if proc.returncode == 99 or "unshare:" in proc.stderr:
        pytest.skip(f"cannot mount a tmpfs in a namespace: {proc.stderr.strip()[-300:]}")
    assert proc.stdout.split() == ["rc=2", "filler", "rc=2", "filler"], proc.stderr[-3000:]
    errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
    assert "Traceback" not in proc.stderr
    assert len(errors) == 2, proc.stderr[-3000:]
    for line, name in zip(errors, (f"{mnt}/p.onnx", f"{mnt}/m.partial/"), strict=True):
        assert line.startswith(f"error: no space left on device writing '{name}"), line
        assert re.search(rf"\(0\.\d MB free on {mnt}\); free space and re-run$", line), line
