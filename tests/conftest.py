"""Test configuration shared by the whole suite.

- Two host CPU devices, so multi-device code (pmap, the sharded mesh) is exercised.
- ``jax_numpy_rank_promotion = "raise"``: accidental broadcasting is an error (as Equinox does).
- JAX's persistent compilation cache, shared across test processes and CI runs: the
  clone's ``.cache/jax`` (as ``./dev`` sets it) unless ``JAX_COMPILATION_CACHE_DIR`` names
  another, so the command lines the tests run never write to the user's cache directory.
- MuJoCo renders headless through whichever of OSMesa and EGL is installed; tests marked
  ``render`` are skipped, with the reason, where neither works.
- Tiers: the default run leaves out tests marked ``full`` (slow end-to-end runs);
  ``--full`` (what ``.ci/run`` passes) runs them too. ``./dev test`` runs either tier in
  two pytest-xdist workers (``pytest_xdist_make_scheduler``). Both tiers compile with
  XLA:CPU's backend optimizations and its newer fusion emitters off
  (``TEST_XLA_FLAGS``): the tests' programs run for moments and compile for tens of
  seconds, and unoptimized code compiles about 30% faster; the older emitters about as
  much again for the big programs and twice as fast for the thousands of one-operation
  programs that eager code compiles (a full-tier training CLI test: 104 s of CPU against
  204 s). The installed-wheel test (tests/test_wheel.py) runs its commands as users do,
  with XLA's defaults but for the older emitters the command lines ask for. Hypothesis
  draws 40 examples of each property in the full tier, 20 in the fast one.
"""

import dataclasses
import fcntl
import gc
import json
import os
import subprocess
import sys
from pathlib import Path

# two host devices even where the caller's XLA_FLAGS already says something else
if "--xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    _flags = os.environ.get("XLA_FLAGS", "")
    os.environ["XLA_FLAGS"] = f"{_flags} --xla_force_host_platform_device_count=2".strip()
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".cache", "jax"),
)
# only the programs that took a second to compile (the command lines write every one,
# train/loop/compilation_cache.py; the suite's thousands of small ones would crowd the cache)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1.0")
from mecanum_jax.sim.render import ensure_gl_backend  # imports no MuJoCo

ensure_gl_backend()  # must precede the first mujoco import

import jax  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

jax.config.update("jax_numpy_rank_promotion", "raise")
from mecanum_jax.tracing import (  # noqa: E402
    OLDER_CPU_EMITTERS,
    threefry_kernel_on_gpus,
    unroll_threefry,
)

unroll_threefry()  # as every entry point does: the same random bits, compiled sooner
threefry_kernel_on_gpus()  # and so: the command lines' programs share JAX's cache keys
if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
    jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

settings.register_profile(
    "default",
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
# the fast tier draws half as many examples (the full tier, what CI runs, draws them all)
settings.register_profile("fast", settings.get_profile("default"), max_examples=20)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

UNOPTIMIZED_XLA_FLAGS = (
    "--xla_backend_optimization_level=0",
    "--xla_llvm_disable_expensive_passes=true",
)
"""The suite's XLA flags that a command line started as a user's would (``optimized_env``)
goes without."""
TEST_XLA_FLAGS = " ".join((*UNOPTIMIZED_XLA_FLAGS, OLDER_CPU_EMITTERS))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--full", action="store_true", help="also run the full tier (tests marked 'full')"
    )


def pytest_configure(config: pytest.Config) -> None:
    """The tests' XLA flags, before XLA's CPU backend starts (the first computation), for
    this process and the command lines its tests start; and the fast tier's Hypothesis
    profile."""
    flags = os.environ["XLA_FLAGS"]  # (pytest-xdist's workers inherit the controller's)
    if TEST_XLA_FLAGS not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {TEST_XLA_FLAGS}"
    if not config.getoption("--full") and "HYPOTHESIS_PROFILE" not in os.environ:
        settings.load_profile("fast")


@pytest.fixture(scope="session")
def optimized_env() -> dict[str, str]:
    """This process's environment without :data:`UNOPTIMIZED_XLA_FLAGS`, for a command
    line whose programs must compile as a user's do (XLA's vectorized loops included)."""
    env = dict(os.environ)
    flags = env.get("XLA_FLAGS", "").split()
    env["XLA_FLAGS"] = " ".join(f for f in flags if f not in UNOPTIMIZED_XLA_FLAGS)
    return env


# Full-tier files that run for minutes on 2 cores (fresh training processes, a wheel
# install, Warp's kernels): under pytest-xdist they start first, after the tiny run's
# files, so that no worker is left with one of them at the end while the other idles.
LONG_FILES = (
    "test_distributed.py",
    "test_warp_training.py",
    "test_learns.py",
    "test_wheel.py",
    "test_physics.py",
)


def _start_order(item: pytest.Item) -> int:
    name = item.path.name
    if name in TINY_RUN_FILES:
        return -1
    return LONG_FILES.index(name) if name in LONG_FILES else len(LONG_FILES)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    full = config.getoption("--full")
    if full:  # (a stable sort: each file's tests keep their order)
        items.sort(key=_start_order)
    skip_full = pytest.mark.skip(reason="full tier: run with ./dev test --full")
    gl_reason: list[str | None] = []
    for item in items:
        if "full" in item.keywords and not full:
            item.add_marker(skip_full)
        elif "render" in item.keywords:
            if not gl_reason:
                from mecanum_jax.sim.render import gl_unavailable_reason

                gl_reason.append(gl_unavailable_reason())
            if gl_reason[0]:
                item.add_marker(pytest.mark.skip(reason=gl_reason[0]))


@pytest.fixture
def x64():
    """Run a test body with float64 enabled."""
    with jax.enable_x64(True):
        yield


@pytest.fixture
def threefry_flag(monkeypatch):
    """The name of the GPUs' threefry-kernel flag (mecanum_jax.tracing), the environment's
    choice of it removed for the test and the flag's value restored after it."""
    from mecanum_jax import tracing

    monkeypatch.delenv(tracing.GPU_THREEFRY_VAR, raising=False)
    before = getattr(jax.config, tracing.GPU_THREEFRY_FLAG)
    yield tracing.GPU_THREEFRY_FLAG
    jax.config.update(tracing.GPU_THREEFRY_FLAG, before)


# --- the process's memory maps ------------------------------------------------------------


def _map_limit() -> int:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530  # Linux's default


MAP_LIMIT = _map_limit()


def mapped_regions() -> int | None:
    """How many memory maps this process holds (Linux), else None."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return None


@pytest.fixture(autouse=True)
def _release_compiled_programs():
    """Every program XLA:CPU compiles keeps about three memory maps (its code and data)
    for as long as JAX's caches hold it, and a test process that compiles thousands of
    them reaches the kernel's limit (``vm.max_map_count``, 65530 by default): the next
    compilation then dies with a segmentation fault inside LLVM. The full tier did, at
    60-70% of its tests, in four clean-clone runs. Past half the limit, JAX's caches are
    emptied after the test (its programs compile again, or come from the persistent
    cache, when next called)."""
    yield
    regions = mapped_regions()
    if regions is not None and regions > MAP_LIMIT // 2:
        jax.clear_caches()
        gc.collect()


# --- a tiny trained run, shared by the trainer and evaluation tests --------------------------


@pytest.fixture(scope="session")
def tiny():
    from train.config_loading import load_train_config

    return load_train_config("tiny")


@pytest.fixture(scope="session")
def learner(tiny):
    from train.learner.ppo import Learner

    return Learner(tiny)


# The test files that build the tiny run's learner: they compile its programs (the reset, the
# epoch and the evaluation's rollout: a minute on 2 cores) and train or read the tiny run.
TINY_RUN_FILES = frozenset(
    {
        "test_aot.py",
        "test_distributed.py",
        "test_eval.py",
        "test_export.py",
        "test_first_hour.py",
        "test_learner.py",
        "test_nan_guard.py",
        "test_preemption.py",
        "test_progress.py",
        "test_train.py",
        "test_train_parallel.py",
    }
)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """Under ``--dist loadfile`` (what ``./dev test`` passes), the files of
    ``TINY_RUN_FILES`` go to one worker, as one work unit (the largest, so it starts
    first): the learner's programs compile in one process, the fresh interpreter's
    imports run once. File by file, a second worker
    that needed them waited for the first to train the tiny run (``full_run``), then
    compiled them again to train runs of its own: a minute of the fast tier's 4. Every
    other file is a work unit of its own, as usual; in the full tier (``--full``, which
    ``./dev test --full`` also runs in two workers) test_distributed.py is one too: its
    two-process runs take minutes and use no learner of the worker's."""
    if config.getoption("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    # the full tier's two-process runs (minutes) need no learner of this process's
    together = (
        TINY_RUN_FILES - {"test_distributed.py"} if config.getoption("--full") else TINY_RUN_FILES
    )

    class TinyRunTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            file = super()._split_scope(nodeid)
            return "tiny run" if Path(file).name in together else file

    return TinyRunTogether(config, log)


@dataclasses.dataclass(frozen=True)
class FinishedRun:
    """A finished run directory that another test process trained (``full_run``)."""

    dir: Path


@pytest.fixture(scope="session")
def full_run(tiny, learner, tmp_path_factory, worker_id):
    """The uninterrupted reference run of configs/train/tiny.toml (3 epochs): ``(run,
    summary)``. Tests read it and never write into it. Under pytest-xdist the first worker
    that needs it trains it, in the session's shared temporary directory, and the others
    wait for it and read it (it costs a worker a minute or more to train); under
    ``--dist loadfile`` the files that use it share one worker (``TINY_RUN_FILES``)."""
    from train.loop.run import Run

    if worker_id == "master":  # one process
        run = Run.create(tiny, tmp_path_factory.mktemp("runs") / "full")
        return run, run.train(learner=learner)
    shared = tmp_path_factory.getbasetemp().parent  # the workers' common directory
    with open(shared / "tiny-run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        summary = shared / "tiny-run" / "summary.json"
        if not summary.exists():
            run = Run.create(tiny, shared / "tiny-run")
            return run, run.train(learner=learner)
    return FinishedRun(summary.parent), json.loads(summary.read_text())


# --- one fresh interpreter's imports, shared by the import tests ----------------------------

FRESH_IMPORTS = """
import json, sys, types
import jax
before = dict(vars(jax))
import mecanum_jax, mecanum_jax.task.env, mecanum_jax.evaluation.rollout
import mecanum_jax.sim.physics
import train, train.learner.ppo
after = dict(vars(jax))
# submodules that other packages import (jax.extend) are not patches
changed = sorted(k for k in set(before) | set(after) if before.get(k) is not after.get(k)
                 and not isinstance(after.get(k), types.ModuleType))
with open(sys.argv[1], "w") as f:  # not printed: what the imports print is checked
    json.dump({"changed": changed}, f)
"""


@pytest.fixture(scope="session")
def fresh_imports(tmp_path_factory):
    """One fresh interpreter that imports the library, then the trainer, as a user's
    script does (``MJX_WARP_ENABLED`` unset): ``(process, findings)``, where findings
    holds the ``jax`` attributes those imports changed. tests/test_first_hour.py checks it
    (a fresh interpreter takes seconds to import them)."""
    out = tmp_path_factory.mktemp("imports") / "findings.json"
    env = {k: v for k, v in os.environ.items() if k != "MJX_WARP_ENABLED"}
    cmd = [sys.executable, "-c", FRESH_IMPORTS, str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    return proc, json.loads(out.read_text()) if out.exists() else None


@pytest.fixture(scope="module")
def shipped():
    """The default evaluation scenarios (configs/eval/default.toml)."""
    from mecanum_jax.evaluation.scenarios import load_scenarios

    return load_scenarios("default")


@pytest.fixture(scope="module")
def eval_env(shipped):
    """The evaluation's environment of the default scenarios."""
    from tasks import PLAIN_FEEDBACK, WHEEL

    from mecanum_jax.evaluation.episodes import eval_env_config
    from mecanum_jax.task import EnvConfig, FeedbackConfig, MecanumEnv

    task = EnvConfig(**WHEEL, feedback=FeedbackConfig(**PLAIN_FEEDBACK))  # quick.toml's
    return MecanumEnv(eval_env_config(task, shipped))
