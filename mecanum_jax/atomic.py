"""Files written whole or not at all, and one line for a disk that cannot take them.

Every writer of the library, the trainer and the command lines goes through here:

- :func:`open_atomic` (and :func:`write_bytes`, :func:`write_text`, :func:`write_json`,
  :func:`copy_file`): a temporary file beside the target (``<name>.<random>.partial``),
  flushed and fsynced, then ``os.replace``\\ d onto the target; on any error the temporary
  file goes and the target is untouched (absent, or its earlier bytes).
- :func:`directory`: a directory built under ``<name>.partial`` (debris of an earlier,
  killed attempt removed first), its files fsynced, then renamed to ``<name>``; on an error
  the ``.partial`` goes.
- :func:`append_text`: lines appended whole or not at all (cut back on an error).

A disk that is full, over quota or read-only raises :class:`DiskError`, an ``OSError``
whose text is one line naming the path and what to do (``no space left on device writing
'PATH' (N MB free on /mnt); free space and re-run``); :func:`explain` makes one of any
exception that reports such a failure (orbax's checkpointer raises ``ValueError`` with the
OS error in its text).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

DISK_ERRNOS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}
"""The failures of the disk rather than of the program, and how :class:`DiskError` says them."""
_TEXTS = {
    "No space left on device": errno.ENOSPC,
    "os_error_code='28'": errno.ENOSPC,
    "Disk quota exceeded": errno.EDQUOT,
    "Read-only file system": errno.EROFS,
}


_UMASK = os.umask(0o022)
os.umask(_UMASK)  # (read once, at import: setting it is not thread-safe)


class DiskError(OSError):
    """A write failed for want of space, quota or write access; the text is one line."""

    def __init__(self, code: int, path: str | Path):
        self.path = Path(path)
        super().__init__(code, DISK_ERRNOS[code], str(path))

    @property
    def no_space(self) -> bool:
        return self.errno in (errno.ENOSPC, errno.EDQUOT)

    def __str__(self) -> str:
        mount = _mount(self.path)
        if self.no_space:
            free = shutil.disk_usage(mount).free / 1e6
            where = f"{free:.{0 if free >= 10 else 1}f} MB free on {mount}"
            return f"{self.strerror} writing {str(self.path)!r} ({where}); free space and re-run"
        return (
            f"{self.strerror} writing {str(self.path)!r} (on {mount}); make it writable or "
            "write elsewhere, and re-run"
        )


def _mount(path: Path) -> str:
    """The mount point of ``path``'s nearest existing ancestor."""
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    while not os.path.ismount(p) and p != p.parent:
        p = p.parent
    return str(p)


def disk_errno(err: BaseException) -> int | None:
    """The :data:`DISK_ERRNOS` code ``err`` (or an exception it was raised from) reports."""
    seen: BaseException | None = err
    while seen is not None:
        if isinstance(seen, OSError) and seen.errno in DISK_ERRNOS:
            return seen.errno
        for text, code in _TEXTS.items():
            if text in str(seen):
                return code
        seen = seen.__cause__ or seen.__context__
    return None


def explain(err: BaseException, path: str | Path | None = None) -> BaseException:
    """``err`` as a :class:`DiskError` where it reports a disk failure (naming its own file,
    else ``path``); otherwise ``err`` itself."""
    code = disk_errno(err)
    if isinstance(err, DiskError) or code is None:
        return err
    name = _written(err) or path
    return DiskError(code, name) if name is not None else err


def _written(err: BaseException) -> str | None:
    """The file a failed OS call was writing: a copy's or a rename's destination
    (``filename2``; shutil's copy names its source first), else its one file."""
    return getattr(err, "filename2", None) or getattr(err, "filename", None)


@contextlib.contextmanager
def disk_errors(path: str | Path) -> Iterator[None]:
    """An ``OSError`` of :data:`DISK_ERRNOS` in the block raised as a :class:`DiskError`
    (naming its own file, else ``path``)."""
    try:
        yield
    except OSError as err:
        if isinstance(err, DiskError) or err.errno not in DISK_ERRNOS:
            raise
        raise DiskError(err.errno, _written(err) or path) from err


def fsync_dir(path: Path) -> None:
    """Make a rename in ``path`` durable (where the file system lets a directory be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def open_atomic(path: str | Path, mode: str = "wb") -> Iterator[IO[Any]]:
    """A file object whose bytes replace ``path`` when the block ends without an error."""
    path = Path(path)
    with disk_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f"{path.name}.", suffix=".partial", dir=path.parent)
        tmp = Path(name)
        try:
            with os.fdopen(fd, mode) as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp's is 0o600; as open() would make it
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        fsync_dir(path.parent)


def write_bytes(path: str | Path, data: bytes) -> Path:
    with open_atomic(path, "wb") as f:
        f.write(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    with open_atomic(path, "w") as f:
        f.write(text)
    return Path(path)


def write_json(path: str | Path, data: object, indent: int | None = 2) -> Path:
    """``data`` as JSON (and a final newline), atomically."""
    return write_text(path, json.dumps(data, indent=indent) + "\n")


def copy_file(src: str | Path, dst: str | Path) -> Path:
    """Copy ``src``'s bytes to ``dst``, atomically."""
    with open(src, "rb") as f, open_atomic(dst, "wb") as g:
        shutil.copyfileobj(f, g)
    return Path(dst)


def copy_tree(src: str | Path, dst: str | Path) -> None:
    """Copy the directory ``src`` to ``dst`` (new), raising the first error as it is (where
    ``shutil.copytree`` gathers every file's into one ``shutil.Error`` list). Meant inside
    :func:`directory`, which makes the whole atomic."""
    src, dst = Path(src), Path(dst)
    with disk_errors(dst):
        dst.mkdir(parents=True)
        for item in sorted(src.iterdir()):
            if item.is_dir():
                copy_tree(item, dst / item.name)
            else:
                shutil.copyfile(item, dst / item.name)


def partial_dir(path: str | Path) -> Path:
    """Where :func:`directory` builds ``path``: ``<path>.partial``."""
    path = Path(path)
    return path.with_name(path.name + ".partial")


@contextlib.contextmanager
def directory(path: str | Path) -> Iterator[Path]:
    """A new directory built under ``<path>.partial`` (yielded) and renamed to ``path``
    when the block ends without an exception; the ``.partial`` is removed on one (a
    ``KeyboardInterrupt`` included)."""
    path = Path(path)
    tmp = partial_dir(path)
    try:
        with disk_errors(tmp):
            if tmp.exists():
                shutil.rmtree(tmp)  # debris of a killed attempt of the same name
            tmp.mkdir(parents=True)
            yield tmp
            _fsync_tree(tmp)
            tmp.rename(path)
            fsync_dir(path.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fsync_tree(root: Path) -> None:
    for folder, _, files in os.walk(root):
        for name in files:
            with open(os.path.join(folder, name), "rb") as f:
                os.fsync(f.fileno())
        fsync_dir(Path(folder))


def append_text(path: str | Path, text: str) -> None:
    """Append ``text`` to ``path`` whole or not at all: on an error the file is cut back to
    its length before (a full disk leaves no half line)."""
    path = Path(path)
    data = memoryview(text.encode())
    with disk_errors(path):
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            size = os.fstat(fd).st_size
            try:
                while data:
                    data = data[os.write(fd, data) :]
                os.fsync(fd)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, size)
                raise
        finally:
            os.close(fd)


__all__ = [
    "DISK_ERRNOS",
    "DiskError",
    "append_text",
    "copy_file",
    "copy_tree",
    "directory",
    "disk_errno",
    "disk_errors",
    "explain",
    "fsync_dir",
    "open_atomic",
    "partial_dir",
    "write_bytes",
    "write_json",
    "write_text",
]
