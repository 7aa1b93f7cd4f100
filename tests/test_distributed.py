"""``--distributed``: the jax.distributed arguments come from validated environment variables."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from mecanum_jax.config import ConfigError
from train.cli import train as cli
from train.loop.distributed import distributed_args, init_distributed

FULL = {
    "JAX_COORDINATOR_ADDRESS": "localhost:12355",
    "JAX_NUM_PROCESSES": "2",
    "JAX_PROCESS_ID": "1",
}


def test_full_environment_gives_all_three_arguments() -> None:
    assert distributed_args(FULL) == {
        "coordinator_address": "localhost:12355",
        "num_processes": 2,
        "process_id": 1,
    }


def test_empty_environment_leaves_detection_to_jax() -> None:
    assert distributed_args({}) == {}
    # an address alone is what JAX reads itself; cluster detection supplies the rest
    assert distributed_args({"JAX_COORDINATOR_ADDRESS": "10.0.0.1:1234"}) == {
        "coordinator_address": "10.0.0.1:1234"
    }


@pytest.mark.parametrize(
    ("update", "needle"),
    [
        ({"JAX_NUM_PROCESSES": "two"}, "JAX_NUM_PROCESSES = 'two'"),
        ({"JAX_PROCESS_ID": "1.5"}, "JAX_PROCESS_ID = '1.5'"),
        ({"JAX_NUM_PROCESSES": "0", "JAX_PROCESS_ID": "0"}, "JAX_NUM_PROCESSES = 0"),
        ({"JAX_PROCESS_ID": "-1"}, "JAX_PROCESS_ID = -1"),
        ({"JAX_PROCESS_ID": "2"}, "JAX_PROCESS_ID = 2: must be < JAX_NUM_PROCESSES = 2"),
        ({"JAX_COORDINATOR_ADDRESS": "localhost"}, "JAX_COORDINATOR_ADDRESS = 'localhost'"),
        ({"JAX_COORDINATOR_ADDRESS": "host:99999"}, "JAX_COORDINATOR_ADDRESS = 'host:99999'"),
        ({"JAX_COORDINATOR_ADDRESS": ":80"}, "JAX_COORDINATOR_ADDRESS = ':80'"),
    ],
)
def test_malformed_variable_is_named_with_its_value(update: dict[str, str], needle: str) -> None:
    with pytest.raises(ConfigError, match=needle.replace("(", r"\(")):
        distributed_args({**FULL, **update})


def test_count_without_id_and_id_without_count_are_rejected() -> None:
    with pytest.raises(ConfigError, match="JAX_NUM_PROCESSES = '2' is set but JAX_PROCESS_ID"):
        distributed_args({"JAX_COORDINATOR_ADDRESS": "h:1", "JAX_NUM_PROCESSES": "2"})
    with pytest.raises(ConfigError, match="JAX_PROCESS_ID = '0' is set but JAX_NUM_PROCESSES"):
        distributed_args({"JAX_COORDINATOR_ADDRESS": "h:1", "JAX_PROCESS_ID": "0"})


def test_count_without_address_is_rejected() -> None:
    with pytest.raises(ConfigError, match="JAX_COORDINATOR_ADDRESS"):
        distributed_args({"JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "0"})


def test_init_calls_initialize_only_when_enabled() -> None:
    calls: list[dict[str, Any]] = []

    def fake(**kw: Any) -> None:
        calls.append(kw)

    assert init_distributed(False, FULL, fake) == {}
    assert calls == []
    passed = init_distributed(True, FULL, fake)
    assert calls == [passed] == [distributed_args(FULL)]
    # bad input fails before jax.distributed is touched
    with pytest.raises(ConfigError):
        init_distributed(True, {**FULL, "JAX_PROCESS_ID": "x"}, fake)
    assert len(calls) == 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return int(s.getsockname()[1])


def _two_processes(*args: str) -> list[str]:
    """``python -m train.cli.train --distributed ARGS`` as two processes of one run (2 CPU devices
    each, gloo collectives); their standard outputs."""
    port = _free_port()
    procs = []
    for i in range(2):
        env = {
            **os.environ,
            "JAX_PLATFORMS": "cpu",
            "JAX_CPU_COLLECTIVES_IMPLEMENTATION": "gloo",
            "JAX_COORDINATOR_ADDRESS": f"localhost:{port}",
            "JAX_NUM_PROCESSES": "2",
            "JAX_PROCESS_ID": str(i),
            "COLUMNS": "200",
        }
        cmd = [sys.executable, "-m", "train.cli.train", "--distributed", *args]
        procs.append(
            subprocess.Popen(
                cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        )
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    return [out for out, _ in outs]


def _metrics(run_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.full
def test_two_process_run_trains_as_one_and_resumes_exactly(tmp_path: Path) -> None:
    """``mecanum-train --distributed`` as two processes: both finish, only process 0 writes
    the run, both hold the same policy (they can only if the gradients were averaged across
    the processes), and a run interrupted after 2 epochs and resumed ends exactly as the
    uninterrupted one (process 1's robots and keys come back from its own saved state):
    two runs of two processes, the second resuming the first's epoch 2."""
    full = tmp_path / "full"
    outs = _two_processes("--config", "tiny", "--run-dir", str(full), "--run.eval-every", "3")
    summary = json.loads((full / "summary.json").read_text())
    shown = summary["seeds"][0]["eval"]["randomized"]["ss_wz"]
    # process 1 printed its own evaluation of its own parameters in the results table
    assert f"{shown:.4f}" in outs[1], (shown, outs[1][-2000:])
    rows = _metrics(full)
    assert [r["epoch"] for r in rows] == [1, 2, 3]  # written once, by process 0
    assert rows[-1]["env_steps"] == 960  # num_envs is global: 8 robots over 4 devices
    assert (summary["devices"], summary["processes"]) == (4, 2)
    assert sorted(p.name for p in (full / "checkpoints").iterdir()) == ["1", "2", "3"]
    assert sorted(p.name for p in (full / "process_state").iterdir()) == ["p1"]

    # interrupted after epoch 2: the run as it stood then (its newest checkpoint and
    # process 1's state of epoch 2; the logs are cut back on resume)
    part = tmp_path / "part"
    shutil.copytree(full, part)
    shutil.rmtree(part / "checkpoints" / "3")
    (part / "process_state" / "p1" / "3.npz").unlink()
    _two_processes("--resume", str(part), "--run.eval-every", "3")
    resumed = json.loads((part / "summary.json").read_text())
    assert resumed["seeds"][0]["eval"] == summary["seeds"][0]["eval"]
    timing = {"steps_per_s"}
    last = {k: v for k, v in _metrics(part)[-1]["train"].items() if k not in timing}
    assert last == {k: v for k, v in rows[-1]["train"].items() if k not in timing}
    assert len(last) > 20  # losses, rewards, errors


def test_no_cluster_and_no_variables_is_a_config_error() -> None:
    def jax_like(**kw: Any) -> None:
        if "coordinator_address" not in kw:
            raise ValueError("coordinator_address should be defined.")

    with pytest.raises(ConfigError, match=r"--distributed: coordinator_address.*JAX_NUM_PROC"):
        init_distributed(True, {}, jax_like)


@pytest.mark.parametrize(
    ("main", "argv", "needle"),
    [
        (cli.main, ["--distributed", "--config", "tiny"], "--distributed: give --run-dir"),
        (cli.batch_main, ["--distributed", "--configs", "tiny"], "--distributed: give --out"),
        (
            cli.main,
            ["--distributed", "--config", "tiny", "--run-dir", "x", "--ppo.num-envs", "0"],
            "num_envs",
        ),
    ],
)
def test_cli_distributed_needs_a_shared_directory_name(
    main: Any, argv: list[str], needle: str, tmp_path: Path, monkeypatch: Any, capsys: Any
) -> None:
    """Every process must name the same run directory; the clock's default name may not."""
    joined: list[bool] = []
    monkeypatch.setattr(cli, "init_distributed", joined.append)
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert joined == [True]  # joined first: JAX refuses to start distributed later
    captured = capsys.readouterr()
    assert needle in (captured.out + captured.err).replace("\n", "")
    assert not (tmp_path / "runs").exists()
    assert not (tmp_path / "x").exists()


def test_loop_keys_are_distinct_per_process(learner: Any, monkeypatch: Any) -> None:
    """Each process's devices get their own PPO loop keys (a resumed process whose saved
    keys are lost falls back to these), and process 0's are those of a one-process run."""
    import jax
    import numpy as np

    alone = np.asarray(learner.init_training()[0].key)
    streams = []
    for index in (0, 1, 2):
        monkeypatch.setattr(jax, "process_index", lambda i=index: i)
        streams.append(np.asarray(learner.init_training()[0].key))  # (D, S, 2)
    np.testing.assert_array_equal(streams[0], alone)
    keys = np.concatenate(streams).reshape(-1, alone.shape[-1])
    assert len({tuple(k) for k in keys}) == len(keys)  # every device of every process
