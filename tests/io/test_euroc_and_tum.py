"""EuRoC folders and TUM trajectory files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.geometry.se3 import make_T, rotvec_to_R
from sea3d.io.euroc import is_euroc, read_euroc
from sea3d.io.trajectory_tum import read_tum, write_tum

EUROC = "vio/euroc_v101_micro"
TUM_TOL = 1e-9  # 9 decimals in the file


def test_tum_round_trip(tmp_path: Path, rng) -> None:
    T = np.stack([make_T(rotvec_to_R(rng.normal(0, 1, 3)), rng.normal(0, 5, 3)) for _ in range(20)])
    t = np.cumsum(rng.uniform(0.01, 0.2, 20)) + 1.4e9
    path = write_tum(tmp_path / "x" / "traj.tum", t, T)
    t2, T2 = read_tum(path)
    np.testing.assert_allclose(t2, t, atol=1e-6)
    np.testing.assert_allclose(T2, T, atol=TUM_TOL * 10)
    (tmp_path / "bad.tum").write_text("0 1 2 3\n")
    with pytest.raises(SessionError, match="expected 8 numbers"):
        read_tum(tmp_path / "bad.tum")


@pytest.mark.data
def test_euroc_micro_reads_with_rig_imu_and_ground_truth(data_dir) -> None:
    root = data_dir / EUROC
    assert is_euroc(root) and is_euroc(root / "mav0") and not is_euroc(data_dir)
    seq = read_euroc(root)
    assert len(seq.t_ns) == 40 and len(seq.left_paths) == len(seq.right_paths) == 40
    # SOURCE.md: baseline 0.1101 m, cam0 fu 458.654, IMU 200 Hz, ADIS16448 noise figures
    assert seq.rig.baseline_m == pytest.approx(0.1101, abs=2e-4)
    assert seq.rig.left.fx == pytest.approx(458.654)
    assert seq.rig.imu is not None and seq.rig.imu.rate_hz == 200.0
    assert seq.rig.imu.gyro_noise_density_radps_sqrthz == pytest.approx(1.6968e-4)
    assert seq.imu_t_ns.size == 29120 and seq.accel_mps2.shape == (29120, 3)
    assert np.linalg.norm(seq.accel_mps2[:100].mean(axis=0)) == pytest.approx(9.8, abs=0.2)
    assert seq.gt_T_world_body.shape[0] == seq.gt_t_ns.size > 2800
    assert seq.image("left", 0).shape == (480, 752)


def test_euroc_reader_refuses_other_folders(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="not an EuRoC folder"):
        read_euroc(tmp_path)
