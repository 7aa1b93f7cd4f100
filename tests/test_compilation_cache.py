"""The persistent compilation cache the command lines turn on (train/loop/compilation_cache.py)."""

from pathlib import Path

import jax
import pytest

from mecanum_jax.config import ConfigError
from mecanum_jax.tracing import OLDER_CPU_EMITTERS, older_cpu_emitters
from train.cli import evaluate
from train.cli import train as cli
from train.loop import compilation_cache
from train.loop.compilation_cache import ENV_VAR, FLAG, MIN_COMPILE_TIME_S, apply, choose, configure

OPTIONS = (
    "jax_enable_compilation_cache",
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
)


@pytest.fixture
def restore_jax_cache_options():
    """JAX's cache options as they were before the test (the suite's own cache)."""
    saved = {name: getattr(jax.config, name) for name in OPTIONS}
    yield
    for name, value in saved.items():
        jax.config.update(name, value)


def test_the_user_cache_directory_is_the_default(tmp_path):
    got = choose(None, {"XDG_CACHE_HOME": str(tmp_path)})
    assert got.directory == tmp_path / "mecanum-jax" / "jax"
    assert got.source == "default"
    home = choose(None, {})
    assert home.directory == Path.home() / ".cache" / "mecanum-jax" / "jax"


def test_the_environment_variable_and_the_flag_take_precedence(tmp_path):
    env = {ENV_VAR: str(tmp_path / "env"), "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    assert choose(None, env).directory == tmp_path / "env"
    assert choose(None, env).source == ENV_VAR
    assert choose(str(tmp_path / "flag"), env).directory == tmp_path / "flag"
    off = choose("off", env)
    assert off.directory is None
    with pytest.raises(ConfigError, match=r"--compilation-cache = ' ': give a directory"):
        choose(" ", env)


def test_the_flag_is_taken_out_of_the_command_line():
    assert compilation_cache.split_flag(["--config", "tiny"]) == (None, ["--config", "tiny"])
    assert compilation_cache.split_flag([FLAG, "off", "--config", "tiny"]) == (
        "off",
        ["--config", "tiny"],
    )
    assert compilation_cache.split_flag([f"{FLAG}=/c", "x"]) == ("/c", ["x"])
    with pytest.raises(ConfigError, match="--compilation-cache: expected a directory"):
        compilation_cache.split_flag(["x", FLAG])


def test_apply_sets_jax_options(tmp_path, restore_jax_cache_options):
    target = tmp_path / "cache"
    rest = configure([FLAG, str(target), "--other"], {})
    assert rest == ["--other"]
    assert target.is_dir()
    assert jax.config.jax_compilation_cache_dir == str(target)
    assert jax.config.jax_enable_compilation_cache
    assert jax.config.jax_persistent_cache_min_compile_time_secs == MIN_COMPILE_TIME_S
    assert compilation_cache.in_force() == target
    configure([FLAG, "off"], {})
    assert not jax.config.jax_enable_compilation_cache
    assert compilation_cache.in_force() is None


def test_the_command_lines_ask_for_xlas_older_cpu_emitters(tmp_path, restore_jax_cache_options):
    environ: dict[str, str] = {}
    configure([FLAG, str(tmp_path)], environ)
    assert (OLDER_CPU_EMITTERS in environ.get("XLA_FLAGS", "")) == older_cpu_emitters({})


def test_a_small_eager_program_is_written(tmp_path, restore_jax_cache_options):
    """A start's many small programs (an eager op compiles one each) go to the cache too:
    on a GPU they took 0.05-0.25 s each to compile and read back in milliseconds."""
    from jax.experimental.compilation_cache import compilation_cache as jax_cache

    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)  # JAX's default
    configure([FLAG, str(tmp_path)], {})
    jax_cache.reset_cache()
    try:
        x = jax.numpy.arange(13.0) * 0.37  # an eager multiply of a shape nothing else uses
        x.block_until_ready()
        assert any(p.is_file() for p in tmp_path.rglob("*")), "nothing was written"
    finally:
        jax_cache.reset_cache()


def test_a_set_threshold_and_the_environment_variable_are_left_to_jax(
    tmp_path, restore_jax_cache_options
):
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 7.0)
    apply(choose(str(tmp_path), {}), {"JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "7"})
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 7.0
    jax.config.update("jax_compilation_cache_dir", "/jax/own")
    configure([], {ENV_VAR: "/somewhere/else", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "7"})
    assert jax.config.jax_compilation_cache_dir == "/jax/own"  # JAX read the variable itself
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 7.0
    # a directory from the variable (./dev, run.sh) still writes every program
    configure([], {ENV_VAR: "/somewhere/else"})
    assert jax.config.jax_compilation_cache_dir == "/jax/own"
    assert jax.config.jax_persistent_cache_min_compile_time_secs == MIN_COMPILE_TIME_S


def test_an_unusable_directory(tmp_path, restore_jax_cache_options, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    # the default one turns the cache off with a warning; training goes on
    got = configure([], {"XDG_CACHE_HOME": str(blocker)})
    assert got == []
    assert not jax.config.jax_enable_compilation_cache
    assert "compilation cache off" in capsys.readouterr().err
    # one given on the command line is an error (exit status 2), naming the flag
    with pytest.raises(SystemExit) as exit_:
        configure([FLAG, str(blocker / "x")], {})
    assert exit_.value.code == 2
    assert "--compilation-cache" in capsys.readouterr().err


@pytest.mark.parametrize("main", [cli.main, cli.batch_main, evaluate.main])
def test_the_command_lines_take_the_flag(main, capsys, restore_jax_cache_options):
    with pytest.raises(SystemExit) as exit_:
        main([FLAG, ""])
    assert exit_.value.code == 2
    assert "--compilation-cache = ''" in capsys.readouterr().err


def test_mecanum_train_passes_the_other_flags_on(tmp_path, capsys, restore_jax_cache_options):
    args = ["--config", "tiny", "--run-dir", str(tmp_path / "r"), "--ppo.learning-rate", "-1"]
    assert cli.main([FLAG, "off", *args]) == 2
    assert "ppo.learning_rate" in capsys.readouterr().err
    assert not jax.config.jax_enable_compilation_cache


def test_warp_physics_leaves_the_persistent_cache(
    tmp_path, restore_jax_cache_options, capsys, monkeypatch
):
    """XLA:CPU crashed writing MuJoCo Warp's programs to the cache (mecanum_jax/sim/
    warp_cache.py): once a process builds Warp physics on the CPU, nothing more is written
    or read; on a GPU the cache stays on."""
    from jax.experimental.compilation_cache import compilation_cache as jax_cache

    from mecanum_jax.sim import warp_cache
    from mecanum_jax.sim.warp_cache import leave_the_persistent_cache

    # it says so once a process: another test of this worker may have had it said
    monkeypatch.setattr(warp_cache, "_warned", False)

    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax_cache.reset_cache()
    try:
        jax.jit(lambda x: x * 3.0 + 1.0)(jax.numpy.ones(7)).block_until_ready()
        written = set(tmp_path.rglob("*"))
        assert written, "the cache wrote nothing before: the check below would prove nothing"
        assert leave_the_persistent_cache("gpu") is False
        assert jax.config.jax_enable_compilation_cache
        assert leave_the_persistent_cache() is True
        assert "persistent compilation cache is off" in capsys.readouterr().err
        jax.jit(lambda x: x * 5.0 - 2.0)(jax.numpy.ones(9)).block_until_ready()
        assert set(tmp_path.rglob("*")) == written
        assert leave_the_persistent_cache() is False  # already off: nothing to do
    finally:
        jax_cache.reset_cache()  # the restored options are read again at the next compile
