"""ROS 2 messages of a sea3d MCAP session: topics, the rosbags type store, and the CDR of
each record (camera image and info, IMU, range) built from sea3d's values (the serialised
bytes, as the memoryview rosbags returns: no copy of an image); and the pixels of a raw
``sensor_msgs/Image`` read back, for sessions and other tools' bags alike."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.io.session.common import check_rig_yaml

TOPICS = {
    "left": "/cam/left/image",
    "right": "/cam/right/image",
    "left_info": "/cam/left/camera_info",
    "right_info": "/cam/right/camera_info",
    "imu": "/imu",
    "sonar": "/sonar",
    "sonar_confidence": "/sonar/confidence",
}
STREAM_OF_TOPIC = {v: k for k, v in TOPICS.items()}
# Also accept image_transport's conventional names when reading other tools' files.
STREAM_OF_TOPIC.update(
    {"/cam/left/image/compressed": "left", "/cam/right/image/compressed": "right"}
)

RIG_ATTACHMENT = "rig.yaml"
METADATA_NAME = "sea3d"
SONAR_FOV_RAD = 0.5236  # 30 degree beam of a Ping-style echosounder
SONAR_MIN_RANGE_M = 0.3
SONAR_MAX_RANGE_M = 100.0


@lru_cache(maxsize=1)
def typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def camera_info_params(
    rig_yaml: str | None, path: Path
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """K (3,3) and distortion per side from the rig text; {} without a rig.

    Raises:
        SessionError: the rig text is not a valid rig (it would give K = 0 in every
            camera_info while claiming a calibrated session).
    """
    rig = check_rig_yaml(rig_yaml, path)
    if rig is None:
        return {}
    out = {}
    for side in ("left", "right"):
        pin = (rig.left if side == "left" else rig.right).lens
        out[side] = (np.asarray(pin.K, dtype=np.float64), np.asarray(pin.dist, dtype=np.float64))
    return out


def stamp_msg(ts: Any, t_ns: int, frame_id: str) -> Any:
    time_t = ts.types["builtin_interfaces/msg/Time"]
    header_t = ts.types["std_msgs/msg/Header"]
    return header_t(
        stamp=time_t(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id
    )


def camera_info_cdr(
    ts: Any, stream: str, t_ns: int, height: int, width: int, k: np.ndarray, dist: np.ndarray
) -> memoryview:
    """``sensor_msgs/CameraInfo`` of one image: K (3, 3), distortion (plumb_bob, or
    rational_polynomial with 8 or more coefficients), R = I, P = [K | 0]."""
    p = np.zeros((3, 4))
    p[:, :3] = k
    model = "rational_polynomial" if dist.size >= 8 else "plumb_bob"
    roi_t = ts.types["sensor_msgs/msg/RegionOfInterest"]
    msg = ts.types["sensor_msgs/msg/CameraInfo"](
        header=stamp_msg(ts, t_ns, stream),
        height=height,
        width=width,
        distortion_model=model,
        d=np.asarray(dist, np.float64),
        k=k.reshape(9).astype(np.float64),
        r=np.eye(3).reshape(9),
        p=p.reshape(12),
        binning_x=0,
        binning_y=0,
        roi=roi_t(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
    return ts.serialize_cdr(msg, "sensor_msgs/msg/CameraInfo")


def compressed_image_cdr(ts: Any, stream: str, t_ns: int, data: bytes, fmt: str) -> memoryview:
    """``sensor_msgs/CompressedImage`` holding ``data`` (png, jxl or jpeg bytes)."""
    msg = ts.types["sensor_msgs/msg/CompressedImage"](
        header=stamp_msg(ts, t_ns, stream),
        format=fmt,
        data=np.frombuffer(data, dtype=np.uint8),
    )
    return ts.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage")


def raw_image_cdr(ts: Any, stream: str, t_ns: int, image: np.ndarray) -> memoryview:
    """``sensor_msgs/Image`` (mono8, rgb8, mono16 or rgb16, little-endian) of ``image``."""
    channels = 1 if image.ndim == 2 else 3
    bits = 8 if image.dtype == np.uint8 else 16
    encoding = {(1, 8): "mono8", (3, 8): "rgb8", (1, 16): "mono16", (3, 16): "rgb16"}[
        (channels, bits)
    ]
    data = (
        np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("<")).view(np.uint8).reshape(-1)
    )
    h, w = image.shape[:2]
    msg = ts.types["sensor_msgs/msg/Image"](
        header=stamp_msg(ts, t_ns, stream),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=w * channels * bits // 8,
        data=data,
    )
    return ts.serialize_cdr(msg, "sensor_msgs/msg/Image")


def imu_cdr(ts: Any, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> memoryview:
    """``sensor_msgs/Imu`` (orientation unknown: covariance[0] = -1)."""
    vec_t = ts.types["geometry_msgs/msg/Vector3"]
    quat_t = ts.types["geometry_msgs/msg/Quaternion"]
    unknown = np.zeros(9)
    unknown[0] = -1.0
    msg = ts.types["sensor_msgs/msg/Imu"](
        header=stamp_msg(ts, t_ns, "imu"),
        orientation=quat_t(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=unknown,
        angular_velocity=vec_t(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vec_t(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
        linear_acceleration_covariance=np.zeros(9),
    )
    return ts.serialize_cdr(msg, "sensor_msgs/msg/Imu")


def range_cdr(ts: Any, t_ns: int, range_m: np.float32) -> memoryview:
    """``sensor_msgs/Range`` (ULTRASOUND) of one echosounder reading."""
    msg = ts.types["sensor_msgs/msg/Range"](
        header=stamp_msg(ts, t_ns, "sonar"),
        radiation_type=0,
        field_of_view=SONAR_FOV_RAD,
        min_range=SONAR_MIN_RANGE_M,
        max_range=SONAR_MAX_RANGE_M,
        range=float(range_m),
    )
    return ts.serialize_cdr(msg, "sensor_msgs/msg/Range")


def float32_cdr(ts: Any, value: np.float32) -> memoryview:
    """``std_msgs/Float32`` (the echosounder's confidence)."""
    msg = ts.types["std_msgs/msg/Float32"](data=float(value))
    return ts.serialize_cdr(msg, "std_msgs/msg/Float32")


RAW_IMAGE_ENCODINGS: dict[str, tuple[int, type[np.generic]]] = {
    "mono8": (1, np.uint8),
    "8uc1": (1, np.uint8),
    "rgb8": (3, np.uint8),
    "bgr8": (3, np.uint8),
    "8uc3": (3, np.uint8),
    "rgba8": (4, np.uint8),
    "bgra8": (4, np.uint8),
    "mono16": (1, np.uint16),
    "16uc1": (1, np.uint16),
    "rgb16": (3, np.uint16),
    "bgr16": (3, np.uint16),
    "32fc1": (1, np.float32),
}
"""The raw ``sensor_msgs/Image`` encodings sea3d reads (lower case): channels and dtype."""


def raw_image_array(msg: Any, where: str) -> np.ndarray:
    """The pixels of a raw ``sensor_msgs/Image``: ``(H, W)`` or ``(H, W, 3)`` in the
    encoding's dtype (uint8, uint16 or float32), native byte order, channels RGB (``bgr*``
    reordered, the alpha of ``rgba8``/``bgra8`` dropped); row padding (``step``) is skipped.

    Args:
        msg: the deserialised message (``encoding``, ``height``, ``width``, ``step``,
            ``is_bigendian``, ``data``).
        where: the record, for error messages.

    Raises:
        SessionError: an encoding not in :data:`RAW_IMAGE_ENCODINGS`, an empty image, or
            data shorter than its rows (``where`` named).
    """
    enc = str(msg.encoding).lower()
    if enc not in RAW_IMAGE_ENCODINGS:
        raise SessionError(f"{where}: image encoding {msg.encoding!r} is not supported")
    ch, dtype = RAW_IMAGE_ENCODINGS[enc]
    item = np.dtype(dtype).itemsize
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or raw.size < h * step or step < w * ch * item:
        raise SessionError(f"{where}: image data is {raw.size} bytes, expected {h} rows of {step}")
    stored = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    rows = np.ascontiguousarray(raw[: h * step].reshape(h, step)[:, : w * ch * item])
    img = rows.view(stored).astype(dtype)
    img = img.reshape(h, w, ch) if ch > 1 else img.reshape(h, w)
    if enc.startswith("bgr"):
        img = np.ascontiguousarray(img[..., [2, 1, 0]] if ch == 3 else img[..., [2, 1, 0, 3]])
    if ch == 4:
        img = np.ascontiguousarray(img[..., :3])
    return img
