"""A simulated session's rig carries the IMU and echosounder the simulator used."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from sea3d.cli import main as sea3d_main
from sea3d.geometry.rig import ImuSpec
from sea3d.geometry.se3 import make_T, rotvec_to_R
from sea3d.io.rig_file import rig_from_yaml, save_rig
from sea3d.io.session import open_session
from sea3d.refraction.presets import paper_rig
from sea3d.sim.motion import ImuNoise
from sea3d.sim.survey import SurveyConfig, survey_mount, with_survey_sensors

T_TOL = 1e-12


def test_sim_stores_the_simulated_imu_and_echosounder_in_the_session_rig(tmp_path: Path) -> None:
    out = tmp_path / "s"
    argv = [
        "sim",
        "--scene",
        "tank",
        "--frames",
        "2",
        "--size",
        "48x27",
        "--supersample",
        "1",
        "--water",
        "none",
        "--out",
        str(out),
        "--format",
        "folder",
    ]
    assert sea3d_main(argv) == 0
    with open_session(out) as s:
        text = s.rig_yaml
    assert text is not None
    rig = rig_from_yaml(text)
    meta = json.loads((out / "gt" / "sim.json").read_text())
    assert rig.imu is not None and rig.sonar is not None
    np.testing.assert_allclose(
        rig.imu.T_left_imu @ np.asarray(meta["T_body_left"]), np.eye(4), atol=T_TOL
    )
    np.testing.assert_allclose(
        np.asarray(meta["T_body_left"]) @ rig.sonar.T_left_sonar, meta["T_body_sonar"], atol=T_TOL
    )
    mti = ImuNoise.mti300()
    assert rig.imu.gyro_noise_density_radps_sqrthz == mti.gyro_noise_density_radps_sqrthz
    assert rig.imu.accel_random_walk_mps2_sqrts == mti.accel_bias_rw_mps2_sqrts
    assert rig.imu.rate_hz == 200.0


def test_a_rig_with_its_own_imu_is_simulated_with_that_mount(tmp_path: Path) -> None:
    T_left_imu = make_T(rotvec_to_R([0.3, -1.2, 0.4]), [0.02, 0.1, -0.05])
    imu = ImuSpec(T_left_imu=T_left_imu, gyro_noise_density_radps_sqrthz=3e-4)
    rig = dataclasses.replace(paper_rig("dome", size_px=(48, 27)), imu=imu)
    config = SurveyConfig(frames=1)
    mount = survey_mount(rig, config)
    np.testing.assert_allclose(T_left_imu @ mount.T_body_left, np.eye(4), atol=T_TOL)
    stored = with_survey_sensors(rig, config)
    assert stored.imu is not None
    np.testing.assert_allclose(stored.imu.T_left_imu, T_left_imu, atol=T_TOL)
    assert stored.imu.gyro_noise_density_radps_sqrthz == 3e-4
    # ... and the CLI keeps it when given that rig file
    path = save_rig(rig, tmp_path / "rig.yaml")
    out = tmp_path / "s"
    argv = [
        "sim",
        "--scene",
        "tank",
        "--rig",
        str(path),
        "--frames",
        "2",
        "--size",
        "48x27",
        "--supersample",
        "1",
        "--water",
        "none",
        "--out",
        str(out),
        "--format",
        "folder",
    ]
    assert sea3d_main(argv) == 0
    meta = json.loads((out / "gt" / "sim.json").read_text())
    np.testing.assert_allclose(T_left_imu @ np.asarray(meta["T_body_left"]), np.eye(4), atol=T_TOL)
