"""The set-up a local worker process runs as it starts, handed over in a file.

``sea3d process`` and ``sea3d live`` give every worker process the same set-up (a function
and its arguments: the stage's rectification maps, megabytes). It travels through a
temporary file, ``<tmp>/sea3d-worker-setup-<pid>-<token>.pickle``, not through the worker's
start-up pipe: ``multiprocessing``'s spawn writes that pipe while holding its read end too,
so a worker killed before reading it all would block the writer forever. The file is
pickled with multiprocessing's own pickler, and is removed by its run, or, when the run was
killed, by the next run that writes one.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import tempfile
from multiprocessing.reduction import ForkingPickler
from pathlib import Path
from typing import Any

__all__ = ["SETUP_PREFIX", "read_worker_setup", "remove_worker_setup", "write_worker_setup"]

SETUP_PREFIX = "sea3d-worker-setup-"


def _remove_setups_of_dead_runs(folder: Path) -> None:
    for path in folder.glob(f"{SETUP_PREFIX}*-*.pickle"):
        pid = path.name[len(SETUP_PREFIX):].split("-", 1)[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            with contextlib.suppress(OSError):
                path.unlink()
        except OSError:
            pass  # another user's process, alive


def write_worker_setup(setup: Any) -> str:
    """Pickle ``setup`` to a new file of this process in the temporary folder (first
    removing those of runs whose process is gone); returns its path.

    Raises:
        OSError: it cannot be written.
    """
    folder = Path(tempfile.gettempdir())
    _remove_setups_of_dead_runs(folder)
    fd, path = tempfile.mkstemp(prefix=f"{SETUP_PREFIX}{os.getpid()}-", suffix=".pickle",
                                dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(ForkingPickler.dumps(setup))
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(path)
        raise
    return path


def read_worker_setup(path: str) -> Any:
    """What :func:`write_worker_setup` wrote (in the worker)."""
    with open(path, "rb") as fh:
        return pickle.load(fh)


def remove_worker_setup(path: str) -> None:
    """Remove the file (gone already is fine)."""
    with contextlib.suppress(OSError):
        os.unlink(path)
