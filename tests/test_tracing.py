"""The CPU's unrolled threefry (mecanum_jax.tracing): the same random bits as JAX's rolled loop,
lowered without a loop, and installed by every entry point's preparation; the GPUs' threefry
kernel, which the preparation asks for unless the environment chooses; and XLA:CPU's older
emitters, which the command lines ask for; and the evaluator's reproducible GPU ops."""

from __future__ import annotations

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from mecanum_jax import tracing
from mecanum_jax.config import ConfigError
from mecanum_jax.precision import matmul_precision, set_matmul_precision


def draws(key: jax.Array) -> tuple[jax.Array, ...]:
    """The kinds of draw the task and the trainer make, from one key."""
    k1, k2, k3, k4, k5 = jax.random.split(key, 5)
    return (
        jax.random.normal(k1, (7, 3)),
        jax.random.uniform(k2, (5,), minval=-1.0, maxval=2.0),
        jax.random.randint(k3, (9,), 0, 1000),
        jax.random.permutation(k4, 33),
        jax.random.bernoulli(k5, 0.3, (11,)),
        jax.random.fold_in(k5, 7),
    )


def lowered(rolled: bool) -> tuple[str, list[np.ndarray]]:
    """Lower and run :func:`draws` with JAX's rolled CPU lowering or the unrolled one."""
    from jax._src.interpreters import mlir
    from jax._src.random import threefry2x32 as tf

    mlir.register_lowering(tf.threefry2x32_p, tracing.threefry_rule(rolled), platform="cpu")
    try:
        keys = jax.random.split(jax.random.PRNGKey(3), 4)
        fn = jax.jit(jax.vmap(lambda k: draws(k)))  # a fresh function: no cached lowering
        text = fn.lower(keys).as_text()
        out = [np.asarray(x) for x in fn(keys)]
        return text, out
    finally:  # as every entry point leaves it
        mlir.register_lowering(tf.threefry2x32_p, tracing.threefry_rule(False), platform="cpu")


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the CPU's lowering")
def test_unrolled_threefry_gives_the_same_bits_without_a_loop() -> None:
    assert tracing.unroll_threefry()  # this JAX has the lowering it reuses
    rolled_text, rolled = lowered(rolled=True)
    unrolled_text, unrolled = lowered(rolled=False)
    assert "stablehlo.while" in rolled_text  # JAX's own CPU lowering loops
    assert "stablehlo.while" not in unrolled_text
    assert len(rolled) == len(unrolled) == 6
    for a, b in zip(rolled, unrolled, strict=True):
        assert (a.dtype, a.shape) == (b.dtype, b.shape)
        np.testing.assert_array_equal(a, b)


def test_prepare_tracing_sets_the_precision_and_the_lowering() -> None:
    before = matmul_precision()
    try:
        tracing.prepare_tracing("high")
        assert matmul_precision() == "high"
        with pytest.raises(ConfigError, match="--matmul-precision = 'tf32'"):
            tracing.prepare_tracing("tf32", "--matmul-precision")
    finally:
        set_matmul_precision(before)
    assert tracing.unroll_threefry()  # idempotent: installed once, reported each time
    text = jax.jit(lambda k: jax.random.normal(k, (4,))).lower(jax.random.PRNGKey(0)).as_text()
    assert "stablehlo.while" not in text


def _cuda_module(fn) -> str:
    """``fn`` of one key lowered for CUDA (no GPU needed), as MLIR text."""
    return jax.export.export(jax.jit(fn), platforms=["cuda"])(jax.random.PRNGKey(0)).mlir_module()


def test_gpus_draw_through_the_threefry_kernel_unless_the_environment_chooses(
    threefry_flag, monkeypatch
):
    """With the flag a CUDA program calls JAX's kernel once per draw instead of holding the
    hash's rounds; the environment's ``JAX_THREEFRY_GPU_KERNEL_LOWERING`` is left to stand.
    (The kernel's bits equal the unrolled hash's: checked on the GPU, docs/profiling.md.)"""
    kernel = "cu_threefry2x32_ffi"
    jax.config.update(threefry_flag, False)
    unrolled = _cuda_module(draws)
    assert kernel not in unrolled
    monkeypatch.setenv(tracing.GPU_THREEFRY_VAR, "0")
    assert not tracing.threefry_kernel_on_gpus()
    monkeypatch.delenv(tracing.GPU_THREEFRY_VAR)
    assert tracing.threefry_kernel_on_gpus()
    kernels = _cuda_module(draws)
    assert kernels.count(kernel) >= 5  # split, normal, uniform, randint, permutation...
    assert len(kernels) < len(unrolled) / 2


def test_a_jax_without_the_switch_keeps_its_own_lowering(monkeypatch):
    """Where JAX's private lowering has no ``use_rolled_loops`` switch (another JAX), the
    call installs nothing and says so, rather than failing later, at a lowering."""
    from jax._src.random import threefry2x32 as tf

    monkeypatch.setattr(tracing, "_installed", [])
    monkeypatch.setattr(tf, "_threefry2x32_lowering", lambda key1, key2, x1, x2: (x1, x2))
    assert tracing.unroll_threefry() is False
    assert tracing.unroll_threefry() is False  # decided once
    text = jax.jit(lambda k: jax.random.normal(k, (4,))).lower(jax.random.PRNGKey(1)).as_text()
    assert "stablehlo.while" not in text  # the rule installed before is left as it was


def test_older_cpu_emitters_adds_the_flag_once_beside_the_callers_flags():
    environ = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    assert tracing.older_cpu_emitters(environ, "0.10.2")
    assert tracing.older_cpu_emitters(environ, "0.10.2")
    assert environ["XLA_FLAGS"].split() == [
        "--xla_force_host_platform_device_count=2",
        tracing.OLDER_CPU_EMITTERS,
    ]


@pytest.mark.parametrize(
    ("environ", "version"),
    [({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}, "0.10.2"), ({}, "0.12.0")],
    ids=["the caller's choice", "an unknown jaxlib"],
)
def test_older_cpu_emitters_leaves_a_callers_choice_and_an_unknown_jaxlib(environ, version):
    before = dict(environ)
    assert not tracing.older_cpu_emitters(environ, version)
    assert environ == before


def test_the_installed_xla_knows_the_flag_where_it_is_added():
    """XLA aborts a process over an unknown flag: under the installed jaxlib, a process
    with the flag added compiles and runs."""
    environ = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if not tracing.older_cpu_emitters(environ):
        pytest.skip("this jaxlib is not one the flag is added under")
    code = "import jax; print(jax.jit(lambda x: x + 1)(1.0))"
    done = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "2.0" in done.stdout


def test_reproducible_gpu_ops_adds_the_flag_once_beside_the_callers_flags():
    environ = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    assert tracing.reproducible_gpu_ops(environ, "0.11.2", started=False)
    assert tracing.reproducible_gpu_ops(environ, "0.10.2", started=False)
    assert environ["XLA_FLAGS"].split() == [
        "--xla_force_host_platform_device_count=2",
        tracing.REPRODUCIBLE_GPU_OPS,
    ]


@pytest.mark.parametrize(
    ("environ", "version", "started"),
    [
        ({"XLA_FLAGS": "--xla_gpu_exclude_nondeterministic_ops=false"}, "0.11.2", False),
        ({}, "0.12.0", False),
        ({}, "0.11.2", True),
    ],
    ids=["the caller's choice", "an unknown jaxlib", "a started backend"],
)
def test_reproducible_gpu_ops_leaves_a_choice_an_unknown_jaxlib_and_a_started_backend(
    environ, version, started
):
    before = dict(environ)
    assert not tracing.reproducible_gpu_ops(environ, version, started=started)
    assert environ == before


def test_mecanum_eval_asks_for_reproducible_gpu_ops_before_jax_starts():
    """In a fresh process the evaluator's command line adds the flag before anything starts
    JAX's backend (XLA reads ``XLA_FLAGS`` once), and the installed XLA knows it: the
    process runs on."""
    environ = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if not tracing.reproducible_gpu_ops(dict(environ), started=False):
        pytest.skip("this jaxlib is not one the flag is added under")
    code = (
        "import os\nfrom train.cli import evaluate\ntry:\n    evaluate.main(['--help'])\n"
        "except SystemExit:\n    pass\nimport jax\nprint(jax.jit(lambda x: x + 1)(1.0))\n"
        "print(os.environ['XLA_FLAGS'])"
    )
    done = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "2.0" in done.stdout
    assert tracing.REPRODUCIBLE_GPU_OPS in done.stdout.split()
