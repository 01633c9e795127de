"""Results MCAP with Foxglove schemas: write, then read back with the official ``mcap`` reader
and decode every message through the protobuf schema stored in the file (what Foxglove and
Lichtblick do)."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from foxglove_client import ProtobufDecoder
from sea3d.errors import SessionError
from sea3d.geometry.se3 import quat_wxyz_to_R
from sea3d.io.foxglove_mcap import ResultsMcapWriter, write_results_mcap

FLOAT32_M = 1e-6  # points are stored as float32: about 1e-7 relative at a few metres
POSE_M = 1e-12  # poses are float64 in the protobuf


def _read(path):
    dec = ProtobufDecoder()
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == "protobuf":
                dec.add(schema.name, schema.data)
                value = dec.decode(schema.name, message.data)
            else:
                import json

                value = json.loads(message.data)
            out.setdefault(channel.topic, []).append((message.log_time, value))
    return out


def _trajectory(n=12):
    rng = np.random.default_rng(0)
    t = (np.arange(n) * 100_000_000 + 5).astype(np.int64)
    T = np.repeat(np.eye(4)[None], n, axis=0)
    for k in range(n):
        a = 0.1 * k
        T[k, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        T[k, :3, 3] = rng.normal(size=3)
    return t, T


def test_results_round_trip_through_the_schemas(tmp_path):
    rng = np.random.default_rng(0)
    t, T = _trajectory()
    pts = rng.uniform(-3, 3, size=(500, 3))
    cols = rng.integers(0, 256, size=(500, 3), dtype=np.uint8)
    verts = rng.normal(size=(30, 3))
    tris = rng.integers(0, 30, size=(40, 3))
    vcols = rng.integers(0, 256, size=(30, 3), dtype=np.uint8)
    T_lr = np.eye(4)
    T_lr[0, 3] = 0.107
    status = ["tracking"] * 11 + ["lost"]

    class Rig:
        T_left_right = T_lr

    path = tmp_path / "results.mcap"
    counts = write_results_mcap(
        path,
        trajectory=(t, T),
        status=status,
        cloud=(pts, cols),
        mesh=(verts, tris, vcols),
        rig=Rig(),
    )
    assert counts == {"poses": 12, "clouds": 1, "meshes": 1}
    got = _read(path)

    poses = got["/odometry/pose"]
    assert [lt for lt, _ in poses] == t.tolist()
    for k, (_, msg) in enumerate(poses):
        p, q = msg.pose.position, msg.pose.orientation
        assert msg.frame_id == "world"
        np.testing.assert_allclose([p.x, p.y, p.z], T[k, :3, 3], atol=POSE_M)
        np.testing.assert_allclose(quat_wxyz_to_R([q.w, q.x, q.y, q.z]), T[k, :3, :3], atol=1e-12)
        assert msg.timestamp.seconds * 10**9 + msg.timestamp.nanos == t[k]
    tf = got["/tf"][3][1].transforms
    assert [(x.parent_frame_id, x.child_frame_id) for x in tf] == [
        ("world", "left"),
        ("left", "right"),
    ]
    assert tf[1].translation.x == pytest.approx(0.107)
    path_msg = got["/odometry/trajectory"][0][1]
    assert len(path_msg.poses) == 12 and got["/odometry/trajectory"][0][0] == t[-1]
    assert [m["status"] for _, m in got["/odometry/status"]] == status

    cloud = got["/cloud"][0][1]
    assert cloud.point_stride == 16
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "red", "green", "blue", "alpha"]
    rec = np.frombuffer(cloud.data, dtype=np.dtype([("xyz", "<f4", 3), ("rgba", "u1", 4)]))
    np.testing.assert_allclose(rec["xyz"], pts, atol=FLOAT32_M * 3)
    np.testing.assert_array_equal(rec["rgba"][:, :3], cols)
    assert (rec["rgba"][:, 3] == 255).all()

    ent = got["/mesh"][0][1].entities[0]
    tri = ent.triangles[0]
    got_v = np.array([[p.x, p.y, p.z] for p in tri.points])
    np.testing.assert_allclose(got_v, verts, atol=POSE_M)
    np.testing.assert_array_equal(np.array(tri.indices).reshape(-1, 3), tris)
    got_c = np.array([[c.r, c.g, c.b] for c in tri.colors])
    np.testing.assert_allclose(got_c * 255, vcols, atol=1e-9)


def test_large_mesh_is_decimated(tmp_path):
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=40)
    v, tri = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    path = tmp_path / "m.mcap"
    with ResultsMcapWriter(path, max_mesh_triangles=500) as w:
        w.mesh(v, tri)
    prim = _read(path)["/mesh"][0][1].entities[0].triangles[0]
    n_tri = len(prim.indices) // 3
    assert tri.shape[0] > 3000 and 0 < n_tri <= 500
    radii = np.linalg.norm(np.array([[p.x, p.y, p.z] for p in prim.points]), axis=1)
    assert np.all(np.abs(radii - 1.0) < 0.05)  # still the sphere


def test_existing_file_and_bad_shapes_are_refused(tmp_path):
    path = tmp_path / "r.mcap"
    path.write_bytes(b"keep me")
    with pytest.raises(SessionError, match="already exists"):
        write_results_mcap(path)
    assert path.read_bytes() == b"keep me"
    with (
        pytest.raises(SessionError, match=r"\(N, 4, 4\)"),
        ResultsMcapWriter(tmp_path / "b.mcap") as w,
    ):
        w.trajectory([0, 1], np.eye(4)[None])
