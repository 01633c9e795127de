"""The recording formats as other tools see them: JPEG XL frames, raw frames in LZ4 or
Zstandard chunks, per-camera camera_info, and the rig a session must carry.

Expected values come from what the test wrote; files are read back with the official ``mcap``
reader (CRCs validated), rosbags' ``AnyReader`` and imagecodecs, independently of sea3d's
reader.
"""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, convert_session, open_session

FRAME_NS = 33_333_333


def _frames(n: int, shape=(18, 26, 3), dtype=np.uint8) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    hi = 256 if dtype == np.uint8 else 4096  # 12-bit camera data in uint16
    return [rng.integers(0, hi, size=shape, dtype=dtype) for _ in range(n)]


def _official(path) -> tuple[dict[str, list], dict[str, str]]:
    """Messages per topic through the official reader with CRC validation, and chunk
    compressions seen."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        comps = {ci.compression for ci in reader.get_summary().chunk_indexes}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append(
                store.deserialize_cdr(message.data, schema.name)
            )
    return out, {"compressions": ",".join(sorted(comps))}


@pytest.mark.parametrize(
    ("shape", "dtype"), [((18, 26, 3), np.uint8), ((18, 26), np.uint8), ((18, 26, 3), np.uint16)]
)
def test_jxl_frames_are_standard_jpeg_xl_read_back_bit_exactly_by_other_tools(
    tmp_path, shape, dtype
):
    import imagecodecs

    frames = _frames(4, shape, dtype)
    path = tmp_path / "j.mcap"
    with SessionWriter(path, image_encoding="jxl") as w:
        for i, img in enumerate(frames):
            w.write_stereo(i * FRAME_NS, img, frames[-1 - i])
    msgs, _ = _official(path)
    for i, msg in enumerate(msgs["/cam/left/image"]):
        assert msg.format == "jxl"
        data = bytes(msg.data)
        # A JPEG XL codestream or its ISO BMFF container (ISO/IEC 18181-1 and -2)
        assert data[:2] == b"\xff\x0a" or data[:12] == b"\x00\x00\x00\x0cJXL \r\n\x87\n"
        np.testing.assert_array_equal(imagecodecs.jpegxl_decode(data), frames[i])
    with open_session(path) as s:
        for i in range(4):
            np.testing.assert_array_equal(s.image("left", i), frames[i])
            np.testing.assert_array_equal(s.image("right", i), frames[-1 - i])
        assert s.image_encoding == "jxl"


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_raw_frames_in_compressed_chunks_are_read_by_the_official_reader_and_rosbags(
    tmp_path, compression
):
    from rosbags.highlevel import AnyReader

    frames = _frames(3, (16, 20, 3), np.uint16)
    path = tmp_path / "r.mcap"
    with SessionWriter(path, image_encoding="raw", chunk_compression=compression) as w:
        for i, img in enumerate(frames):
            w.write_image("left", i * FRAME_NS, img)
    msgs, info = _official(path)
    assert info["compressions"] == compression
    for i, msg in enumerate(msgs["/cam/left/image"]):
        assert (msg.encoding, msg.is_bigendian) == ("rgb16", 0)
        got = np.frombuffer(bytes(msg.data), "<u2").reshape(16, 20, 3)
        np.testing.assert_array_equal(got, frames[i])
    with AnyReader([path]) as reader:
        n = sum(1 for conn, _t, _raw in reader.messages() if conn.topic == "/cam/left/image")
    assert n == 3


def test_each_camera_info_carries_its_own_cameras_intrinsics(tmp_path):
    # Left and right differ in every intrinsic, so writing the left camera into both streams
    # (a planted bug that survived the old test, whose preset rig has equal cameras) fails.
    left = PinholeCamera(
        fx=1082.4, fy=1074.4, cx=949.5, cy=535.7, width=1920, height=1080,
        dist=[-0.1, 0.02, 0.001, -0.0005, 0.0],
    )  # fmt: skip
    right = PinholeCamera(
        fx=1090.1, fy=1081.9, cx=958.2, cy=541.3, width=1920, height=1080,
        dist=[-0.12, 0.03, -0.002, 0.0007, 0.0001],
    )  # fmt: skip
    T = np.eye(4)
    T[0, 3] = 0.107
    rig = StereoRig(left=left, right=right, T_left_right=T)
    path = tmp_path / "s.mcap"
    img = np.zeros((27, 48), np.uint8)
    with SessionWriter(path, rig_yaml=rig_to_yaml(rig)) as w:
        w.write_stereo(5, img, img)
    msgs, _ = _official(path)
    for side, cam in (("left", left), ("right", right)):
        (info,) = msgs[f"/cam/{side}/camera_info"]
        np.testing.assert_array_equal(info.k.reshape(3, 3), cam.K)
        np.testing.assert_array_equal(info.d, cam.dist)
        np.testing.assert_array_equal(info.p.reshape(3, 4)[:, :3], cam.K)
        assert (info.height, info.width) == (27, 48)  # the images' size


@pytest.mark.parametrize("fmt", ["mcap", "folder"])
def test_a_session_refuses_a_rig_it_cannot_parse_instead_of_writing_zero_intrinsics(tmp_path, fmt):
    with pytest.raises(SessionError, match=r"cannot store an invalid rig.*key 'format'"):
        SessionWriter(tmp_path / ("s.mcap" if fmt == "mcap" else "s"), rig_yaml="a: 1\n")


def test_jxl_and_png_sessions_convert_into_each_other_losslessly(tmp_path):
    frames = _frames(3)
    src = tmp_path / "a.mcap"
    with SessionWriter(src, image_encoding="jxl") as w:
        for i, img in enumerate(frames):
            w.write_stereo(i * FRAME_NS, img, img)
    for dst, enc in ((tmp_path / "b_dir", None), (tmp_path / "c.mcap", "png")):
        report = convert_session(src, dst, image_encoding=enc)
        assert report["skipped"] == 0 and report["problems"] == []
        with open_session(dst) as s:
            for i in range(3):
                np.testing.assert_array_equal(s.image("left", i), frames[i])
    assert sorted(p.suffix for p in (tmp_path / "b_dir" / "left").iterdir()) == [".jxl"] * 3
