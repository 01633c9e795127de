"""Session writer/reader: exact round trips in both layouts, pairing, statistics, conversion.

Expected values come from what the test wrote; the MCAP file is also read back with the
official ``mcap`` reader and rosbags' CDR deserialiser (independent of sea3d's reader).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, StereoPair, convert_session, open_session
from sea3d.refraction.presets import paper_rig

FRAME_NS = 33_333_333
T0_NS = 1_700_000_000_123_456_789
RIG_YAML = rig_to_yaml(paper_rig("dome"))
LAYOUTS = [("mcap", "s.mcap"), ("folder", "s_dir")]


def _images(
    rng: np.random.Generator, n: int, shape: tuple[int, ...], dtype: type
) -> list[np.ndarray]:
    hi = 256 if dtype == np.uint8 else 65536
    return [rng.integers(0, hi, size=shape, dtype=dtype) for _ in range(n)]


def _write_all(path, fmt, rng, *, shape=(24, 32, 3), dtype=np.uint8, n=6, encoding="png"):
    left = _images(rng, n, shape, dtype)
    right = _images(rng, n, shape, dtype)
    imu_t = T0_NS + np.arange(4 * n, dtype=np.int64) * 5_000_000
    accel = rng.normal(0.0, 3.0, size=(imu_t.size, 3))
    gyro = rng.normal(0.0, 0.5, size=(imu_t.size, 3))
    sonar_t = T0_NS + np.arange(n, dtype=np.int64) * 100_000_000 + 7
    ranges = rng.uniform(0.5, 40.0, size=n)
    conf = rng.uniform(0.0, 1.0, size=n)
    with SessionWriter(path, format=fmt, rig_yaml=RIG_YAML, image_encoding=encoding) as w:
        for i in range(n):
            w.write_stereo(T0_NS + i * FRAME_NS, left[i], right[i])
        for k in range(imu_t.size):
            w.write_imu(int(imu_t[k]), accel[k], gyro[k])
        for k in range(n):
            w.write_sonar(int(sonar_t[k]), ranges[k], conf[k])
    return left, right, (imu_t, accel, gyro), (sonar_t, ranges, conf)


@pytest.mark.parametrize("encoding", ["png", "jxl"])
@pytest.mark.parametrize(("fmt", "name"), LAYOUTS)
@pytest.mark.parametrize(
    ("shape", "dtype"),
    [
        ((24, 32, 3), np.uint8),
        ((24, 32), np.uint8),
        ((24, 32), np.uint16),
        ((24, 32, 3), np.uint16),
    ],
)
def test_lossless_round_trip_is_exact_for_every_stream(tmp_path, fmt, name, shape, dtype, encoding):
    rng = np.random.default_rng(0)
    path = tmp_path / name
    left, right, imu, sonar = _write_all(
        path, fmt, rng, shape=shape, dtype=dtype, encoding=encoding
    )
    with open_session(path) as s:
        assert s.format == fmt
        assert s.rig_yaml == RIG_YAML
        expected_t = T0_NS + np.arange(len(left), dtype=np.int64) * FRAME_NS
        np.testing.assert_array_equal(s.stamps("left"), expected_t)
        np.testing.assert_array_equal(s.stamps("right"), expected_t)
        for i in range(len(left)):
            got = s.image("left", i)
            assert got.dtype == dtype and got.shape == shape
            np.testing.assert_array_equal(got, left[i])
            np.testing.assert_array_equal(s.image("right", int(expected_t[i])), right[i])
        series = s.imu()
        np.testing.assert_array_equal(series.t_ns, imu[0])
        np.testing.assert_array_equal(series.accel_mps2, imu[1])  # float64 exact
        np.testing.assert_array_equal(series.gyro_radps, imu[2])
        son = s.sonar()
        np.testing.assert_array_equal(son.t_ns, sonar[0])
        np.testing.assert_array_equal(son.range_m, sonar[1].astype(np.float32))  # float32 exact
        np.testing.assert_array_equal(son.confidence, sonar[2].astype(np.float32))


@pytest.mark.parametrize("compression", [None, "none", "lz4", "zstd"])
def test_raw_image_messages_round_trip_exactly(tmp_path, compression):
    rng = np.random.default_rng(0)
    path = tmp_path / "raw.mcap"
    left = _images(rng, 4, (20, 30, 3), np.uint16)
    right = _images(rng, 4, (20, 30), np.uint8)
    with SessionWriter(path, image_encoding="raw", chunk_compression=compression) as w:
        for i in range(4):
            w.write_image("left", i * FRAME_NS, left[i])
            w.write_image("right", i * FRAME_NS, right[i])
    with open_session(path) as s:
        for i in range(len(left)):
            np.testing.assert_array_equal(s.image("left", i), left[i])
            np.testing.assert_array_equal(s.image("right", i), right[i])


@pytest.mark.parametrize(("fmt", "name"), LAYOUTS)
def test_jpeg_sessions_match_opencv_jpeg_codec(tmp_path, fmt, name):
    rng = np.random.default_rng(0)
    path = tmp_path / name
    left, _, _, _ = _write_all(path, fmt, rng, encoding="jpeg")
    with open_session(path) as s:
        for i in range(len(left)):
            ok, buf = cv2.imencode(
                ".jpg", cv2.cvtColor(left[i], cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95]
            )
            assert ok
            ref = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
            np.testing.assert_array_equal(s.image("left", i), ref)


def test_mcap_is_readable_by_the_official_reader_with_ros2_types(tmp_path):
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    rng = np.random.default_rng(0)
    path = tmp_path / "s.mcap"
    left, _, imu, sonar = _write_all(path, "mcap", rng)
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, str] = {}
    lefts, imus, ranges = [], [], []
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        assert attachments["rig.yaml"].decode() == RIG_YAML
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            types[channel.topic] = schema.name
            assert channel.message_encoding == "cdr"
            msg = store.deserialize_cdr(message.data, schema.name)
            stamp_ns = (
                msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if hasattr(msg, "header")
                else message.log_time
            )
            assert stamp_ns == message.log_time
            if channel.topic == "/cam/left/image":
                assert msg.format == "png"
                img = cv2.imdecode(np.asarray(msg.data), cv2.IMREAD_UNCHANGED)
                lefts.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
            elif channel.topic == "/imu":
                imus.append(msg.linear_acceleration.x)
            elif channel.topic == "/sonar":
                ranges.append(msg.range)
            elif channel.topic == "/cam/left/camera_info":
                assert (msg.height, msg.width) == left[0].shape[:2]
    assert types == {
        "/cam/left/image": "sensor_msgs/msg/CompressedImage",
        "/cam/right/image": "sensor_msgs/msg/CompressedImage",
        "/cam/left/camera_info": "sensor_msgs/msg/CameraInfo",
        "/cam/right/camera_info": "sensor_msgs/msg/CameraInfo",
        "/imu": "sensor_msgs/msg/Imu",
        "/sonar": "sensor_msgs/msg/Range",
        "/sonar/confidence": "std_msgs/msg/Float32",
    }
    for got, want in zip(lefts, left, strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(imus, imu[1][:, 0])
    np.testing.assert_array_equal(np.float32(ranges), sonar[1].astype(np.float32))


@pytest.mark.parametrize(("fmt", "name"), LAYOUTS)
def test_pairs_match_nearest_stamps_within_tolerance_and_count_unpaired(tmp_path, fmt, name):
    rng = np.random.default_rng(0)
    path = tmp_path / name
    img = _images(rng, 1, (8, 8), np.uint8)[0]
    left_t = [T0_NS + i * FRAME_NS for i in range(10)]
    # right jittered by up to 2 ms; frame 3 missing on the right, frame 7 far off (10 ms).
    jitter = rng.integers(-2_000_000, 2_000_000, size=10)
    right_t = [t + int(j) for t, j in zip(left_t, jitter, strict=True)]
    right_t[7] = left_t[7] + 10_000_000
    del right_t[3]
    with SessionWriter(path, format=fmt) as w:
        for t in left_t:
            w.write_image("left", t, img)
        for t in right_t:
            w.write_image("right", t, img)
    with open_session(path) as s:
        match = s.match_pairs(tolerance_ns=5_000_000)
        assert len(match) == 8
        assert (match.unpaired_left, match.unpaired_right) == (2, 1)
        pairs = list(s.pairs(tolerance_ns=5_000_000))
        assert all(isinstance(p, StereoPair) for p in pairs)
        assert [p.t_ns for p in pairs] == [t for i, t in enumerate(left_t) if i not in (3, 7)]
        for p in pairs:
            assert abs((p.right_t_ns or p.t_ns) - p.t_ns) <= 5_000_000
        # The default tolerance is half the median frame interval: frame 7 pairs too.
        assert s.match_pairs().tolerance_ns == FRAME_NS // 2
        assert len(s.match_pairs()) == 9


@pytest.mark.parametrize(("fmt", "name"), LAYOUTS)
def test_info_reports_counts_rates_and_gaps(tmp_path, fmt, name):
    path = tmp_path / name
    img = np.zeros((8, 8), np.uint8)
    stamps = [T0_NS + i * FRAME_NS for i in range(20) if i not in (10, 11, 12)]  # one gap
    with SessionWriter(path, format=fmt) as w:
        for t in stamps:
            w.write_stereo(t, img, img)
        for k in range(50):
            w.write_imu(T0_NS + k * 2_500_000, [0, 0, 9.81], [0, 0, 0])
    with open_session(path) as s:
        info = s.info()
        assert set(info) == {"left", "right", "imu", "sonar"}
        assert info["left"]["count"] == 17
        assert info["left"]["rate_hz"] == pytest.approx(1e9 / FRAME_NS, rel=1e-6)
        assert info["left"]["gaps"] == 1
        assert info["left"]["first_t_ns"] == stamps[0] and info["left"]["last_t_ns"] == stamps[-1]
        assert info["imu"]["rate_hz"] == pytest.approx(400.0, rel=1e-9)
        assert info["sonar"]["count"] == 0
        summary = s.summary()
        assert summary["duration_s"] == pytest.approx((stamps[-1] - T0_NS) * 1e-9)
        assert summary["size_bytes"] > 0


@pytest.mark.parametrize(("src_name", "dst_name"), [("a.mcap", "b_dir"), ("a_dir", "b.mcap")])
def test_convert_between_layouts_is_lossless_for_png(tmp_path, src_name, dst_name):
    rng = np.random.default_rng(0)
    src, dst, back = tmp_path / src_name, tmp_path / dst_name, tmp_path / f"back_{src_name}"
    left, right, imu, sonar = _write_all(src, None, rng, shape=(16, 20), dtype=np.uint16)
    counts = convert_session(src, dst)
    assert counts == {"left": 6, "right": 6, "imu": 24, "sonar": 6, "skipped": 0, "problems": []}
    convert_session(dst, back)
    with open_session(src) as a, open_session(dst) as b, open_session(back) as c:
        assert b.rig_yaml == RIG_YAML and c.rig_yaml == RIG_YAML
        for s in (b, c):
            for i in range(len(left)):
                np.testing.assert_array_equal(s.image("left", i), left[i])
                np.testing.assert_array_equal(s.image("right", i), right[i])
                assert s.image_bytes("left", i) == a.image_bytes("left", i)  # byte for byte
            np.testing.assert_array_equal(s.imu().accel_mps2, imu[1])
            np.testing.assert_array_equal(s.sonar().range_m, sonar[1].astype(np.float32))
            np.testing.assert_array_equal(s.sonar().confidence, sonar[2].astype(np.float32))


@pytest.mark.parametrize(("fmt", "name"), LAYOUTS)
def test_writer_rejects_bad_stamps_images_and_existing_output(tmp_path, fmt, name):
    path = tmp_path / name
    img = np.zeros((8, 8, 3), np.uint8)
    with SessionWriter(path, format=fmt) as w:
        w.write_image("left", 100, img)
        with pytest.raises(SessionError, match="duplicate left stamp t_ns=100"):
            w.write_image("left", 100, img)
        with pytest.raises(SessionError, match="out-of-order left stamp t_ns=50"):
            w.write_image("left", 50, img)
        with pytest.raises(SessionError, match=r"t_ns=200 is \(8, 9, 3\)"):
            w.write_image("left", 200, np.zeros((8, 9, 3), np.uint8))
        with pytest.raises(SessionError, match="uint8 or uint16"):
            w.write_image("right", 100, img.astype(np.float32))
        with pytest.raises(SessionError, match="unknown image stream"):
            w.write_image("middle", 100, img)
        with pytest.raises(SessionError, match="nanoseconds"):
            w.write_image("right", 1.5, img)  # type: ignore[arg-type]
        with pytest.raises(SessionError, match=r"expected \(3,\) accel"):
            w.write_imu(1, [0, 0], [0, 0, 0])
    with pytest.raises(SessionError, match="refusing to overwrite"):
        SessionWriter(path, format=fmt)
    with open_session(path) as s:
        assert s.stamps("left").tolist() == [100]


def test_open_session_reports_missing_paths_and_non_sessions(tmp_path):
    with pytest.raises(SessionError, match="does not exist"):
        open_session(tmp_path / "nope.mcap")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(SessionError, match="not an MCAP file"):
        open_session(tmp_path / "notes.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SessionError, match="holds no session"):
        open_session(tmp_path / "empty")


def test_image_lookup_by_index_stamp_and_nearest(tmp_path):
    path = tmp_path / "s.mcap"
    imgs = [np.full((4, 4), i, np.uint8) for i in range(3)]
    with SessionWriter(path) as w:
        for i, img in enumerate(imgs):
            w.write_image("left", 1000 + i * 10, img)
    with open_session(path) as s:
        assert s.image("left", -1)[0, 0] == 2
        assert s.image("left", 1010)[0, 0] == 1
        assert s.image("left", 1, by="index")[0, 0] == 1
        assert s.index_of("left", 1013, tolerance_ns=5) == 1
        with pytest.raises(SessionError, match="no left image with t_ns=1011"):
            s.image("left", 1011, by="stamp")
        with pytest.raises(SessionError, match="neither an index nor a stamp"):
            s.image("left", 5)
        with pytest.raises(SessionError, match="no left record within 2 ns"):
            s.index_of("left", 1015, tolerance_ns=2)


def test_camera_info_carries_the_rig_intrinsics(tmp_path):
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.refraction.presets import paper_rig

    rig = paper_rig(port="dome")
    path = tmp_path / "s.mcap"
    img = np.zeros((1080 // 40, 1920 // 40), np.uint8)
    with SessionWriter(path, rig_yaml=rig_to_yaml(rig)) as w:
        w.write_stereo(5, img, img)
    store = get_typestore(Stores.ROS2_HUMBLE)
    with open(path, "rb") as f:
        infos = {
            ch.topic: store.deserialize_cdr(m.data, sc.name)
            for sc, ch, m in make_reader(f).iter_messages(
                topics=["/cam/left/camera_info", "/cam/right/camera_info"]
            )
        }
    for side, cam in (("left", rig.left), ("right", rig.right)):
        k = infos[f"/cam/{side}/camera_info"].k.reshape(3, 3)
        np.testing.assert_array_equal(k, cam.pinhole.K)  # paper: fx 1082.4, cx 949.5
    with open_session(path) as s:
        assert s.rig_yaml == rig_to_yaml(rig)


def test_paper_folders_named_in_microseconds_open_with_name_unit_us(tmp_path):
    rng = np.random.default_rng(0)
    imgs = _images(rng, 3, (6, 8, 3), np.uint8)
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for k, img in enumerate(imgs):
            t_us = 1_650_000_000_000_000 + k * 33_333
            cv2.imwrite(str(tmp_path / side / f"{t_us}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    with open_session(tmp_path, name_unit="us") as s:
        assert s.stamps("left").tolist() == [
            (1_650_000_000_000_000 + k * 33_333) * 1000 for k in range(3)
        ]
        assert len(list(s.pairs())) == 3
        np.testing.assert_array_equal(s.image("right", 2), imgs[2])


def test_convert_from_raw_mcap_to_png_folder_and_to_jpeg(tmp_path):
    rng = np.random.default_rng(0)
    src = tmp_path / "raw.mcap"
    left, _, _, _ = _write_all(src, "mcap", rng, encoding="raw")
    convert_session(src, tmp_path / "png_dir")  # raw cannot go in a folder: PNG, lossless
    with open_session(tmp_path / "png_dir") as s:
        assert (tmp_path / "png_dir" / "left" / f"{T0_NS}.png").is_file()
        np.testing.assert_array_equal(s.image("left", 0), left[0])
    convert_session(tmp_path / "png_dir", tmp_path / "j.mcap", image_encoding="jpeg")
    with open_session(tmp_path / "j.mcap") as s:
        data, fmt = s.image_bytes("left", 0)
        assert fmt == "jpeg" and data[:2] == b"\xff\xd8"
        assert s.image("left", 0).shape == left[0].shape


def test_rosbags_anyreader_reads_the_mcap_file_as_a_ros2_bag(tmp_path):
    from rosbags.highlevel import AnyReader

    rng = np.random.default_rng(0)
    path = tmp_path / "s.mcap"
    *_, sonar = _write_all(path, "mcap", rng)
    counts: dict[str, int] = {}
    ranges = []
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/sonar":
                assert t_ns in sonar[0].tolist()
                ranges.append(msg.range)
    assert counts == {
        "/cam/left/image": 6,
        "/cam/right/image": 6,
        "/cam/left/camera_info": 6,
        "/cam/right/camera_info": 6,
        "/imu": 24,
        "/sonar": 6,
        "/sonar/confidence": 6,
    }
    np.testing.assert_array_equal(np.float32(ranges), sonar[1].astype(np.float32))
