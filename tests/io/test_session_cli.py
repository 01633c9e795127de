"""``sea3d session info`` and ``sea3d session convert`` through the real CLI entry point."""

from __future__ import annotations

import json

import numpy as np

from sea3d.cli import main
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, open_session
from sea3d.refraction.presets import paper_rig

FRAME_NS = 50_000_000  # 20 fps


def _make(path, n=10):
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(8, 10, 3), dtype=np.uint8) for _ in range(n)]
    with SessionWriter(path, rig_yaml=rig_to_yaml(paper_rig("none"))) as w:
        for i in range(n):
            if i == 5:
                continue  # a gap of two frame intervals
            w.write_stereo(i * FRAME_NS, imgs[i], imgs[i])
        w.write_image("left", n * FRAME_NS, imgs[0])  # one unpaired left frame
        for k in range(20):
            w.write_imu(k * 10_000_000, [0, 0, 9.81], [0, 0, 0])
    return imgs


def test_session_info_json_has_the_documented_keys_per_stream(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    _make(path)
    assert main(["session", "info", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    left = report["streams"]["left"]
    assert {"count", "rate_hz", "first_t_ns", "last_t_ns", "gaps"} <= set(left)
    assert left["count"] == 10 and left["gaps"] == 1
    assert left["rate_hz"] == 20.0
    assert left["first_t_ns"] == 0 and left["last_t_ns"] == 10 * FRAME_NS
    assert report["streams"]["imu"]["rate_hz"] == 100.0
    assert report["pairs"] == {
        "count": 9,
        "unpaired_left": 1,
        "unpaired_right": 0,
        "tolerance_ns": FRAME_NS // 2,
    }
    assert report["duration_s"] == 0.5 and report["rig"] is True and report["format"] == "mcap"


def test_session_info_table_and_bad_paths(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    _make(path)
    assert main(["session", "info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "stereo pairs 9 within 25.000 ms; unpaired: 1 left, 0 right" in text
    assert main(["session", "info", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_session_convert_round_trip_through_the_cli(tmp_path, capsys):
    src, mid, back = tmp_path / "a.mcap", tmp_path / "folder", tmp_path / "b.mcap"
    imgs = _make(src)
    assert main(["session", "convert", str(src), str(mid)]) == 0
    assert main(["session", "convert", str(mid), str(back)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert (mid / "left" / f"{FRAME_NS}.png").is_file() and (mid / "imu.csv").is_file()
    with open_session(back) as s:
        assert s.rig_yaml == rig_to_yaml(paper_rig("none"))
        np.testing.assert_array_equal(s.image("left", 3 * FRAME_NS), imgs[3])
        assert s.imu().t_ns.size == 20
    assert main(["session", "convert", str(src), str(back)]) == 2  # refuses to overwrite
    assert "refusing to overwrite" in capsys.readouterr().err


def test_session_verify_lists_damage_with_file_and_stamp(tmp_path, capsys):
    path = tmp_path / "s"
    _make(path)
    assert main(["session", "verify", str(path)]) == 0
    assert "no problems" in capsys.readouterr().out
    (path / "left" / f"{2 * FRAME_NS}.png").write_bytes(b"not a png")
    with open(path / "imu.csv", "a") as f:
        f.write("12,1,2\n")
    assert main(["session", "verify", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False
    assert report["records"]["left"] == 9 and report["records"]["imu"] == 20
    text = "\n".join(report["problems"])
    # checksums.csv catches the replaced file before it is decoded
    assert f"{2 * FRAME_NS}.png (t_ns={2 * FRAME_NS}) is damaged: 9 bytes" in text
    assert "imu.csv line 22" in text


# --------------------------------------------------------------------------- damage, as the
# issue found it: values from a damaged chunk copied and reported as "0 problems".
def _uncompressed_with_imu(path):
    rng = np.random.default_rng(1)
    imgs = [rng.integers(0, 256, size=(8, 10, 3), dtype=np.uint8) for _ in range(6)]
    with SessionWriter(path, rig_yaml=rig_to_yaml(paper_rig("dome")), chunk_size=1500) as w:
        for i in range(6):
            w.write_stereo(i * FRAME_NS, imgs[i], imgs[i])
            w.write_imu(i * FRAME_NS + 1, [0.1 * i, 0.0, 9.81], [0.0, 0.0, 0.01 * i])
    return imgs


def _flip_imu_acceleration(path, k):
    """Flip the exponent of the k-th IMU message's linear acceleration x (as the issue saw:
    -3.7e307 read back)."""
    import struct as _struct

    data = bytearray(path.read_bytes())
    with open_session(path) as s:
        chunk_k, off = (int(v) for v in s._loc["imu"][k])
        chunk = s._chunks[chunk_k]
        assert chunk.compression == ""  # PNG sessions keep chunks uncompressed
    msg_at = chunk.data_offset + off
    (length,) = _struct.unpack_from("<Q", data, msg_at + 1)
    value = _struct.pack("<d", 0.1 * k)
    pos = bytes(data).index(value, msg_at, msg_at + 9 + length)
    data[pos + 7] ^= 0x7F
    path.write_bytes(bytes(data))
    return chunk.file_offset


def test_a_flipped_imu_value_is_never_read_verified_or_converted_as_good(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    _uncompressed_with_imu(path)
    offset = _flip_imu_acceleration(path, 3)
    with open_session(path) as s:
        imu = s.imu()
    assert np.all(np.abs(imu.accel_mps2) < 20)  # no -3.7e307
    assert 3 * FRAME_NS + 1 not in imu.t_ns.tolist()
    assert main(["session", "verify", str(path)]) == 1
    out = capsys.readouterr().out
    assert f"damaged chunk at byte {offset}: t_ns {3 * FRAME_NS}" in out and "imu" in out
    assert "CRC mismatch" in out and f"damaged left frame t_ns={3 * FRAME_NS}" in out
    assert main(["session", "verify", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    (chunk,) = report["damaged_chunks"]
    assert chunk["offset"] == offset and chunk["start_ns"] == 3 * FRAME_NS
    assert set(chunk["streams"]) >= {"left", "right", "imu"}
    # convert: skips and lists, exit 1; the copy holds no damaged value
    out_dir = tmp_path / "copy"
    assert main(["session", "convert", str(path), str(out_dir)]) == 1
    text = capsys.readouterr().out
    assert "skipped" in text and "damaged" in text
    with open_session(out_dir) as s:
        assert np.all(np.abs(s.imu().accel_mps2) < 20)
        assert 3 * FRAME_NS not in s.stamps("left").tolist() and s.stamps("left").size == 5
    # --strict refuses and leaves nothing behind
    strict = tmp_path / "strict.mcap"
    assert main(["session", "convert", str(path), str(strict), "--strict"]) == 2
    assert "refusing to convert a damaged session (--strict)" in capsys.readouterr().err
    assert not strict.exists()


def test_a_damaged_stored_rig_is_never_used_and_says_so(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    _uncompressed_with_imu(path)
    data = bytearray(path.read_bytes())
    for pos in [i for i in range(len(data)) if data.startswith(b"0.03125", i)]:
        data[pos + 3] = ord("8")  # 0.03125 -> 0.08125 m in both stored copies
    path.write_bytes(bytes(data))
    with open_session(path) as s:
        assert s.rig_status.startswith("damaged")
    assert main(["session", "info", str(path)]) == 0
    assert "rig       damaged" in capsys.readouterr().out
    assert main(["session", "verify", str(path)]) == 1
    assert "attachment 'rig.yaml'" in capsys.readouterr().out
    assert main(["depth", "--session", str(path), "-o", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert "stored rig.yaml is damaged" in err and "Traceback" not in err


def test_stereo_and_depth_refuse_a_truncated_jpeg(tmp_path, capsys):
    import cv2

    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 256, (90, 160, 3), dtype=np.uint8), (5, 5), 2)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    (tmp_path / "L.jpg").write_bytes(buf.tobytes()[: buf.size // 2])
    (tmp_path / "R.jpg").write_bytes(buf.tobytes())
    args = [str(tmp_path / "L.jpg"), str(tmp_path / "R.jpg"), "--max-disparity", "16", "-o"]
    assert main(["stereo", *args, str(tmp_path / "d.pfm")]) == 2
    assert "L.jpg: JPEG is cut short" in capsys.readouterr().err
    from sea3d.io.rig_file import save_rig

    save_rig(paper_rig("none", size_px=(160, 90)), tmp_path / "rig.yaml")
    depth = ["depth", "--rig", str(tmp_path / "rig.yaml"), "--left", str(tmp_path / "L.jpg")]
    assert main([*depth, "--right", str(tmp_path / "R.jpg"), "-o", str(tmp_path / "z.png")]) == 2
    assert "L.jpg: JPEG is cut short" in capsys.readouterr().err
