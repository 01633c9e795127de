"""Frame sources of the process pipeline: stereo pairs in time order, with the IMU between.

:class:`SessionFrames` is the offline source (a recorded session); a live source (cameras, or
a session replayed at its rate) hands the same :class:`FramePair`s on as they arrive.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import SessionError
from sea3d.odometry.types import ImuChunk

if TYPE_CHECKING:
    from sea3d.geometry.rig import StereoRig
    from sea3d.io.session import ImuSeries, SessionReader

__all__ = ["FramePair", "SessionFrames", "imu_between"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class FramePair:
    """One stereo pair to process: its left stamp and where its images are."""

    index: int
    """Position in the source's time order."""
    t_ns: int
    """The left image's stamp."""
    left_index: int
    right_index: int


def imu_between(imu: ImuSeries, t_prev: int | None, t: int) -> ImuChunk | None:
    """The IMU samples in ``(t_prev, t]`` (all up to ``t`` for the first frame), or None
    without an IMU."""
    if imu is None or len(imu) == 0:
        return None
    lo = 0 if t_prev is None else int(np.searchsorted(imu.t_ns, t_prev, side="right"))
    hi = int(np.searchsorted(imu.t_ns, t, side="right"))
    return ImuChunk(t_ns=np.asarray(imu.t_ns[lo:hi], np.int64),
                    accel_mps2=np.asarray(imu.accel_mps2[lo:hi], np.float64),
                    gyro_radps=np.asarray(imu.gyro_radps[lo:hi], np.float64))


class SessionFrames:
    """The stereo pairs of an open session, in time order, and the rig to process them with.

    Args:
        session: an open session (:func:`sea3d.io.session.open_session`).
        path: its path (for messages).
        rig: the rig at the recorded size (``--rig``'s or the session's).
        max_frames: only the first N pairs.

    Raises:
        SessionError: no stereo pairs, none that can be read, or images of another size than
            the rig.
    """

    def __init__(self, session: SessionReader, path: Path, rig: StereoRig, *,
                 max_frames: int | None = None) -> None:
        self.session = session
        self.path = Path(path)
        self.match = session.match_pairs()
        self.pairs_in_session = len(self.match)
        if self.pairs_in_session == 0:
            raise SessionError(f"{path}: no stereo pairs to process")
        n = self.pairs_in_session if max_frames is None else min(self.pairs_in_session,
                                                                 max_frames)
        stamps = session.stamps("left")
        self.pairs = [FramePair(index=i, t_ns=int(stamps[self.match.left_index[i]]),
                                left_index=int(self.match.left_index[i]),
                                right_index=int(self.match.right_index[i]))
                      for i in range(n)]
        native = rig
        first = self._first_readable_left()
        if first.shape[:2] != (native.height, native.width):
            raise SessionError(
                f"{path}: images are {first.shape[1]}x{first.shape[0]} but the rig is "
                f"{native.width}x{native.height}; give the rig of this camera"
                " (size_px then sets the processing size)")
        self.native_rig = native
        self.imu = session.imu()

    def _first_readable_left(self) -> NDArray[Any]:
        """The first left image that can be read, for the size check: pairs in a damaged
        chunk at the start are skipped here as the pipeline skips them (their warning names
        the chunk), not taken as the whole session's failure.

        Raises:
            SessionError: no left image of the pairs can be read.
        """
        first_err: SessionError | None = None
        for pair in self.pairs:
            try:
                return np.asarray(self.session.image("left", pair.left_index, by="index"))
            except SessionError as err:
                first_err = first_err or err
        raise SessionError(f"{self.path}: none of the {len(self.pairs)} stereo pairs can be "
                           f"read (the first: {first_err})")

    def __len__(self) -> int:
        return len(self.pairs)

    def read(self, pair: FramePair) -> tuple[NDArray[Any], NDArray[Any]]:
        """The raw ``(left, right)`` images of a pair.

        Raises:
            SessionError: an image cannot be read.
        """
        left = self.session.image("left", pair.left_index, by="index")
        right = self.session.image("right", pair.right_index, by="index")
        return left, right
