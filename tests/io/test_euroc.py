"""EuRoC folders (TUM files are io.trajectory_files', tested in test_trajectory_files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.io.euroc import is_euroc, read_euroc

EUROC = "vio/euroc_v101_micro"


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
