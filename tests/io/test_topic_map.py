"""Other cameras' ROS 2 bags read by topic map: bags are built here with rosbags' writer in
the layouts of the OAK-D, ZED and RealSense ROS 2 drivers (no downloads).

The scene: a fronto-parallel textured plane seen by a rectified stereo pair (fx 200 px,
baseline 75 mm as the OAK-D's) with a disparity of 10 px, so depth = f B / d = 1.5 m.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from sea3d.cli import main
from sea3d.errors import SessionError
from sea3d.io.session import open_session
from sea3d.io.topic_map import (
    PRESETS,
    MappedBag,
    TopicMap,
    camera_from_info,
    image_from_message,
    parse_topic_args,
)

TS = get_typestore(Stores.ROS2_HUMBLE)
W, H, FX, B, D = 320, 200, 200.0, 0.075, 10
PLANE_M = FX * B / D  # 1.5 m
N = 6
DEPTH_MEDIAN_M = 0.03  # OpenCV SGBM at 320x200 on a clean shifted texture: 2 % at 1.5 m


def _header(t_ns: int, frame: str):
    return TS.types["std_msgs/msg/Header"](
        stamp=TS.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9),
        frame_id=frame,
    )


def _image(t_ns, img, encoding, frame="cam"):
    if img.dtype == np.uint16:
        data = img.astype("<u2").view(np.uint8).reshape(-1)
    elif img.dtype == np.float32:
        data = img.astype("<f4").view(np.uint8).reshape(-1)
    else:
        data = np.ascontiguousarray(img).reshape(-1)
    ch = 1 if img.ndim == 2 else img.shape[2]
    return TS.types["sensor_msgs/msg/Image"](
        header=_header(t_ns, frame), height=img.shape[0], width=img.shape[1], encoding=encoding,
        is_bigendian=0, step=img.shape[1] * ch * img.dtype.itemsize, data=data,
    )  # fmt: skip


def _info(t_ns, frame, *, tx=0.0, R=None, size=(W, H), fx=FX):
    w, h = size
    K = np.array([[fx, 0, (w - 1) / 2], [0, fx, (h - 1) / 2], [0, 0, 1.0]])
    P = np.zeros((3, 4))
    P[:, :3] = K
    P[0, 3] = tx
    roi = TS.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return TS.types["sensor_msgs/msg/CameraInfo"](
        header=_header(t_ns, frame), height=h, width=w, distortion_model="plumb_bob",
        d=np.zeros(5), k=K.reshape(9), r=(np.eye(3) if R is None else R).reshape(9),
        p=P.reshape(12), binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip


def _imu(t_ns, k):
    v = TS.types["geometry_msgs/msg/Vector3"]
    q = TS.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    return TS.types["sensor_msgs/msg/Imu"](
        header=_header(t_ns, "imu"), orientation=q, orientation_covariance=np.zeros(9),
        angular_velocity=v(x=0.01 * k, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=v(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9),
    )  # fmt: skip


def _scene(k):
    rng = np.random.default_rng(k)
    big = cv2.GaussianBlur(rng.random((H, W + D)).astype(np.float32), (0, 0), 1.5)
    big = ((big - big.min()) / (big.max() - big.min()) * 255).astype(np.uint8)
    return big[:, :W].copy(), big[:, D:].copy()


def _write(path, msgs, storage):
    with Writer(path, version=9, storage_plugin=storage) as w:
        conns = {}
        for topic, t, msg, typename in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typename, typestore=TS)
            w.write(conns[topic], t + 1000, TS.serialize_cdr(msg, typename))


@pytest.fixture(scope="module")
def oak_bag(tmp_path_factory):
    """The depthai-ros layout: mono left/right, RGB (bgr8), stereo depth 16UC1 mm aligned to
    RGB, camera_info for each, IMU at 10x the frame rate; MCAP storage."""
    p = PRESETS["oak-d"]
    msgs = []
    depth_mm = np.full((H, W), round(PLANE_M * 1000), np.uint16)
    depth_mm[:5, :5] = 0  # invalid corner
    for k in range(N):
        t = 1_700_000_000_000_000_000 + k * 100_000_000
        left, right = _scene(k)
        img, info = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"
        bgr = np.dstack([left, left // 2, right])
        tr = t + 2000  # the right camera's header stamp, 2 us later
        msgs += [
            (p["left"], t, _image(t, left, "mono8", "oak_left"), img),
            (p["right"], tr, _image(tr, right, "mono8", "oak_right"), img),
            (p["left_info"], t, _info(t, "oak_left"), info),
            (p["right_info"], t, _info(t, "oak_right", tx=-FX * B), info),
            (p["color"], t, _image(t, bgr, "bgr8", "oak_rgb"), img),
            (p["color_info"], t, _info(t, "oak_rgb"), info),
            (p["depth"], t, _image(t, depth_mm, "16UC1", "oak_rgb"), img),
            (p["depth_info"], t, _info(t, "oak_rgb"), info),
        ]
        for j in range(10):
            msgs.append(
                (p["imu"], t + j * 10_000_000, _imu(t + j * 10_000_000, j), "sensor_msgs/msg/Imu")
            )
    path = tmp_path_factory.mktemp("oak") / "oak_bag"
    _write(path, msgs, StoragePlugin.MCAP)
    return path


def test_oak_bag_to_session_then_sea3d_depth(oak_bag, tmp_path, capsys):
    out = tmp_path / "oak.mcap"
    assert main(["bag", "export", str(oak_bag), "--preset", "oak-d", "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["session"]
    assert summary["counts"]["left"] == N and summary["counts"]["imu"] == 10 * N
    assert summary["baseline_m"] == pytest.approx(B, rel=1e-12)
    with open_session(out) as s:
        assert s.stamps("left")[0] == 1_700_000_000_000_000_000  # header stamps, not bag time
        assert s.image("left", 2).shape == (H, W)
        np.testing.assert_array_equal(s.image("left", 2), _scene(2)[0])
    assert main(["depth", "--session", str(out), "-o", str(tmp_path / "d"), "--min-depth", "0.6",
                 "--engine", "opencv", "--json"]) == 0  # fmt: skip
    capsys.readouterr()
    z = cv2.imread(str(next((tmp_path / "d" / "depth").glob("*.png"))), cv2.IMREAD_UNCHANGED)
    z = z.astype(np.float64) / 1000
    assert np.median(z[z > 0]) == pytest.approx(PLANE_M, abs=DEPTH_MEDIAN_M)


def test_oak_bag_to_rgbd_frames(oak_bag, tmp_path, capsys):
    out = tmp_path / "rgbd"
    assert main(["bag", "export", str(oak_bag), "--preset", "oak-d", "--rgbd", str(out)]) == 0
    text = capsys.readouterr().out
    assert "RGB-D frames" in text and "--depth-scale 1000" in text
    colors = sorted((out / "color").glob("*.png"))
    depths = sorted((out / "depth").glob("*.png"))
    assert len(colors) == len(depths) == N
    assert [p.name for p in colors] == [p.name for p in depths]
    d = cv2.imread(str(depths[0]), cv2.IMREAD_UNCHANGED)
    assert d.dtype == np.uint16 and d[100, 100] == 1500 and d[0, 0] == 0
    c = cv2.imread(str(colors[1]))[..., ::-1]  # RGB: bgr8 came in as (left, left/2, right)
    left, right = _scene(1)
    np.testing.assert_array_equal(c[..., 2], left)
    np.testing.assert_array_equal(c[..., 0], right)
    intr = json.loads((out / "intrinsics.json").read_text())
    assert intr["fx"] == FX and intr["cx"] == (W - 1) / 2 and intr["depth_scale"] == 1000.0
    assoc = (out / "associations.txt").read_text().splitlines()
    assert len(assoc) == N + 1 and assoc[1].split()[1] == f"color/{colors[0].name}"


def test_a_topic_the_file_lacks_is_named(oak_bag, capsys):
    argv = ["bag", "export", str(oak_bag), "--preset", "oak-d", "--topic", "left=/oak/nope",
            "-o", "never.mcap"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "lacks /oak/nope (mapped as left)" in err[0] and "/oak/right/image_raw" in err[0]


def test_bag_info_lists_topics_and_roles(oak_bag, capsys):
    assert main(["bag", "info", str(oak_bag), "--preset", "oak-d"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any("/oak/stereo/image_raw" in ln and ln.rstrip().endswith("depth") for ln in lines)
    assert any("/oak/imu/data" in ln and "sensor_msgs/msg/Imu" in ln for ln in lines)


def test_zed_layout_in_sqlite_with_32fc1_depth_and_overrides(tmp_path, capsys):
    """A ZED-like bag (sqlite3 storage) whose depth is 32FC1 metres, with the colour given
    through --topic instead of the preset's."""
    p = PRESETS["zed"]
    msgs = []
    z = np.full((H, W), PLANE_M, np.float32)
    z[0, :] = np.nan
    z[1, :] = 0.0
    z[2, :] = np.inf
    for k in range(3):
        t = 5_000_000_000 + k * 66_666_667
        left, _ = _scene(k)
        rgba = np.dstack([left, left, left, np.full_like(left, 255)])
        msgs += [
            ("/zed/custom/rgb", t, _image(t, rgba, "bgra8"), "sensor_msgs/msg/Image"),
            (p["depth"], t, _image(t, z, "32FC1"), "sensor_msgs/msg/Image"),
            (p["depth_info"], t, _info(t, "zed_left"), "sensor_msgs/msg/CameraInfo"),
        ]  # fmt: skip
    bag = tmp_path / "zed_bag"
    _write(bag, msgs, StoragePlugin.SQLITE3)
    out = tmp_path / "rgbd"
    drop = ["color_info", "left", "right", "left_info", "right_info", "imu"]
    argv = ["bag", "export", str(bag), "--preset", "zed", "--topic", "color=/zed/custom/rgb"]
    for role in drop:
        argv += ["--topic", f"{role}="]
    argv += ["--rgbd", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    d = cv2.imread(str(next((out / "depth").glob("*.png"))), cv2.IMREAD_UNCHANGED)
    assert (d[:3] == 0).all() and (d[3:] == 1500).all()


def test_image_decoding_known_answers():
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    bgr = _image(0, rgb[..., ::-1].copy(), "bgr8")
    np.testing.assert_array_equal(image_from_message(bgr, "t", depth=False), rgb)
    mono16 = np.array([[1, 65535]], np.uint16)
    np.testing.assert_array_equal(
        image_from_message(_image(0, mono16, "mono16"), "t", depth=False), mono16
    )
    mm = np.array([[0, 1234]], np.uint16)
    got = image_from_message(_image(0, mm, "16UC1"), "t", depth=True)
    assert np.isnan(got[0, 0]) and got[0, 1] == pytest.approx(1.234)
    with pytest.raises(SessionError, match="encoding 'yuv422' is not supported"):
        image_from_message(_image(0, rgb, "yuv422"), "t", depth=False)


def test_compressed_depth_formats():
    """image_transport's compressedDepth: 12-byte header (format, quantisation a, b), PNG."""
    mm = np.array([[0, 1000], [2500, 65535]], np.uint16)
    png = cv2.imencode(".png", mm)[1].reshape(-1)
    head = np.frombuffer(
        np.array([0], "<i4").tobytes() + np.array([0, 0], "<f4").tobytes(), np.uint8
    )
    msg16 = TS.types["sensor_msgs/msg/CompressedImage"](
        header=_header(0, "d"),
        format="16UC1; compressedDepth png",
        data=np.concatenate([head, png]),
    )
    got = image_from_message(msg16, "t", depth=True)
    assert np.isnan(got[0, 0]) and got[1, 0] == pytest.approx(2.5)
    # 32FC1: inverse depth quantised as q = a / z + b (a = 100, b = 1000 here)
    a, b = 100.0, 1000.0
    zs = np.array([[2.0, 4.0]], np.float32)
    q = np.round(a / zs + b).astype(np.uint16)
    q[0, 1] = 0  # no depth
    head = np.frombuffer(
        np.array([0], "<i4").tobytes() + np.array([a, b], "<f4").tobytes(), np.uint8
    )
    msg32 = TS.types["sensor_msgs/msg/CompressedImage"](
        header=_header(0, "d"), format="32FC1; compressedDepth png",
        data=np.concatenate([head, cv2.imencode(".png", q)[1].reshape(-1)]),
    )  # fmt: skip
    got = image_from_message(msg32, "t", depth=True)
    assert got[0, 0] == pytest.approx(2.0, rel=1e-3) and np.isnan(got[0, 1])


def test_rig_from_unrectified_camera_infos_matches_opencv():
    """R and P of both camera_info messages as OpenCV's stereoRectify makes them (what ROS
    camera calibration writes) give back the rig's T_left_right."""
    from sea3d.io.topic_map import BagCamera

    rvec = np.array([0.01, -0.02, 0.005])
    R_rl = cv2.Rodrigues(rvec)[0]
    t_rl = np.array([-0.075, 0.002, 0.001])
    K = np.array([[FX, 0, 160], [0, FX, 100], [0, 0, 1.0]])
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K, np.zeros(5), K, np.zeros(5), (W, H), R_rl, t_rl)

    class Fake:
        def __init__(self, cams):
            self.cams = cams
            self.path = "fake"

        def camera(self, role):
            return self.cams[role]

    def cam(R, P):
        msg = _info(0, "x")
        return BagCamera(pinhole=camera_from_info(msg, "x").pinhole, R=R, P=P, frame_id="x")

    rig = MappedBag.stereo_rig(Fake({"left": cam(R1, P1), "right": cam(R2, P2)}))  # type: ignore[arg-type]
    T_right_left = np.linalg.inv(rig.T_left_right)
    np.testing.assert_allclose(T_right_left[:3, :3], R_rl, atol=1e-9)
    np.testing.assert_allclose(T_right_left[:3, 3], t_rl, atol=1e-9)


def test_topic_arguments_and_presets():
    assert parse_topic_args(["left=/a", "depth=/b"]) == {"left": "/a", "depth": "/b"}
    with pytest.raises(SessionError, match="unknown role 'lft'"):
        parse_topic_args(["lft=/a"])
    with pytest.raises(SessionError, match="must start with '/'"):
        parse_topic_args(["left=a"])
    tm = TopicMap.build("realsense", {"depth": "/camera/camera/depth/image_rect_raw", "imu": ""})
    assert tm.topics["depth"] == "/camera/camera/depth/image_rect_raw" and "imu" not in tm.topics
    with pytest.raises(SessionError, match="unknown preset"):
        TopicMap.build("kinect")


def test_a_bare_mcap_file_is_read_too(tmp_path):
    """A single .mcap (no rosbag2 folder), as Foxglove or sea3d itself record them."""
    from sea3d.io.session import SessionWriter

    path = tmp_path / "plain.mcap"
    left, right = _scene(0)
    with SessionWriter(path) as w:
        w.write_stereo(123, np.dstack([left] * 3), np.dstack([right] * 3))
    tm = TopicMap.build(
        None, parse_topic_args(["left=/cam/left/image", "left_info=/cam/left/camera_info"])
    )
    with MappedBag(path, tm) as bag:
        ((t, img),) = list(bag.images("left"))
        assert t == 123 and img.shape == (H, W, 3)
        np.testing.assert_array_equal(img[..., 0], left)
        with pytest.raises(SessionError, match="has no intrinsics"):
            bag.camera("left")  # sea3d wrote no rig, so K is zero: refused, not guessed


def test_bag_info_on_a_bag_lacking_a_preset_topic_lists_what_is_there(oak_bag, capsys):
    """Info names the preset's missing roles instead of failing; export refuses."""
    argv = ["bag", "info", str(oak_bag), "--preset", "oak-d", "--topic", "imu=/oak/no_imu"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "/oak/stereo/image_raw" in out  # the bag's topics are listed
    assert "not in this bag (preset oak-d): imu (/oak/no_imu)" in out
    assert main([*argv, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["missing"] == {"imu": "/oak/no_imu"} and "imu" not in d["map"]
    assert main(["bag", "export", str(oak_bag), "--preset", "oak-d", "--topic",
                 "imu=/oak/no_imu", "-o", "never.mcap"]) == 2
