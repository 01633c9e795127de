"""Image files given by a glob or a folder: which files, in which order, read as RGB.

Image files are those whose suffix is in :data:`IMAGE_SUFFIXES` (any case); they sort in
natural order (``left2.png`` before ``left10.png``, numbers compared as numbers, over the
whole path). Images are returned as OpenCV reads them, then ``(H, W)`` grey or ``(H, W, 3)``
RGB (alpha dropped), of the file's own dtype (uint8 or uint16). Written images are put in
place atomically (a reader never sees half an image under the final name).
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.io._atomic import atomic_path

__all__ = ["IMAGE_SUFFIXES", "image_paths", "image_writer", "natural_key", "read_image_rgb",
           "write_image_rgb"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")


def natural_key(path: str | os.PathLike[str]) -> list[Any]:
    """Sort key of a whole path with its numbers compared as numbers (``1e9`` after ``2e8``)."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", os.fspath(path))]


def image_paths(pattern: str) -> list[Path]:
    """The image files of a folder (by suffix) or the files a glob matches, in natural order;
    empty when there are none (the caller says what it needed them for)."""
    p = Path(pattern)
    if p.is_dir():
        paths = [q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES]
    else:
        paths = [q for q in (Path(g) for g in glob.glob(pattern)) if q.is_file()]
    return sorted(paths, key=natural_key)


def read_image_rgb(path: str | os.PathLike[str]) -> NDArray[Any] | None:
    """An image file as ``(H, W)`` grey or ``(H, W, 3)`` RGB (alpha dropped), or None when
    OpenCV cannot read it (missing, not an image, damaged)."""
    import cv2

    img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.asarray(img)


def image_writer(folder: str | os.PathLike[str], error: Callable[[str], Exception], *,
                 png_compression: int | None = None) -> Callable[[str, NDArray[Any]], None]:
    """A ``write(name, image)`` that saves ``(H, W)`` grey or ``(H, W, 3)`` RGB images as
    ``folder/name`` (the suffix of ``name`` chooses the format; sub-folders are made).

    Args:
        folder: where the images go.
        error: makes the exception raised when a file cannot be written, from its message.
        png_compression: zlib level 0-9 of PNG files (None: OpenCV's default, 3); 1 writes
            scratch images fast.
    """
    import cv2

    root = Path(folder)
    params = [] if png_compression is None else [cv2.IMWRITE_PNG_COMPRESSION, png_compression]

    def write(name: str, img: NDArray[Any]) -> None:
        path = root / name
        arr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
        with atomic_path(path, fsync=False) as tmp:
            if not cv2.imwrite(str(tmp), arr, params):
                raise error(f"cannot write {path}")

    return write


def write_image_rgb(path: str | os.PathLike[str], img: NDArray[Any],
                    error: Callable[[str], Exception]) -> None:
    """Write ``(H, W)`` grey or ``(H, W, 3)`` RGB as an image file (the suffix chooses the
    format; the folder is made): float images in [0, 1] become 8-bit, 16-bit images 8-bit in a
    JPEG.

    Args:
        error: makes the exception raised when the file cannot be written, from its message.
    """
    import cv2

    p = Path(path)
    data = np.asarray(img)
    if data.dtype.kind == "f":
        data = (np.clip(data, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    if data.dtype == np.uint16 and p.suffix.lower() in (".jpg", ".jpeg"):
        data = (data // 257).astype(np.uint8)
    if data.ndim == 3:
        data = cv2.cvtColor(data, cv2.COLOR_RGB2BGR)
    try:
        with atomic_path(p, fsync=False) as tmp:
            if not cv2.imwrite(str(tmp), data):
                raise error(f"cannot write {p} (unknown image type {p.suffix!r}?)")
    except (cv2.error, OSError) as err:
        raise error(f"cannot write {p}: {err}") from err
