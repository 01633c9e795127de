"""``sea3d odometry`` and ``sea3d calibrate imu`` on a simulated session, RGB-D files and EuRoC;
bad input gives one clear line, never a traceback."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from odometry._survey import PLANTED_OFFSET_S
from sea3d.cli import main as sea3d_main
from sea3d.geometry.se3 import R_to_rotvec
from sea3d.io.rig_file import save_rig
from sea3d.io.trajectory_files import read_trajectory

CLI_FRAMES = 30
# calibrate imu on the 12 s orbit: visual odometry orientations (about 0.3 deg per 0.5 s) and
# the MTi gyro; measured 0.5-1.0 deg (its own sigma: 0.3 deg) and under 1 ms from the truth
CALIB_ROTATION_TOL_DEG = 1.5
CALIB_OFFSET_TOL_S = 0.005


def _json(capsys) -> dict:
    out = capsys.readouterr().out
    return json.loads(out[out.index("{") :])


def test_odometry_of_a_session_writes_one_pose_per_frame(sim_survey, tmp_path, capsys) -> None:
    rig = save_rig(sim_survey.rig_true, tmp_path / "rig.yaml")
    traj, status = tmp_path / "traj.tum", tmp_path / "status.csv"
    argv = [
        "odometry",
        str(sim_survey.session),
        "--rig",
        str(rig),
        "-o",
        str(traj),
        "--json",
        "--engine",
        "opencv",
        "--max-frames",
        str(CLI_FRAMES),
        "--status",
        str(status),
    ]
    assert sea3d_main(argv) == 0
    s = _json(capsys)
    for key in ("frames", "keyframes", "frames_lost", "loop_closures", "path_length_m", "seconds"):
        assert key in s
    assert s["frames"] == CLI_FRAMES and s["frames_lost"] == 0 and s["imu"] is True
    traj_file = read_trajectory(traj)
    t, T = traj_file.t_ns, traj_file.T_world_x
    np.testing.assert_array_equal(t, sim_survey.gt_t_ns[:CLI_FRAMES])  # exact ns stamps
    assert T.shape == (CLI_FRAMES, 4, 4)
    gt = sim_survey.gt_T_world_left[:CLI_FRAMES, :3, 3]
    assert s["path_length_m"] == pytest.approx(
        np.linalg.norm(np.diff(gt, axis=0), axis=1).sum(), rel=0.05
    )
    lines = status.read_text().splitlines()
    assert lines[0] == "t_ns,status,segment" and len(lines) == CLI_FRAMES + 1


def test_session_without_rig_or_imu(sim_survey, tmp_path, capsys) -> None:
    bare = tmp_path / "bare"
    shutil.copytree(sim_survey.session, bare)
    (bare / "rig.yaml").unlink()
    out = tmp_path / "t.tum"
    assert sea3d_main(["odometry", str(bare), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    # A session recorded with a rig whose rig.yaml is gone is damaged, not rig-less:
    # the error names the missing file (a rig-less session's "stores no rig" is
    # tests/io/test_resolve_rig.py's).
    assert "rig.yaml is missing, though the session was recorded with a rig" in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()
    (bare / "imu.csv").unlink()
    rig = save_rig(sim_survey.rig, tmp_path / "rig.yaml")
    argv = [
        "odometry",
        str(bare),
        "--rig",
        str(rig),
        "-o",
        str(out),
        "--json",
        "--engine",
        "opencv",
        "--max-frames",
        "15",
    ]
    assert sea3d_main(argv) == 0
    s = _json(capsys)
    assert s["imu"] is False and any("no IMU samples" in n for n in s["notes"])
    assert s["frames"] == 15 and s["frames_lost"] == 0


@pytest.mark.slow
def test_calibrate_imu_finds_the_mounting_and_the_planted_offset(
    sim_survey, tmp_path, capsys
) -> None:
    out = tmp_path / "rig_imu.yaml"
    argv = [
        "calibrate",
        "imu",
        str(sim_survey.session),
        "--engine",
        "opencv",
        "--json",
        "-o",
        str(out),
    ]
    assert sea3d_main(argv) == 0
    r = _json(capsys)
    assert r["status"] == "ok"
    assert abs(r["time_offset_s"] - PLANTED_OFFSET_S) < CALIB_OFFSET_TOL_S
    R_true = sim_survey.rig.imu.T_left_imu[:3, :3]
    err = np.degrees(np.linalg.norm(R_to_rotvec(np.asarray(r["R_cam_imu"]).T @ R_true)))
    assert err < CALIB_ROTATION_TOL_DEG
    from sea3d.io.rig_file import load_rig

    rig = load_rig(out)
    assert rig.imu is not None and rig.imu.time_offset_s == pytest.approx(r["time_offset_s"])
    np.testing.assert_allclose(rig.imu.T_left_imu[:3, 3], sim_survey.rig.imu.T_left_imu[:3, 3])


def test_rgbd_files_give_one_pose_per_frame_with_index_times(data_dir, tmp_path, capsys) -> None:
    src = data_dir / "rgbd/7scenes_chess"
    for i in range(8):
        for kind, ext in (("color", "jpg"), ("depth", "png")):
            shutil.copy(
                src / f"frame-{i:06d}.{kind}.{ext}", tmp_path / f"frame-{i:06d}.{kind}.{ext}"
            )
    out = tmp_path / "t.tum"
    argv = [
        "odometry",
        "rgbd",
        "--color",
        str(tmp_path / "*.color.jpg"),
        "--depth",
        str(tmp_path / "*.depth.png"),
        "--intrinsics",
        "585",
        "585",
        "320",
        "240",
        "-o",
        str(out),
        "--json",
    ]
    assert sea3d_main(argv) == 0
    assert _json(capsys)["frames"] == 8
    np.testing.assert_array_equal(read_trajectory(out).t_ns, np.arange(8) * 10**9)
    (tmp_path / "frame-000007.depth.png").unlink()
    assert sea3d_main(argv) == 2
    assert "--color matches 8 files but --depth 7" in capsys.readouterr().err


def test_bad_arguments_are_one_line_errors(tmp_path, capsys) -> None:
    assert sea3d_main(["odometry", "rgbd", "--color", "x", "-o", str(tmp_path / "t")]) == 2
    assert "needs --color GLOB, --depth GLOB and --intrinsics" in capsys.readouterr().err
    assert sea3d_main(["odometry", str(tmp_path / "nope"), "-o", str(tmp_path / "t")]) == 2
    assert "does not exist" in capsys.readouterr().err
