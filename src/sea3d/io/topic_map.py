"""Other cameras' recordings: ROS 2 bags (rosbag2 folders, sqlite3 or MCAP storage) and
MCAP files, read through a map from sea3d's roles to the file's topics.

Roles: ``left``, ``right`` (a stereo pair's images), ``color`` and ``depth`` (an RGB-D
camera's registered colour and depth), their ``*_info`` (``sensor_msgs/CameraInfo``), ``imu``
(``sensor_msgs/Imu``) and ``sonar`` (``sensor_msgs/Range``). Presets hold the topic layouts of
the common ROS 2 drivers; ``role=/topic`` entries override them:

==============  ==================================================================================
``oak-d``       depthai-ros (``depthai_ros_driver``, namespace ``/oak``): ``/oak/left|right/
                image_raw``, ``/oak/rgb/image_raw``, ``/oak/stereo/image_raw`` (depth, 16UC1 mm,
                aligned to the RGB camera by default), their ``camera_info``, ``/oak/imu/data``
``zed``         zed-ros2-wrapper (``/zed/zed_node``): ``left|right/image_rect_color``,
                ``depth/depth_registered`` (32FC1 m, registered to the left camera),
                ``imu/data``
``realsense``   realsense-ros 4.x (``/camera/camera``): ``infra1|infra2/image_rect_raw``,
                ``color/image_raw``, ``aligned_depth_to_color/image_raw`` (16UC1 mm), ``imu``
==============  ==================================================================================

Images: ``sensor_msgs/Image`` in ``mono8``, ``mono16``, ``rgb8``, ``bgr8``, ``rgba8``,
``bgra8``, ``8UC1``, ``8UC3``, ``16UC1`` (depth in millimetres, 0 invalid) and ``32FC1``
(depth in metres; 0, NaN, inf invalid), and ``sensor_msgs/CompressedImage`` in ``jpeg`` and
``png``, including image_transport's ``compressedDepth`` (a 12-byte header, then PNG of 16-bit
millimetres, or of quantised inverse depth for 32FC1: ``z = a / (q - b)``). Depth comes back
as float32 metres with NaN invalid; stamps are the messages' header stamps (the sensor's time),
the bag's receive time where a header has none.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sea3d.errors import SessionError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.io.session.common import decode_image
from sea3d.io.session.ros_messages import raw_image_array

__all__ = [
    "PRESETS",
    "ROLES",
    "BagCamera",
    "MappedBag",
    "TopicMap",
    "export_rgbd",
    "export_session",
    "parse_topic_args",
]

_log = logging.getLogger(__name__)

ROLES = (
    "left", "right", "color", "depth", "left_info", "right_info", "color_info", "depth_info",
    "imu", "sonar",
)  # fmt: skip
IMAGE_ROLES = ("left", "right", "color", "depth")

PRESETS: dict[str, dict[str, str]] = {
    "oak-d": {
        "left": "/oak/left/image_raw",
        "right": "/oak/right/image_raw",
        "color": "/oak/rgb/image_raw",
        "depth": "/oak/stereo/image_raw",
        "left_info": "/oak/left/camera_info",
        "right_info": "/oak/right/camera_info",
        "color_info": "/oak/rgb/camera_info",
        "depth_info": "/oak/stereo/camera_info",
        "imu": "/oak/imu/data",
    },
    "zed": {
        "left": "/zed/zed_node/left/image_rect_color",
        "right": "/zed/zed_node/right/image_rect_color",
        "color": "/zed/zed_node/left/image_rect_color",
        "depth": "/zed/zed_node/depth/depth_registered",
        "left_info": "/zed/zed_node/left/camera_info",
        "right_info": "/zed/zed_node/right/camera_info",
        "color_info": "/zed/zed_node/left/camera_info",
        "depth_info": "/zed/zed_node/depth/camera_info",
        "imu": "/zed/zed_node/imu/data",
    },
    "realsense": {
        "left": "/camera/camera/infra1/image_rect_raw",
        "right": "/camera/camera/infra2/image_rect_raw",
        "color": "/camera/camera/color/image_raw",
        "depth": "/camera/camera/aligned_depth_to_color/image_raw",
        "left_info": "/camera/camera/infra1/camera_info",
        "right_info": "/camera/camera/infra2/camera_info",
        "color_info": "/camera/camera/color/camera_info",
        "depth_info": "/camera/camera/aligned_depth_to_color/camera_info",
        "imu": "/camera/camera/imu",
    },
}


def parse_topic_args(items: Sequence[str]) -> dict[str, str]:
    """``["left=/oak/left/image_raw", ...]`` -> ``{"left": "/oak/left/image_raw", ...}``;
    ``"imu="`` maps a role to "" (drop it from a preset).

    Raises:
        SessionError: an entry without ``=``, an unknown role, or a topic not starting with /.
    """
    out: dict[str, str] = {}
    for item in items:
        role, sep, topic = item.partition("=")
        role = role.strip()
        if not sep or not role:
            raise SessionError(f"a topic entry expects ROLE=/topic, got {item!r}")
        if role not in ROLES:
            raise SessionError(
                f"unknown role {role!r} in topic entry {item!r}; roles: {', '.join(ROLES)}"
            )
        topic = topic.strip()
        if topic and not topic.startswith("/"):
            raise SessionError(f"topic of {role} must start with '/', got {topic!r}")
        out[role] = topic
    return out


@dataclass(frozen=True)
class TopicMap:
    """Which topic fills which role (roles not named are simply absent).

    Attributes:
        topics: role -> topic.
    """

    topics: dict[str, str] = field(default_factory=dict)

    @classmethod
    def build(
        cls, preset: str | None = None, overrides: Mapping[str, str] | None = None
    ) -> TopicMap:
        """A preset's layout (or none) with ``overrides`` on top; ``role=`` "" removes a role.

        Raises:
            SessionError: an unknown preset.
        """
        if preset is not None and preset not in PRESETS:
            raise SessionError(f"unknown preset {preset!r}; choose {', '.join(PRESETS)}")
        topics = dict(PRESETS[preset]) if preset else {}
        for role, topic in (overrides or {}).items():
            if topic:
                topics[role] = topic
            else:
                topics.pop(role, None)
        return cls(topics)


@dataclass(frozen=True, kw_only=True, eq=False)
class BagCamera:
    """What a ``sensor_msgs/CameraInfo`` says.

    Attributes:
        pinhole: K and D as a :class:`~sea3d.geometry.pinhole.PinholeCamera`.
        R: (3, 3) rectification rotation (raw camera -> rectified).
        P: (3, 4) projection matrix of the rectified camera.
        frame_id: the message's frame.
    """

    pinhole: PinholeCamera
    R: np.ndarray
    P: np.ndarray
    frame_id: str


def _stamp(msg: Any, fallback: int) -> int:
    h = getattr(msg, "header", None)
    if h is None:
        return int(fallback)
    t = int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    return t if t > 0 else int(fallback)


def image_from_message(msg: Any, where: str, *, depth: bool) -> np.ndarray:
    """A ``sensor_msgs/Image`` or ``CompressedImage`` as an array: RGB (or grey) for images,
    float32 metres with NaN invalid for depth (``depth=True``).

    Raises:
        SessionError: an encoding sea3d does not read, or damaged data (``where`` named).
    """
    if hasattr(msg, "format"):
        return _decode_compressed(msg, where, depth=depth)
    img = raw_image_array(msg, where)
    if depth:
        img = _to_metres(img, str(msg.encoding).lower(), where)
    return img


def _to_metres(img: np.ndarray, enc: str, where: str) -> np.ndarray:
    if img.ndim != 2:
        raise SessionError(f"{where}: depth must be one channel, got {img.shape}")
    if img.dtype == np.uint16:
        out = img.astype(np.float32) * np.float32(1e-3)
        out[img == 0] = np.nan
        return out
    if img.dtype == np.float32:
        out = img.astype(np.float32, copy=True)
        out[~np.isfinite(out) | (out <= 0)] = np.nan
        return out
    raise SessionError(f"{where}: depth encoding {enc!r} is neither 16UC1 (mm) nor 32FC1 (m)")


def _decode_compressed(msg: Any, where: str, *, depth: bool) -> np.ndarray:
    fmt = str(msg.format).lower()
    data = np.asarray(msg.data, dtype=np.uint8)
    if "compresseddepth" in fmt:
        # image_transport compressed_depth: ConfigHeader {int32 format; float depthParam[2]}
        if data.size < 12:
            raise SessionError(f"{where}: compressedDepth message of {data.size} bytes")
        qa, qb = np.frombuffer(data[4:12].tobytes(), "<f4")
        img = cv2.imdecode(data[12:], cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SessionError(f"{where}: compressedDepth data does not decode")
        if fmt.startswith("32fc1"):
            q = img.astype(np.float32)
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.float32(qa) / (q - np.float32(qb))
            z[q == 0] = np.nan
            return _to_metres(z.astype(np.float32), "32fc1", where)
        return _to_metres(img.astype(np.uint16), "16uc1", where)
    img = decode_image(data, where)
    return _to_metres(img, fmt, where) if depth else img


def camera_from_info(msg: Any, where: str) -> BagCamera:
    """A :class:`BagCamera` from ``sensor_msgs/CameraInfo`` (plumb_bob or
    rational_polynomial distortion; an all-zero K is refused).

    Raises:
        SessionError: no intrinsics, or a distortion model sea3d does not read.
    """
    K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise SessionError(f"{where}: camera_info has no intrinsics (K = {K.ravel().tolist()})")
    model = str(msg.distortion_model).lower()
    d = np.asarray(msg.d, dtype=np.float64).reshape(-1)
    if model not in ("plumb_bob", "rational_polynomial", "") and np.any(d != 0):
        raise SessionError(f"{where}: distortion model {msg.distortion_model!r} is not supported")
    if d.size not in (0, 4, 5, 8, 12, 14):
        raise SessionError(
            f"{where}: {d.size} distortion coefficients; expected 0, 4, 5, 8, 12 or 14"
        )
    pin = PinholeCamera(
        fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
        width=int(msg.width), height=int(msg.height), dist=d,
    )  # fmt: skip
    R: np.ndarray = np.asarray(msg.r, dtype=np.float64).reshape(3, 3)
    if not np.any(R):
        R = np.eye(3)
    P = np.asarray(msg.p, dtype=np.float64).reshape(3, 4)
    return BagCamera(pinhole=pin, R=R, P=P, frame_id=str(msg.header.frame_id))


class MappedBag:
    """A ROS 2 bag or MCAP file read through a :class:`TopicMap`.

    Args:
        path: a rosbag2 folder (``metadata.yaml``, sqlite3 or MCAP storage) or an ``.mcap``
            / ``.db3`` file.
        topic_map: role -> topic.

    Raises:
        SessionError: the file cannot be opened, or a mapped topic is not in it (the topic,
            its role, and the topics the file has are named).
    """

    def __init__(self, path: str | os.PathLike[str], topic_map: TopicMap) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if not self.path.exists():
            raise SessionError(f"bag {self.path} does not exist")
        if not topic_map.topics:
            raise SessionError("no topics mapped: build the TopicMap from a preset or "
                               "role=/topic overrides")
        self.topic_map = topic_map
        try:
            self._reader = AnyReader(
                [self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)
            )
            self._reader.open()
        except Exception as err:  # rosbags raises its own error types
            raise SessionError(f"cannot open bag {self.path}: {err}") from err
        self.topics = {c.topic: c.msgtype for c in self._reader.connections}
        missing = [(r, t) for r, t in topic_map.topics.items() if t not in self.topics]
        if missing:
            self._reader.close()
            names = ", ".join(f"{t} (mapped as {r})" for r, t in missing)
            have = ", ".join(sorted(self.topics)) or "none"
            raise SessionError(f"{self.path} lacks {names}; its topics: {have}")
        self._cache_info: dict[str, BagCamera] = {}

    def close(self) -> None:
        """Close the file."""
        self._reader.close()

    def __enter__(self) -> MappedBag:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def has(self, role: str) -> bool:
        """Whether ``role`` is mapped."""
        return role in self.topic_map.topics

    def messages(self, role: str, *, limit: int | None = None) -> Iterator[tuple[int, Any]]:
        """``(t_ns, decoded message)`` of one role in file order; damaged ones are skipped
        with a warning."""
        topic = self.topic_map.topics[role]
        conns = [c for c in self._reader.connections if c.topic == topic]
        n = 0
        for conn, t_bag, raw in self._reader.messages(connections=conns):
            try:
                msg = self._reader.deserialize(raw, conn.msgtype)
            except Exception as err:
                _log.warning(
                    "%s topic %s at %d: cannot decode (%s); skipped", self.path, topic, t_bag, err
                )
                continue
            yield _stamp(msg, t_bag), msg
            n += 1
            if limit is not None and n >= limit:
                return

    def images(self, role: str, *, limit: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """``(t_ns, image)`` of an image role: RGB/grey arrays, or float32 metres for
        ``depth``; undecodable ones are skipped with a warning."""
        topic = self.topic_map.topics[role]
        for t, msg in self.messages(role, limit=limit):
            where = f"{self.path} topic {topic} t_ns={t}"
            try:
                yield t, image_from_message(msg, where, depth=role == "depth")
            except SessionError as err:
                _log.warning("%s; skipped", err)

    def camera(self, role: str) -> BagCamera | None:
        """The first ``camera_info`` of ``left``/``right``/``color``/``depth``, or None."""
        info = f"{role}_info"
        if info not in self.topic_map.topics:
            return None
        if info not in self._cache_info:
            for _t, msg in self.messages(info, limit=1):
                self._cache_info[info] = camera_from_info(
                    msg, f"{self.path} topic {self.topic_map.topics[info]}"
                )
        return self._cache_info.get(info)

    def stereo_rig(self) -> Any:
        """The stereo rig from the left and right camera_info (ROS convention: ``R`` takes
        raw camera points into the rectified frame, ``P_right[0, 3] = -f B``).

        Raises:
            SessionError: a missing camera_info or a right P without a baseline.
        """
        from sea3d.geometry.rig import StereoRig

        left, right = self.camera("left"), self.camera("right")
        if left is None or right is None:
            raise SessionError(
                f"{self.path}: the stereo rig needs left_info and right_info (CameraInfo) topics"
            )
        fx = right.P[0, 0]
        if not fx > 0 or right.P[0, 3] == 0:
            raise SessionError(
                f"{self.path}: right camera_info's P has no baseline (P[0,3] = {right.P[0, 3]})"
            )
        B = -right.P[0, 3] / fx
        # p_rect_right = p_rect_left - (B, 0, 0); p_rect = R p_raw
        T_right_left = np.eye(4)
        T_right_left[:3, :3] = right.R.T @ left.R
        T_right_left[:3, 3] = -right.R.T @ np.array([B, 0.0, 0.0])
        from sea3d.geometry.se3 import invert_T

        return StereoRig(
            left=left.pinhole, right=right.pinhole, T_left_right=invert_T(T_right_left)
        )


def _pairs_by_stamp(
    a: list[tuple[int, Any]], b: list[tuple[int, Any]], tol_ns: int
) -> list[tuple[tuple[int, Any], tuple[int, Any]]]:
    from sea3d.io.session.common import match_stamps

    ta = np.array([t for t, _ in a], dtype=np.int64)
    tb = np.array([t for t, _ in b], dtype=np.int64)
    oa, ob = np.argsort(ta, kind="stable"), np.argsort(tb, kind="stable")
    ia, ib = match_stamps(ta[oa], tb[ob], tol_ns)
    return [(a[int(oa[i])], b[int(ob[j])]) for i, j in zip(ia.tolist(), ib.tolist(), strict=True)]


def _tolerance(stamps: Sequence[int]) -> int:
    t = np.sort(np.asarray(stamps, dtype=np.int64))
    return int(np.median(np.diff(t)) // 2) if t.size > 1 else 10_000_000


def export_session(
    bag: MappedBag,
    out: str | os.PathLike[str],
    *,
    max_frames: int | None = None,
    image_encoding: str = "png",
) -> dict[str, Any]:
    """Write the bag's stereo pair (``left``, ``right``), IMU and echosounder as a sea3d
    session, with the rig from the camera_info topics, so ``sea3d depth``, ``sea3d process``
    and ``sea3d eval`` run on it.

    Returns:
        Counts per stream, pairs unmatched, and the rig's baseline.

    Raises:
        SessionError: no left/right roles, or the output exists.
    """
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter

    if not (bag.has("left") and bag.has("right")):
        raise SessionError(f"{bag.path}: a stereo session needs the left and right roles mapped")
    rig = bag.stereo_rig()
    lefts = list(bag.images("left", limit=max_frames))
    rights = list(bag.images("right", limit=None if max_frames is None else 2 * max_frames))
    pairs = _pairs_by_stamp(lefts, rights, _tolerance([t for t, _ in lefts]))
    with SessionWriter(out, rig_yaml=rig_to_yaml(rig), image_encoding=image_encoding) as w:
        for (t, left), (_tr, right) in pairs:
            w.write_stereo(t, left, right)
        if bag.has("imu"):
            for t, m in sorted(bag.messages("imu"), key=lambda x: x[0]):
                a, g = m.linear_acceleration, m.angular_velocity
                try:
                    w.write_imu(t, [a.x, a.y, a.z], [g.x, g.y, g.z])
                except SessionError as err:
                    _log.warning("imu sample skipped: %s", err)
        if bag.has("sonar"):
            for t, m in sorted(bag.messages("sonar"), key=lambda x: x[0]):
                try:
                    w.write_sonar(t, float(m.range), float("nan"))
                except SessionError as err:
                    _log.warning("echosounder sample skipped: %s", err)
    counts = dict(w.counts)  # after close: the writer counts only what reached the file
    return {
        "counts": counts,
        "unpaired_left": len(lefts) - len(pairs),
        "unpaired_right": len(rights) - len(pairs),
        "baseline_m": rig.baseline_m,
        "size": [rig.width, rig.height],
    }


def export_rgbd(
    bag: MappedBag, out_dir: str | os.PathLike[str], *, max_frames: int | None = None
) -> dict[str, Any]:
    """Write registered colour and depth frames as files for RGB-D tools (``sea3d fuse``, the
    RGB-D odometry): ``color/<t_ns>.png``, ``depth/<t_ns>.png`` (16-bit millimetres, 0
    invalid: depth scale 1000), ``intrinsics.json`` (the depth camera's ``fx fy cx cy``, size,
    depth scale) and ``associations.txt`` (TUM RGB-D layout: ``t color t depth``, seconds).

    Colour and depth are paired by nearest stamp within half a frame interval; a depth
    image of another size than the colour is refused (map a registered depth topic).

    Returns:
        Frames written, unpaired counts and the intrinsics.

    Raises:
        SessionError: no color/depth roles, unregistered sizes, or an existing folder.
    """
    out = Path(out_dir)
    if not (bag.has("color") and bag.has("depth")):
        raise SessionError(f"{bag.path}: RGB-D export needs the color and depth roles mapped")
    if out.exists() and any(out.iterdir()):
        raise SessionError(f"{out} exists and is not empty; refusing to mix frames into it")
    (out / "color").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    colors = list(bag.images("color", limit=max_frames))
    depths = list(bag.images("depth", limit=None if max_frames is None else 2 * max_frames))
    pairs = _pairs_by_stamp(colors, depths, _tolerance([t for t, _ in colors]))
    cam = bag.camera("depth") or bag.camera("color")
    lines = ["# color and depth images, TUM RGB-D association layout (t in seconds)"]
    written = 0
    for (tc, color), (td, depth) in pairs:
        if color.shape[:2] != depth.shape:
            raise SessionError(
                f"{bag.path}: colour {color.shape[1]}x{color.shape[0]} and depth "
                f"{depth.shape[1]}x{depth.shape[0]} differ: map a depth topic registered to "
                "the colour camera (aligned_depth_to_color, depth_registered)"
            )
        bgr = cv2.cvtColor(color, cv2.COLOR_RGB2BGR) if color.ndim == 3 else color
        mm = np.where(np.isfinite(depth), np.clip(np.round(depth * 1000.0), 0, 65535), 0)
        ok_c = cv2.imwrite(str(out / "color" / f"{tc}.png"), bgr)
        ok_d = cv2.imwrite(str(out / "depth" / f"{tc}.png"), mm.astype(np.uint16))
        if not (ok_c and ok_d):
            raise SessionError(f"cannot write frames into {out}")
        lines.append(f"{tc * 1e-9:.9f} color/{tc}.png {td * 1e-9:.9f} depth/{tc}.png")
        written += 1
    (out / "associations.txt").write_text("\n".join(lines) + "\n")
    intr: dict[str, Any] = {"depth_scale": 1000.0}
    if cam is not None:
        p = cam.pinhole
        intr.update(fx=p.fx, fy=p.fy, cx=p.cx, cy=p.cy, width=p.width, height=p.height,
                    frame_id=cam.frame_id)  # fmt: skip
    (out / "intrinsics.json").write_text(json.dumps(intr, indent=1))
    return {
        "frames": written,
        "unpaired_color": len(colors) - written,
        "unpaired_depth": len(depths) - written,
        "intrinsics": intr,
    }
