"""io.ground_truth: one rule for where ground truth lives and what its files are called."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sea3d.io.ground_truth import (
    GroundTruth,
    find_ground_truth,
    ground_truth_dir,
    write_gt_depth,
)


def test_gt_inside_a_folder_session_and_beside_an_mcap(tmp_path: Path) -> None:
    folder = tmp_path / "dive"
    folder.mkdir()
    assert ground_truth_dir(folder) == folder / "gt"
    assert ground_truth_dir(tmp_path / "dive.mcap") == tmp_path / "dive_gt"
    # a session not yet written: the caller says which layout it will have
    assert ground_truth_dir(tmp_path / "new", folder=True) == tmp_path / "new" / "gt"
    assert ground_truth_dir(tmp_path / "new.mcap", folder=False) == tmp_path / "new_gt"


def test_find_ground_truth_sees_only_what_exists(tmp_path: Path) -> None:
    bag = tmp_path / "dive.mcap"
    bag.write_bytes(b"")
    assert find_ground_truth(bag) is None
    root = tmp_path / "dive_gt"
    root.mkdir()
    assert find_ground_truth(bag) is None  # an empty folder is no ground truth
    gt = GroundTruth(root)
    gt.depth_folder.mkdir()
    depth = np.full((4, 6), 2.5, np.float32)
    depth[0, 0] = np.nan
    write_gt_depth(gt.new_depth_path(123), depth)
    found = find_ground_truth(bag)
    assert found == gt and found.depth_dir == root / "depth"
    assert found.poses_left is None and found.scene_mesh is None and found.sim_meta is None
    assert np.array_equal(found.read_depth(123), depth, equal_nan=True)
    assert found.depth_path(123) == root / "depth" / "123.tiff"
