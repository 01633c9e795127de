"""The reader side of a session: :class:`SessionReader`, the interface every storage's reader
implements, and :func:`open_session`, which picks the storage from what the path is."""

from __future__ import annotations

import collections
import itertools
import logging
import os
from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.io.session.common import (
    IMAGE_STREAMS,
    DamagedChunk,
    ImuSeries,
    PairMatch,
    SonarSeries,
    StereoPair,
    match_stamps,
    stream_stats,
)

__all__ = ["SessionReader", "is_session", "layout_of", "open_session"]

_log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- reader base


class SessionReader(ABC):
    """Read access to a recorded session, whatever its layout.

    Open one with :func:`sea3d.io.session.open_session`. Use it as a context manager or call
    :meth:`close`. Every stamp is an integer number of nanoseconds.
    """

    format: str = ""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._ref_shape: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
        # What the reader found damaged or missing (each also logged as a warning), and how
        # many records of each stream it skipped because of damage.
        self.problems: list[str] = []
        self.skipped: dict[str, int] = {}
        # The chunks whose bytes failed a check (a layout without chunks has none).
        self.damaged_chunks: list[DamagedChunk] = []
        self._rig: str | None = None
        self._rig_problem: str | None = None
        self._rig_checked = False

    # -- layout-specific -----------------------------------------------------------------
    @property
    def rig_yaml(self) -> str | None:
        """The rig file's YAML text stored with the session, or None when none is stored.

        Raises:
            SessionError: a rig is stored but cannot be used (damaged, not UTF-8 text), so
                that it is never mistaken for "no rig" or passed on as good.
        """
        self._check_rig()
        if self._rig_problem is not None:
            raise SessionError(self._rig_problem)
        return self._rig

    def _check_rig(self) -> None:
        """A stored rig must parse as a rig (an empty or cut rig.yaml is damage, not a rig)."""
        if self._rig is None or self._rig_checked:
            return
        self._rig_checked = True
        from sea3d.errors import RigFileError
        from sea3d.io.rig_file import rig_from_yaml

        try:
            rig_from_yaml(self._rig, f"{self.path} (stored rig.yaml)")
        except RigFileError as err:
            self._rig_problem = f"the stored rig cannot be used: {err}"
            self.problems.append(self._rig_problem)
            _log.warning("%s", self._rig_problem)

    @property
    def rig_status(self) -> str:
        """``"yes"``, ``"no"`` or ``"damaged: <why>"`` (never raises)."""
        self._check_rig()
        if self._rig_problem is not None:
            return f"damaged: {self._rig_problem}"
        return "yes" if self._rig is not None else "no"

    @property
    def image_encoding(self) -> str | None:
        """The image encoding the session was written with, when it says so."""
        return None

    @abstractmethod
    def stamps(self, stream: str) -> np.ndarray:
        """(N,) int64 sorted stamps of ``stream`` (``left``, ``right``, ``imu``, ``sonar``).

        Raises:
            SessionError: for an unknown stream name.
        """

    @abstractmethod
    def _read_image(self, stream: str, index: int) -> np.ndarray:
        """Decode image ``index`` of ``stream``; raise SessionError naming the record."""

    @abstractmethod
    def image_bytes(self, stream: str, index: int) -> tuple[bytes, str]:
        """The stored bytes of image ``index`` of ``stream`` and their format (``png``,
        ``jpeg``, ...); raw images come back PNG-encoded (lossless).

        Raises:
            SessionError: if the record cannot be read.
        """

    @abstractmethod
    def _record_name(self, stream: str, index: int) -> str:
        """Human-readable name of a record (file or topic) for messages."""

    @abstractmethod
    def imu(self) -> ImuSeries:
        """All IMU samples, sorted; an empty series when there are none."""

    @abstractmethod
    def sonar(self) -> SonarSeries:
        """All echosounder samples, sorted; an empty series when there are none."""

    @abstractmethod
    def size_bytes(self) -> int:
        """Bytes on disk."""

    @abstractmethod
    def check(self) -> list[str]:
        """Read what opening the session did not (every chunk's bytes, the CSVs), so that
        every problem the readers can see is in :attr:`problems` (``session verify``, and a
        strict ``session convert``, before they read the records).

        Returns the new problems (also in :attr:`problems`).
        """

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release open files."""

    def streams(self) -> list[str]:
        """Names of the streams that hold at least one record."""
        return [s for s in ("left", "right", "imu", "sonar") if self.stamps(s).size]

    # -- shared --------------------------------------------------------------------------
    def __enter__(self) -> SessionReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r})"

    def index_of(self, stream: str, t_ns: int, tolerance_ns: int = 0) -> int:
        """Index of the record of ``stream`` nearest to ``t_ns`` within ``tolerance_ns``.

        Raises:
            SessionError: if no record lies within the tolerance.
        """
        stamps = self.stamps(stream)
        if stamps.size == 0:
            raise SessionError(f"{self.path}: stream {stream!r} is empty")
        j = int(np.searchsorted(stamps, t_ns))
        cands = [k for k in (j - 1, j) if 0 <= k < stamps.size]
        best = min(cands, key=lambda k: abs(int(stamps[k]) - int(t_ns)))
        if abs(int(stamps[best]) - int(t_ns)) > tolerance_ns:
            raise SessionError(
                f"{self.path}: no {stream} record within {tolerance_ns} ns of t_ns={int(t_ns)} "
                f"(nearest is {int(stamps[best])})"
            )
        return best

    def image(self, stream: str, key: int, *, by: str = "auto") -> np.ndarray:
        """One image of ``left`` or ``right``, by index or by stamp.

        Args:
            stream: ``"left"`` or ``"right"``.
            key: an index (0-based, negative counts from the end) or a stamp in nanoseconds.
            by: ``"index"``, ``"stamp"`` (exact stamp), or ``"auto"``: an exact stamp match
                first, otherwise an index.

        Returns:
            (H, W) or (H, W, 3) RGB, uint8 or uint16.

        Raises:
            SessionError: unknown stream, no such index or stamp, a damaged record, or an
                image whose size differs from the stream's first image (file and stamp named).
        """
        if stream not in IMAGE_STREAMS:
            raise SessionError(f"unknown image stream {stream!r}; expected one of {IMAGE_STREAMS}")
        stamps = self.stamps(stream)
        n = int(stamps.size)
        index: int | None = None
        if by in ("auto", "stamp"):
            j = int(np.searchsorted(stamps, key))
            if j < n and int(stamps[j]) == int(key):
                index = j
            elif by == "stamp":
                raise SessionError(f"{self.path}: no {stream} image with t_ns={int(key)}")
        if index is None:
            if by not in ("auto", "index"):
                raise SessionError(f"by must be 'auto', 'index' or 'stamp', got {by!r}")
            if not -n <= int(key) < n:
                raise SessionError(
                    f"{self.path}: {stream} has {n} images; {int(key)} is neither an index "
                    "nor a stamp"
                )
            index = int(key) % n
        img = self._read_image(stream, index)
        self._check_shape(stream, index, img)
        return img

    def _check_shape(self, stream: str, index: int, img: np.ndarray) -> None:
        ref = self._ref_shape.get(stream)
        if ref is None:
            first = img
            if index != 0:
                try:
                    first = self._read_image(stream, 0)
                except SessionError as err:  # a damaged first image must not condemn the rest
                    _log.warning(
                        "%s; using %s as the stream's reference size",
                        err,
                        self._record_name(stream, index),
                    )
            ref = (first.shape, first.dtype)
            self._ref_shape[stream] = ref
        if img.shape != ref[0] or img.dtype != ref[1]:
            raise SessionError(
                f"{self._record_name(stream, index)} (t_ns={int(self.stamps(stream)[index])}) is "
                f"{img.shape} {img.dtype} but the stream's first image is {ref[0]} {ref[1]}"
            )

    def default_tolerance_ns(self) -> int:
        """Half the median left frame interval (0 with fewer than two left frames)."""
        stamps = self.stamps("left")
        if stamps.size < 2:
            return 0
        return int(np.median(np.diff(stamps)) // 2)

    def match_pairs(self, tolerance_ns: int | None = None) -> PairMatch:
        """Match left and right frames by mutual-nearest stamp within ``tolerance_ns``.

        Args:
            tolerance_ns: largest stamp difference of a pair; None uses
                :meth:`default_tolerance_ns` (half the median left frame interval).
        """
        tol = self.default_tolerance_ns() if tolerance_ns is None else int(tolerance_ns)
        if tol < 0:
            raise SessionError(f"tolerance_ns must be >= 0, got {tol}")
        left, right = self.stamps("left"), self.stamps("right")
        li, ri = match_stamps(left, right, tol)
        return PairMatch(
            left_index=li,
            right_index=ri,
            unpaired_left=int(left.size - li.size),
            unpaired_right=int(right.size - ri.size),
            tolerance_ns=tol,
        )

    def pairs(self, tolerance_ns: int | None = None, *, workers: int = 2) -> Iterator[StereoPair]:
        """Iterate over stereo pairs in stamp order, skipping damaged ones with a warning.

        Images are decoded ahead in ``workers`` threads (OpenCV releases the GIL while
        decoding), at most ``2 * workers`` pairs ahead; ``workers=0`` decodes in the caller's
        thread. Unpaired frames are counted and logged (see :meth:`match_pairs`).
        """
        match = self.match_pairs(tolerance_ns)
        if match.unpaired_left or match.unpaired_right:
            _log.warning(
                "%s: %d left and %d right frames have no partner within %d ns",
                self.path,
                match.unpaired_left,
                match.unpaired_right,
                match.tolerance_ns,
            )
        ls, rs = self.stamps("left"), self.stamps("right")
        todo = list(zip(match.left_index.tolist(), match.right_index.tolist(), strict=True))

        def load(i: int, j: int) -> StereoPair | None:
            try:
                left = self.image("left", i, by="index")
                right = self.image("right", j, by="index")
            except SessionError as err:
                _log.warning("skipping pair at t_ns=%d: %s", int(ls[i]), err)
                return None
            rt = int(rs[j])
            return StereoPair(int(ls[i]), left, right, None if rt == int(ls[i]) else rt)

        if workers <= 0 or len(todo) < 2:
            for i, j in todo:
                pair = load(i, j)
                if pair is not None:
                    yield pair
            return
        from concurrent.futures import Future, ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="sea3d-read") as pool:
            ahead: collections.deque[Future[StereoPair | None]] = collections.deque()
            it = iter(todo)
            for i, j in itertools.islice(it, 2 * workers):
                ahead.append(pool.submit(load, i, j))
            while ahead:
                pair = ahead.popleft().result()
                nxt = next(it, None)
                if nxt is not None:
                    ahead.append(pool.submit(load, *nxt))
                if pair is not None:
                    yield pair

    def info(self) -> dict[str, dict[str, Any]]:
        """Per-stream statistics: ``count``, ``rate_hz``, ``first_t_ns``, ``last_t_ns``, ``gaps``
        (intervals longer than 1.5 median intervals) and ``max_interval_s``."""
        return {s: stream_stats(self.stamps(s)) for s in ("left", "right", "imu", "sonar")}

    def checks(self) -> tuple[str, str]:
        """What opening the session checked, and what it did not (read by ``session info``,
        which must not show counts as if they were verified)."""
        return ("nothing", "every record (run `sea3d session verify`)")

    def summary(self, tolerance_ns: int | None = None) -> dict[str, Any]:
        """Session-level report: path, format, size, duration, rig, streams and pairing,
        what was checked on opening and not (``checked``, ``not_checked``) and the
        ``problems`` found so far."""
        streams = self.info()
        checked, not_checked = self.checks()
        firsts = [v["first_t_ns"] for v in streams.values() if v["count"]]
        lasts = [v["last_t_ns"] for v in streams.values() if v["count"]]
        match = self.match_pairs(tolerance_ns)
        return {
            "path": os.fspath(self.path),
            "format": self.format,
            "size_bytes": self.size_bytes(),
            "duration_s": (max(lasts) - min(firsts)) * 1e-9 if firsts else 0.0,
            "rig_status": self.rig_status,
            "rig": self._rig is not None and self._rig_problem is None,
            "streams": streams,
            "pairs": {
                "count": len(match),
                "unpaired_left": match.unpaired_left,
                "unpaired_right": match.unpaired_right,
                "tolerance_ns": match.tolerance_ns,
            },
            "checked": checked,
            "not_checked": not_checked,
            "problems": list(self.problems),
        }


def layout_of(path: str | os.PathLike[str]) -> str:
    """``"mcap"`` for a path ending in ``.mcap``, ``"folder"`` otherwise."""
    return "mcap" if os.fspath(path).lower().endswith(".mcap") else "folder"


def is_session(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a session: an ``.mcap`` file or a file starting with the MCAP magic,
    or a folder with ``left/`` or ``session.json`` in it (a folder of images is not one)."""
    p = Path(path)
    if p.is_file():
        with open(p, "rb") as fh:
            return p.suffix.lower() == ".mcap" or fh.read(8).startswith(b"\x89MCAP")
    return p.is_dir() and ((p / "left").is_dir() or (p / "session.json").is_file())


def open_session(path: str | os.PathLike[str], *, name_unit: str = "ns") -> SessionReader:
    """Open a recorded session, choosing the reader from what ``path`` is.

    Args:
        path: an ``.mcap`` file (or any file starting with the MCAP magic) or a session folder.
        name_unit: for folders only: unit of the numbers in image file names, ``"ns"`` or
            ``"us"`` (the paper's recordings use microseconds).

    Returns:
        A :class:`SessionReader`; use it as a context manager.

    Raises:
        SessionError: if the path does not exist or is neither an MCAP file nor a session folder.
    """
    p = Path(path)
    if p.is_dir():
        from sea3d.io.session.storage_folder import FolderSessionReader

        return FolderSessionReader(p, name_unit=name_unit)
    if p.is_file():
        from sea3d.io.session.mcap_reader import McapSessionReader

        return McapSessionReader(p)
    raise SessionError(f"session {p} does not exist")
