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


def _euroc_without_imu(data_dir, tmp_path: Path, frames: int = 6) -> Path:
    """A copy of the micro excerpt's first frames with no imu0 folder at all."""
    import shutil

    src = data_dir / EUROC / "mav0"
    dst = tmp_path / "seq" / "mav0"
    for cam in ("cam0", "cam1"):
        (dst / cam / "data").mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", dst / cam / "sensor.yaml")
        lines = (src / cam / "data.csv").read_text().splitlines()
        rows = [ln for ln in lines if not ln.startswith("#")][:frames]
        (dst / cam / "data.csv").write_text("\n".join([lines[0], *rows]) + "\n")
        for row in rows:
            name = row.split(",")[1].strip()
            shutil.copy(src / cam / "data" / name, dst / cam / "data" / name)
    return dst.parent


@pytest.mark.data
def test_euroc_without_imu0_reads_the_cameras(data_dir, tmp_path: Path) -> None:
    root = _euroc_without_imu(data_dir, tmp_path)
    seq = read_euroc(root, imu=False)
    assert len(seq.t_ns) == 6 and seq.rig.imu is None and seq.imu_t_ns.size == 0
    # asked for the IMU, a folder without imu0 reads as a sequence without IMU
    assert read_euroc(root).rig.imu is None


@pytest.mark.data
def test_odometry_of_euroc_without_imu0(data_dir, tmp_path: Path, capsys) -> None:
    import json

    from sea3d.cli import main

    root = _euroc_without_imu(data_dir, tmp_path)
    for extra in (["--no-imu"], []):
        out = tmp_path / "t.tum"
        argv = ["odometry", str(root), "-o", str(out), "--engine", "opencv", "--json", *extra]
        assert main(argv) == 0
        text = capsys.readouterr().out
        s = json.loads(text[text.index("{"):])
        assert s["frames"] == 6 and s["imu"] is False
