"""Atomic file writes: the one way sea3d puts a file in place.

A file is written under a temporary name in the same folder
(``.<stem>.<pid>-<token>.tmp<suffix>``: hidden, unique, and with the real suffix so that
libraries choosing the format by extension, such as Open3D, still do), flushed to the disk
(``fsync``, unless the caller says a lost file is recomputed or checked anyway) and renamed
over the target with ``os.replace``. A reader never sees half a file under the final name;
on any error the temporary file is removed. :func:`is_temp_name` tells leftovers of a crash
(with this convention or the older ``.<name>.tmp``) from real files.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_open", "atomic_path", "atomic_write", "is_temp_name", "remove_stale_temps",
           "temp_path"]

_TEMP_NAME = re.compile(r"^\..+\.(?P<pid>\d+)-[0-9a-f]{8}\.tmp(\.[^.]+)?$")


def temp_path(path: str | os.PathLike[str]) -> Path:
    """A fresh temporary name beside ``path`` (same folder, same suffix)."""
    p = Path(path)
    return p.with_name(f".{p.stem}.{os.getpid()}-{secrets.token_hex(4)}.tmp{p.suffix}")


def is_temp_name(name: str) -> bool:
    """True for a name :func:`temp_path` (or the older ``.<name>.tmp``) made."""
    return name.startswith(".") and ".tmp" in name


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # someone else's process
        return True
    return True


def remove_stale_temps(folder: str | os.PathLike[str], *, depth: int = 2) -> list[Path]:
    """Remove the temporary files :func:`temp_path` named in ``folder`` (and its subfolders,
    ``depth`` levels down) whose writing process is gone: what a killed run left behind.
    A temporary file of a process still running is kept. Call it while holding the folder
    (:func:`~sea3d.pipeline.lock.output_lock`).

    Returns:
        The files removed.
    """
    removed: list[Path] = []
    root = Path(folder)
    level = [root]
    for _ in range(depth + 1):
        below: list[Path] = []
        for d in level:
            try:
                entries = list(os.scandir(d))
            except OSError:
                continue
            for e in entries:
                if e.is_dir(follow_symlinks=False):
                    below.append(Path(e.path))
                    continue
                m = _TEMP_NAME.match(e.name)
                if m is None or _alive(int(m["pid"])):
                    continue
                with contextlib.suppress(OSError):
                    os.unlink(e.path)
                    removed.append(Path(e.path))
        level = below
    return removed


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # not every file system lets a folder be synced
        _fsync_path(folder)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, fsync: bool = True) -> Iterator[Path]:
    """Yield a temporary path for the caller (or a library) to write; on leaving the block
    it is synced and renamed onto ``path``; on an error it is removed and ``path`` untouched.

    Raises:
        OSError: the folder cannot be created, or the rename fails.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(p)
    try:
        yield tmp
        if fsync:
            _fsync_path(tmp)
        os.replace(tmp, p)
        if fsync:
            _fsync_dir(p.parent)
    finally:
        with contextlib.suppress(OSError):
            if tmp.exists():
                tmp.unlink()


@contextlib.contextmanager
def atomic_open(
    path: str | os.PathLike[str],
    mode: str = "w",
    *,
    fsync: bool = True,
    encoding: str | None = None,
    newline: str | None = None,
) -> Iterator[IO[Any]]:
    """Open a temporary file for writing (``"w"`` or ``"wb"``) that replaces ``path`` when
    the block ends without an error. Files get mode 0666 less the umask, as any file the
    user writes (``O_EXCL`` keeps the temporary name from being raced).

    Raises:
        OSError: as :func:`atomic_path`.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes new files ('w' or 'wb'), not {mode!r}")
    with atomic_path(path, fsync=False) as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        if "b" in mode:
            fh: IO[Any] = os.fdopen(fd, mode)
        else:
            fh = os.fdopen(fd, mode, encoding=encoding or "utf-8", newline=newline)
        with fh:
            yield fh
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
    if fsync:
        _fsync_dir(Path(path).parent)


def atomic_write(
    path: str | os.PathLike[str], data: bytes | str, *, fsync: bool = True, encoding: str = "utf-8"
) -> None:
    """Write ``data`` (bytes, or text in ``encoding``) to ``path`` atomically.

    Raises:
        OSError: the file cannot be written; ``path`` is then unchanged.
    """
    raw = data.encode(encoding) if isinstance(data, str) else data
    with atomic_open(path, "wb", fsync=fsync) as fh:
        fh.write(raw)
