"""``sea3d depth --session``: every pair of a simulated session, checked against ground truth.

The check goes through the independent tracer of ``tests/_trace3d.py``: each point of the
written clouds (left camera frame) is traced back to the raw left pixel that sees it, where the
simulator's ground-truth depth is read. Ignoring the paper's domes costs 2-2.5 % of depth at
this range, so the tolerance on the median relative error sits well below that; the test also
runs the same session with the ports stripped from the rig and asserts it fails the tolerance,
so it can tell whether refraction was corrected.
"""

import json

import numpy as np
import open3d as o3d

from _trace3d import project
from sea3d.cli import main
from sea3d.geometry.rig import StereoRig
from sea3d.io.ground_truth import gt_depth_path, read_gt_depth
from sea3d.io.rig_file import rig_from_yaml, save_rig
from sea3d.io.session import open_session

# Median |z - z_gt| / z_gt of the points. Measured at 480x270 on this scene: 0.14 % with the
# ports corrected, 2.48 % with them ignored (both frames).
MEDIAN_REL_TOL = 0.006
PORTS_IGNORED_MIN_REL = 0.015
POINT_STRIDE = 15  # every 15th point is plenty for a median (the tracer's Newton is slow)


def _median_rel_errors(out, gt_dir, rig) -> list[float]:
    errs = []
    for ply in sorted((out / "cloud").glob("*.ply")):
        pts = np.asarray(o3d.io.read_point_cloud(str(ply)).points, dtype=np.float64)
        assert len(pts) > 50_000
        pts = pts[::POINT_STRIDE]
        gt = read_gt_depth(gt_depth_path(gt_dir, int(ply.stem)))
        uv = np.rint(project(rig.left, pts)).astype(int)
        inside = ((uv[:, 0] >= 0) & (uv[:, 0] < gt.shape[1]) & (uv[:, 1] >= 0)
                  & (uv[:, 1] < gt.shape[0]))
        z_gt = gt[uv[inside, 1], uv[inside, 0]]
        ok = np.isfinite(z_gt)
        errs.append(float(np.median(np.abs(pts[inside][ok, 2] / z_gt[ok] - 1.0))))
    return errs


def test_depth_over_a_session_matches_ground_truth(tmp_path, capsys):
    session = tmp_path / "s.mcap"
    assert main(["sim", "--scene", "lake", "--frames", "2", "--size", "480x270", "--water",
                 "none", "--out", str(session)]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["depth", "--session", str(session), "-o", str(out), "--points", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pairs"] == 2 and summary["refractive"] is True
    depth_files = sorted((out / "depth").glob("*.png"))
    assert [p.stem for p in depth_files] == ["0", "100000000"]
    with open_session(session) as s:
        rig = rig_from_yaml(s.rig_yaml, "session rig")
    gt_dir = tmp_path / "s_gt" / "depth"
    errs = _median_rel_errors(out, gt_dir, rig)
    assert len(errs) == 2
    assert max(errs) < MEDIAN_REL_TOL, errs
    # the same session through the in-air rig (ports ignored) must fail that tolerance
    air = StereoRig(rig.left.pinhole, rig.right.pinhole, rig.T_left_right)
    save_rig(air, tmp_path / "air.yaml")
    out_air = tmp_path / "out_air"
    assert main(["depth", "--session", str(session), "--rig", str(tmp_path / "air.yaml"), "-o",
                 str(out_air), "--points", "--json"]) == 0
    capsys.readouterr()
    errs_air = _median_rel_errors(out_air, gt_dir, rig)
    assert min(errs_air) > PORTS_IGNORED_MIN_REL, errs_air


def test_depth_needs_either_a_pair_or_a_session(tmp_path, capsys):
    assert main(["depth", "-o", str(tmp_path / "d.png")]) == 2
    assert "needs --rig with --left and --right, or --session" in capsys.readouterr().err
