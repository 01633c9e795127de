"""The mesh scene encoded from numpy arrays: decoded through the schema Foxglove is given, it is
the very message the foxglove-sdk builds from one ``Point3``/``Color`` object per vertex (the
reference, built here the slow way)."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove.messages import (
    Color,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

from foxglove_client import ProtobufDecoder
from sea3d.errors import GeometryError
from sea3d.io import foxglove_msgs as fm

NAME = "foxglove.SceneUpdate"


_DECODER = ProtobufDecoder()  # one pool: messages of two pools never compare equal
_DECODER.add(NAME, fm.SCENE_UPDATE_SCHEMA.data)


def _decode(data: bytes):
    return _DECODER.decode(NAME, data)


def _sdk_reference(t_ns, frame_id, v, tri, col, entity_id) -> bytes:
    """The SDK's own encoding, one object per vertex."""
    colors = None
    if col is not None:
        colors = [Color(r=r, g=g, b=b, a=1.0) for r, g, b in (col / 255.0).tolist()]
    prim = TriangleListPrimitive(
        pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0),
                  orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
        points=[Point3(x=a, y=b, z=c) for a, b, c in v.tolist()],
        color=Color(r=0.7, g=0.7, b=0.7, a=1.0),
        colors=colors,
        indices=[int(i) for i in tri.reshape(-1)],
    )
    ent = SceneEntity(timestamp=Timestamp(t_ns // 10**9, t_ns % 10**9), frame_id=frame_id,
                      id=entity_id, triangles=[prim])
    return bytes(SceneUpdate(entities=[ent]).encode())


@pytest.mark.parametrize("coloured", [True, False])
def test_mesh_scene_from_arrays_is_the_sdk_message(coloured):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(300, 3))
    v[0] = 0.0  # zeros: proto3 omits them in the SDK's bytes, we write them; same message
    tri = rng.integers(0, 300, size=(500, 3))
    tri[0] = (299, 0, 150)
    col = rng.integers(0, 256, size=(300, 3), dtype=np.uint8) if coloured else None
    t_ns = 1_700_000_000_123_456_789
    ours = _decode(fm.mesh_scene(t_ns, "world", v, tri, col, entity_id="submap-12"))
    ref = _decode(_sdk_reference(t_ns, "world", v, tri, col, "submap-12"))
    assert ours == ref
    prim = ours.entities[0].triangles[0]
    got_v = np.array([[p.x, p.y, p.z] for p in prim.points])
    np.testing.assert_array_equal(got_v, v)  # float64 both ways: exact
    np.testing.assert_array_equal(np.array(prim.indices).reshape(-1, 3), tri)
    if coloured:
        got_c = np.array([[c.r, c.g, c.b, c.a] for c in prim.colors])
        np.testing.assert_array_equal(got_c[:, :3], col / 255.0)
        assert (got_c[:, 3] == 1.0).all()
    else:
        assert len(prim.colors) == 0
    ent = ours.entities[0]
    assert (ent.timestamp.seconds, ent.timestamp.nanos) == (1_700_000_000, 123_456_789)


def test_empty_mesh_and_deletions_decode():
    empty = _decode(fm.mesh_scene(0, "world", np.zeros((0, 3)), np.zeros((0, 3), int)))
    prim = empty.entities[0].triangles[0]
    assert empty.entities[0].id == "mesh" and len(prim.points) == 0 and len(prim.indices) == 0
    dels = _decode(fm.scene_deletions(5, ["submap-0", "submap-1"])).deletions
    assert [d.id for d in dels] == ["submap-0", "submap-1"]


def test_bad_meshes_are_refused_with_what_was_wrong():
    v = np.zeros((3, 3))
    with pytest.raises(GeometryError, match=r"\(V, 3\) vertices"):
        fm.mesh_scene(0, "world", v[:, :2], [[0, 1, 2]])
    with pytest.raises(GeometryError, match=r"0\.\.2"):
        fm.mesh_scene(0, "world", v, [[0, 1, 3]])
    with pytest.raises(GeometryError, match="colours"):
        fm.mesh_scene(0, "world", v, [[0, 1, 2]], np.zeros((2, 3), np.uint8))
    with pytest.raises(GeometryError, match=">= 0"):
        fm.mesh_scene(-1, "world", v, [[0, 1, 2]])
