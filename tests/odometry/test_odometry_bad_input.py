"""Bad input to ``sea3d odometry`` and ``sea3d process``: a warning that names what is wrong, or
a non-zero exit; never a trajectory of identity poses reported with exit status 0 (issues 19,
21)."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.geometry.rig import ImuSpec
from sea3d.pipeline.odometry import imu_clock_check, imu_decision

SHIFT_S = 5.0
SIZE = (320, 180)


def _json(capsys) -> dict:
    out = capsys.readouterr().out
    return json.loads(out[out.index("{") :])


def test_imu_clock_check_finds_an_imu_seconds_away() -> None:
    cam = np.arange(30, dtype=np.int64) * 100_000_000 + 10**12  # 3 s at 10 Hz
    imu = np.arange(-100, 700, dtype=np.int64) * 5_000_000 + 10**12  # 200 Hz, covers it
    assert imu_clock_check(cam, imu) is None
    why = imu_clock_check(cam, imu + round(SHIFT_S * 1e9))
    assert why is not None and "start +4.50 s" in why and "not synchronised" in why
    # the rig's offset (t_imu = t_cam + offset) puts the same series back on the camera clock
    assert imu_clock_check(cam, imu + round(SHIFT_S * 1e9), SHIFT_S) is None
    assert "no IMU samples" in str(imu_clock_check(cam, np.zeros(0, np.int64)))


def test_imu_decision_leaves_out_an_unusable_imu_and_says_why() -> None:
    cam = np.arange(30, dtype=np.int64) * 100_000_000 + 10**12
    imu = np.arange(-100, 700, dtype=np.int64) * 5_000_000 + 10**12
    block = ImuSpec(T_left_imu=np.eye(4), time_offset_s=0.0)
    assert imu_decision(True, block, cam, imu) == (True, None)
    off = imu_decision(False, block, cam, imu)
    none = imu_decision(True, block, cam, np.zeros(0, np.int64))
    no_block = imu_decision(True, None, cam, imu)
    away = imu_decision(True, block, cam, imu + round(SHIFT_S * 1e9))
    assert off == (False, "use_imu off: visual-only")
    assert none == (False, "the session has no IMU samples: visual-only")
    assert no_block[0] is False and "no imu block" in str(no_block[1])
    assert away[0] is False and "not synchronised" in str(away[1])
    assert str(away[1]).endswith(": visual-only")
    # a live IMU stream: its samples are still to come, its clock is checked on them later
    assert imu_decision(True, block, None, None) == (True, None)
    assert imu_decision(True, None, None, None)[0] is False
    # the rig's offset puts an IMU clock seconds away back on the camera's
    shifted = ImuSpec(T_left_imu=np.eye(4), time_offset_s=SHIFT_S)
    assert imu_decision(True, shifted, cam, imu + round(SHIFT_S * 1e9)) == (True, None)


def _black_session(tmp_path, value: int = 0):
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter
    from sea3d.refraction.presets import paper_rig

    rig = paper_rig("dome", size_px=SIZE)
    path = tmp_path / "flat"
    img = np.full((SIZE[1], SIZE[0]), value, np.uint8)
    with SessionWriter(path, format="folder", rig_yaml=rig_to_yaml(rig)) as w:
        for i in range(6):
            w.write_stereo(10**9 + i * 100_000_000, img, img)
    return path


@pytest.mark.parametrize("value", [0, 128])
def test_images_with_nothing_to_track_exit_non_zero(tmp_path, capsys, value) -> None:
    session = _black_session(tmp_path, value)
    out = tmp_path / "t.tum"
    argv = ["odometry", str(session), "-o", str(out), "--engine", "opencv"]
    assert sea3d_main(argv) != 0
    err = capsys.readouterr().err
    assert "nothing to track" in err and "Traceback" not in err
    assert not out.exists()


def test_max_frames_below_one_and_a_folder_as_output_are_refused(tmp_path, capsys) -> None:
    session = _black_session(tmp_path)
    assert sea3d_main(["odometry", str(session), "-o", str(tmp_path / "t.tum"),
                       "--max-frames", "-3"]) == 2  # fmt: skip
    assert "--max-frames must be >= 1, got -3" in capsys.readouterr().err
    folder = tmp_path / "paths"
    folder.mkdir()
    assert sea3d_main(["odometry", str(session), "-o", str(folder)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flat", "paths"]  # no paths.tmp


def test_write_tum_into_a_folder_leaves_no_temporary_file(tmp_path) -> None:
    from sea3d.errors import OdometryError
    from sea3d.io.trajectory_files import write_tum

    (tmp_path / "paths").mkdir()
    with pytest.raises(OdometryError, match="is a folder"):
        write_tum(tmp_path / "paths", [0], np.eye(4)[None])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paths"]


# ------------------------------------------------------------------------------------ RGB-D
def _chess(data_dir, tmp_path, n: int = 6, depth: str = "png16"):
    src = data_dir / "rgbd/7scenes_chess"
    for i in range(n):
        shutil.copy(src / f"frame-{i:06d}.color.jpg", tmp_path / f"frame-{i:06d}.color.jpg")
        d = cv2.imread(str(src / f"frame-{i:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        d[d == 65535] = 0
        if depth == "png16":
            shutil.copy(src / f"frame-{i:06d}.depth.png", tmp_path / f"frame-{i:06d}.depth.png")
        elif depth == "png8":
            cv2.imwrite(str(tmp_path / f"frame-{i:06d}.depth.png"),
                        np.clip(d // 20, 0, 255).astype(np.uint8))
        else:  # float32 metres
            cv2.imwrite(str(tmp_path / f"frame-{i:06d}.depth.tiff"),
                        (d.astype(np.float32) / 1000.0))
    ext = "png" if depth.startswith("png") else "tiff"
    return ["odometry", "rgbd", "--color", str(tmp_path / "*.color.jpg"), "--depth",
            str(tmp_path / f"*.depth.{ext}"), "--intrinsics", "585", "585", "320", "240"]


@pytest.mark.parametrize("method", ["dense", "features"])
def test_rgbd_8bit_depth_is_refused(data_dir, tmp_path, capsys, method) -> None:
    argv = _chess(data_dir, tmp_path, depth="png8") + ["--method", method, "-o",
                                                       str(tmp_path / "t.tum")]
    assert sea3d_main(argv) == 2
    err = capsys.readouterr().err
    assert "8-bit depth" in err and "frame-000000.depth.png" in err
    assert not (tmp_path / "t.tum").exists()


def test_rgbd_float_tiff_depth_is_metres(data_dir, tmp_path, capsys) -> None:
    from sea3d.io.trajectory_files import read_trajectory

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    assert sea3d_main(_chess(data_dir, a) + ["-o", str(a / "t.tum")]) == 0
    assert sea3d_main(_chess(data_dir, b, depth="tiff") + ["-o", str(b / "t.tum")]) == 0
    Ta = read_trajectory(a / "t.tum").T_world_x
    Tb = read_trajectory(b / "t.tum").T_world_x
    # the same depth in metres gives the same path (to float32 rounding of the depth)
    np.testing.assert_allclose(Tb[:, :3, 3], Ta[:, :3, 3], atol=1e-4)
    assert np.linalg.norm(Ta[-1, :3, 3]) > 1e-3  # the camera moved: not identity poses
    # millimetres given as metres (scale 1) is no plausible depth
    argv = _chess(data_dir, a) + ["--depth-scale", "1", "-o", str(a / "u.tum")]
    assert sea3d_main(argv) == 2
    assert "no plausible depth" in capsys.readouterr().err


@pytest.mark.parametrize("cx,cy", [(700, 240), (320, -5)])
def test_rgbd_principal_point_outside_the_image_is_refused(data_dir, tmp_path, capsys,
                                                           cx, cy) -> None:
    argv = _chess(data_dir, tmp_path, n=2)
    argv[argv.index("320")] = str(cx)
    argv[argv.index("240")] = str(cy)
    assert sea3d_main(argv + ["-o", str(tmp_path / "t.tum")]) == 2
    assert "principal point" in capsys.readouterr().err


# ---------------------------------------------------------------- IMU far from the cameras
@pytest.mark.slow
def test_process_with_an_imu_seconds_away_runs_visual_only_and_says_so(
    sim_survey, tmp_path, capsys
) -> None:
    from sea3d.io.session import SessionWriter, open_session

    shifted = tmp_path / "shifted"
    with open_session(sim_survey.session) as s, SessionWriter(
        shifted, format="folder", rig_yaml=s.rig_yaml
    ) as w:
        for k, p in enumerate(s.pairs()):
            if k >= 12:
                break
            w.write_stereo(p.t_ns, p.left, p.right)
        imu = s.imu()
        for t, a, g in zip(imu.t_ns, imu.accel_mps2, imu.gyro_radps, strict=True):
            w.write_imu(int(t) + round(SHIFT_S * 1e9), a, g)
    out = tmp_path / "out"
    argv = ["process", str(shifted), "-o", str(out), "--workers", "0", "--engine", "opencv",
            "--max-frames", "12", "--no-report", "--json"]  # fmt: skip
    assert sea3d_main(argv) == 0
    processed = _json(capsys)
    assert processed["imu_used"] is False and "not synchronised" in processed["imu_note"]
    argv = ["odometry", str(shifted), "-o", str(tmp_path / "t.tum"), "--engine", "opencv",
            "--max-frames", "12", "--json"]  # fmt: skip
    assert sea3d_main(argv) == 0
    s = _json(capsys)
    assert s["imu"] is False and "not synchronised" in s["imu_note"]
    assert processed["imu_note"] == s["imu_note"]  # one decision, said the same way


@pytest.mark.data
def test_a_depth_range_that_excludes_the_scene_exits_non_zero(data_dir, tmp_path, capsys) -> None:
    # the EuRoC room is 2-8 m away: nothing lies between 50 and 60 m
    out = tmp_path / "t.tum"
    argv = ["odometry", str(data_dir / "vio/euroc_v101_micro"), "-o", str(out), "--engine",
            "opencv", "--max-frames", "5", "--min-depth", "50", "--max-depth", "60"]
    assert sea3d_main(argv) == 2
    err = capsys.readouterr().err
    assert "50..60 m" in err and "--min-depth/--max-depth" in err and not out.exists()
    # an empty range is a one-line error before anything runs
    assert sea3d_main(argv[:-4] + ["--max-depth", "0.3"]) == 2
    assert "is empty for this rig" in capsys.readouterr().err


@pytest.mark.data
def test_default_depth_range_comes_from_the_rig(data_dir, tmp_path, capsys) -> None:
    argv = ["odometry", str(data_dir / "vio/euroc_v101_micro"), "-o", str(tmp_path / "t.tum"),
            "--engine", "opencv", "--max-frames", "3", "--json"]
    assert sea3d_main(argv) == 0
    s = _json(capsys)
    # f B = 458 px * 0.110 m = 50 px m: 752 px wide -> disparities 0..95 -> 0.5 m; / 4 px -> 12.6 m
    lo, hi = s["depth_range_m"]
    assert lo == pytest.approx(50.4 / 95, rel=0.05) and hi == pytest.approx(50.4 / 4, rel=0.05)


def test_calibrate_imu_without_an_answer_exits_non_zero_with_advice(tmp_path, capsys) -> None:
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter
    from sea3d.refraction.presets import paper_rig

    session = tmp_path / "flat_imu"
    img = np.full((SIZE[1], SIZE[0]), 90, np.uint8)
    with SessionWriter(session, format="folder",
                       rig_yaml=rig_to_yaml(paper_rig("dome", size_px=SIZE))) as w:
        for k in range(200):  # 1 s of IMU at 200 Hz
            w.write_imu(10**9 + k * 5_000_000, np.array([0.0, 0.0, 9.81]), np.zeros(3))
        for i in range(6):
            w.write_stereo(10**9 + i * 100_000_000, img, img)
    out = tmp_path / "rig_imu.yaml"
    argv = ["calibrate", "imu", str(session), "--engine", "opencv", "-o", str(out)]
    assert sea3d_main(argv) == 1
    cap = capsys.readouterr()
    assert "advice: only 0 camera rates" in cap.out and "record at least 10 s" in cap.out
    assert "the rig was not written" in cap.err and not out.exists()
