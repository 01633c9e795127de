"""Records, image codecs and the reader base class shared by both session layouts.

A session holds named streams with integer-nanosecond stamps:

- ``left``, ``right``: images, ``(H, W)`` or ``(H, W, 3)`` RGB, ``uint8`` or ``uint16``;
- ``imu``: accelerometer (m/s^2) and gyroscope (rad/s) samples in the IMU (``body``) frame;
- ``sonar``: echosounder range (m) and confidence (0..1).

:class:`SessionReader` implements everything that does not depend on the layout (access by
index and by stamp, stereo pairing, per-stream statistics); the MCAP and folder readers only
index their files and fetch single records.
"""

from __future__ import annotations

import logging
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
import numpy.typing as npt

from sea3d.errors import SessionError, SessionWriteError

__all__ = [
    "IMAGE_STREAMS",
    "DamagedChunk",
    "ImuSample",
    "ImuSeries",
    "PairMatch",
    "SessionWriteError",
    "SonarSample",
    "SonarSeries",
    "StereoPair",
    "check_encoded_image",
    "decode_image",
    "encode_image",
    "image_format_of",
    "read_image_file",
]

_log = logging.getLogger(__name__)

IMAGE_STREAMS = ("left", "right")
IMAGE_ENCODINGS = ("png", "jpeg", "jxl", "raw")
COMPRESSED_ENCODINGS = ("png", "jpeg", "jxl")
MAX_STAMP_NS = 2**63 - 1
# An interval longer than this many median intervals counts as a gap in ``info()``.
GAP_FACTOR = 1.5


ImageArray = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]

# PNG row filter "Up" only: on 1080p camera frames about 2.5x faster to encode than libpng's
# adaptive choice at the same size (measured in benchmarks/bench_record.py); still lossless.
_PNG_FAST_FILTER: tuple[int, ...] = (
    (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP)
    if hasattr(cv2, "IMWRITE_PNG_FILTER")
    else ()
)


@dataclass(frozen=True)
class DamagedChunk:
    """A chunk whose bytes failed a check; none of its records is decoded.

    Attributes:
        offset: byte offset of the chunk record in the file.
        start_ns, end_ns: stamps of its first and last message (from its header).
        streams: the streams (topics) its message index names, or ``("unknown",)``.
        reason: what failed (CRC mismatch, decompression, cut short, ...).
    """

    offset: int
    start_ns: int
    end_ns: int
    streams: tuple[str, ...]
    reason: str

    def describe(self, path: Path) -> str:
        span = (self.end_ns - self.start_ns) * 1e-9
        return (
            f"{path}: chunk at byte {self.offset} (t_ns {self.start_ns}..{self.end_ns}, "
            f"{span:.3f} s; streams {', '.join(self.streams)}) is damaged ({self.reason}); its "
            "records are skipped"
        )


@dataclass(frozen=True)
class StereoPair:
    """A left and right image matched by stamp.

    Attributes:
        t_ns: stamp of the left image, integer nanoseconds.
        left: left image, (H, W) or (H, W, 3) RGB, uint8 or uint16.
        right: right image, same layout as ``left``.
        right_t_ns: stamp of the right image (``None`` when it equals ``t_ns``).
    """

    t_ns: int
    left: np.ndarray = field(repr=False)
    right: np.ndarray = field(repr=False)
    right_t_ns: int | None = None


@dataclass(frozen=True)
class ImuSample:
    """One IMU reading in the IMU (``body``) frame.

    Attributes:
        t_ns: stamp, integer nanoseconds.
        accel_mps2: (3,) float64 specific force in m/s^2.
        gyro_radps: (3,) float64 angular rate in rad/s.
    """

    t_ns: int
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray


@dataclass(frozen=True)
class SonarSample:
    """One echosounder reading.

    Attributes:
        t_ns: stamp, integer nanoseconds.
        range_m: distance to the bottom in metres (stored as float32, as in sensor_msgs/Range).
        confidence: 0..1 (stored as float32); NaN when the sensor gives none.
    """

    t_ns: int
    range_m: float
    confidence: float


@dataclass(frozen=True)
class ImuSeries:
    """All IMU samples of a session, sorted by stamp.

    Attributes:
        t_ns: (N,) int64 stamps in nanoseconds, strictly increasing.
        accel_mps2: (N, 3) float64 specific force in m/s^2, IMU frame.
        gyro_radps: (N, 3) float64 angular rate in rad/s, IMU frame.
    """

    t_ns: np.ndarray
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class SonarSeries:
    """All echosounder samples of a session, sorted by stamp.

    Attributes:
        t_ns: (N,) int64 stamps in nanoseconds, strictly increasing.
        range_m: (N,) float32 ranges in metres.
        confidence: (N,) float32 confidence 0..1, NaN where unknown.
    """

    t_ns: np.ndarray
    range_m: np.ndarray
    confidence: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class PairMatch:
    """Stereo pairs matched by nearest stamp within a tolerance.

    Attributes:
        left_index: (P,) int64 indices into the left stream.
        right_index: (P,) int64 indices into the right stream.
        unpaired_left: number of left frames with no right frame within the tolerance.
        unpaired_right: number of right frames with no left frame within the tolerance.
        tolerance_ns: the tolerance used, nanoseconds.
    """

    left_index: np.ndarray
    right_index: np.ndarray
    unpaired_left: int
    unpaired_right: int
    tolerance_ns: int

    def __len__(self) -> int:
        return int(self.left_index.shape[0])


# ----------------------------------------------------------------------------- validation


def check_stamp(t_ns: Any, what: str) -> int:
    """Return ``t_ns`` as a Python int after checking it is a non-negative integer.

    Raises:
        SessionError: if it is not an integer in [0, 2**63).
    """
    if isinstance(t_ns, bool) or not isinstance(t_ns, int | np.integer):
        raise SessionError(f"{what}: stamp must be an integer number of nanoseconds, got {t_ns!r}")
    value = int(t_ns)
    if not 0 <= value <= MAX_STAMP_NS:
        raise SessionError(f"{what}: stamp {value} ns is outside [0, 2**63)")
    return value


def check_image(image: Any, what: str) -> np.ndarray:
    """Check an image array: (H, W) or (H, W, 3), uint8 or uint16, non-empty.

    Raises:
        SessionError: naming ``what`` with the shape and dtype that came.
    """
    if not isinstance(image, np.ndarray):
        raise SessionError(f"{what}: expected a numpy image array, got {type(image).__name__}")
    if image.dtype not in (np.uint8, np.uint16):
        raise SessionError(f"{what}: expected a uint8 or uint16 image, got dtype {image.dtype}")
    ok_shape = image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
    if not ok_shape or image.size == 0:
        raise SessionError(
            f"{what}: expected an image of shape (H, W) or (H, W, 3), got {image.shape}"
        )
    return image


def check_rig_yaml(rig_yaml: str | None, path: Path) -> Any:
    """The rig stored with a session, parsed (None without one): every storage refuses an
    invalid rig rather than storing it as if the session were calibrated.

    Raises:
        SessionError: the text is not a valid rig.
    """
    if rig_yaml is None:
        return None
    from sea3d.errors import RigFileError
    from sea3d.io.rig_file import rig_from_yaml

    try:
        return rig_from_yaml(rig_yaml, f"rig stored in {path}")
    except RigFileError as err:
        raise SessionError(f"cannot store an invalid rig: {err}") from err


# ----------------------------------------------------------------------------- codecs

# JPEG XL lossless at effort 1 (libjxl's fast-lossless path, through imagecodecs): on 1080p
# camera frames about 5x less CPU than PNG at zlib level 1 and half its size
# (benchmarks/bench_record.py --codecs prints the table).
JXL_EFFORT = 1
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JXL_CONTAINER = b"\x00\x00\x00\x0cJXL \r\n\x87\n"


def image_format_of(data: bytes | memoryview) -> str | None:
    """``png``, ``jpeg``, ``jxl`` or ``tiff`` from the first bytes of an encoded image, or None."""
    head = bytes(data[:12])
    if head.startswith(PNG_SIGNATURE):
        return "png"
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith(b"\xff\x0a") or head == _JXL_CONTAINER:
        return "jxl"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff"
    return None


def encode_image(
    image: np.ndarray,
    encoding: str,
    *,
    png_compression: int = 1,
    jpeg_quality: int = 95,
    jxl_effort: int = JXL_EFFORT,
) -> bytes:
    """Encode an RGB image as PNG, JPEG or JPEG XL bytes (thread-safe; the codecs release the
    GIL).

    Args:
        image: (H, W) or (H, W, 3) RGB, uint8 or uint16 (uint16 only for PNG and JPEG XL).
        encoding: ``"png"`` (lossless), ``"jxl"`` (JPEG XL, lossless) or ``"jpeg"`` (lossy).
        png_compression: zlib level 0..9 (1 is fast and still about 2x smaller than raw).
        jpeg_quality: 0..100.
        jxl_effort: libjxl effort 1..9 (1: fast lossless; higher is smaller and far slower).

    Raises:
        SessionError: for an unknown encoding, uint16 JPEG, or an encoder failure.
    """
    image = check_image(image, "encode_image")
    if encoding == "jxl":
        import imagecodecs

        try:
            return bytes(
                imagecodecs.jpegxl_encode(
                    np.ascontiguousarray(image), lossless=True, effort=jxl_effort, numthreads=1
                )
            )
        except Exception as err:  # imagecodecs raises its own error classes
            raise SessionError(
                f"JPEG XL could not encode a {image.shape} {image.dtype} image: {err}"
            ) from err
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    if encoding == "png":
        ok, buf = cv2.imencode(
            ".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression), *_PNG_FAST_FILTER]
        )
    elif encoding == "jpeg":
        if image.dtype != np.uint8:
            raise SessionError("JPEG encoding needs uint8 images; use png or jxl for uint16")
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    else:
        raise SessionError(f"unknown image encoding {encoding!r}; expected 'png', 'jxl' or 'jpeg'")
    if not ok:
        raise SessionError(
            f"OpenCV could not encode a {image.shape} {image.dtype} image as {encoding}"
        )
    return buf.tobytes()


def check_encoded_image(data: bytes | memoryview, where: str) -> str:
    """Check that encoded image bytes are complete, without decoding pixels where the format
    allows it, and return the format (``png``, ``jpeg``, ``jxl``, ``tiff``).

    PNG: every chunk is walked and its CRC checked, up to ``IEND``. JPEG: starts with SOI and
    ends with EOI (trailing zero padding allowed); JPEG has no checksum, so flipped bits inside
    it can only be caught by the MCAP chunk CRC or a folder's checksum list. JPEG XL and TIFF
    carry no cheap end marker: they are decoded.

    Raises:
        SessionError: naming ``where``, for an unknown format or incomplete or damaged bytes.
    """
    view = memoryview(data).cast("B")
    fmt = image_format_of(view)
    if fmt == "png":
        pos, n = 8, len(view)
        while True:
            if pos + 12 > n:
                raise SessionError(f"{where}: PNG is cut short at byte {n} (no IEND chunk)")
            length = int.from_bytes(view[pos : pos + 4], "big")
            kind = bytes(view[pos + 4 : pos + 8])
            end = pos + 12 + length
            if length > 2**31 - 1 or end > n:
                raise SessionError(f"{where}: PNG chunk {kind!r} at byte {pos} is cut short")
            crc = int.from_bytes(view[end - 4 : end], "big")
            if zlib.crc32(view[pos + 4 : end - 4]) != crc:
                raise SessionError(f"{where}: PNG chunk {kind!r} at byte {pos} is damaged (CRC)")
            if kind == b"IEND":
                return fmt
            pos = end
    if fmt == "jpeg":
        tail = bytes(view[-4096:]).rstrip(b"\x00")
        if not tail.endswith(b"\xff\xd9"):
            raise SessionError(
                f"{where}: JPEG is cut short ({len(view)} bytes, no end-of-image marker)"
            )
        return fmt
    if fmt in ("jxl", "tiff"):
        decode_image(view, where)
        return fmt
    raise SessionError(f"{where}: not a PNG, JPEG, JPEG XL or TIFF image ({len(view)} bytes)")


def decode_image(data: bytes | memoryview | np.ndarray, where: str) -> np.ndarray:
    """Decode PNG/JPEG/JPEG XL/TIFF bytes to an RGB (or grey) array, keeping 16-bit depth.

    Incomplete images are refused, not returned half grey: OpenCV refuses cut PNGs (and checks
    their chunk CRCs) and cut JPEGs in memory; a JPEG must also end with its end-of-image
    marker, and libjxl refuses cut JPEG XL streams.

    Raises:
        SessionError: naming ``where`` when the bytes are not a complete, decodable image.
    """
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    buf = buf.reshape(-1)
    fmt = image_format_of(buf[:12].tobytes())
    if fmt == "jxl":
        import imagecodecs

        try:
            return np.ascontiguousarray(imagecodecs.jpegxl_decode(cast(Any, buf), numthreads=1))
        except Exception as err:  # JpegxlError, RuntimeError for cut headers
            raise SessionError(
                f"{where}: cannot decode JPEG XL data ({buf.size} bytes; damaged or cut "
                f"short?): {err}"
            ) from err
    if fmt in ("png", "jpeg"):
        # Structure first (PNG chunk CRCs up to IEND, JPEG end marker): a damaged image is
        # refused with its reason, before libpng prints its own complaints to stderr.
        check_encoded_image(memoryview(cast(Any, buf)), where)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise SessionError(f"{where}: cannot decode image data ({buf.size} bytes; damaged?)")
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def image_size_of(data: bytes, fmt: str, where: str) -> tuple[int, int]:
    """(width, height) of encoded image bytes: from the PNG header, else by decoding.

    Raises:
        SessionError: if the bytes cannot be decoded.
    """
    if fmt == "png" and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    img = decode_image(data, where)
    return img.shape[1], img.shape[0]


def read_image_file(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file (PNG, JPEG, JPEG XL, TIFF, ...) as RGB or grey, refusing incomplete
    files (``cv2.imread`` returns a cut JPEG half grey).

    Returns:
        (H, W) or (H, W, 3) RGB, uint8 or uint16 (an alpha channel is dropped).

    Raises:
        SessionError: the file is missing, unreadable, cut short or not an image.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as err:
        raise SessionError(f"cannot read image {p}: {err.strerror or err}") from err
    return decode_image(data, str(p))


# ----------------------------------------------------------------------------- helpers


def sort_stamps(stamps: np.ndarray, where: str) -> np.ndarray:
    """Indices that sort ``stamps`` and drop duplicates (keeping the first), with warnings.

    Args:
        stamps: (N,) int64 stamps in the order they were stored.
        where: file or topic name for the warning.

    Returns:
        (M,) int64 indices into ``stamps``, M <= N, giving strictly increasing stamps.
    """
    stamps = np.asarray(stamps, dtype=np.int64)
    if stamps.size == 0:
        return np.zeros(0, dtype=np.int64)
    backwards = np.flatnonzero(np.diff(stamps) < 0)
    if backwards.size:
        first = int(backwards[0]) + 1
        _log.warning(
            "%s: stamps out of order, going back %d times (first at record %d: t_ns=%d after %d); "
            "sorting them",
            where,
            backwards.size,
            first,
            int(stamps[first]),
            int(stamps[first - 1]),
        )
    order = np.argsort(stamps, kind="stable")
    sorted_stamps = stamps[order]
    dup = np.flatnonzero(np.diff(sorted_stamps) == 0) + 1
    if dup.size:
        _log.warning(
            "%s: %d duplicate stamps (first t_ns=%d); keeping the first record of each",
            where,
            dup.size,
            int(sorted_stamps[dup[0]]),
        )
        keep = np.ones(order.size, dtype=bool)
        keep[dup] = False
        order = order[keep]
    return order.astype(np.int64)


def stream_stats(stamps: np.ndarray) -> dict[str, Any]:
    """Count, rate, first/last stamp and gaps of one stream.

    ``rate_hz`` is 1 / median interval; a gap is an interval longer than 1.5 median intervals.
    """
    stamps = np.asarray(stamps, dtype=np.int64)
    n = int(stamps.size)
    out: dict[str, Any] = {
        "count": n,
        "rate_hz": 0.0,
        "first_t_ns": int(stamps[0]) if n else None,
        "last_t_ns": int(stamps[-1]) if n else None,
        "gaps": 0,
        "max_interval_s": 0.0,
    }
    if n >= 2:
        dt = np.diff(stamps)
        median = float(np.median(dt))
        if median > 0:
            out["rate_hz"] = 1e9 / median
            out["gaps"] = int(np.count_nonzero(dt > GAP_FACTOR * median))
        out["max_interval_s"] = float(dt.max()) * 1e-9
    return out


def match_stamps(
    left: np.ndarray, right: np.ndarray, tolerance_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual-nearest matching of two sorted stamp arrays within ``tolerance_ns``.

    Returns:
        (left_index, right_index): (P,) int64 each; pairs are one-to-one and increasing.
    """
    left = np.asarray(left, dtype=np.int64)
    right = np.asarray(right, dtype=np.int64)
    if left.size == 0 or right.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty

    def nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        j = np.searchsorted(b, a)
        lo = np.clip(j - 1, 0, b.size - 1)
        hi = np.clip(j, 0, b.size - 1)
        pick_hi = np.abs(b[hi] - a) < np.abs(b[lo] - a)
        return np.where(pick_hi, hi, lo)

    l2r = nearest(left, right)
    r2l = nearest(right, left)
    li = np.arange(left.size)
    mutual = r2l[l2r] == li
    close = np.abs(right[l2r] - left) <= tolerance_ns
    keep = mutual & close
    return li[keep].astype(np.int64), l2r[keep].astype(np.int64)
