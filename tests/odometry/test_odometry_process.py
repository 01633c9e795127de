"""``sea3d process SESSION`` without ``--poses`` runs sea3d's own odometry end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sea3d.cli import main as sea3d_main
from sea3d.eval.trajectory import evaluate_trajectory
from sea3d.io.rig_file import save_rig
from sea3d.io.trajectory_files import read_trajectory

PROCESS_FRAMES = 20
# The first 2 s of the test orbit (about 1.5 m of path): the odometry alone gets 0.2-0.3 % of
# the path (test_odometry_sim); through process (its own depth engine, its IMU chunks) 1 % still
# fails a frame-to-frame chain that slips or a pose written for the wrong frame.
ATE_FRACTION_MAX = 0.01


@pytest.mark.slow
def test_process_without_poses_runs_the_stereo_inertial_odometry(sim_survey, tmp_path, capsys):
    rig = save_rig(sim_survey.rig_true, tmp_path / "rig.yaml")
    out = tmp_path / "out"
    argv = ["process", str(sim_survey.session), "--rig", str(rig), "-o", str(out),
            "--workers", "0", "--engine", "opencv", "--max-frames", str(PROCESS_FRAMES),
            "--no-report", "--json"]  # fmt: skip
    assert sea3d_main(argv) == 0
    text = capsys.readouterr().out
    s = json.loads(text[text.index("{"):])
    assert s["odometry"] == "sea3d stereo-inertial odometry"
    assert s["frames"] == PROCESS_FRAMES and s["frames_lost"] == 0 and s["keyframes"] >= 3
    traj = read_trajectory(out / "trajectory.tum")
    np.testing.assert_array_equal(traj.t_ns, sim_survey.gt_t_ns[:PROCESS_FRAMES])
    m = evaluate_trajectory(traj.t_ns, traj.T_world_x, sim_survey.gt_t_ns,
                            sim_survey.gt_T_world_left, align="se3")
    assert m.ate_rmse_m < ATE_FRACTION_MAX * m.path_length_m
    assert (out / "mesh.ply").is_file() and (out / "cloud.ply").is_file()
