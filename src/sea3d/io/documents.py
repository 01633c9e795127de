"""Documents a stage renders in memory and io puts in place: the printable board PDF of
``sea3d calibrate board`` and the HTML reports of calibration and ``sea3d process``.

Their contents are the renderer's (``calib.printable`` builds the PDF's bytes, ``calib.report``
and ``pipeline.report`` the HTML text); io only writes them, atomically (a reader sees the old
file or the new one, never half of one; the folder is made).
"""

from __future__ import annotations

import os

from sea3d.io._atomic import atomic_write

__all__ = ["write_document"]


def write_document(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Write a rendered document (bytes as they are, text as UTF-8) to ``path`` atomically.

    Raises:
        OSError: the file cannot be written; ``path`` is then unchanged.
    """
    atomic_write(path, data)
