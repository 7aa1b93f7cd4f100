"""Runs that survive a cluster (train/loop/preemption.py): SIGTERM and SIGUSR1 checkpoint the
epoch in progress and stop the run resumably; status.json says where a run is after every
epoch; a resumed run's logs hold each epoch once.

The fast tests signal the test process itself from inside an epoch; the ``full`` one stops
``mecanum-train`` in a subprocess with SIGTERM and resumes it.
"""

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from tensorboardX.proto import event_pb2

from train.loop import preemption
from train.loop.loggers import TensorBoardLogger
from train.loop.preemption import Preempted, StopSignals
from train.loop.run import Run
from train.loop.run_records import keep_rows
from train.store import checkpoint


def _status(run_dir: Path) -> dict:
    return json.loads((run_dir / "status.json").read_text())


def _epochs(run_dir: Path) -> list[int]:
    return [json.loads(x)["epoch"] for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


def _params(run_dir: Path, learner) -> list[np.ndarray]:
    """The newest checkpoint's whole training state, as a list of arrays."""
    state, env_state = learner.init()
    host = checkpoint.restore(run_dir, *jax.tree.map(np.asarray, (state, env_state)))[0]
    return jax.tree.leaves(host)


def _signal_in_epoch(learner, monkeypatch, signum: int, at: int) -> None:
    """``learner.epoch`` sends ``signum`` to this process during its ``at``-th call."""
    real, calls = learner.epoch, []

    def epoch(*args):
        calls.append(1)
        if len(calls) == at:
            os.kill(os.getpid(), signum)
        return real(*args)

    monkeypatch.setattr(learner, "epoch", epoch)


def test_sigterm_saves_the_epoch_in_progress_and_resumes_exactly(
    full_run, tiny, learner, tmp_path, monkeypatch
):
    reference, _ = full_run
    before = signal.getsignal(signal.SIGTERM)
    run = Run.create(tiny, tmp_path / "run")
    _signal_in_epoch(learner, monkeypatch, signal.SIGTERM, at=2)
    with pytest.raises(
        Preempted, match=r"SIGTERM received: stopped after epoch 2; checkpoint "
    ) as err:
        run.train(learner=learner)
    monkeypatch.undo()
    assert isinstance(err.value, KeyboardInterrupt)  # what handles Ctrl-C handles it
    assert (err.value.exit_code, err.value.epoch) == (128 + signal.SIGTERM, 2)
    assert signal.getsignal(signal.SIGTERM) is before  # the handler was put back
    status = _status(run.dir)
    assert status["state"] == "interrupted"
    assert status["signal"] == "SIGTERM"
    assert status["epoch"] == 2  # the epoch in progress was finished and kept
    assert status["env_steps"] == 2 * tiny.steps_per_iteration * tiny.run.epoch_iterations
    assert status["last_checkpoint"]["epoch"] == 2
    assert Path(status["last_checkpoint"]["path"]) == checkpoint.checkpoint_path(run.dir, 2)
    assert checkpoint.latest_epoch(run.dir) == 2
    assert _epochs(run.dir) == [1, 2]

    Run.resume(run.dir).train(learner=learner)
    assert _epochs(run.dir) == [1, 2, 3]
    assert _status(run.dir)["state"] == "finished"
    for x, y in zip(_params(reference.dir, learner), _params(run.dir, learner), strict=True):
        np.testing.assert_array_equal(x, y)  # optimizer, params, normalizer, keys: identical
    ref_rows = [json.loads(x) for x in (reference.dir / "metrics.jsonl").read_text().splitlines()]
    rows = [json.loads(x) for x in (run.dir / "metrics.jsonl").read_text().splitlines()]
    for a, b in zip(ref_rows, rows, strict=True):
        a["train"].pop("steps_per_s"), b["train"].pop("steps_per_s")
        assert a["train"] == b["train"]


def test_sigusr1_stops_with_its_exit_code_and_status_follows_each_epoch(
    tiny, learner, tmp_path, monkeypatch
):
    """SLURM's warning before the time limit stops the run too; before it, status.json
    said "running" with the epoch and checkpoint of each epoch that ended."""
    run = Run.create(tiny, tmp_path / "run")
    seen = []

    class StatusAtEachEpoch:  # a user's metric sink: called once per epoch, before it saves
        def log(self, steps, rows):
            seen.append(_status(run.dir))

        def close(self):
            pass

    run._logs._extra.append(StatusAtEachEpoch())
    _signal_in_epoch(learner, monkeypatch, signal.SIGUSR1, at=2)
    with pytest.raises(Preempted) as err:
        run.train(learner=learner)
    assert err.value.exit_code == 138
    assert [(s["state"], s["epoch"]) for s in seen] == [("running", 0), ("running", 1)]
    assert seen[0]["last_checkpoint"] is None
    assert seen[1]["last_checkpoint"]["epoch"] == 1
    assert (_status(run.dir)["state"], _status(run.dir)["signal"]) == ("interrupted", "SIGUSR1")


def test_signals_are_left_alone_outside_the_main_thread_and_after_training():
    before = {s: signal.getsignal(s) for s in preemption.STOP_SIGNALS}
    errors = []

    def enter():
        try:
            with StopSignals() as signals:
                assert signals.signum is None
        except Exception as err:  # signal.signal raises ValueError outside the main thread
            errors.append(err)

    thread = threading.Thread(target=enter)
    thread.start()
    thread.join()
    assert errors == []
    assert {s: signal.getsignal(s) for s in preemption.STOP_SIGNALS} == before
    with StopSignals() as signals:
        os.kill(os.getpid(), signal.SIGUSR1)
        os.kill(os.getpid(), signal.SIGTERM)  # a second signal: the first one counts
        time.sleep(0.01)
        assert signals.signum == signal.SIGUSR1
    assert {s: signal.getsignal(s) for s in preemption.STOP_SIGNALS} == before
    assert preemption.agree(5, None, True) == (None, True)  # one process: its own


def test_resume_cuts_the_logs_back_to_the_checkpoint(tmp_path):
    """metrics.jsonl keeps the rows up to the checkpoint's epoch (a line cut short by a
    kill goes too); TensorBoard's writer of a resumed run starts with the marker that
    hides the earlier session's events from its first step on."""
    path = tmp_path / "metrics.jsonl"
    path.write_text("".join(json.dumps({"epoch": e}) + "\n" for e in (1, 2, 3, 4)) + '{"ep')
    assert keep_rows(path, 2) == 3
    assert [json.loads(x)["epoch"] for x in path.read_text().splitlines()] == [1, 2]
    assert keep_rows(path, 2) == 0
    assert keep_rows(tmp_path / "none.jsonl", 2) == 0
    TensorBoardLogger(tmp_path, (0,), purge_step=641).close()
    (events,) = (tmp_path / "tb" / "seed_0").glob("events.*")
    data, marks = events.read_bytes(), []
    while data:  # TFRecords: length (8 bytes), its CRC (4), the Event, its CRC (4)
        n = int.from_bytes(data[:8], "little")
        event = event_pb2.Event.FromString(data[12 : 12 + n])
        data = data[16 + n :]
        if event.HasField("session_log"):
            marks.append((event.session_log.status, event.step))
    assert marks == [(event_pb2.SessionLog.START, 641)]


AGREE = """
import json
import jax
from train.loop.distributed import init_distributed
from train.loop.preemption import agree
init_distributed(True)
me = jax.process_index()
said = [(None, False), (15 if me else None, False), (None, not me), (10 if not me else None, me)]
print(json.dumps([agree(epoch, *x) for epoch, x in enumerate(said, 1)]))
"""


def test_processes_of_a_run_agree_on_when_to_stop():
    """Two processes of a ``jax.distributed`` run stop after the same epoch: a signal or
    a time limit that one of them saw counts for both."""
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", AGREE],
            env={
                **os.environ,
                "JAX_PLATFORMS": "cpu",
                "JAX_COORDINATOR_ADDRESS": f"localhost:{port}",
                "JAX_NUM_PROCESSES": "2",
                "JAX_PROCESS_ID": str(i),
            },
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    agreed = [[None, False], [15, False], [None, True], [10, True]]
    assert [json.loads(out) for out, _ in outs] == [agreed, agreed]


def _train_cli(*args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "train.cli.train", *args]
    env = {**os.environ, "COLUMNS": "200", "TTY_COMPATIBLE": "0"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.full  # three command-line runs: minutes on 2 cores
def test_sigterm_from_outside_and_resume_equal_an_uninterrupted_run(tmp_path):
    """``mecanum-train`` stopped by SIGTERM mid-run exits with 143 and a checkpoint;
    ``--resume`` then ends with the uninterrupted run's state, each epoch logged once."""
    steps = ["--ppo.num-timesteps", "9600"]  # 30 epochs of the tiny config
    whole, part = tmp_path / "whole", tmp_path / "part"
    proc = _train_cli("--config", "tiny", "--run-dir", str(whole), *steps)
    assert proc.wait(timeout=900) == 0, proc.stderr.read()[-3000:] if proc.stderr else ""
    proc = _train_cli("--config", "tiny", "--run-dir", str(part), *steps)
    end = time.monotonic() + 900
    while not ((part / "status.json").exists() and _status(part).get("epoch", 0) >= 1):
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < end, "never reached epoch 1"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err[-3000:]
    assert "SIGTERM received" in err
    assert "Traceback" not in err
    stopped = _status(part)
    assert stopped["state"] == "interrupted"
    assert 1 <= stopped["epoch"] < 30
    assert stopped["last_checkpoint"]["epoch"] == stopped["epoch"]
    proc = _train_cli("--resume", str(part))
    assert proc.wait(timeout=900) == 0, proc.stderr.read()[-3000:] if proc.stderr else ""
    assert _epochs(part) == _epochs(whole) == list(range(1, 31))
    for a, b in zip(
        (whole / "metrics.jsonl").read_text().splitlines(),
        (part / "metrics.jsonl").read_text().splitlines(),
        strict=True,
    ):
        a_train, b_train = json.loads(a)["train"], json.loads(b)["train"]
        a_train.pop("steps_per_s"), b_train.pop("steps_per_s")
        assert a_train == b_train
    final = [json.loads((d / "summary.json").read_text()) for d in (whole, part)]
    assert final[0]["seeds"] == final[1]["seeds"]  # the last evaluation: the same policy
