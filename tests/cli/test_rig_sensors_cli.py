"""``sea3d rig show`` prints the IMU and echosounder; ``rig create --kalibr`` attaches an IMU."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from sea3d.cli import main as sea3d_main
from sea3d.geometry.se3 import invert_T, make_T, rotvec_to_R
from sea3d.io.rig_file import load_rig

T_CAM_IMU = make_T(rotvec_to_R([0.02, -1.57, 0.01]), [0.01, -0.06, 0.02])


def _camchain(tmp_path: Path) -> Path:
    T_right_left = make_T(np.eye(3), [-0.107, 0.0, 0.0])
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "cam0": {
                    "T_cam_imu": T_CAM_IMU.tolist(),
                    "timeshift_cam_imu": -0.003,
                    "intrinsics": [1082.4, 1074.4, 949.5, 535.7],
                    "resolution": [1920, 1080],
                },
                "cam1": {
                    "T_cam_imu": (T_right_left @ T_CAM_IMU).tolist(),
                    "intrinsics": [1082.4, 1074.4, 949.5, 535.7],
                    "resolution": [1920, 1080],
                    "T_cn_cnm1": T_right_left.tolist(),
                },
            }
        )
    )
    return path


def test_create_with_kalibr_then_show_text_and_json(tmp_path: Path, capsys) -> None:
    out = tmp_path / "rig.yaml"
    chain = _camchain(tmp_path)
    argv = ["rig", "create", "--preset", "sea3d-paper", "--kalibr", str(chain), "-o", str(out)]
    assert sea3d_main(argv) == 0
    rig = load_rig(out)
    assert rig.imu is not None
    np.testing.assert_allclose(rig.imu.T_left_imu, T_CAM_IMU, atol=1e-12)
    capsys.readouterr()
    assert sea3d_main(["rig", "show", str(out)]) == 0
    text = capsys.readouterr().out
    assert "imu   200 Hz" in text and "time offset -3.000 ms" in text
    assert sea3d_main(["rig", "show", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(data["imu"]["T_left_imu"], T_CAM_IMU, atol=1e-12)
    assert data["sonar"] is None


def test_create_from_a_kalibr_camchain_alone(tmp_path: Path) -> None:
    out = tmp_path / "rig.yaml"
    assert sea3d_main(["rig", "create", "--from", str(_camchain(tmp_path)), "-o", str(out)]) == 0
    rig = load_rig(out)
    assert rig.width == 1920 and abs(rig.baseline_m - 0.107) < 1e-12
    assert rig.imu is not None
    np.testing.assert_allclose(invert_T(rig.imu.T_left_imu) @ T_CAM_IMU, np.eye(4), atol=1e-12)


def test_show_says_when_a_rig_has_no_imu(tmp_path: Path, capsys) -> None:
    out = tmp_path / "rig.yaml"
    assert sea3d_main(["rig", "create", "--preset", "sea3d-paper", "-o", str(out)]) == 0
    capsys.readouterr()
    assert sea3d_main(["rig", "show", str(out)]) == 0
    assert "imu   none (odometry runs visual-only)" in capsys.readouterr().out


def test_kalibr_imu_without_a_camchain_is_a_clear_error(tmp_path: Path, capsys) -> None:
    imu = tmp_path / "imu.yaml"
    imu.write_text("imu0: {update_rate: 200.0}\n")
    argv = [
        "rig",
        "create",
        "--preset",
        "sea3d-paper",
        "--kalibr-imu",
        str(imu),
        "-o",
        str(tmp_path / "r.yaml"),
    ]
    assert sea3d_main(argv) == 2
    assert "--kalibr-imu needs --kalibr" in capsys.readouterr().err
