"""Calibration targets: board specifications, their 3D points, and detection in images.

A board is written as a short string or kept in a small YAML file:

- ``checkerboard:9x6:25mm`` -- 9 x 6 *inner* corners, 25 mm squares.
- ``charuco:5x7:40mm:30mm:DICT_6X6_250`` -- 5 x 7 *squares*, 40 mm squares, 30 mm markers.
- ``apriltag:7x5:91.4mm:114.3mm`` -- a grid of 7 x 5 AprilTag 36h11 tags, 91.4 mm tags at a
  114.3 mm pitch (centre to centre), ids 0, 1, 2 ... row by row; an optional fifth field names
  another dictionary and an optional ``first=N`` the first id.
- ``aruco:5x7:40mm:50mm:DICT_4X4_50`` -- the same for ArUco markers.

The board frame (see ``docs/calibration.md``): the origin is the first inner corner of a
checkerboard or ChArUco board, or the top-left corner of the first tag of a tag grid; x runs
along the first count, y along the second, z into the board; metres. Every corner has an integer
id: ``i + j * cols`` for checkerboard and ChArUco corners (i along x, j along y), and
``4 * tag_id + k`` for tag corners (k = 0..3 clockwise from the tag's top-left corner, OpenCV's
order).

Detection returns a :class:`Detection` with a :class:`DetectionStatus` for every image; it never
raises on an image in which the board is missing.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import logging
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.errors import ConfigError

__all__ = [
    "CHECKER_DETECTORS",
    "DETECTOR_ALIASES",
    "BoardSpec",
    "Detection",
    "DetectionStatus",
    "corner_convention_offset_px",
    "detect_board",
    "detect_checkerboard_all",
    "detect_images",
    "grid_continues",
    "load_board",
    "parse_board",
    "render_board",
]

log = logging.getLogger(__name__)

IntArray = NDArray[np.int64]

_KINDS = ("checkerboard", "charuco", "apriltag", "aruco")
_LENGTH_RE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm|cm|m|in)\s*$")
_UNIT_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}


def _parse_length_m(text: str, what: str, spec: str) -> float:
    match = _LENGTH_RE.match(text)
    if match is None:
        raise ConfigError(
            f"board {spec!r}: {what} must be a length with a unit such as '25mm', '2.5cm' or "
            f"'0.025m'; got {text!r}"
        )
    value = float(match.group(1)) * _UNIT_M[match.group(2)]
    if value <= 0:
        raise ConfigError(f"board {spec!r}: {what} must be positive; got {text!r}")
    return value


def _parse_counts(text: str, spec: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if match is None:
        raise ConfigError(f"board {spec!r}: expected counts such as '9x6'; got {text!r}")
    return int(match.group(1)), int(match.group(2))


def _aruco_dictionary(name: str) -> Any:
    key = name.upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    value = getattr(cv2.aruco, key, None)
    if not isinstance(value, int):
        raise ConfigError(f"unknown marker dictionary {name!r} (e.g. DICT_6X6_250, "
                          f"DICT_APRILTAG_36h11)")
    return cv2.aruco.getPredefinedDictionary(value)


@dataclass(frozen=True, kw_only=True)
class BoardSpec:
    """A planar calibration target.

    Attributes:
        kind: ``"checkerboard"``, ``"charuco"``, ``"apriltag"`` or ``"aruco"``.
        cols: checkerboard: inner corners along x; ChArUco: squares along x; tag grids: tags
            along x.
        rows: the same along y.
        square_m: checkerboard/ChArUco square side; for tag grids the pitch (tag centre to
            tag centre), metres.
        marker_m: ChArUco marker side or tag side (black border included), metres; 0 for
            checkerboards.
        dictionary: OpenCV marker dictionary name (``"DICT_6X6_250"``); empty for
            checkerboards.
        tag_ids: tag grids only: ``rows`` tuples of ``cols`` ids, row 0 at the board origin;
            empty means ``first_id, first_id + 1, ...`` row by row.
        legacy_pattern: ChArUco only: OpenCV's pre-4.6 layout for boards with an even row
            count.
    """

    kind: str
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = ""
    tag_ids: tuple[tuple[int, ...], ...] = ()
    legacy_pattern: bool = False
    _cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False,
                                   hash=False)

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ConfigError(f"board kind must be one of {_KINDS}; got {self.kind!r}")
        minimum = 2 if self.kind in ("checkerboard", "charuco") else 1
        if self.cols < minimum or self.rows < minimum:
            raise ConfigError(f"{self.kind} board needs at least {minimum}x{minimum}; "
                              f"got {self.cols}x{self.rows}")
        if not np.isfinite(self.square_m) or self.square_m <= 0:
            raise ConfigError(f"board square/pitch must be positive metres; got {self.square_m}")
        if self.kind != "checkerboard":
            if not (0 < self.marker_m <= self.square_m):
                raise ConfigError(
                    f"{self.kind} board: marker size {self.marker_m} m must be positive and no "
                    f"larger than the square/pitch {self.square_m} m"
                )
            _aruco_dictionary(self.dictionary)
        if self.tag_ids and (len(self.tag_ids) != self.rows or any(
                len(r) != self.cols for r in self.tag_ids)):
            raise ConfigError(f"board tag_ids must be {self.rows} rows of {self.cols} ids")

    # ------------------------------------------------------------------ geometry
    @property
    def name(self) -> str:
        """The board as a spec string (without custom tag ids)."""
        sq = f"{self.square_m * 1e3:g}mm"
        mk = f"{self.marker_m * 1e3:g}mm"
        if self.kind == "checkerboard":
            return f"checkerboard:{self.cols}x{self.rows}:{sq}"
        if self.kind == "charuco":
            return f"charuco:{self.cols}x{self.rows}:{sq}:{mk}:{self.dictionary}"
        return f"{self.kind}:{self.cols}x{self.rows}:{mk}:{sq}:{self.dictionary}"

    @property
    def corner_grid(self) -> tuple[int, int]:
        """``(cols, rows)`` of chessboard inner corners (checkerboard and ChArUco only)."""
        if self.kind == "checkerboard":
            return self.cols, self.rows
        if self.kind == "charuco":
            return self.cols - 1, self.rows - 1
        raise ConfigError(f"a {self.kind} board has no chessboard corner grid")

    def ids_grid(self) -> IntArray:
        """``(rows, cols)`` int64 tag ids of a tag grid."""
        if self.tag_ids:
            return np.asarray(self.tag_ids, dtype=np.int64)
        return np.arange(self.rows * self.cols, dtype=np.int64).reshape(self.rows, self.cols)

    def object_points(self) -> tuple[IntArray, FloatArray]:
        """All corners of the board.

        Returns:
            ``ids`` ``(N,)`` int64 and ``points_board`` ``(N, 3)`` float64 metres in the board
            frame (z = 0).
        """
        if "object_points" in self._cache:
            ids, pts = self._cache["object_points"]
            return ids.copy(), pts.copy()
        if self.kind in ("checkerboard", "charuco"):
            nx, ny = self.corner_grid
            jj, ii = np.mgrid[0:ny, 0:nx]
            ids = (ii + jj * nx).ravel().astype(np.int64)
            pts = np.stack([ii.ravel() * self.square_m, jj.ravel() * self.square_m,
                            np.zeros(nx * ny)], axis=1)
        else:
            grid = self.ids_grid()
            t, p = self.marker_m, self.square_m
            offsets = np.array([[0, 0], [t, 0], [t, t], [0, t]], dtype=np.float64)
            id_list, pt_list = [], []
            for r in range(self.rows):
                for c in range(self.cols):
                    for k in range(4):
                        id_list.append(4 * int(grid[r, c]) + k)
                        pt_list.append([c * p + offsets[k, 0], r * p + offsets[k, 1], 0.0])
            ids = np.asarray(id_list, dtype=np.int64)
            pts = np.asarray(pt_list, dtype=np.float64)
        self._cache["object_points"] = (ids, pts)
        return ids.copy(), pts.copy()

    @property
    def n_corners(self) -> int:
        """Number of corners the board holds."""
        return int(self.object_points()[0].shape[0])

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed extent ``(width, height)`` in metres, including the outer squares/margins."""
        if self.kind == "checkerboard":
            return (self.cols + 1) * self.square_m, (self.rows + 1) * self.square_m
        if self.kind == "charuco":
            return self.cols * self.square_m, self.rows * self.square_m
        gap = self.square_m - self.marker_m
        return (self.cols * self.square_m + gap, self.rows * self.square_m + gap)

    def _charuco_board(self) -> Any:
        if "charuco" not in self._cache:
            board = cv2.aruco.CharucoBoard(
                (self.cols, self.rows), self.square_m, self.marker_m,
                _aruco_dictionary(self.dictionary))
            board.setLegacyPattern(self.legacy_pattern)
            self._cache["charuco"] = board
        return self._cache["charuco"]


def parse_board(spec: str) -> BoardSpec:
    """Parse a board string (see the module docstring) or, if ``spec`` names an existing
    ``.yaml``/``.yml`` file, load it with :func:`load_board`.

    Raises:
        ConfigError: the string is malformed (the message shows the expected form).
    """
    text = spec.strip()
    if text.lower().endswith((".yaml", ".yml")) or Path(text).is_file():
        return load_board(Path(text))
    parts = text.split(":")
    kind = parts[0].strip().lower()
    if kind in ("chessboard", "checker"):
        kind = "checkerboard"
    if kind in ("april", "apriltags", "aprilgrid"):
        kind = "apriltag"
    if kind not in _KINDS:
        raise ConfigError(
            f"board {spec!r}: unknown kind {parts[0]!r}; expected e.g. 'checkerboard:9x6:25mm', "
            f"'charuco:5x7:40mm:30mm:DICT_6X6_250' or 'apriltag:7x5:91.4mm:114.3mm'"
        )
    if kind == "checkerboard":
        if len(parts) != 3:
            raise ConfigError(f"board {spec!r}: expected 'checkerboard:COLSxROWS:SQUARE' with "
                              f"inner-corner counts, e.g. 'checkerboard:9x6:25mm'")
        cols, rows = _parse_counts(parts[1], spec)
        return BoardSpec(kind=kind, cols=cols, rows=rows,
                         square_m=_parse_length_m(parts[2], "square size", spec))
    if kind == "charuco":
        if len(parts) not in (4, 5, 6):
            raise ConfigError(f"board {spec!r}: expected "
                              f"'charuco:COLSxROWS:SQUARE:MARKER[:DICT][:legacy]' with square "
                              f"counts, e.g. 'charuco:5x7:40mm:30mm:DICT_6X6_250'")
        cols, rows = _parse_counts(parts[1], spec)
        extra = [p.strip() for p in parts[4:]]
        legacy = "legacy" in [e.lower() for e in extra]
        dicts = [e for e in extra if e.lower() != "legacy"]
        return BoardSpec(kind=kind, cols=cols, rows=rows,
                         square_m=_parse_length_m(parts[2], "square size", spec),
                         marker_m=_parse_length_m(parts[3], "marker size", spec),
                         dictionary=dicts[0] if dicts else "DICT_6X6_250",
                         legacy_pattern=legacy)
    # tag grids
    if len(parts) < 4:
        raise ConfigError(f"board {spec!r}: expected '{kind}:COLSxROWS:TAG:PITCH[:DICT]"
                          f"[:first=N]', e.g. 'apriltag:7x5:91.4mm:114.3mm'")
    cols, rows = _parse_counts(parts[1], spec)
    dictionary = "DICT_APRILTAG_36h11" if kind == "apriltag" else "DICT_4X4_50"
    first = 0
    for raw in parts[4:]:
        field_text = raw.strip()
        if field_text.lower().startswith("first="):
            try:
                first = int(field_text.split("=", 1)[1])
            except ValueError as err:
                raise ConfigError(f"board {spec!r}: bad first id {field_text!r}") from err
        elif field_text:
            dictionary = field_text
    ids = tuple(tuple(first + r * cols + c for c in range(cols)) for r in range(rows))
    return BoardSpec(kind=kind, cols=cols, rows=rows,
                     square_m=_parse_length_m(parts[3], "pitch", spec),
                     marker_m=_parse_length_m(parts[2], "tag size", spec),
                     dictionary=dictionary, tag_ids=ids if first else ())


def _load_opencv_board(path: Path) -> BoardSpec:
    """A board file in OpenCV FileStorage YAML as used by the APL calibration tools
    (``type: apriltags_36h11``, ``squareSize``/``tagSize`` in mm, ``ids`` matrix)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        kind = fs.getNode("type").string()
        if not kind.startswith("apriltag"):
            raise ConfigError(f"board file {path}: unsupported OpenCV board type {kind!r}")
        pitch_mm = fs.getNode("squareSize").real()
        tag_mm = fs.getNode("tagSize").real()
        ids = fs.getNode("ids").mat()
    finally:
        fs.release()
    if ids is None or pitch_mm <= 0 or tag_mm <= 0:
        raise ConfigError(f"board file {path}: needs squareSize, tagSize and an ids matrix")
    ids = np.asarray(ids, dtype=np.int64)
    # The APL files list the rows from the poster's top row; we keep that order as row 0.
    return BoardSpec(kind="apriltag", cols=ids.shape[1], rows=ids.shape[0],
                     square_m=pitch_mm * 1e-3, marker_m=tag_mm * 1e-3,
                     dictionary="DICT_APRILTAG_36h11",
                     tag_ids=tuple(tuple(int(v) for v in row) for row in ids))


def load_board(path: str | Path) -> BoardSpec:
    """Load a board file.

    Our format is plain YAML with units in the key names::

        type: charuco            # checkerboard | charuco | apriltag | aruco
        cols: 5                  # inner corners (checkerboard), squares (charuco), tags (grids)
        rows: 7
        square_mm: 40            # square side, or tag pitch for grids
        marker_mm: 30            # charuco marker / tag side
        dictionary: DICT_6X6_250
        ids: [[0, 1, 2], ...]    # optional, tag grids: rows of ids

    OpenCV FileStorage board files as written by the APL calibration tools (``%YAML:1.0``,
    ``type: apriltags_36h11``, ``squareSize`` and ``tagSize`` in mm) are read too.

    Raises:
        ConfigError: the file is missing, unreadable, or a key is missing or invalid (the
            message names the file and the key).
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"board file {path} does not exist")
    text = path.read_text(encoding="utf-8", errors="replace")
    if text.lstrip().startswith("%YAML:1.0"):
        return _load_opencv_board(path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f"board file {path}: not valid YAML ({err})") from err
    if not isinstance(data, dict):
        raise ConfigError(f"board file {path}: expected a mapping with 'type', 'cols', 'rows'")

    def need(key: str) -> Any:
        if key not in data:
            raise ConfigError(f"board file {path}: missing key {key!r}")
        return data[key]

    kind = str(need("type")).lower()
    try:
        cols, rows = int(need("cols")), int(need("rows"))
        square_m = float(need("square_mm")) * 1e-3
        marker_m = float(data.get("marker_mm", 0.0)) * 1e-3
    except (TypeError, ValueError) as err:
        raise ConfigError(f"board file {path}: cols/rows/square_mm/marker_mm must be numbers "
                          f"({err})") from err
    default_dict = {"charuco": "DICT_6X6_250", "apriltag": "DICT_APRILTAG_36h11",
                    "aruco": "DICT_4X4_50"}.get(kind, "")
    ids_raw = data.get("ids")
    tag_ids: tuple[tuple[int, ...], ...] = ()
    if ids_raw is not None:
        try:
            tag_ids = tuple(tuple(int(v) for v in row) for row in ids_raw)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"board file {path}: 'ids' must be rows of integers") from err
    try:
        return BoardSpec(kind=kind, cols=cols, rows=rows, square_m=square_m, marker_m=marker_m,
                         dictionary=str(data.get("dictionary", default_dict)),
                         tag_ids=tag_ids, legacy_pattern=bool(data.get("legacy_pattern", False)))
    except ConfigError as err:
        raise ConfigError(f"board file {path}: {err}") from err


# ---------------------------------------------------------------------- detection
class DetectionStatus(enum.StrEnum):
    """What detection found in one image."""

    DETECTED = "detected"  #: the whole board (checkerboard) or enough corners (ChArUco, tags)
    PARTIAL = "partial"  #: some corners, too few to use
    NOT_FOUND = "not_found"  #: no board
    WRONG_SIZE = "wrong_size"  #: a board of other dimensions than the one asked for
    UNREADABLE = "unreadable"  #: the image could not be read or is empty


@dataclass(frozen=True, kw_only=True, eq=False)
class Detection:
    """Board corners found in one image.

    Attributes:
        status: see :class:`DetectionStatus`.
        corners_px: ``(N, 2)`` float64 pixel coordinates (integer values at pixel centres).
        ids: ``(N,)`` int64 corner ids (see the module docstring).
        points_board_m: ``(N, 3)`` float64 the same corners in the board frame, metres.
        image_size: ``(width, height)`` pixels of the image searched.
        message: a short human-readable explanation (why nothing was found, ...).
        name: the image's name (file name) when known.
        ambiguous_order: True for checkerboards: a symmetric pattern whose corner order may
            come back rotated by 180 degrees (the ids of ChArUco and tag corners are unique).
    """

    status: DetectionStatus
    corners_px: FloatArray
    ids: IntArray
    points_board_m: FloatArray
    image_size: tuple[int, int]
    message: str = ""
    name: str = ""
    ambiguous_order: bool = False

    @property
    def ok(self) -> bool:
        """True when the detection is usable for calibration."""
        return self.status is DetectionStatus.DETECTED

    def __len__(self) -> int:
        return int(self.corners_px.shape[0])

    def with_name(self, name: str) -> Detection:
        """The same detection with ``name`` set."""
        return dataclasses.replace(self, name=name)


def _empty(status: DetectionStatus, size: tuple[int, int], message: str) -> Detection:
    return Detection(status=status, corners_px=np.zeros((0, 2)), ids=np.zeros(0, np.int64),
                     points_board_m=np.zeros((0, 3)), image_size=size, message=message)


def _to_gray(image: NDArray[Any]) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        if np.issubdtype(img.dtype, np.floating):
            scale = 255.0 if float(np.nanmax(img)) <= 1.0 else 1.0
            img = np.clip(img * scale, 0, 255).astype(np.uint8)
        else:
            img = (img.astype(np.float64) * (255.0 / max(1, np.iinfo(img.dtype).max))).astype(
                np.uint8)
    return np.ascontiguousarray(img)


#: Checkerboard corner detectors (``detect_board(..., checker_detector=...)``):
#: ``sector``: OpenCV's sector-based detector (``findChessboardCornersSB``, accuracy flag);
#: ``sector+subpix``: the same corners refined by ``cornerSubPix``; ``classic``:
#: ``findChessboardCorners`` + ``cornerSubPix``. The sector-based ones fall back to the classic
#: detector where they find nothing. Which is best depends on the images (docs/calibration.md):
#: ``sea3d calibrate`` tries them all and keeps the one with the lowest holdout error.
CHECKER_DETECTORS = ("sector+subpix", "sector", "classic")
DETECTOR_ALIASES = {"accurate": "sector", "fast": "classic"}
"""Old names of detectors: ``accurate`` is ``sector``, ``fast`` is ``classic``."""


def _subpix_window(uv: FloatArray, pattern: tuple[int, int]) -> int:
    """``cornerSubPix`` half-window: 0.4 of the smallest corner spacing, 2..11 px."""
    grid = uv.reshape(pattern[1], pattern[0], 2)
    step = float(min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
                     np.linalg.norm(np.diff(grid, axis=0), axis=2).min()))
    return int(np.clip(step * 0.4, 2, 11))


def _subpix(gray: NDArray[np.uint8], uv: FloatArray, pattern: tuple[int, int]) -> FloatArray:
    win = _subpix_window(uv, pattern)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    out = cv2.cornerSubPix(gray, uv.reshape(-1, 1, 2).astype(np.float32), (win, win), (-1, -1),
                           criteria)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _find_classic(gray: NDArray[np.uint8], pattern: tuple[int, int]) -> FloatArray | None:
    flags = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
             | cv2.CALIB_CB_FAST_CHECK)
    found, c = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not found:
        found, c = cv2.findChessboardCorners(
            gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    return np.asarray(c, dtype=np.float64).reshape(-1, 2) if found else None


def _find_sector(gray: NDArray[np.uint8], pattern: tuple[int, int]) -> FloatArray | None:
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
    found, c = cv2.findChessboardCornersSB(gray, pattern, flags=flags)
    return np.asarray(c, dtype=np.float64).reshape(-1, 2) if found else None


def _is_x_corner(gray: NDArray[np.uint8], point: FloatArray, radius_px: float,
                 min_contrast: float) -> bool:
    """Whether a checkerboard corner (an X-junction of four squares) lies at ``point``.

    On a circle around an X-junction the grey level changes sign four times and is point-
    symmetric (the squares facing each other have one colour); at the corner of a board's
    outer square against its white margin it changes twice and is not symmetric.
    """
    angles = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    xs = (point[0] + radius_px * np.cos(angles)).astype(np.float32).reshape(1, -1)
    ys = (point[1] + radius_px * np.sin(angles)).astype(np.float32).reshape(1, -1)
    vals = cv2.remap(gray, xs, ys, cv2.INTER_LINEAR).astype(np.float64).ravel()
    lo, hi = float(vals.min()), float(vals.max())
    if hi - lo < min_contrast:
        return False
    sign = vals > 0.5 * (lo + hi)
    changes = int(np.count_nonzero(sign != np.roll(sign, 1)))
    half = len(vals) // 2
    if changes != 4 or np.std(vals[:half]) == 0 or np.std(vals[half:]) == 0:
        return False
    return float(np.corrcoef(vals[:half], vals[half:])[0, 1]) > 0.5


def grid_continues(gray: NDArray[np.uint8], uv: FloatArray,
                   pattern: tuple[int, int]) -> list[str]:
    """Sides past which a detected checkerboard grid continues: a sub-grid of a larger board.

    For each side of the detected grid, the corners one step beyond its outermost corner line
    are predicted through a homography fitted to the three outermost lines, refined with
    ``cornerSubPix`` and tested for an X-junction (:func:`_is_x_corner`). On a board of the
    asked size those points lie on the board's outer edge, against its white margin; if most
    of them are X-junctions, the squares go on, the board has more corners than asked for,
    and which sub-grid was found is ambiguous (the classic detector finds an 8x6 grid on 11
    of 12 images of a 9x6 board, starting at either end; the sector-based one finds none).

    Args:
        gray: the image searched.
        uv: ``(nx * ny, 2)`` detected corners in OpenCV's row-major order.
        pattern: ``(nx, ny)`` inner corners.

    Returns:
        The sides (``"left"``, ``"right"``, ``"top"``, ``"bottom"`` of the grid's own order)
        past which the squares go on; empty for a board of the asked size. Sides whose
        predicted corners leave the image are not tested.
    """
    nx, ny = pattern
    if nx < 3 or ny < 3:
        return []
    grid = uv.reshape(ny, nx, 2)
    h, w = gray.shape
    # The board's own contrast: the grey levels at its corners' surroundings.
    contrast = float(np.percentile(gray, 95) - np.percentile(gray, 5))
    sides = []
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-2)
    for name, lines in (("left", grid[:, :3][:, ::-1]), ("right", grid[:, -3:]),
                        ("top", grid[:3].transpose(1, 0, 2)[:, ::-1]),
                        ("bottom", grid[-3:].transpose(1, 0, 2))):
        # lines: (n_along, 3, 2): along the side, then three corner lines towards the edge.
        n_along = lines.shape[0]
        a, b = np.mgrid[0:n_along, 0:3]
        src = np.stack([b.ravel(), a.ravel()], axis=1).astype(np.float64)
        H, _ = cv2.findHomography(src, lines.reshape(-1, 2).astype(np.float64))
        if H is None:
            continue
        step = float(np.median(np.linalg.norm(np.diff(lines, axis=1), axis=2)))
        beyond = np.stack([np.full(n_along, 3.0), np.arange(n_along, dtype=np.float64)], 1)
        pred = cv2.perspectiveTransform(beyond.reshape(-1, 1, 2), H).reshape(-1, 2)
        margin = step + 2
        inside = ((pred[:, 0] > margin) & (pred[:, 0] < w - 1 - margin) & (pred[:, 1] > margin)
                  & (pred[:, 1] < h - 1 - margin))
        if inside.mean() < 0.75 or step < 6:
            continue
        win = max(2, round(0.3 * step))
        refined = cv2.cornerSubPix(gray, pred.reshape(-1, 1, 2).astype(np.float32), (win, win),
                                   (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
        near = np.linalg.norm(refined - pred, axis=1) < 0.35 * step
        hits = sum(bool(inside[k] and near[k])
                   and _is_x_corner(gray, refined[k], 0.3 * step, 0.25 * contrast)
                   for k in range(n_along))
        if hits < 0.6 * n_along:
            continue
        # X-junctions also appear where a narrow margin meets a dark background (a hand, a
        # shirt): the squares beyond them must alternate too, against the outer squares.
        c2 = lines[:, 2]
        c3 = np.where(near[:, None], refined, pred)
        mid2, mid3 = 0.5 * (c2[:-1] + c2[1:]), 0.5 * (c3[:-1] + c3[1:])
        squares = _patch_means(gray, 0.5 * (mid2 + mid3), 0.15 * step)
        past = _patch_means(gray, mid3 + 0.5 * (mid3 - mid2), 0.15 * step)
        if squares is None or past is None or np.std(past) < 1e-6 or np.std(squares) < 1e-6:
            continue
        swing_squares = float(np.mean(np.abs(np.diff(squares))))
        swing_past = float(np.mean(np.abs(np.diff(past))))
        if (float(np.corrcoef(squares, past)[0, 1]) < -0.75
                and swing_past > 0.25 * swing_squares):
            sides.append(name)
    return sides


def _patch_means(gray: NDArray[np.uint8], points: FloatArray, radius_px: float
                 ) -> FloatArray | None:
    """Mean grey level in a square patch around each of ``points`` ``(K, 2)``; None when a
    patch leaves the image."""
    h, w = gray.shape
    r = max(1, round(radius_px))
    if len(points) < 2 or not np.isfinite(points).all() or points.min() < r + 1 or (
            points[:, 0].max() > w - r - 2) or points[:, 1].max() > h - r - 2:
        return None
    return np.array([float(gray[round(y) - r:round(y) + r + 1,
                                round(x) - r:round(x) + r + 1].mean()) for x, y in points])


def _detect_checkerboard(gray: NDArray[np.uint8], board: BoardSpec, detector: str,
                         size: tuple[int, int], found: dict[str, Any] | None = None
                         ) -> Detection:
    """One checkerboard detector; ``found`` caches the raw sector/classic corners across
    detectors of the same image."""
    pattern = board.corner_grid
    cache: dict[str, Any] = {} if found is None else found
    uv = None
    how = ""
    if detector in ("sector", "sector+subpix"):
        if "sector" not in cache:
            cache["sector"] = _find_sector(gray, pattern)
        if cache["sector"] is not None:
            uv = cache["sector"]
            how = "sector-based detector"
            if detector == "sector+subpix":
                uv = _subpix(gray, uv, pattern)
                how += f" + cornerSubPix ({_subpix_window(cache['sector'], pattern)} px)"
    if uv is None:
        if "classic" not in cache:
            cache["classic"] = _find_classic(gray, pattern)
        if cache["classic"] is not None:
            uv = _subpix(gray, cache["classic"], pattern)
            how = (f"classic detector + cornerSubPix "
                   f"({_subpix_window(cache['classic'], pattern)} px)")
    if uv is None:
        return _empty(DetectionStatus.NOT_FOUND, size,
                      f"no {pattern[0]}x{pattern[1]} checkerboard found")
    # The sector-based detector refuses a grid inside a larger board by itself (it finds none
    # of 12 views of a 9x6 board asked for 8x6); the classic one finds them (11 of 12).
    sides = grid_continues(gray, uv, pattern) if how.startswith("classic") else []
    if sides:
        return _empty(DetectionStatus.WRONG_SIZE, size,
                      f"found {pattern[0]}x{pattern[1]} corners, but the squares go on past "
                      f"its {' and '.join(sides)} side: the board has more inner corners, and "
                      f"which part of it was found is ambiguous")
    uv = _canonical_checker_order(uv, pattern)
    ids, pts = board.object_points()
    return Detection(status=DetectionStatus.DETECTED, corners_px=uv, ids=ids,
                     points_board_m=pts, image_size=size,
                     message=f"{len(uv)} corners ({how})", ambiguous_order=True)


def detect_checkerboard_all(image: NDArray[Any], board: BoardSpec) -> dict[str, Detection]:
    """Every checkerboard detector of :data:`CHECKER_DETECTORS` on one image, sharing work (the
    sector-based and the classic search run once each).

    Returns:
        ``{detector: Detection}``.
    """
    img = np.asarray(image)
    if board.kind != "checkerboard":
        raise ConfigError(f"detect_checkerboard_all needs a checkerboard, not {board.kind}")
    if img.size == 0 or img.ndim not in (2, 3):
        bad = _empty(DetectionStatus.UNREADABLE, (0, 0), f"not an image (shape {img.shape})")
        return dict.fromkeys(CHECKER_DETECTORS, bad)
    size = (int(img.shape[1]), int(img.shape[0]))
    gray = _to_gray(img)
    found: dict[str, Any] = {}
    return {name: _detect_checkerboard(gray, board, name, size, found)
            for name in CHECKER_DETECTORS}


def _canonical_checker_order(uv: FloatArray, pattern: tuple[int, int]) -> FloatArray:
    """Fix the 180-degree ambiguity of a checkerboard's corner order.

    A symmetric checkerboard can be returned starting from either end. OpenCV's order is kept
    except that the first corner is made the one nearer the image's top-left, so that the left
    and right images of a stereo pair agree.
    """
    nx, ny = pattern
    grid: FloatArray = uv.reshape(ny, nx, 2)
    first, last = grid[0, 0], grid[-1, -1]
    if first.sum() > last.sum():
        grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2).copy()


def _refinement_of(board: BoardSpec) -> str:
    """Which OpenCV corner detector and refinement :func:`detect_board` uses for ``board``:
    ``"charuco"``, ``"apriltag"`` (tag corners, AprilTag refinement) or ``"subpix"`` (tag
    corners, ``cornerSubPix`` refinement)."""
    if board.kind == "charuco":
        return "charuco"
    return "apriltag" if board.dictionary.upper().startswith("DICT_APRILTAG") else "subpix"


def _detect_markers(gray: NDArray[np.uint8], board: BoardSpec) -> tuple[Any, Any]:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    if _refinement_of(board) == "apriltag":
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    detector = cv2.aruco.ArucoDetector(_aruco_dictionary(board.dictionary), params)
    corners, ids, _ = detector.detectMarkers(gray)
    return corners, ids


# Boards drawn by render_board to find the pixel convention of OpenCV's corners (see
# corner_convention_offset_px); their corners are known exactly.
_PROBE_BOARDS = {"charuco": ("charuco:4x5:25mm:18mm:DICT_5X5_100", 2400.0),
                 "apriltag": ("apriltag:2x2:30mm:40mm", 2500.0),
                 "subpix": ("aruco:2x2:30mm:40mm:DICT_4X4_50", 2500.0)}


def _version_offset_px(refinement: str) -> float:
    """The convention as measured on OpenCV 4.10-4.14 (docs/calibration.md), by version."""
    if refinement == "subpix":
        return 0.0
    if refinement == "charuco":
        major, minor = (int(v) for v in cv2.__version__.split(".")[:2])
        return 0.5 if (major, minor) < (4, 14) else 0.0
    return 0.5


@functools.cache
def corner_convention_offset_px(refinement: str) -> float:
    """How far OpenCV's marker-based corners are from sea3d's pixel-centre convention.

    OpenCV's ArUco and ChArUco detectors have returned corners in the pixel-edge convention
    (integer coordinates at pixel corners, +0.5 px against ours) or in the pixel-centre one,
    depending on the version (ChArUco changed in 4.14) and on the corner refinement
    (``cornerSubPix`` refinement gives pixel centres). This detects the convention at run time:
    a board with known corners is drawn by :func:`render_board`, detected once per process
    with the same detector settings, and the median offset is rounded to the nearest half
    pixel. Should that detection fail, the offsets measured on OpenCV 4.10-4.14 are used.

    Args:
        refinement: ``"charuco"``, ``"apriltag"`` or ``"subpix"`` (see :func:`detect_board`).

    Returns:
        The offset in pixels (0.0 or 0.5 on every version seen) to subtract from OpenCV's
        corners, both axes.
    """
    spec, px_per_m = _PROBE_BOARDS[refinement]
    board = parse_board(spec)
    margin_px = 40
    img = np.asarray(cv2.copyMakeBorder(render_board(board, px_per_m=px_per_m), margin_px,
                                        margin_px, margin_px, margin_px, cv2.BORDER_CONSTANT,
                                        value=255), dtype=np.uint8)
    ids, pts = board.object_points()
    ox, oy = board_origin_offset_m(board)
    expected = (pts[:, :2] + [ox, oy]) * px_per_m + margin_px - 0.5
    lookup = {int(i): k for k, i in enumerate(ids)}
    found: list[FloatArray] = []
    if refinement == "charuco":
        ch_corners, ch_ids, _, _ = cv2.aruco.CharucoDetector(board._charuco_board()).detectBoard(
            img)
        if ch_ids is not None:
            found = [c - expected[lookup[int(i)]]
                     for c, i in zip(ch_corners.reshape(-1, 2), ch_ids.ravel(), strict=True)]
    else:
        corners, marker_ids = _detect_markers(img, board)
        if marker_ids is not None:
            for quad, mid in zip(corners, marker_ids.ravel(), strict=True):
                found += [quad.reshape(4, 2)[k] - expected[lookup[4 * int(mid) + k]]
                          for k in range(4)]
    if len(found) < 8:
        offset = _version_offset_px(refinement)
        log.warning("could not measure OpenCV %s's %s corner convention on a drawn board; "
                    "assuming %.1f px", cv2.__version__, refinement, offset)
        return offset
    median = np.median(np.asarray(found), axis=0)
    offset = round(float(np.mean(median)) * 2.0) / 2.0
    log.debug("OpenCV %s %s corners: median offset (%.3f, %.3f) px against pixel centres; "
              "shifting by -%.1f px", cv2.__version__, refinement, median[0], median[1], offset)
    return offset


def detect_board(image: NDArray[Any], board: BoardSpec, *, min_corners: int = 0,
                 use_sector_based: bool = True, checker_detector: str | None = None
                 ) -> Detection:
    """Find ``board`` in one image.

    Checkerboards use OpenCV's sector-based detector (``findChessboardCornersSB``, with its
    accuracy flag), falling back to ``findChessboardCorners`` + ``cornerSubPix`` (see
    :data:`CHECKER_DETECTORS` for the choices); a grid whose squares go on past its side (a
    sub-grid of a larger board) is refused as ``WRONG_SIZE`` (:func:`grid_continues`).
    ChArUco uses ``cv2.aruco.CharucoDetector``; tag grids use ``cv2.aruco.ArucoDetector``
    (AprilTag 36h11 via ``DICT_APRILTAG_36h11``, with AprilTag corner refinement).

    Args:
        image: ``(H, W)`` or ``(H, W, 3)`` RGB (or ``(H, W, 4)`` RGBA) image, uint8, uint16 or
            float in [0, 1].
        board: the board to look for.
        min_corners: ChArUco and tag grids: fewer corners than this is ``PARTIAL`` (default:
            6 corners for ChArUco, one whole tag for grids). Checkerboards are all or nothing.
        use_sector_based: checkerboards: try ``findChessboardCornersSB`` first (``sector``;
            False: ``classic``).
        checker_detector: checkerboards: one of :data:`CHECKER_DETECTORS` (overrides
            ``use_sector_based``).

    Returns:
        A :class:`Detection`; ``status`` says what was found, corners sorted by id.
    """
    img = np.asarray(image)
    if img.size == 0 or img.ndim not in (2, 3):
        return _empty(DetectionStatus.UNREADABLE, (0, 0), f"not an image (shape {img.shape})")
    size = (int(img.shape[1]), int(img.shape[0]))
    gray = _to_gray(img)
    if board.kind == "checkerboard":
        checker = checker_detector or ("sector" if use_sector_based else "classic")
        if checker not in CHECKER_DETECTORS:
            raise ConfigError(f"checker_detector must be one of {CHECKER_DETECTORS}; got "
                              f"{checker!r}")
        return _detect_checkerboard(gray, board, checker, size)
    ids: IntArray
    uv: FloatArray
    all_ids, all_pts = board.object_points()
    lookup = {int(i): k for k, i in enumerate(all_ids)}
    if board.kind == "charuco":
        detector = cv2.aruco.CharucoDetector(board._charuco_board())
        ch_corners, ch_ids, _marker_corners, marker_ids = detector.detectBoard(gray)
        n_markers = 0 if marker_ids is None else len(marker_ids)
        need = min_corners or 6
        if ch_ids is None or len(ch_ids) == 0:
            status = DetectionStatus.PARTIAL if n_markers else DetectionStatus.NOT_FOUND
            return _empty(status, size, f"no ChArUco corners ({n_markers} markers)")
        ids = ch_ids.reshape(-1).astype(np.int64)
        uv = ch_corners.reshape(-1, 2).astype(np.float64)
    else:
        corners, marker_ids = _detect_markers(gray, board)
        need = min_corners or 4
        if marker_ids is None or len(marker_ids) == 0:
            return _empty(DetectionStatus.NOT_FOUND, size, "no tags found")
        id_list, uv_list = [], []
        foreign = 0
        for quad, mid in zip(corners, marker_ids.reshape(-1), strict=True):
            for k in range(4):
                cid = 4 * int(mid) + k
                if cid in lookup:
                    id_list.append(cid)
                    uv_list.append(quad.reshape(4, 2)[k])
                elif k == 0:
                    foreign += 1
        if not id_list:
            return _empty(DetectionStatus.WRONG_SIZE, size,
                          f"{foreign} tags found, none with an id of this board")
        ids = np.asarray(id_list, dtype=np.int64)
        uv = np.asarray(uv_list, dtype=np.float64)
        n_markers = len(marker_ids)
    # Ours puts pixel centres on integers. Depending on the OpenCV version and the corner
    # refinement, ArUco and ChArUco corners come in that convention or in the pixel-edge one
    # (the top-left corner of the top-left pixel at 0, 0): measured once per process.
    uv = uv - corner_convention_offset_px(_refinement_of(board))
    order = np.argsort(ids, kind="stable")
    ids, uv = ids[order], uv[order]
    # Tags can be seen twice if ids repeat; keep the first of each id.
    ids, first = np.unique(ids, return_index=True)
    uv = uv[first]
    pts = all_pts[[lookup[int(i)] for i in ids]]
    status = DetectionStatus.DETECTED if len(ids) >= need else DetectionStatus.PARTIAL
    return Detection(status=status, corners_px=uv, ids=ids, points_board_m=pts,
                     image_size=size,
                     message=f"{len(ids)} of {len(all_ids)} corners ({n_markers} markers)")


def diagnose_checkerboard_size(image: NDArray[Any], board: BoardSpec,
                               max_delta: int = 2) -> tuple[int, int] | None:
    """Find the inner-corner counts of the checkerboard an image holds, when they are not
    ``board``'s.

    Used to explain a failed detection ("holds 9x6 -- did you mean checkerboard:9x6?"). First
    the sector-based detector is asked for any board of at least 3x3 corners (OpenCV's
    ``CALIB_CB_LARGER``), which finds the whole board; then the classic detector tries counts
    within ``max_delta`` of ``board``'s, larger boards first (a smaller count would only find a
    part of the board).

    Returns:
        ``(cols, rows)`` of a checkerboard found in the image (in ``board``'s orientation:
        the larger count first if ``board.cols >= board.rows``), or None.
    """
    if board.kind != "checkerboard":
        return None
    gray: NDArray[Any] = _to_gray(np.asarray(image))
    scale = 1.0
    if max(gray.shape) > 1000:
        scale = 1000.0 / max(gray.shape)
        gray = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    found, _corners, meta = cv2.findChessboardCornersSBWithMeta(
        gray, (3, 3), cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_LARGER)
    if found and meta is not None:
        a, b = sorted(int(v) for v in np.asarray(meta).shape[:2])
        counts = (b, a) if board.cols >= board.rows else (a, b)
        if counts != (board.cols, board.rows):
            return counts
    candidates = []
    for dc in range(-max_delta, max_delta + 1):
        for dr in range(-max_delta, max_delta + 1):
            c, r = board.cols + dc, board.rows + dr
            if (dc, dr) != (0, 0) and c >= 3 and r >= 3:
                candidates.append((abs(dc) + abs(dr), -c * r, c, r))
    for _, _, c, r in sorted(candidates):
        ok, _ = cv2.findChessboardCorners(
            gray, (c, r), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK
            | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            return c, r
    return None


# ---------------------------------------------------------------------- rendering
def render_board(board: BoardSpec, *, px_per_m: float, margin_m: float = 0.0) -> NDArray[
        np.uint8]:
    """Draw the board as a grey image at ``px_per_m`` pixels per metre.

    Args:
        board: the board.
        px_per_m: resolution; the drawn square side is ``board.square_m * px_per_m`` pixels.
        margin_m: white margin around the board, metres.

    Returns:
        ``(H, W)`` uint8 image, 255 white, 0 black. For checkerboards and tag grids, board
        point ``(x, y)`` lies at pixel ``(margin + x0 + x) * px_per_m - 0.5`` (pixel centres at
        integers), with ``x0`` the offset of the board origin from the outer edge.

    Raises:
        ConfigError: the image would be larger than 40000 pixels on a side.
    """
    width_m, height_m = board.size_m
    w = round((width_m + 2 * margin_m) * px_per_m)
    h = round((height_m + 2 * margin_m) * px_per_m)
    if max(w, h) > 40000 or min(w, h) < 8:
        raise ConfigError(f"board image would be {w}x{h} px; choose another resolution")
    img = np.full((h, w), 255, np.uint8)

    def px(x_m: float) -> int:
        return round(x_m * px_per_m)

    m = margin_m
    if board.kind in ("checkerboard", "charuco"):
        nx = board.cols + 1 if board.kind == "checkerboard" else board.cols
        ny = board.rows + 1 if board.kind == "checkerboard" else board.rows
        if board.kind == "charuco":
            inner = board._charuco_board().generateImage(
                (px(nx * board.square_m), px(ny * board.square_m)), marginSize=0, borderBits=1)
            y0, x0 = px(m), px(m)
            img[y0:y0 + inner.shape[0], x0:x0 + inner.shape[1]] = inner
            return img
        s = board.square_m
        for j in range(ny):
            for i in range(nx):
                if (i + j) % 2 == 0:
                    img[px(m + j * s):px(m + (j + 1) * s), px(m + i * s):px(m + (i + 1) * s)] = 0
        return img
    dictionary = _aruco_dictionary(board.dictionary)
    grid = board.ids_grid()
    gap = board.square_m - board.marker_m
    side = px(board.marker_m)
    for r in range(board.rows):
        for c in range(board.cols):
            tag = cv2.aruco.generateImageMarker(dictionary, int(grid[r, c]), side, borderBits=1)
            y0 = px(m + gap + r * board.square_m)
            x0 = px(m + gap + c * board.square_m)
            img[y0:y0 + side, x0:x0 + side] = tag
    return img


def board_origin_offset_m(board: BoardSpec) -> tuple[float, float]:
    """Offset of the board-frame origin from the board's outer top-left edge, metres."""
    if board.kind == "checkerboard":
        return board.square_m, board.square_m
    if board.kind == "charuco":
        return board.square_m, board.square_m
    gap = board.square_m - board.marker_m
    return gap, gap



def detect_images(images: Iterable[tuple[str, NDArray[Any] | None]], board: BoardSpec,
                  detector: str = "auto") -> dict[str, list[Detection]]:
    """The detections of a sequence of images, per checkerboard detector.

    Args:
        images: ``(name, image)`` pairs, the image None where it could not be read (its
            detection is then ``UNREADABLE``).
        board: the board.
        detector: ``auto`` runs every detector of :data:`CHECKER_DETECTORS` on a checkerboard
            (``{detector: [...]}`` for each; the caller keeps the one whose calibration is
            best) and the board's own detector on other boards; a name (or an alias of
            :data:`DETECTOR_ALIASES`) runs that one.

    Returns:
        ``{detector: [Detection, ...]}`` in input order, each named; the key is ``"auto"`` for
        a non-checkerboard board with ``detector="auto"``.
    """
    detector = DETECTOR_ALIASES.get(detector, detector)
    every = detector == "auto" and board.kind == "checkerboard"
    names = list(CHECKER_DETECTORS) if every else [detector]
    out: dict[str, list[Detection]] = {n: [] for n in names}
    for name, img in images:
        if img is None:
            for n in names:
                out[n].append(_empty(DetectionStatus.UNREADABLE, (0, 0),
                                     "cannot read the image").with_name(name))
            continue
        if every:
            found = detect_checkerboard_all(img, board)
            for n in names:
                out[n].append(found[n].with_name(name))
        else:
            checker = None if detector == "auto" or board.kind != "checkerboard" else detector
            out[detector].append(detect_board(img, board, checker_detector=checker).with_name(
                name))
        log.debug("%s: %s", name, out[names[0]][-1].message)
    return out
