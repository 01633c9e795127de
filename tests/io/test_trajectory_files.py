"""Trajectory files: exact stamps, round trips, the three formats, bad input."""

import numpy as np
import pytest

from sea3d.errors import OdometryError
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.io.trajectory_files import (
    format_tum_stamp,
    parse_seconds_ns,
    read_trajectory,
    write_tum,
)

# TUM files carry 9 decimals of position and 12 of quaternion.
POS_TOL_M = 1e-9
ROT_TOL = 1e-11


def test_seconds_parse_to_exact_nanoseconds():
    assert parse_seconds_ns("1305031102.160407") == 1305031102160407000
    assert parse_seconds_ns("0.000000001") == 1
    assert parse_seconds_ns("-1.5") == -1_500_000_000
    assert parse_seconds_ns("1e-3") == 1_000_000
    assert parse_seconds_ns("12") == 12_000_000_000
    assert parse_seconds_ns("1.0000000004") == 1_000_000_000
    assert parse_seconds_ns("1.0000000005") == 1_000_000_001
    with pytest.raises(ValueError):
        parse_seconds_ns("1.2.3")
    # A float64 would round this stamp: the text parser does not.
    assert round(float("1305031102.160407123") * 1e9) != 1305031102160407123
    assert parse_seconds_ns("1305031102.160407123") == 1305031102160407123


def test_tum_round_trip_keeps_stamps_and_poses(tmp_path, rng):
    n = 20
    t = np.cumsum(rng.integers(1, 10**8, n)).astype(np.int64) + 1403715273262142976
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = rotvec_to_R(rng.normal(0, 1.0, (n, 3)))
    T[:, :3, 3] = rng.normal(0, 10, (n, 3))
    write_tum(tmp_path / "a.tum", t, T)
    back = read_trajectory(tmp_path / "a.tum")
    assert back.format == "tum" and back.timed
    np.testing.assert_array_equal(back.t_ns, t)
    np.testing.assert_allclose(back.T_world_x[:, :3, 3], T[:, :3, 3], atol=POS_TOL_M)
    np.testing.assert_allclose(back.T_world_x[:, :3, :3], T[:, :3, :3], atol=ROT_TOL)
    assert format_tum_stamp(1) == "0.000000001"


def test_kitti_is_numbered_or_stamped_from_times(tmp_path):
    rows = [np.hstack([np.eye(3), [[k], [0.0], [0.0]]]).ravel() for k in range(3)]
    (tmp_path / "k.txt").write_text("\n".join(" ".join(map(str, r)) for r in rows) + "\n")
    k = read_trajectory(tmp_path / "k.txt")
    assert k.format == "kitti" and not k.timed
    assert k.T_world_x[2, 0, 3] == 2.0
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")
    ks = read_trajectory(tmp_path / "k.txt", kitti_times=tmp_path / "times.txt")
    assert ks.timed and ks.t_ns.tolist() == [0, 100_000_000, 200_000_000]


@pytest.mark.data
def test_euroc_ground_truth_csv(data_dir):
    p = data_dir / "vio" / "euroc_v101_micro" / "gt" / "V1_01_easy_vicon2gt.csv"
    tum = data_dir / "vio" / "euroc_v101_micro" / "gt" / "V1_01_easy_vicon2gt_tum.txt"
    e = read_trajectory(p)
    t = read_trajectory(tum)
    assert e.format == "euroc" and e.t_ns[0] == 1403715273262142976
    # The same poses in two formats (the TUM copy rounds stamps to fewer digits).
    n = min(len(e), len(t))
    np.testing.assert_allclose(e.T_world_x[:n, :3, 3], t.T_world_x[:n, :3, 3], atol=1e-5)
    np.testing.assert_allclose(e.T_world_x[:n, :3, :3], t.T_world_x[:n, :3, :3], atol=1e-5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 0 0 0 0 0 0 1\n0.1 0 0\n", "t.tum:2: expected 8 values"),
        ("0 0 0 0 0 0 0 2\n", "quaternion norm"),
        ("0 0 0 x 0 0 0 1\n", "t.tum:1: not a number"),
        ("# only a comment\n", "holds no poses"),
    ],
)
def test_bad_tum_files_name_file_and_line(tmp_path, text, message):
    (tmp_path / "t.tum").write_text(text)
    with pytest.raises(OdometryError, match=message):
        read_trajectory(tmp_path / "t.tum")


def test_unsorted_stamps_are_sorted(tmp_path):
    (tmp_path / "t.tum").write_text("2 2 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    t = read_trajectory(tmp_path / "t.tum")
    assert t.t_ns.tolist() == [1_000_000_000, 2_000_000_000]
    assert t.T_world_x[0, 0, 3] == 1.0


def test_repeated_stamps_keep_the_first_pose_with_a_count(tmp_path, caplog):
    (tmp_path / "t.tum").write_text(
        "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n1 9 9 9 0 0 0 1\n2 2 0 0 0 0 0 1\n"
        "2 8 8 8 0 0 0 1\n0.5 0.5 0 0 0 0 0 1\n"
    )
    with caplog.at_level("WARNING"):
        t = read_trajectory(tmp_path / "t.tum")
    assert t.t_ns.tolist() == [0, 500_000_000, 1_000_000_000, 2_000_000_000]
    assert t.T_world_x[:, 0, 3].tolist() == [0.0, 0.5, 1.0, 2.0]  # the first of each stamp
    assert t.duplicates_dropped == 2 and t.unsorted
    assert "2 pose(s) repeat an earlier stamp" in caplog.text
    assert any("2 pose(s) with a repeated stamp dropped" in n for n in t.notes)
