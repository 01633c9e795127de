"""A short simulated survey shared by the odometry tests (rendered once per test session).

An orbit of 1.2 m radius 1.25 times round the lake scene's ArUco cube in 12 s (120 frames at
10 Hz: the last quarter revisits the first, so a loop can close), wobbling by a few degrees about
every axis like a hand-held rig (so the camera-IMU rotation is observable),
through the paper's dome-port rig at 320x180 in coastal water, with the simulated IMU written
``PLANTED_OFFSET_S`` late (``t_imu = t_cam + offset``), as an unsynchronised IMU would be. The
session's stored rig does not know the offset (as a user's would not); ``rig_true`` does.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PLANTED_OFFSET_S = 0.025
FRAMES = 120
FPS = 10.0
SIZE = (320, 180)


@dataclass
class SimSurvey:
    session: Path
    gt_t_ns: np.ndarray
    gt_T_world_left: np.ndarray
    rig: object  # as stored in the session (time offset unknown: 0)
    rig_true: object  # with the planted time offset
    maps: object
    observations: list  # FrameObservation per frame, IMU chunks with raw (IMU-clock) stamps


@dataclass(frozen=True)
class WobblyOrbit:
    """The simulator's :class:`~sea3d.sim.motion.Orbit` with a hand-held wobble on top."""

    orbit: object
    amplitude_deg: tuple[float, float, float] = (4.0, 3.0, 3.0)
    frequency_hz: tuple[float, float, float] = (0.7, 1.1, 0.9)

    @property
    def duration_s(self) -> float:
        return float(self.orbit.duration_s)  # type: ignore[attr-defined]

    def position_m(self, t_s):
        return self.orbit.position_m(t_s)  # type: ignore[attr-defined]

    def rotation(self, t_s):
        from sea3d.geometry.se3 import rotvec_to_R

        t = np.asarray(t_s, dtype=np.float64)
        R = self.orbit.rotation(t)  # type: ignore[attr-defined]
        out = np.empty_like(R)
        for i, ti in enumerate(t):
            w = np.deg2rad(self.amplitude_deg) * np.sin(
                2 * np.pi * np.asarray(self.frequency_hz) * ti + np.array([0.0, 1.0, 2.0])
            )
            out[i] = R[i] @ rotvec_to_R(w)
        return out


class _ShiftedImu:
    """Writes the IMU stream late by ``PLANTED_OFFSET_S``."""

    def __init__(self, writer) -> None:
        self.w = writer

    def write_stereo(self, t_ns, left, right) -> None:
        self.w.write_stereo(t_ns, left, right)

    def write_imu(self, t_ns, accel, gyro) -> None:
        self.w.write_imu(int(t_ns + round(PLANTED_OFFSET_S * 1e9)), accel, gyro)

    def write_sonar(self, t_ns, r, c=float("nan")) -> None:
        self.w.write_sonar(t_ns, r, c)


def make_sim_survey(out: Path) -> SimSurvey:
    """Render the survey into ``out`` and compute its frame observations."""
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter, open_session
    from sea3d.odometry.observe import Observer, imu_chunks
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim.motion import Orbit
    from sea3d.sim.scene import builtin_scene
    from sea3d.sim.survey import SurveyConfig, simulate_survey, survey_mount, with_survey_sensors
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    rig = paper_rig("dome", size_px=SIZE)
    config = SurveyConfig(
        frames=FRAMES, fps=FPS, trajectory="orbit", water="coastal", supersample=1, seed=3
    )
    duration = (FRAMES - 1) / FPS
    traj = WobblyOrbit(
        Orbit(
            target_m=(0.0, 0.0, 0.1),
            radius_m=1.2,
            height_m=0.9,
            period_s=duration / 1.25,
            duration_s=duration,
            camera_tilt_deg=30.0,
        )
    )
    mount = survey_mount(rig, config)
    stored = with_survey_sensors(rig, config, mount)
    session = out / "session"
    with SessionWriter(session, format="folder", rig_yaml=rig_to_yaml(stored)) as w:
        result = simulate_survey(
            builtin_scene("lake"),
            rig,
            config,
            _ShiftedImu(w),
            out / "gt",
            trajectory=traj,
            mount=mount,
        )
    assert stored.imu is not None
    rig_true = dataclasses.replace(
        stored, imu=dataclasses.replace(stored.imu, time_offset_s=PLANTED_OFFSET_S)
    )
    observer = Observer(StereoDepth(stored, DepthConfig(engine="opencv")))
    maps = observer.maps
    with open_session(session) as s:
        pairs = list(s.pairs())
        imu = s.imu()
    t = np.array([p.t_ns for p in pairs], dtype=np.int64)
    chunks = imu_chunks(t + round(PLANTED_OFFSET_S * 1e9), imu.t_ns, imu.accel_mps2, imu.gyro_radps)
    obs = [observer.observe(p.t_ns, p.left, p.right, c) for p, c in zip(pairs, chunks, strict=True)]
    return SimSurvey(
        session=session,
        gt_t_ns=result.frame_t_ns,
        gt_T_world_left=result.T_world_left,
        rig=stored,
        rig_true=rig_true,
        maps=maps,
        observations=obs,
    )
