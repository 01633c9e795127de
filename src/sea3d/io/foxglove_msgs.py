"""sea3d data as Foxglove messages (foxglove-sdk), shared by the live server and MCAP files.

The topics and schemas sea3d publishes and writes:

==========================  ====================================  ==================================
topic                       schema                                what
==========================  ====================================  ==================================
``/cam/left/image``         ``foxglove.CompressedImage`` (jpeg)   left camera (``/cam/right/image``)
``/cam/left/camera_info``   ``foxglove.CameraCalibration``        K, D, P of the image sent
``/imu``                    JSON ``sea3d.Imu``                    ``linear_acceleration`` m/s^2,
                                                                  ``angular_velocity`` rad/s
``/sonar``                  JSON ``sea3d.Range``                  ``range_m``, ``confidence``,
                                                                  ``field_of_view_rad``
``/depth``                  ``foxglove.RawImage`` (32FC1)         metres along the rectified left
                                                                  z axis, NaN invalid
``/disparity``              ``foxglove.RawImage`` (32FC1)         pixels (when there is no rig)
``/tf``                     ``foxglove.FrameTransforms``          ``world`` -> ``left`` (pose),
                                                                  ``left`` -> ``right`` (rig)
``/odometry/pose``          ``foxglove.PoseInFrame``              ``T_world_left`` per frame
``/odometry/trajectory``    ``foxglove.PosesInFrame``             the path so far
``/cloud``                  ``foxglove.PointCloud``               x, y, z float32 m + rgba uint8
``/mesh``                   ``foxglove.SceneUpdate``              triangle list, vertex colours
==========================  ====================================  ==================================

Stamps are integer nanoseconds; Foxglove's ``Timestamp`` holds seconds and nanoseconds.
IMU and echosounder go as JSON (with a JSON schema) so that any WebSocket client can read them
and Foxglove's Plot panel plots them; their field names follow ``sensor_msgs/Imu`` and
``sensor_msgs/Range``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from foxglove.messages import (
    CameraCalibration,
    CompressedImage,
    FrameTransform,
    FrameTransforms,
    PackedElementField,
    PackedElementFieldNumericType,
    PointCloud,
    Pose,
    PoseInFrame,
    PosesInFrame,
    Quaternion,
    RawImage,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    Timestamp,
    Vector3,
)

from sea3d.errors import GeometryError
from sea3d.geometry.se3 import R_to_quat_wxyz, check_T
from sea3d.io.session.ros_messages import TOPICS as SESSION_TOPICS

__all__ = [
    "IMU_SCHEMA",
    "SCENE_UPDATE_SCHEMA",
    "SONAR_SCHEMA",
    "TOPICS",
    "camera_calibration",
    "compressed_image",
    "encode_preview_jpeg",
    "float_image",
    "frame_transform",
    "frame_transforms",
    "imu_message",
    "mesh_scene",
    "point_cloud",
    "pose",
    "pose_in_frame",
    "poses_in_frame",
    "scene_deletions",
    "sonar_message",
    "timestamp",
]

# The sensors go on a session's own topics, so that a recorded session and what sea3d
# publishes open in the same Foxglove layout.
TOPICS = {
    **{k: SESSION_TOPICS[k] for k in ("left", "right", "left_info", "right_info", "imu", "sonar")},
    "depth": "/depth",
    "disparity": "/disparity",
    "tf": "/tf",
    "pose": "/odometry/pose",
    "trajectory": "/odometry/trajectory",
    "cloud": "/cloud",
    "mesh": "/mesh",
}

_VEC3 = {
    "type": "object",
    "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}},
}
_STAMP = {
    "type": "object",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
}
IMU_SCHEMA: dict[str, Any] = {
    "title": "sea3d.Imu",
    "type": "object",
    "properties": {
        "timestamp": _STAMP,
        "frame_id": {"type": "string"},
        "linear_acceleration": {**_VEC3, "description": "specific force, m/s^2, IMU frame"},
        "angular_velocity": {**_VEC3, "description": "angular rate, rad/s, IMU frame"},
    },
}
SONAR_SCHEMA: dict[str, Any] = {
    "title": "sea3d.Range",
    "type": "object",
    "properties": {
        "timestamp": _STAMP,
        "frame_id": {"type": "string"},
        "range_m": {"type": ["number", "null"], "description": "distance to the bottom, m"},
        "confidence": {"type": ["number", "null"], "description": "0..1"},
        "field_of_view_rad": {"type": "number"},
    },
}


def timestamp(t_ns: int) -> Timestamp:
    """Foxglove ``Timestamp`` of an integer-nanosecond stamp (must be >= 0)."""
    t = int(t_ns)
    if t < 0:
        raise GeometryError(f"stamp must be >= 0 ns for Foxglove, got {t}")
    return Timestamp(t // 1_000_000_000, t % 1_000_000_000)


def _stamp_json(t_ns: int) -> dict[str, int]:
    t = int(t_ns)
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def encode_preview_jpeg(
    image: np.ndarray, *, quality: int = 80, max_width_px: int | None = None
) -> tuple[bytes, float]:
    """JPEG bytes of an RGB (or grey) image, optionally downscaled, and the scale applied.

    Args:
        image: (H, W) or (H, W, 3) RGB, uint8 or uint16 (uint16 is shifted to 8 bits).
        quality: JPEG quality 0..100.
        max_width_px: downscale (area interpolation) to at most this width; None keeps the size.

    Returns:
        ``(jpeg_bytes, scale)`` with ``scale = new_width / old_width`` (1.0 when not resized).

    Raises:
        GeometryError: an image OpenCV cannot encode.
    """
    img = image
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    scale = 1.0
    if max_width_px is not None and img.shape[1] > max_width_px:
        scale = max_width_px / img.shape[1]
        size = (int(max_width_px), max(1, round(img.shape[0] * scale)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise GeometryError(f"OpenCV could not encode a {image.shape} {image.dtype} image as JPEG")
    return buf.tobytes(), scale


def compressed_image(t_ns: int, data: bytes, fmt: str, frame_id: str) -> CompressedImage:
    """A ``foxglove.CompressedImage`` (``fmt``: ``jpeg`` or ``png``)."""
    return CompressedImage(timestamp=timestamp(t_ns), frame_id=frame_id, data=data, format=fmt)


def camera_calibration(
    t_ns: int,
    frame_id: str,
    K: np.ndarray,
    dist: np.ndarray,
    width: int,
    height: int,
    *,
    scale: float = 1.0,
) -> CameraCalibration:
    """A ``foxglove.CameraCalibration`` from a 3x3 ``K`` (pixels) and OpenCV distortion, for an
    image resized by ``scale`` (pixel centres kept: ``c' = (c + 0.5) s - 0.5``)."""
    K = np.asarray(K, dtype=np.float64)
    d = np.asarray(dist, dtype=np.float64).reshape(-1)
    Ks = K.copy()
    Ks[0, 0] *= scale
    Ks[1, 1] *= scale
    Ks[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
    Ks[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    P = np.zeros((3, 4))
    P[:, :3] = Ks
    model = "rational_polynomial" if d.size >= 8 else "plumb_bob"
    return CameraCalibration(
        timestamp=timestamp(t_ns),
        frame_id=frame_id,
        width=max(1, round(width * scale)),
        height=max(1, round(height * scale)),
        distortion_model=model,
        D=[float(v) for v in d],
        K=[float(v) for v in Ks.reshape(9)],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[float(v) for v in P.reshape(12)],
    )


def float_image(t_ns: int, values: np.ndarray, frame_id: str) -> RawImage:
    """A ``foxglove.RawImage`` with encoding ``32FC1`` (little-endian float32, NaN invalid).

    Raises:
        GeometryError: not a 2-D array.
    """
    arr = np.asarray(values)
    if arr.ndim != 2:
        raise GeometryError(f"expected an (H, W) float image, got shape {arr.shape}")
    data = np.ascontiguousarray(arr, dtype="<f4")
    h, w = data.shape
    return RawImage(
        timestamp=timestamp(t_ns),
        frame_id=frame_id,
        width=w,
        height=h,
        encoding="32FC1",
        step=4 * w,
        data=data.tobytes(),
    )


def imu_message(
    t_ns: int, accel_mps2: Sequence[float], gyro_radps: Sequence[float]
) -> dict[str, Any]:
    """The JSON ``sea3d.Imu`` message (see :data:`IMU_SCHEMA`)."""
    a = [float(v) for v in accel_mps2]
    g = [float(v) for v in gyro_radps]
    return {
        "timestamp": _stamp_json(t_ns),
        "frame_id": "imu",
        "linear_acceleration": {"x": a[0], "y": a[1], "z": a[2]},
        "angular_velocity": {"x": g[0], "y": g[1], "z": g[2]},
    }


def sonar_message(
    t_ns: int, range_m: float, confidence: float, field_of_view_rad: float
) -> dict[str, Any]:
    """The JSON ``sea3d.Range`` message (see :data:`SONAR_SCHEMA`; NaN becomes null)."""
    return {
        "timestamp": _stamp_json(t_ns),
        "frame_id": "sonar",
        "range_m": _finite_or_none(range_m),
        "confidence": _finite_or_none(confidence),
        "field_of_view_rad": float(field_of_view_rad),
    }


def _vec_quat(T: np.ndarray) -> tuple[Vector3, Quaternion]:
    T = check_T(T, "T")
    q = R_to_quat_wxyz(T[:3, :3])
    return (
        Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
    )


def pose(T: np.ndarray) -> Pose:
    """A ``foxglove.Pose`` (position, orientation) of a 4x4 rigid transform.

    Raises:
        GeometryError: ``T`` is not a rigid 4x4 transform.
    """
    position, orientation = _vec_quat(T)
    return Pose(position=position, orientation=orientation)


def frame_transform(
    t_ns: int, parent: str, child: str, T_parent_child: np.ndarray
) -> FrameTransform:
    """``foxglove.FrameTransform``: ``child``'s pose in ``parent`` (``T_parent_child``)."""
    translation, rotation = _vec_quat(T_parent_child)
    return FrameTransform(
        timestamp=timestamp(t_ns),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=translation,
        rotation=rotation,
    )


def frame_transforms(items: Sequence[FrameTransform]) -> FrameTransforms:
    """``foxglove.FrameTransforms`` of several transforms."""
    return FrameTransforms(transforms=list(items))


def pose_in_frame(t_ns: int, frame_id: str, T: np.ndarray) -> PoseInFrame:
    """``foxglove.PoseInFrame`` of one pose ``T_frame_x``."""
    return PoseInFrame(timestamp=timestamp(t_ns), frame_id=frame_id, pose=pose(T))


def poses_in_frame(t_ns: int, frame_id: str, Ts: np.ndarray) -> PosesInFrame:
    """``foxglove.PosesInFrame`` of ``(N, 4, 4)`` poses (a trajectory)."""
    return PosesInFrame(
        timestamp=timestamp(t_ns), frame_id=frame_id, poses=[pose(T) for T in np.asarray(Ts)]
    )


def point_cloud(
    t_ns: int, frame_id: str, points: np.ndarray, colors_rgb: np.ndarray | None = None
) -> PointCloud:
    """``foxglove.PointCloud`` of ``(N, 3)`` points (metres, stored float32) with optional
    ``(N, 3)`` uint8 RGB colours (stored as ``red, green, blue, alpha`` uint8 fields).

    Raises:
        GeometryError: shapes that do not match.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise GeometryError(f"points must be (N, 3), got {pts.shape}")
    n = pts.shape[0]
    f32 = PackedElementFieldNumericType.Float32
    u8 = PackedElementFieldNumericType.Uint8
    fields = [
        PackedElementField(name="x", offset=0, type=f32),
        PackedElementField(name="y", offset=4, type=f32),
        PackedElementField(name="z", offset=8, type=f32),
    ]
    if colors_rgb is None:
        rec = np.ascontiguousarray(pts, dtype="<f4")
        stride = 12
    else:
        col = np.asarray(colors_rgb)
        if col.shape != (n, 3):
            raise GeometryError(f"colours must be (N, 3) = ({n}, 3), got {col.shape}")
        dtype = np.dtype([("xyz", "<f4", 3), ("rgba", "u1", 4)])
        rec = np.empty(n, dtype=dtype)
        rec["xyz"] = pts
        rec["rgba"][:, :3] = np.clip(col, 0, 255).astype(np.uint8)
        rec["rgba"][:, 3] = 255
        stride = 16
        fields += [
            PackedElementField(name=c, offset=12 + k, type=u8)
            for k, c in enumerate(("red", "green", "blue", "alpha"))
        ]
    return PointCloud(
        timestamp=timestamp(t_ns),
        frame_id=frame_id,
        pose=pose(np.eye(4)),
        point_stride=stride,
        fields=fields,
        data=rec.tobytes(),
    )


SCENE_UPDATE_SCHEMA = SceneUpdate.get_schema()
"""The protobuf schema (FileDescriptorSet) of ``foxglove.SceneUpdate``, for a channel that
carries :func:`mesh_scene`'s bytes (message encoding ``protobuf``)."""


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b, n = n & 0x7F, n >> 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _field(number: int, payload: bytes) -> bytes:
    """A length-delimited protobuf field (wire type 2)."""
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


# Protobuf wire tags of the fixed-size fields (field number << 3 | wire type; 1: 64-bit).
_DOUBLE_TAGS = (0x09, 0x11, 0x19, 0x21)  # fields 1..4 as doubles
_POINT3 = np.dtype([("tag", "u1"), ("len", "u1"), ("tx", "u1"), ("x", "<f8"), ("ty", "u1"),
                    ("y", "<f8"), ("tz", "u1"), ("z", "<f8")])
_COLOR = np.dtype([("tag", "u1"), ("len", "u1"), ("tr", "u1"), ("r", "<f8"), ("tg", "u1"),
                   ("g", "<f8"), ("tb", "u1"), ("b", "<f8"), ("ta", "u1"), ("a", "<f8")])


def _point3_fields(number: int, xyz: np.ndarray) -> bytes:
    """``repeated Point3`` field ``number`` of (N, 3) float64 points, one 29-byte record each:
    tag, length 27, then x, y, z as tagged doubles (fields 1, 2, 3)."""
    rec = np.empty(len(xyz), _POINT3)
    rec["tag"], rec["len"] = number << 3 | 2, _POINT3.itemsize - 2
    rec["tx"], rec["ty"], rec["tz"] = _DOUBLE_TAGS[:3]
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return rec.tobytes()


def _color_fields(number: int, rgba: np.ndarray) -> bytes:
    """``repeated Color`` field ``number`` of (N, 4) float64 RGBA in 0..1 (38 bytes each)."""
    rec = np.empty(len(rgba), _COLOR)
    rec["tag"], rec["len"] = number << 3 | 2, _COLOR.itemsize - 2
    rec["tr"], rec["tg"], rec["tb"], rec["ta"] = _DOUBLE_TAGS
    rec["r"], rec["g"], rec["b"], rec["a"] = rgba[:, 0], rgba[:, 1], rgba[:, 2], rgba[:, 3]
    return rec.tobytes()


def mesh_scene(
    t_ns: int,
    frame_id: str,
    vertices: np.ndarray,
    triangles: np.ndarray,
    vertex_colors_rgb: np.ndarray | None = None,
    *,
    entity_id: str = "mesh",
) -> bytes:
    """A ``foxglove.SceneUpdate`` with one entity holding the mesh as an indexed triangle
    list, protobuf-encoded (:data:`SCENE_UPDATE_SCHEMA`) straight from the arrays: a
    100,000-vertex mesh takes milliseconds (building one ``Point3`` object per vertex took
    about 0.2 CPU-s). Log it on a channel with that schema and message encoding
    ``protobuf``.

    Field numbers are those of the schema (foxglove/SceneUpdate.proto and the messages it
    uses): ``SceneUpdate.entities`` 2; ``SceneEntity`` timestamp 1, frame_id 2, id 3,
    triangles 12; ``TriangleListPrimitive`` pose 1, points 2, color 3, colors 4, indices 5
    (packed fixed32). Every double is written, zeros too (a proto3 reader takes an explicit
    zero as the default).

    Args:
        t_ns: stamp.
        frame_id: frame the vertices are in.
        vertices: (V, 3) metres.
        triangles: (T, 3) vertex indices.
        vertex_colors_rgb: (V, 3) uint8 RGB, or None for a uniform grey.
        entity_id: the scene entity's id.

    Returns:
        The encoded message.

    Raises:
        GeometryError: bad shapes, indices out of range, or a stamp before 0.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3:
        raise GeometryError(
            f"mesh needs (V, 3) vertices and (T, 3) triangles, got {v.shape}, {tri.shape}"
        )
    if tri.size and (tri.min() < 0 or tri.max() >= v.shape[0]):
        raise GeometryError(f"triangle indices must lie in 0..{v.shape[0] - 1}")
    timestamp(t_ns)  # checks the stamp
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    # identity pose: position (field 1) all zeros, orientation (field 2) w (field 4) = 1
    pose_bytes = _field(1, b"") + _field(2, bytes([_DOUBLE_TAGS[3]]) + struct.pack("<d", 1.0))
    prim_parts = [_field(1, pose_bytes), _point3_fields(2, v),
                  _color_fields(3, np.array([[0.7, 0.7, 0.7, 1.0]]))]
    if vertex_colors_rgb is not None:
        col = np.asarray(vertex_colors_rgb, dtype=np.float64)
        if col.shape != v.shape:
            raise GeometryError(f"vertex colours must be {v.shape}, got {col.shape}")
        rgba = np.concatenate([col / 255.0, np.ones((len(col), 1))], axis=1)
        prim_parts.append(_color_fields(4, rgba))
    if tri.size:
        prim_parts.append(_field(5, np.ascontiguousarray(tri.reshape(-1), "<u4").tobytes()))
    prim = b"".join(prim_parts)
    entity = b"".join([
        _field(1, _varint(1 << 3) + _varint(sec) + _varint(2 << 3) + _varint(nsec)),
        _field(2, frame_id.encode()),
        _field(3, entity_id.encode()),
        _field(12, prim),
    ])
    return _field(2, entity)


def scene_deletions(t_ns: int, entity_ids: Sequence[str]) -> bytes:
    """A ``foxglove.SceneUpdate`` deleting the entities ``entity_ids`` (matching id),
    protobuf-encoded like :func:`mesh_scene`."""
    dels = [SceneEntityDeletion(timestamp=timestamp(t_ns),
                                type=SceneEntityDeletionType.MatchingId, id=e)
            for e in entity_ids]
    return bytes(SceneUpdate(deletions=dels).encode())
