"""``sea3d fuse`` on real RGB-D frames (7-Scenes chess): the mesh lies where the depth says."""

import json

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.eval.surface import point_to_mesh_distance
from sea3d.io.depth_files import read_depth
from sea3d.io.mesh_files import read_mesh
from sea3d.io.trajectory_files import write_tum

FX, CX, CY = 585.0, 320.0, 240.0
# 2 cm voxels on Kinect depth: the fused surface stays within a few millimetres of each
# frame's own depth (median); a wrong depth scale, pose direction or intrinsics misplaces it
# by centimetres to metres.
MEDIAN_TO_MESH_TOL_M = 0.006


@pytest.mark.data
def test_fuse_7scenes_chess(data_dir, tmp_path, capsys):
    root = data_dir / "rgbd" / "7scenes_chess"
    poses = np.stack([np.loadtxt(p) for p in sorted(root.glob("frame-*.pose.txt"))])[:12]
    write_tum(tmp_path / "poses.tum", np.arange(12) * 33_000_000, poses)
    # 12 frames: link them so the glob sees only those
    for kind, ext in (("color", "jpg"), ("depth", "png")):
        (tmp_path / kind).mkdir()
        for k in range(12):
            (tmp_path / kind / f"frame-{k:06d}.{ext}").symlink_to(
                root / f"frame-{k:06d}.{kind}.{ext}")
    code = main(["fuse", "--color", str(tmp_path / "color" / "*.jpg"), "--depth",
                 str(tmp_path / "depth" / "*.png"), "--poses", str(tmp_path / "poses.tum"),
                 "--intrinsics", str(FX), str(FX), str(CX), str(CY), "--voxel-m", "0.02",
                 "-o", str(tmp_path / "mesh.ply"), "--cloud", str(tmp_path / "cloud.ply"),
                 "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 12 and out["triangles"] > 20_000
    mesh = read_mesh(tmp_path / "mesh.ply")
    # Frame 6's own depth, back-projected with its pose, lies on the fused surface.
    z = read_depth(root / "frame-000006.depth.png", 1000.0)
    v, u = np.nonzero(np.isfinite(z) & (z < 3.0))
    v, u = v[::50], u[::50]
    zz = z[v, u].astype(np.float64)
    p = np.stack([(u - CX) / FX * zz, (v - CY) / FX * zz, zz], axis=1)
    T = poses[6]
    pw = p @ T[:3, :3].T + T[:3, 3]
    d = point_to_mesh_distance(pw, mesh.vertices, mesh.triangles)
    assert np.median(d) < MEDIAN_TO_MESH_TOL_M
    assert read_mesh(tmp_path / "cloud.ply").vertices.shape[0] == out["cloud_points"]


def test_fuse_bad_input_names_the_problem(tmp_path, capsys):
    write_tum(tmp_path / "p.tum", [0], np.eye(4)[None])
    code = main(["fuse", "--color", str(tmp_path / "*.jpg"), "--depth", str(tmp_path / "*.png"),
                 "--poses", str(tmp_path / "p.tum"), "--intrinsics", "1", "1", "0", "0",
                 "--voxel-m", "0.02", "-o", str(tmp_path / "m.ply")])
    assert code == 2
    assert "no colour files match" in capsys.readouterr().err
