"""An exclusive lock on an output folder, so that two runs never write into one folder.

The lock is ``fcntl.flock`` on ``OUT/.sea3d.lock``, which holds the owner's pid and command.
The kernel releases it when its process ends, however it ends (SIGKILL included), so a lock
file left by a dead process never blocks a new run: the next run takes it and says so.
Where ``fcntl`` is missing (Windows) folders are not locked.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from sea3d.errors import OutputInUseError, SessionError

__all__ = ["LOCK_NAME", "clear_stale_temps", "locks_out_dir", "output_lock"]

LOCK_NAME = ".sea3d.lock"
_log = logging.getLogger(__name__)
F = TypeVar("F", bound=Callable[..., Any])


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Create ``folder`` if needed and hold its lock while the block runs.

    Yields:
        The folder's path.

    Raises:
        OutputInUseError: another live process holds the folder (its pid named).
        SessionError: the folder or its lock file cannot be created.
    """
    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionError(f"cannot create the output folder {out}: {err}") from err
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on Linux/macOS
        yield out
        return
    path = out / LOCK_NAME
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise SessionError(f"cannot create the lock file {path}: {err.strerror}") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            owner = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "unknown"
            os.close(fd)
            raise OutputInUseError(
                f"{out} is in use by another sea3d run ({owner}); wait for it to finish or "
                "choose another output folder"
            ) from None
        # The file may have been removed by its previous owner between our open and flock:
        # then we hold a lock on a file nobody else can see; take the lock again.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    stale = os.pread(fd, 200, 0).decode("utf-8", "replace").strip()
    if stale:
        _log.info("%s: taking over a lock left by a process that ended (%s)", out, stale)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}: {' '.join(sys.argv[:3])}\n".encode(), 0)
    try:
        yield out
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # while still held: a waiting run re-checks the inode
        os.close(fd)


def locks_out_dir(fn: F) -> F:
    """Decorator for ``fn(session, config, ...)``: hold :func:`output_lock` on
    ``config.out_dir`` while ``fn`` runs."""

    @functools.wraps(fn)
    def wrapper(session_path: Any, config: Any, *args: Any, **kwargs: Any) -> Any:
        with output_lock(config.out_dir):
            return fn(session_path, config, *args, **kwargs)

    return wrapper  # type: ignore[return-value]


def clear_stale_temps(folder: str | os.PathLike[str]) -> None:
    """Remove what a killed run left half-written in ``folder`` (its temporary files: a
    ``.mesh.<pid>-<token>.tmp.ply`` and the like); call it holding the folder's lock."""
    from sea3d.io.process_outputs import remove_stale_temps

    removed = remove_stale_temps(folder)
    if removed:
        _log.info("%s: removed %d temporary files an earlier run left (%s%s)", folder,
                  len(removed), ", ".join(p.name for p in removed[:3]),
                  ", ..." if len(removed) > 3 else "")
