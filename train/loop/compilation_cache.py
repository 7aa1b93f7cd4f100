"""JAX's persistent compilation cache, on by default for the command lines.

XLA's compilation of the training epoch and the evaluation rollouts takes most of a short
run's start (docs/profiling.md); with the cache a second start reads them from disk.
:func:`configure` is called first thing by ``mecanum-train``, ``mecanum-eval`` and the
trainer's benchmarks, and picks the cache directory:

1. ``--compilation-cache DIR`` on the command line, or ``--compilation-cache off`` (no
   persistent cache);
2. else ``JAX_COMPILATION_CACHE_DIR``, which JAX reads itself (``./dev`` sets it to the
   clone's ``.cache/jax``);
3. else the user's cache directory: ``$XDG_CACHE_HOME/mecanum-jax/jax``, by default
   ``~/.cache/mecanum-jax/jax``.

Every program is written, however fast it compiled (:data:`MIN_COMPILE_TIME_S` is 0, unless
``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` says otherwise): a start builds some 150
small eager programs (the model's constants, the robots' reset), which took 0.05–0.25 s
each to compile on a GPU and read back in milliseconds (docs/profiling.md). JAX keeps the
cache unbounded (its size limit needs the ``filelock`` package); delete the directory to
reclaim the space.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Mapping, MutableMapping
from pathlib import Path

import jax

from mecanum_jax.config import ConfigError
from mecanum_jax.tracing import older_cpu_emitters

FLAG = "--compilation-cache"
OFF = "off"
ENV_VAR = "JAX_COMPILATION_CACHE_DIR"
MIN_COMPILE_TIME_S = 0.0
"""Programs compiled faster than this are not written (JAX's default is 1 s): none."""
MIN_TIME_VAR = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


@dataclasses.dataclass(frozen=True)
class CacheChoice:
    """Where the persistent cache lives (``None``: off) and what chose it."""

    directory: Path | None
    source: str


def default_directory(environ: Mapping[str, str] = os.environ) -> Path:
    """``$XDG_CACHE_HOME/mecanum-jax/jax``, or ``~/.cache/mecanum-jax/jax``."""
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "mecanum-jax" / "jax"


def choose(value: str | None, environ: Mapping[str, str] = os.environ) -> CacheChoice:
    """The cache for a ``--compilation-cache`` value (``None``: not given)."""
    if value is not None:
        if value == OFF:
            return CacheChoice(None, f"{FLAG} {OFF}")
        if not value.strip():
            raise ConfigError(f"{FLAG} = {value!r}: give a directory, or '{OFF}'")
        return CacheChoice(Path(value).expanduser(), FLAG)
    if environ.get(ENV_VAR):
        return CacheChoice(Path(environ[ENV_VAR]), ENV_VAR)
    return CacheChoice(default_directory(environ), "default")


def apply(choice: CacheChoice, environ: Mapping[str, str] = os.environ) -> CacheChoice:
    """Set JAX's cache options for ``choice`` (before anything compiles); returns what is
    in force. A default directory that cannot be created turns the cache off with a
    warning; one given on the command line is an error."""
    if choice.directory is None:
        jax.config.update("jax_enable_compilation_cache", False)
        return choice
    if choice.source == ENV_VAR:  # JAX has read it, with any other JAX_* cache options
        _write_every_program(environ)
        return choice
    try:
        choice.directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        message = f"cannot create the directory {str(choice.directory)!r}: {err.strerror}"
        if choice.source == FLAG:
            raise ConfigError(f"{FLAG} = {str(choice.directory)!r}: {message}") from None
        print(f"warning: compilation cache off ({choice.source}): {message}", file=sys.stderr)
        jax.config.update("jax_enable_compilation_cache", False)
        return CacheChoice(None, f"{choice.source} (unusable)")
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(choice.directory))
    _write_every_program(environ)
    return choice


def in_force() -> Path | None:
    """The persistent cache's directory as JAX has it now (``None``: the cache is off).
    Read at the time of asking: building MuJoCo Warp's physics on the CPU turns the cache
    off for the rest of the process (``mecanum_jax.sim.warp_cache``)."""
    where = getattr(jax.config, "jax_compilation_cache_dir", None)
    on = getattr(jax.config, "jax_enable_compilation_cache", False)
    return Path(where) if on and where else None


def _write_every_program(environ: Mapping[str, str]) -> None:
    if not environ.get(MIN_TIME_VAR):  # the user's own threshold stands
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)


def split_flag(argv: list[str]) -> tuple[str | None, list[str]]:
    """``--compilation-cache VALUE`` (or ``=VALUE``) taken out of ``argv``: ``(value, rest)``;
    the last one counts."""
    value, rest, i = None, [], 0
    while i < len(argv):
        arg = argv[i]
        if arg == FLAG:
            if i + 1 == len(argv):
                raise ConfigError(f"{FLAG}: expected a directory or '{OFF}' after it")
            value, i = argv[i + 1], i + 2
            continue
        if arg.startswith(FLAG + "="):
            value = arg[len(FLAG) + 1 :]
        else:
            rest.append(arg)
        i += 1
    return value, rest


def configure(argv: list[str], environ: MutableMapping[str, str] = os.environ) -> list[str]:
    """Take ``--compilation-cache`` out of a command line and set the cache (module
    docstring), and XLA:CPU's older emitters (``mecanum_jax.tracing.older_cpu_emitters``);
    returns the other arguments. A bad value exits with status 2."""
    older_cpu_emitters(environ)
    try:
        value, rest = split_flag(argv)
        apply(choose(value, environ), environ)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    return rest


__all__ = [
    "ENV_VAR",
    "FLAG",
    "MIN_COMPILE_TIME_S",
    "OFF",
    "CacheChoice",
    "apply",
    "choose",
    "configure",
    "default_directory",
    "in_force",
    "split_flag",
]
