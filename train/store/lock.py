"""A run directory has one writer: an OS lock on ``<run>/.lock`` (``fcntl.flock``).

:func:`acquire` takes it without waiting, or raises :class:`RunInUse` naming the process
that holds it (its pid is written in the file); the OS drops it when the holder exits,
however it exits (SIGKILL included), so a stale lock file never blocks a resume. Within
one process the lock is counted: a second :func:`acquire` of the same directory (a test
that resumes the run it created) shares it, and the last :func:`release` drops it.
"""

from __future__ import annotations

import errno
import fcntl
import os
import threading
from pathlib import Path

from mecanum_jax.atomic import DiskError

LOCK_FILE = ".lock"

_held: dict[str, list[int]] = {}  # realpath of the run directory -> [fd, count]
_guard = threading.Lock()


class RunInUse(ValueError):  # noqa: N818 (reads as the state it reports)
    """Another process writes the run directory."""


def _key(run_dir: Path) -> str:
    return os.path.realpath(run_dir)


def acquire(run_dir: str | Path, then: str = "retry") -> None:
    """Take ``run_dir``'s lock (the directory exists) or raise :class:`RunInUse` (its
    message ends with ``then``, what to do once the holder ends); a directory that cannot
    take the lock file raises :class:`DiskError`."""
    run_dir = Path(run_dir)
    key = _key(run_dir)
    with _guard:
        if key in _held:
            _held[key][1] += 1
            return
        path = run_dir / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            if err.errno in (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC):
                raise DiskError(err.errno, path) from err
            raise
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunInUse(
                f"run directory {str(run_dir)!r} is in use by another process (pid {pid}); "
                f"wait for it to end or stop it, then {then}"
            ) from None
        try:  # the holder's pid, for the message above (the lock itself is the flock)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass  # a full disk: the lock holds all the same
        _held[key] = [fd, 1]


def release(run_dir: str | Path) -> None:
    """Give back one :func:`acquire` of ``run_dir``; the last one drops the lock."""
    key = _key(Path(run_dir))
    with _guard:
        entry = _held.get(key)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] == 0:
            del _held[key]
            os.close(entry[0])  # (closing drops the flock)


def holds(run_dir: str | Path) -> bool:
    """Whether this process holds ``run_dir``'s lock."""
    return _key(Path(run_dir)) in _held


__all__ = ["LOCK_FILE", "RunInUse", "acquire", "holds", "release"]
