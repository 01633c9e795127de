"""Disparity, depth and point-cloud files: PFM (read/write), NPY, float32 TIFF, Middlebury scaled
PNG/PGM, 16-bit millimetre depth PNG (0 invalid) and binary PLY point clouds.

PFM ("Portable Float Map", as used by the Middlebury benchmark): a text header
``Pf`` (one channel) or ``PF`` (three), then ``"<width> <height>"``, then a scale whose sign
gives the byte order (negative: little-endian), each on its own line, followed by float32
rows stored **bottom to top**. Middlebury marks unknown disparities with ``inf``; they are read
as NaN here. Scaled PNG/PGM ground truth stores ``round(d * scale)`` in uint8/uint16 with 0 as
unknown.

**Which pixel grid a depth file lives on** is said by a small JSON sidecar beside it,
``<file>.grid.json`` (:class:`DepthGrid`, :func:`write_depth_grid`, :func:`read_depth_grid`):
the raw left view (the camera's own pixels) or the rectified left view with its virtual
pinhole ``K``, the image size, and the rig's identity (a hash of its calibration), so that a
consumer can check a depth map is on the grid it needs (:func:`check_depth_grid`) and resample
it with the rig or refuse in one line. A file without a sidecar says nothing (external RGB-D
data): consumers then check the size only.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import StereoError
from sea3d.io._atomic import atomic_open, atomic_path

__all__ = [
    "DEPTH_SUFFIXES",
    "DISPARITY_SUFFIXES",
    "DepthGrid",
    "check_depth_grid",
    "check_depth_pinhole",
    "read_depth",
    "read_depth_grid",
    "read_depth_png_mm",
    "read_disparity",
    "read_pfm",
    "rig_identity",
    "write_depth",
    "write_depth_grid",
    "write_depth_png_mm",
    "write_disparity",
    "write_pfm",
    "write_ply",
]

# Output suffixes the writers accept (any case): :func:`write_disparity` writes float32;
# :func:`write_depth` also writes a 16-bit PNG of millimetres.
DISPARITY_SUFFIXES = (".pfm", ".npy", ".tif", ".tiff")
DEPTH_SUFFIXES = (".png", *DISPARITY_SUFFIXES)

GridKind = Literal["raw-left", "rectified-left"]


@dataclass(frozen=True, kw_only=True)
class DepthGrid:
    """The pixel grid of a depth map.

    Attributes:
        kind: ``raw-left`` (the left camera's own pixels, depth z along its optical axis) or
            ``rectified-left`` (the rectified left view, z along the rectified axis).
        width_px, height_px: the grid's size.
        K: ``3x3`` row-major pinhole of the grid: the virtual pinhole for ``rectified-left``,
            the left camera's pinhole (without distortion or port) for ``raw-left``.
        rig_id: :func:`rig_identity` of the rig the depth came from (its rectification
            identity: the same calibration gives the same rectified grid).
    """

    kind: GridKind
    width_px: int
    height_px: int
    K: tuple[tuple[float, ...], ...]
    rig_id: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("raw-left", "rectified-left"):
            raise StereoError(f"unknown depth grid {self.kind!r}: raw-left or rectified-left")
        if self.width_px <= 0 or self.height_px <= 0:
            raise StereoError(f"depth grid size must be > 0, got {self.width_px}x{self.height_px}")
        k = np.asarray(self.K, dtype=np.float64)
        if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise StereoError(f"depth grid K must be a 3x3 pinhole, got {self.K}")

    def describe(self) -> str:
        """One phrase: ``rectified-left 1920x1080 (fx 1082.4, rig 1a2b...)``."""
        return (f"{self.kind} {self.width_px}x{self.height_px} (fx {self.K[0][0]:.1f}"
                + (f", rig {self.rig_id[:8]}" if self.rig_id else "") + ")")


def rig_identity(rig_yaml: str) -> str:
    """A short identity of a rig's calibration: the first 16 hex digits of the SHA-256 of its
    YAML (:func:`sea3d.io.rig_file.rig_to_yaml`)."""
    return hashlib.sha256(rig_yaml.encode("utf-8")).hexdigest()[:16]


def _grid_path(path: str | Path) -> Path:
    p = Path(path)
    return p.with_name(p.name + ".grid.json")


def write_depth_grid(path: str | Path, grid: DepthGrid) -> None:
    """Write the sidecar ``<path>.grid.json`` saying which grid the depth file lives on.

    Raises:
        StereoError: the sidecar cannot be written.
    """
    g = _grid_path(path)
    tmp = g.with_name(g.name + ".tmp")
    try:
        tmp.write_text(json.dumps(asdict(grid), indent=1))
        tmp.replace(g)
    except OSError as err:
        raise StereoError(f"cannot write {g}: {err}") from err


def read_depth_grid(path: str | Path) -> DepthGrid | None:
    """The :class:`DepthGrid` of a depth file from its sidecar, None when it has none.

    Raises:
        StereoError: a sidecar that is not valid JSON or not a depth grid.
    """
    g = _grid_path(path)
    if not g.is_file():
        return None
    try:
        d = json.loads(g.read_text())
        k = tuple(tuple(float(v) for v in row) for row in d["K"])
        return DepthGrid(kind=d["kind"], width_px=int(d["width_px"]),
                         height_px=int(d["height_px"]), K=k, rig_id=str(d.get("rig_id", "")))
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise StereoError(f"{g}: not a depth grid sidecar ({err})") from err


def check_depth_grid(
    path: str | Path,
    depth_shape: tuple[int, ...],
    *,
    kind: GridKind,
    width_px: int,
    height_px: int,
    rig_id: str | None = None,
    consumer: str = "this command",
) -> DepthGrid | None:
    """Check that a depth file read as ``depth_shape`` lives on the grid a consumer needs.

    Returns:
        The file's :class:`DepthGrid` (None when it has no sidecar and its size matches).

    Raises:
        StereoError: one line naming the file, the grid it lives on and the one needed.
    """
    grid = read_depth_grid(path)
    size = f"{width_px}x{height_px}"
    have = f"{depth_shape[1]}x{depth_shape[0]}" if len(depth_shape) >= 2 else str(depth_shape)
    if grid is None:
        if have != size:
            raise StereoError(f"depth {path} is {have} but {consumer} needs {kind} {size}")
        return None
    if grid.kind != kind or (grid.width_px, grid.height_px) != (width_px, height_px):
        raise StereoError(
            f"depth {path} lives on the {grid.describe()} grid but {consumer} needs {kind} "
            f"{size}" + ("; write raw-view depth (the raw grid) with sea3d depth"
                         if kind == "raw-left" else "")
        )
    if rig_id and grid.rig_id and grid.rig_id != rig_id:
        raise StereoError(
            f"depth {path} came from another rig (rig {grid.rig_id[:8]}, this one "
            f"{rig_id[:8]}): its grid does not match"
        )
    if have != size:
        raise StereoError(f"depth {path} is {have} but its sidecar says {size}")
    return grid


def check_depth_pinhole(
    path: str | Path,
    depth_shape: tuple[int, ...],
    K: np.ndarray,
    *,
    first: DepthGrid | None = None,
    consumer: str = "this command",
    rtol: float = 1e-3,
) -> DepthGrid | None:
    """Check that a depth file lives on the pinhole grid a consumer was given (``K``, the
    depth's size), for consumers without a rig to resample with (``sea3d fuse``).

    Args:
        path: the depth file; its sidecar ``<path>.grid.json`` is read.
        depth_shape: the shape the file was read as, ``(H, W)``.
        K: ``3x3`` intrinsics the consumer projects the depth with, pixels.
        first: the grid of the run's first depth file: every later file must be on the same
            grid (same kind, size, ``K`` and rig).
        consumer: named in the message.
        rtol: relative tolerance on ``fx, fy, cx, cy`` (1e-3: 1 px in 1000).

    Returns:
        The file's :class:`DepthGrid`, None when it has no sidecar (then nothing is known
        beyond its size).

    Raises:
        StereoError: one line naming the file, the grid it lives on and what was given.
    """
    grid = read_depth_grid(path)
    if grid is None:
        if first is not None:
            raise StereoError(f"depth {path} has no grid sidecar but the first depth file "
                              f"lives on the {first.describe()} grid")
        return None
    have = f"{depth_shape[1]}x{depth_shape[0]}" if len(depth_shape) >= 2 else str(depth_shape)
    if have != f"{grid.width_px}x{grid.height_px}":
        raise StereoError(f"depth {path} is {have} but its sidecar says "
                          f"{grid.width_px}x{grid.height_px}")
    if first is not None and grid != first:
        raise StereoError(f"depth {path} lives on the {grid.describe()} grid but the first "
                          f"depth file on the {first.describe()} grid")
    k_file = np.asarray(grid.K, dtype=np.float64)
    k = np.asarray(K, dtype=np.float64)
    pick = [(0, 0), (1, 1), (0, 2), (1, 2)]
    a = np.array([k_file[i] for i in pick])
    b = np.array([k[i] for i in pick])
    if not np.allclose(a, b, rtol=rtol, atol=rtol * float(max(grid.width_px, grid.height_px))):
        raise StereoError(
            f"depth {path} lives on the {grid.describe()} grid (fx fy cx cy "
            f"{' '.join(f'{v:.2f}' for v in a)}) but {consumer} was given "
            f"{' '.join(f'{v:.2f}' for v in b)}: give the grid's intrinsics, or write depth "
            "on the grid the colour images live on (the grid option of sea3d depth)"
        )
    return grid


def write_pfm(path: str | Path, image: np.ndarray) -> None:
    """Write ``(H, W)`` or ``(H, W, 3)`` float32 to a little-endian PFM (NaN kept as NaN).

    Raises:
        StereoError: wrong shape, or the file cannot be written.
    """
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim == 3 and arr.shape[2] == 3:
        kind = b"PF"
    elif arr.ndim == 2:
        kind = b"Pf"
    else:
        raise StereoError(f"PFM needs (H, W) or (H, W, 3) data, got shape {arr.shape}")
    h, w = arr.shape[:2]
    data = np.ascontiguousarray(arr[::-1]).astype("<f4")
    try:
        with atomic_open(path, "wb", fsync=False) as fh:
            fh.write(kind + b"\n" + f"{w} {h}\n".encode() + b"-1.0\n")
            fh.write(data.tobytes())
    except OSError as err:
        raise StereoError(f"cannot write PFM file {path}: {err}") from err


def _read_line(fh: object, path: str | Path) -> bytes:
    line = fh.readline()  # type: ignore[attr-defined]
    while line.startswith(b"#"):
        line = fh.readline()  # type: ignore[attr-defined]
    if not line:
        raise StereoError(f"{path}: truncated PFM header")
    return bytes(line.strip())


def read_pfm(path: str | Path) -> NDArray[np.float32]:
    """Read a PFM file into ``(H, W)`` or ``(H, W, 3)`` float32, top row first; ``inf`` -> NaN.

    Raises:
        StereoError: missing file, bad header, or too little data.
    """
    try:
        with open(path, "rb") as fh:
            kind = _read_line(fh, path)
            if kind not in (b"Pf", b"PF"):
                raise StereoError(f"{path}: not a PFM file (header {kind[:10]!r})")
            dims = _read_line(fh, path).split()
            if len(dims) != 2:
                raise StereoError(f"{path}: bad PFM size line {b' '.join(dims)!r}")
            w, h = int(dims[0]), int(dims[1])
            scale = float(_read_line(fh, path))
            raw = fh.read()
    except OSError as err:
        raise StereoError(f"cannot read PFM file {path}: {err}") from err
    except ValueError as err:
        raise StereoError(f"{path}: bad PFM header: {err}") from err
    channels = 3 if kind == b"PF" else 1
    count = w * h * channels
    endian = "<" if scale < 0 else ">"
    if len(raw) < 4 * count:
        raise StereoError(f"{path}: PFM holds {len(raw)} bytes of data, {4 * count} needed")
    data = np.frombuffer(raw[: 4 * count], dtype=endian + "f4").astype(np.float32)
    shape = (h, w, 3) if channels == 3 else (h, w)
    out = np.ascontiguousarray(data.reshape(shape)[::-1])
    out[~np.isfinite(out)] = np.nan
    return out


def _read_pfm_or_npy(p: Path) -> np.ndarray | None:
    """The array a ``.pfm`` or ``.npy`` file stores, as stored; None for any other suffix.

    Raises:
        StereoError: the file cannot be read as its suffix says.
    """
    suffix = p.suffix.lower()
    if suffix == ".pfm":
        return read_pfm(p)
    if suffix != ".npy":
        return None
    try:
        return np.asarray(np.load(p, allow_pickle=False))
    except (OSError, ValueError) as err:
        raise StereoError(f"cannot read {p}: {err}") from err


def read_disparity(path: str | Path, scale: float | None = None) -> NDArray[np.float32]:
    """Read a disparity map in pixels, NaN where unknown.

    Formats: ``.pfm`` (``inf``/NaN unknown), ``.npy``, ``.tif``/``.tiff`` (float), and integer
    ``.png``/``.pgm`` holding ``d * scale`` with 0 unknown (Middlebury: tsukuba 16, venus 8,
    cones/teddy 4). For float formats, non-positive or non-finite values are unknown; ``scale``
    divides the stored values if given (default 1 for float formats, required for PNG/PGM).

    Returns:
        (H, W) float32 pixels.

    Raises:
        StereoError: unreadable file, unknown suffix, multi-channel data, missing ``scale`` for
            integer images.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if not p.is_file():
        raise StereoError(f"disparity file not found: {p}")
    stored = _read_pfm_or_npy(p)
    if stored is not None:
        d = stored
    elif suffix in (".png", ".pgm", ".ppm", ".tif", ".tiff"):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise StereoError(f"cannot read image {p}")
        if img.dtype.kind in "ui":
            if scale is None:
                raise StereoError(
                    f"{p} stores integers ({img.dtype}); give the disparity scale "
                    "(e.g. scale 16 for tsukuba, 8 venus, 4 cones/teddy)"
                )
            d = img.astype(np.float32)
            d[img == 0] = np.nan
            d /= np.float32(scale)
            scale = None
        else:
            d = np.asarray(img, dtype=np.float32)
    else:
        raise StereoError(f"unknown disparity file type {suffix!r} ({p}); use .pfm .npy .png .tiff")
    d = np.asarray(d, dtype=np.float32)
    if d.ndim == 3:
        if d.shape[2] >= 1 and np.allclose(d[..., 0], d[..., -1], equal_nan=True):
            d = d[..., 0]
        else:
            raise StereoError(f"{p}: expected a one-channel disparity map, got shape {d.shape}")
    if d.ndim != 2:
        raise StereoError(f"{p}: expected a 2-D disparity map, got shape {d.shape}")
    d = d.copy()
    if scale is not None:
        d /= np.float32(scale)
    with np.errstate(invalid="ignore"):
        d[~np.isfinite(d) | (d <= 0)] = np.nan
    return d


def write_disparity(path: str | Path, disparity: np.ndarray) -> None:
    """Write float32 disparity (pixels, NaN invalid) as ``.pfm``, ``.npy`` or ``.tif(f)``.

    PFM and NPY keep NaN; TIFF is float32 with NaN too (read back by :func:`read_disparity`).

    Raises:
        StereoError: unknown suffix or the file cannot be written.
    """
    p = Path(path)
    d = np.asarray(disparity, dtype=np.float32)
    suffix = p.suffix.lower()
    if suffix == ".pfm":
        write_pfm(p, d)
        return
    if suffix not in (".npy", ".tif", ".tiff"):
        raise StereoError(
            f"unknown disparity output type {suffix!r} ({p}); use .pfm, .npy or .tiff"
        )
    try:
        with atomic_path(p, fsync=False) as tmp:
            if suffix == ".npy":
                np.save(tmp, d)
            elif not cv2.imwrite(str(tmp), d):
                raise StereoError(f"OpenCV could not write {p}")
    except OSError as err:
        raise StereoError(f"cannot write {p}: {err}") from err



def write_depth_png_mm(path: str | Path, depth_m: np.ndarray) -> None:
    """Write depth as a 16-bit PNG of **millimetres**, 0 = invalid (NaN, <= 0 or > 65.535 m).

    Raises:
        StereoError: the file cannot be written.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        mm = np.round(z * 1000.0)
        ok = np.isfinite(mm) & (mm > 0) & (mm <= 65535)
    out = np.where(ok, mm, 0).astype(np.uint16)
    try:
        with atomic_path(path, fsync=False) as tmp:
            if not cv2.imwrite(str(tmp), out):
                raise StereoError(f"cannot write 16-bit PNG {path}")
    except OSError as err:
        raise StereoError(f"cannot write 16-bit PNG {path}: {err}") from err


def read_depth_png_mm(path: str | Path) -> NDArray[np.float32]:
    """Read a 16-bit millimetre depth PNG into float32 metres, NaN where 0.

    Raises:
        StereoError: unreadable, or not a 16-bit one-channel image.
    """
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise StereoError(f"{path}: expected a 16-bit one-channel PNG of millimetres")
    return _metres_from_integer(img, 1000.0)


_DEPTH_IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def read_depth(
    path: str | os.PathLike[str], depth_scale: float | None = None
) -> NDArray[np.float32]:
    """Read a depth (or range) map in metres, NaN where invalid.

    Formats: float ``.npy``, ``.tif``/``.tiff`` and ``.pfm`` (and any float image OpenCV
    reads) in metres; integer images (16-bit ``.png`` as :func:`write_depth_png_mm` writes
    them, and as Kinect, RealSense, OAK-D and 7-Scenes do; 16-bit TIFF, PGM) hold
    ``metres * depth_scale`` with 0 invalid. NaN, inf and values <= 0 are invalid. 8-bit
    images are refused: 256 levels are no metric depth (they are a picture of depth, or a
    colour image given as depth).

    Args:
        path: the depth file.
        depth_scale: integer depth units per metre (1000 for millimetres, 5000 for the TUM
            RGB-D benchmark). None: integer images are millimetres, and an integer ``.npy`` is
            refused (its unit is unknown); a number applies to integer depth of any format.

    Returns:
        ``(H, W)`` float32 metres.

    Raises:
        StereoError: a missing or unreadable file, an unknown suffix, more than one channel, an
            integer ``.npy`` without ``depth_scale``, 8-bit depth, or a ``depth_scale`` that is
            not > 0.
    """
    p = Path(path)
    if depth_scale is not None and not depth_scale > 0:
        raise StereoError(f"depth_scale must be > 0, got {depth_scale}")
    if not p.is_file():
        raise StereoError(f"depth file not found: {p}")
    suffix = p.suffix.lower()
    d: np.ndarray
    stored = _read_pfm_or_npy(p)
    if stored is not None:
        d = stored
        if suffix == ".npy" and d.dtype.kind != "f" and depth_scale is None:
            raise StereoError(
                f"{p}: depth .npy holds {d.dtype}; expected float metres (NaN invalid)"
            )
    else:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None and suffix in _DEPTH_IMAGE_SUFFIXES:
            raise StereoError(f"cannot read image {p}")
        if img is None:
            raise StereoError(
                f"unknown depth file type {suffix!r} ({p}); use .npy/.tiff (float m) or .png "
                "(uint16 mm)"
            )
        d = img
    if d.dtype.itemsize == 1:
        raise StereoError(
            f"{p}: 8-bit depth ({d.dtype}) holds only 256 levels and is no metric depth (it is "
            "a picture of depth); give a 16-bit PNG of millimetres (or of 1/depth_scale m) or "
            "float32 .npy/.tiff metres"
        )
    if d.ndim != 2:
        raise StereoError(f"{p}: expected a one-channel (H, W) depth map, got shape {d.shape}")
    if d.dtype.kind in "ui":
        d = _metres_from_integer(d, 1000.0 if depth_scale is None else depth_scale)
    elif d.dtype.kind != "f":
        raise StereoError(f"{p}: unsupported depth type {d.dtype}")
    d = np.array(d, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        d[~np.isfinite(d) | (d <= 0)] = np.nan
    return d


def _metres_from_integer(img: np.ndarray, units_per_m: float) -> NDArray[np.float32]:
    """Integer depth ``img`` in units of ``1 / units_per_m`` metres as float32 metres, NaN
    where 0."""
    z = img.astype(np.float32) / np.float32(units_per_m)
    z[img == 0] = np.nan
    return z


def write_depth(path: str | Path, depth_m: np.ndarray, grid: DepthGrid | None = None) -> None:
    """Write depth in metres: ``.png`` as 16-bit millimetres (0 invalid), ``.pfm``/``.npy``/
    ``.tif(f)`` as float32 metres with NaN invalid; with ``grid``, its sidecar too.

    Raises:
        StereoError: unknown suffix, unwritable file, or a grid of another size.
    """
    if grid is not None and np.asarray(depth_m).shape != (grid.height_px, grid.width_px):
        raise StereoError(
            f"{path}: depth is {np.asarray(depth_m).shape[::-1]} but its grid says "
            f"{grid.width_px}x{grid.height_px}"
        )
    if Path(path).suffix.lower() == ".png":
        write_depth_png_mm(path, depth_m)
    else:
        write_disparity(path, depth_m)
    if grid is not None:
        write_depth_grid(path, grid)


def write_ply(path: str | Path, points: np.ndarray, colors_rgb: np.ndarray | None = None) -> None:
    """Write a binary little-endian PLY point cloud: float32 x y z (metres) and, if given,
    uchar red green blue.

    Args:
        points: (N, 3) metres.
        colors_rgb: (N, 3) uint8 or None.

    Raises:
        StereoError: mismatched shapes or unwritable file.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise StereoError(f"points must be (N, 3), got {pts.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors_rgb is not None:
        cols = np.asarray(colors_rgb)
        if cols.shape != pts.shape:
            raise StereoError(f"colours {cols.shape} do not match points {pts.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(len(pts), dtype=fields)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(pts)}",
              "property float x", "property float y", "property float z"]
    if colors_rgb is not None:
        rec["red"], rec["green"], rec["blue"] = cols[:, 0], cols[:, 1], cols[:, 2]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    try:
        with atomic_open(path, "wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(rec.tobytes())
    except OSError as err:
        raise StereoError(f"cannot write PLY {path}: {err}") from err
