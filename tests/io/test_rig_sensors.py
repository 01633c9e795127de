"""The rig's IMU and echosounder blocks: round trips, old files, bad values, Kalibr imports."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from sea3d.errors import GeometryError, RigFileError
from sea3d.geometry.rig import ImuSpec, SonarSpec
from sea3d.geometry.se3 import invert_T, make_T, rotvec_to_R
from sea3d.io.kalibr import imu_from_kalibr, is_kalibr_camchain, rig_from_kalibr, with_kalibr_imu
from sea3d.io.rig_file import load_rig, rig_from_dict, rig_to_dict, save_rig
from sea3d.refraction.presets import paper_rig, with_ports

# EuRoC MAV cam0 (Burri et al. 2016, mav0/cam0/sensor.yaml): T_BS maps cam0 into the IMU frame.
EUROC_T_BS_CAM0 = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
ORTHO_TOL = 1e-9


def _imu() -> ImuSpec:
    T = make_T(rotvec_to_R([0.1, -0.2, 0.3]), [0.05, -0.02, 0.1])
    return ImuSpec(
        T_left_imu=T,
        rate_hz=400.0,
        gyro_noise_density_radps_sqrthz=2e-4,
        gyro_random_walk_radps_sqrts=3e-5,
        accel_noise_density_mps2_sqrthz=1e-3,
        accel_random_walk_mps2_sqrts=4e-4,
        gravity_mps2=9.806,
        time_offset_s=-0.012,
    )


def _sensor_rig(port: str = "dome"):
    import dataclasses

    sonar = SonarSpec(T_left_sonar=make_T(np.eye(3), [0.0, 0.1, 0.0]), beam_deg=30.0)
    return dataclasses.replace(paper_rig(port), imu=_imu(), sonar=sonar)


@pytest.mark.parametrize("ext", ["yaml", "json"])
def test_imu_and_sonar_round_trip_exactly(tmp_path: Path, ext: str) -> None:
    rig = _sensor_rig()
    back = load_rig(save_rig(rig, tmp_path / f"rig.{ext}"))
    assert rig_to_dict(back) == rig_to_dict(rig)
    assert back.imu is not None and back.sonar is not None
    np.testing.assert_array_equal(back.imu.T_left_imu, rig.imu.T_left_imu)
    assert back.imu.time_offset_s == -0.012 and back.imu.rate_hz == 400.0
    assert back.sonar.beam_deg == 30.0


def test_a_rig_file_without_sensors_still_loads_and_writes_no_blocks(tmp_path: Path) -> None:
    rig = paper_rig("flat")
    data = rig_to_dict(rig)
    assert "imu" not in data and "sonar" not in data
    back = load_rig(save_rig(rig, tmp_path / "rig.yaml"))
    assert back.imu is None and back.sonar is None


def test_optional_imu_keys_take_their_defaults() -> None:
    data = rig_to_dict(_sensor_rig())
    del data["imu"]["gravity_mps2"], data["imu"]["time_offset_s"]
    rig = rig_from_dict(data)
    assert rig.imu is not None and rig.imu.gravity_mps2 == 9.81 and rig.imu.time_offset_s == 0.0


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["imu"].pop("rate_hz"), "imu.rate_hz': missing"),
        (lambda d: d["imu"].update(rate_hz=-5), "rate_hz must be"),
        (lambda d: d["imu"].update(gyro_noise_density_radps_sqrthz="x"), "expected a number"),
        (lambda d: d["imu"].update(accel_random_walk_mps2_sqrts=0.0), "accel_random_walk"),
        (lambda d: d["imu"].update(T_left_imu=np.eye(3).tolist()), "expected shape (4, 4)"),
        (lambda d: d["imu"]["T_left_imu"][0].__setitem__(0, 2.0), "not a proper rotation"),
        (lambda d: d["imu"].update(gyro_noise=1.0), "imu.gyro_noise': unknown key"),
        (lambda d: d.update(imu=[1, 2]), "key 'imu': expected a mapping"),
        (lambda d: d["sonar"].pop("beam_deg"), "sonar.beam_deg': missing"),
        (lambda d: d["sonar"].update(beam_deg=200.0), "beam_deg must be < 180"),
    ],
)
def test_bad_sensor_blocks_name_the_key_and_load_nothing(edit, message: str, tmp_path) -> None:
    data = copy.deepcopy(rig_to_dict(_sensor_rig()))
    edit(data)
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(RigFileError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        load_rig(path)
    assert str(path) in str(e.value)


def test_imu_spec_rejects_bad_values_directly() -> None:
    with pytest.raises(GeometryError, match="gravity_mps2"):
        ImuSpec(T_left_imu=np.eye(4), gravity_mps2=float("nan"))
    with pytest.raises(GeometryError, match="time_offset_s"):
        ImuSpec(T_left_imu=np.eye(4), time_offset_s=float("inf"))


def test_changing_ports_keeps_the_sensors() -> None:
    rig = with_ports(_sensor_rig("dome"), "flat")
    assert rig.imu is not None and rig.sonar is not None
    np.testing.assert_array_equal(rig.imu.T_left_imu, _imu().T_left_imu)


def _write_kalibr(tmp_path: Path, *, with_imu: bool = True, shift: float = 0.0042) -> Path:
    T_cam0_imu = invert_T(EUROC_T_BS_CAM0)
    T_cam1_cam0 = make_T(rotvec_to_R([0.001, -0.002, 0.0005]), [-0.110, 0.0004, -0.0008])
    cam0 = {
        "camera_model": "pinhole",
        "intrinsics": [458.654, 457.296, 367.215, 248.375],
        "distortion_model": "radtan",
        "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
        "resolution": [752, 480],
        "rostopic": "/cam0/image_raw",
    }
    cam1 = dict(cam0, intrinsics=[457.587, 456.134, 379.999, 255.238], rostopic="/cam1/image_raw")
    cam1["T_cn_cnm1"] = T_cam1_cam0.tolist()
    if with_imu:
        cam0["T_cam_imu"] = T_cam0_imu.tolist()
        cam0["timeshift_cam_imu"] = shift
        cam1["T_cam_imu"] = (T_cam1_cam0 @ T_cam0_imu).tolist()
        cam1["timeshift_cam_imu"] = shift
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(yaml.safe_dump({"cam0": cam0, "cam1": cam1}))
    return path


def _write_imu_yaml(tmp_path: Path) -> Path:
    path = tmp_path / "imu.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "imu0": {
                    "accelerometer_noise_density": 2.0e-3,
                    "accelerometer_random_walk": 3.0e-3,
                    "gyroscope_noise_density": 1.6968e-04,
                    "gyroscope_random_walk": 1.9393e-05,
                    "update_rate": 200.0,
                    "model": "calibrated",
                }
            }
        )
    )
    return path


def test_kalibr_camchain_gives_the_rig_and_its_imu(tmp_path: Path) -> None:
    chain = _write_kalibr(tmp_path)
    assert is_kalibr_camchain(chain) and not is_kalibr_camchain(_write_imu_yaml(tmp_path))
    rig = rig_from_kalibr(chain, _write_imu_yaml(tmp_path))
    assert (rig.width, rig.height) == (752, 480)
    assert rig.baseline_m == pytest.approx(np.linalg.norm([0.110, 0.0004, 0.0008]), abs=1e-9)
    assert rig.imu is not None
    # T_left_imu is Kalibr's T_cam_imu: the inverse of EuRoC's T_BS of cam0.
    np.testing.assert_allclose(rig.imu.T_left_imu @ EUROC_T_BS_CAM0, np.eye(4), atol=ORTHO_TOL)
    assert rig.imu.time_offset_s == pytest.approx(0.0042)
    assert rig.imu.gyro_noise_density_radps_sqrthz == pytest.approx(1.6968e-4)
    assert rig.imu.accel_random_walk_mps2_sqrts == pytest.approx(3.0e-3)


def test_kalibr_imu_attaches_to_an_existing_rig_and_checks_the_baseline(tmp_path: Path) -> None:
    chain = _write_kalibr(tmp_path)
    rig = rig_from_kalibr(chain)
    import dataclasses

    bare = dataclasses.replace(rig, imu=None)
    again = with_kalibr_imu(bare, chain)
    assert again.imu is not None
    np.testing.assert_allclose(again.imu.T_left_imu, rig.imu.T_left_imu)
    wrong = paper_rig("none")  # baseline 107 mm along +x, the camchain's is 110 mm
    T = wrong.T_left_right.copy()
    T[:3, 3] = [0.2, 0.0, 0.0]
    with pytest.raises(RigFileError, match="mm from where the rig has it"):
        with_kalibr_imu(dataclasses.replace(wrong, T_left_right=T), chain)


def test_kalibr_files_with_problems_say_which(tmp_path: Path) -> None:
    chain = _write_kalibr(tmp_path, with_imu=False)
    with pytest.raises(RigFileError, match="T_cam_imu': missing"):
        imu_from_kalibr(chain)
    assert rig_from_kalibr(chain).imu is None
    with pytest.raises(RigFileError, match="not found"):
        imu_from_kalibr(tmp_path / "nope.yaml")
    bad = tmp_path / "imu_bad.yaml"
    bad.write_text("imu0: {gyroscope_noise_density: 1e-4}\n")
    with pytest.raises(RigFileError, match="gyroscope_random_walk"):
        imu_from_kalibr(_write_kalibr(tmp_path), bad)
