"""TensorBoard's event files (train/loop/loggers.py): every logged number reaches them, and
logging never waits for tensorboardX's writer thread."""

import struct

import pytest
from tensorboardX import SummaryWriter
from tensorboardX.proto import event_pb2

from train.loop.loggers import TensorBoardLogger


def _scalars(folder):
    """``{(tag, step): value}`` of every event file in ``folder`` (TFRecord framing: a
    length, its CRC, the Event, its CRC)."""
    out = {}
    for path in sorted(folder.glob("events.*")):
        data = path.read_bytes()
        at = 0
        while at < len(data):
            (length,) = struct.unpack("<Q", data[at : at + 8])
            event = event_pb2.Event.FromString(data[at + 12 : at + 12 + length])
            at += 12 + length + 4
            for value in event.summary.value:
                out[(value.tag, event.step)] = value.simple_value
    return out


def test_every_logged_number_reaches_the_event_files(tmp_path):
    logger = TensorBoardLogger(tmp_path, (0, 3))
    rows = {0: {"loss": 0.5, "eval/ss_lin": 0.25}, 3: {"loss": 1.5, "eval/ss_lin": 0.75}}
    logger.log(100, rows)
    logger.log(200, {s: {k: 2 * v for k, v in row.items()} for s, row in rows.items()})
    logger.close()
    for seed, row in rows.items():
        got = _scalars(tmp_path / "tb" / f"seed_{seed}")
        want = {(k, 100): v for k, v in row.items()} | {(k, 200): 2 * v for k, v in row.items()}
        assert got == pytest.approx(want)


def test_logging_does_not_flush(tmp_path, monkeypatch):
    """An epoch's log only queues its events: the writer thread flushes them on its own
    clock and at close."""
    logger = TensorBoardLogger(tmp_path, (0,))

    def refuse(self):
        raise AssertionError("flushed while logging")

    monkeypatch.setattr(SummaryWriter, "flush", refuse)
    logger.log(
        1, {0: {f"metric_{i}": float(i) for i in range(300)}}
    )  # 300: more than the old queue of 10
    monkeypatch.undo()
    logger.close()
    assert len(_scalars(tmp_path / "tb" / "seed_0")) == 300
