"""Stereo(-inertial) odometry on a simulated dome-port survey with ground truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from odometry._survey import PLANTED_OFFSET_S
from sea3d.errors import OdometryError
from sea3d.eval.trajectory import evaluate_trajectory, path_length_m
from sea3d.odometry import OdometryConfig, TrackingStatus, create_odometry
from sea3d.odometry.types import ImuChunk

# The budget for the long survey is 0.5 % of the path; this 8 m orbit at 320x180 gets
# 0.22 % with the IMU and 0.23 % without (measured with loop closure; 0.34 % and 0.40 % without
# it), so 0.5 % holds with margin and an error in the refraction handling or the back end
# (several per cent) cannot pass.
ATE_FRACTION_MAX = 0.005
# After 1 s of blank images the IMU-bridged trajectory is still within 1 % of the path.
ATE_FRACTION_BRIDGED_MAX = 0.01
# Loop closure must remove a good part of the visual-only drift (0.40 % -> 0.23 % measured).
LOOP_GAIN_MIN = 0.25
GOOD = {TrackingStatus.TRACKING, TrackingStatus.RELOCALISED}
# Loops close after the first quarter-turn is revisited (12 s orbit, 1.25 turns).
TEST_CONFIG = OdometryConfig(loop_min_gap_s=6.0, vocabulary_train_keyframes=10)


def _run(survey, observations=None, *, use_imu=True, config=TEST_CONFIG, rig=None):
    odo = create_odometry(rig or survey.rig_true, survey.maps, use_imu=use_imu, config=config)
    est = [odo.step(o) for o in (observations or survey.observations)]
    return odo, est


def _ate_fraction(survey, odo, keep=None):
    """ATE RMSE after SE3 alignment (sea3d.eval.trajectory, evo's figures) over the path."""
    t, T = odo.trajectory()
    if keep is not None:
        t, T = t[keep], T[keep]
    m = evaluate_trajectory(t, T, survey.gt_t_ns, survey.gt_T_world_left, align="se3")
    return m.ate_rmse_m / path_length_m(survey.gt_T_world_left[:, :3, 3])


@pytest.fixture(scope="module")
def runs(sim_survey):
    return {
        "vio": _run(sim_survey),
        "vo": _run(sim_survey, use_imu=False),
        "vo_no_loop": _run(
            sim_survey, use_imu=False, config=dataclasses.replace(TEST_CONFIG, loop_closure=False)
        ),
    }


@pytest.mark.parametrize("name", ["vio", "vo"])
def test_every_frame_tracks_and_the_trajectory_is_within_budget(sim_survey, runs, name) -> None:
    odo, est = runs[name]
    assert [e.status in GOOD for e in est] == [True] * len(sim_survey.observations)
    assert _ate_fraction(sim_survey, odo) < ATE_FRACTION_MAX
    assert (odo.imu_disabled_reason is None) == (name == "vio")
    # keyframes carry their ids and every frame an anchor keyframe
    assert all(e.anchor_keyframe_id is not None for e in est)
    assert sum(e.keyframe_id is not None for e in est) == odo.keyframe_count > 10


def test_loop_closure_closes_the_orbit_and_removes_drift(sim_survey, runs) -> None:
    odo, est = runs["vo"]
    plain, _ = runs["vo_no_loop"]
    assert odo.loop_closures >= 1 and plain.loop_closures == 0
    assert any(e.loop_closure for e in est)
    with_loop = _ate_fraction(sim_survey, odo)
    without = _ate_fraction(sim_survey, plain)
    assert with_loop < (1 - LOOP_GAIN_MIN) * without


def _blank(obs):
    grey = np.full_like(obs.rect_left, 90)
    return dataclasses.replace(
        obs, rect_left=grey, rect_right=grey, depth_m=np.full_like(obs.depth_m, np.nan)
    )


def test_a_textureless_second_is_bridged_by_the_imu_then_tracked_again(sim_survey) -> None:
    obs = list(sim_survey.observations)
    blank = range(50, 60)
    for i in blank:
        obs[i] = _blank(obs[i])
    odo, est = _run(sim_survey, obs)
    st = [e.status for e in est]
    assert all(st[i] is TrackingStatus.IMU_ONLY for i in blank)
    assert TrackingStatus.LOST not in st
    assert all(s in GOOD for s in st[61:])
    assert len({e.segment for e in est}) == 1  # one segment: the IMU carried it through
    assert _ate_fraction(sim_survey, odo) < ATE_FRACTION_BRIDGED_MAX


def test_without_imu_a_textureless_second_is_lost_then_joined_by_relocalisation(
    sim_survey,
) -> None:
    obs = list(sim_survey.observations)
    blank = range(50, 60)
    for i in blank:
        obs[i] = _blank(obs[i])
    odo, est = _run(sim_survey, obs, use_imu=False)
    st = [e.status for e in est]
    assert all(st[i] is TrackingStatus.LOST for i in blank)  # never a wrong pose called good
    after = [i for i in range(60, len(st)) if st[i] is TrackingStatus.RELOCALISED]
    assert after, "the new segment was never joined to the first"
    # before the join the frames said they were in a new segment; no silent jump
    assert est[60].segment != est[49].segment or st[60] is TrackingStatus.RELOCALISED
    keep = np.array([s in GOOD for s in st])
    assert _ate_fraction(sim_survey, odo, keep) < ATE_FRACTION_BRIDGED_MAX


def _drop(observations, dropped):
    """Frames lost by the camera; the IMU keeps streaming, so the next frame's chunk holds the
    samples since the last frame delivered (as ``imu_chunks`` slices them)."""
    out, pending = [], []
    for i, o in enumerate(observations):
        if o.imu is not None:
            pending.append(o.imu)
        if i in dropped:
            continue
        imu = None
        if pending:
            imu = ImuChunk(
                t_ns=np.concatenate([c.t_ns for c in pending]),
                accel_mps2=np.concatenate([c.accel_mps2 for c in pending]),
                gyro_radps=np.concatenate([c.gyro_radps for c in pending]),
            )
        out.append(dataclasses.replace(o, imu=imu))
        pending = []
    return out


def test_dropped_frames_are_tracked_through(sim_survey) -> None:
    dropped = {i for i in range(30, 70) if i % 3}  # two of every three frames for 4 s
    obs = _drop(sim_survey.observations, dropped)
    odo, est = _run(sim_survey, obs)
    assert all(e.status in GOOD for e in est)
    assert _ate_fraction(sim_survey, odo) < ATE_FRACTION_MAX


def test_an_imu_far_from_the_cameras_in_time_is_switched_off(sim_survey) -> None:
    far = [
        dataclasses.replace(
            o,
            imu=ImuChunk(
                t_ns=o.imu.t_ns + 3600 * 10**9,
                accel_mps2=o.imu.accel_mps2,
                gyro_radps=o.imu.gyro_radps,
            ),
        )
        if o.imu is not None
        else o
        for o in sim_survey.observations
    ]
    odo, est = _run(sim_survey, far)
    assert odo.imu_disabled_reason is not None and "clock" in odo.imu_disabled_reason
    assert all(e.status in GOOD for e in est)
    assert _ate_fraction(sim_survey, odo) < ATE_FRACTION_MAX


def test_stamps_must_increase_and_shapes_must_match(sim_survey) -> None:
    odo = create_odometry(sim_survey.rig_true, sim_survey.maps)
    obs = sim_survey.observations
    odo.step(obs[1])
    with pytest.raises(OdometryError, match="not after the previous frame"):
        odo.step(obs[0])
    with pytest.raises(OdometryError, match="depth_m must be"):
        odo.step(dataclasses.replace(obs[2], depth_m=obs[2].depth_m[:10]))


def test_state_stays_bounded(sim_survey, runs) -> None:
    odo, _ = runs["vio"]
    seg = odo._seg
    assert seg is not None
    lag_kf = int(TEST_CONFIG.smoother_lag_s / 0.1) + 2  # at most one keyframe per frame
    assert len(seg.backend.keyframes) <= lag_kf
    assert seg.track_ids.size <= TEST_CONFIG.max_features
    assert seg.backend.estimate.size() < lag_kf * (TEST_CONFIG.max_features + 3)
    assert odo.memory_bytes() < 60_000 * odo.keyframe_count + 200 * len(sim_survey.observations)


@pytest.mark.slow
def test_the_rig_time_offset_is_applied(sim_survey) -> None:
    """The IMU was written 25 ms late. With the rig's true offset the trajectory beats an
    offset 100 ms below it by far (measured 0.34 % of the path against 7.7 %); an offset applied
    with the wrong sign would leave 50 ms of error at both, and one not applied at all the same
    error at both. (25 ms alone is within the run-to-run spread of this orbit: 0.31 % with the
    offset left at 0, so that comparison cannot be a test.)"""
    cfg = dataclasses.replace(TEST_CONFIG, loop_closure=False)

    def ate(offset_s):
        imu = dataclasses.replace(sim_survey.rig.imu, time_offset_s=offset_s)
        odo, _ = _run(sim_survey, config=cfg, rig=dataclasses.replace(sim_survey.rig, imu=imu))
        return _ate_fraction(sim_survey, odo)

    right = ate(PLANTED_OFFSET_S)
    assert right < ATE_FRACTION_MAX
    assert right < 0.5 * ate(PLANTED_OFFSET_S - 0.1)
