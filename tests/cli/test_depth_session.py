"""``sea3d depth --session``: every pair of a simulated session, checked against ground truth."""

import json

import cv2
import numpy as np

from sea3d.cli import main
from sea3d.sim.survey import read_gt_depth

# The depth PNGs are on the rectified grid and the ground truth on the raw one, so this test
# compares the scene's median depth: a correct pipeline agrees to a few percent (rectification
# crops the border differently); the metric-scale bugs of public scripts (depth from disparity
# times 16, per-frame normalisation) are off by factors.
SCENE_MEDIAN_RATIO_TOL = 0.1


def test_depth_over_a_session_matches_ground_truth(tmp_path, capsys):
    session = tmp_path / "s.mcap"
    assert (
        main(
            [
                "sim",
                "--scene",
                "lake",
                "--frames",
                "2",
                "--size",
                "480x270",
                "--water",
                "none",
                "--out",
                str(session),
            ]
        )
        == 0
    )
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["depth", "--session", str(session), "-o", str(out), "--points", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["pairs"] == 2 and summary["refractive"] is True
    depth_files = sorted((out / "depth").glob("*.png"))
    assert [p.stem for p in depth_files] == ["0", "100000000"]
    assert len(list((out / "cloud").glob("*.ply"))) == 2
    gt_dir = tmp_path / "s_gt" / "depth"
    for png in depth_files:
        est_mm = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        assert est_mm.dtype == np.uint16
        gt = read_gt_depth(gt_dir / f"{png.stem}.tiff")
        # The PNG is on the rectified grid; compare medians of the scene depth, which a scale
        # error would shift (per-pixel checks are in tests/stereo and tests/pipeline).
        est = est_mm[est_mm > 0] / 1000.0
        ratio = np.median(est) / np.nanmedian(gt)
        assert abs(ratio - 1.0) < SCENE_MEDIAN_RATIO_TOL


def test_depth_needs_either_a_pair_or_a_session(tmp_path, capsys):
    assert main(["depth", "-o", str(tmp_path / "d.png")]) == 2
    assert "needs --rig with --left and --right, or --session" in capsys.readouterr().err
