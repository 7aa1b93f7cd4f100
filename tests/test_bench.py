"""Smoke test of ``mecanum-bench kinematics`` at small sizes: it runs and writes its report.

It asserts the report's structure, never a speed (speed is proved by the full run recorded
in docs/benchmarks.md).
"""

import json

from mecanum_jax import bench


def test_kinematics_bench_smoke(tmp_path, capsys):
    out = tmp_path / "k.json"
    bench.main(
        [
            "kinematics",
            "--sizes",
            "100",
            "1000",
            "--repeats",
            "1",
            "--min-time",
            "0.001",
            "--odometry-steps",
            "2",
            "--json-out",
            str(out),
        ]
    )
    report = json.loads(out.read_text())
    assert report["benchmark"] == "kinematics"
    ops = {(r["op"], r["size"]) for r in report["results"]}
    assert ops == {
        (op, n) for op in ("inverse", "inverse_soa", "forward", "odometry") for n in (100, 1000)
    }
    for r in report["results"]:
        for key in ("jax_s", "jax_latency_s", "numpy_s", "copy_s", "roofline_fraction"):
            assert r[key] > 0
    assert "inverse_soa" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.tmp"))  # written atomically


def test_bench_rejects_bad_arguments(capsys):
    assert bench.main(["kinematics", "--ops", "nope", "--sizes", "10"]) == 2
    assert "error: --ops: unknown operation 'nope'" in capsys.readouterr().err
    assert bench.main(["kinematics", "--sizes", "0"]) == 2
    assert "error: --sizes = [0]: 0 is not a positive batch size" in capsys.readouterr().err
