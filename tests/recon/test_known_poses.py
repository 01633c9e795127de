"""Known poses as an odometry: lookup, interpolation, gaps, keyframes, segments."""

import numpy as np
import pytest

from sea3d.errors import OdometryError
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.odometry.reference import KnownPoses, KnownPosesConfig
from sea3d.odometry.types import FrameObservation, TrackingStatus


def _frame(t):
    z = np.zeros((2, 2), np.uint8)
    return FrameObservation(t_ns=t, rect_left=z, rect_right=z, depth_m=np.zeros((2, 2),
                            np.float32), K_rect=np.eye(3), baseline_m=0.1,
                            R_rect_left_left=np.eye(3))


def _poses():
    t = np.array([0, 100, 200, 2000, 2100], np.int64) * 1_000_000  # a 1.8 s gap
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, 0, 3] = [0.0, 0.05, 0.10, 0.20, 0.25]
    T[:, :3, :3] = rotvec_to_R(np.outer([0, 1, 2, 3, 4], [0.0, 0.0, 0.1]))
    return t, T


def test_interpolates_within_small_gaps_and_is_lost_in_large_ones():
    t, T = _poses()
    odo = KnownPoses(t, T, KnownPosesConfig(max_gap_s=0.5, keyframe_m=0.5, keyframe_deg=30.0,
                                            keyframe_every=100))
    e = [odo.step(_frame(int(s))) for s in (0, 50_000_000, 200_000_000, 1_000_000_000,
                                             2_000_000_000, 2_050_000_000, 3_000_000_000)]
    assert [x.status for x in e] == [TrackingStatus.TRACKING] * 3 + [TrackingStatus.LOST] + [
        TrackingStatus.TRACKING] * 2 + [TrackingStatus.LOST]
    assert e[1].T_world_left[0, 3] == pytest.approx(0.025)
    angle = np.arccos((np.trace(e[1].T_world_left[:3, :3]) - 1) / 2)
    assert angle == pytest.approx(0.05)  # halfway between 0 and 0.1 rad
    # The gap starts a new segment, and a new segment starts with a keyframe.
    assert [x.segment for x in e[:6]] == [0, 0, 0, 0, 1, 1]
    assert e[0].keyframe_id == 0 and e[4].keyframe_id == 1 and e[5].keyframe_id is None
    assert e[5].anchor_keyframe_id == 1
    t_all, T_all = odo.trajectory()
    assert len(t_all) == 7 and T_all.shape == (7, 4, 4)
    assert set(odo.keyframe_poses()) == {0, 1}


def test_keyframes_by_motion():
    t = np.arange(10, dtype=np.int64) * 100_000_000
    T = np.tile(np.eye(4), (10, 1, 1))
    T[:, 0, 3] = np.arange(10) * 0.04
    odo = KnownPoses(t, T, KnownPosesConfig(keyframe_m=0.1, keyframe_every=100))
    kf = [odo.step(_frame(int(s))).keyframe_id for s in t]
    assert [i for i, k in enumerate(kf) if k is not None] == [0, 3, 6, 9]


def test_stamps_must_increase():
    t, T = _poses()
    odo = KnownPoses(t, T)
    odo.step(_frame(100))
    with pytest.raises(OdometryError, match="increase"):
        odo.step(_frame(100))
    with pytest.raises(OdometryError):
        KnownPoses(t[::-1], T)
