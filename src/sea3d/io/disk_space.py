"""Free space on the disk that holds a path: what the writers check before and while they
write (the session storages' reserve, the recorder's and monitor's figures, the simulator's
refusal of a run the disk cannot hold)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["disk_free_bytes"]


def disk_free_bytes(path: str | os.PathLike[str]) -> int:
    """Bytes an unprivileged process may still write on the file system that holds ``path``,
    or its nearest existing parent when ``path`` does not exist yet (``statvfs``'s
    ``f_bavail * f_frsize``, as ``shutil.disk_usage(...).free`` counts them)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    st = os.statvfs(p)
    return int(st.f_bavail) * int(st.f_frsize)
