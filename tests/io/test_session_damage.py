"""Bad input and crashes: truncated or damaged MCAP, killed writers, odd folder contents.

Every reader must keep what is intact and warn (naming file and stamp) about the rest.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, open_session
from sea3d.refraction.presets import paper_rig

RIG_YAML = rig_to_yaml(paper_rig("dome"))

SRC = str(Path(__file__).resolve().parents[2] / "src")
FRAME_NS = 33_333_333


def _frame(i: int, shape=(12, 16, 3)) -> np.ndarray:
    """Deterministic image for frame i, so a child process and the test agree on it."""
    return np.random.default_rng(i).integers(0, 256, size=shape, dtype=np.uint8)


def _small_mcap(path: Path, n: int = 8) -> None:
    # chunk_size=1 closes a chunk after every message: many chunks to cut through.
    with SessionWriter(path, chunk_size=1, rig_yaml=RIG_YAML) as w:
        for i in range(n):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(100 + i))
            w.write_imu(i * FRAME_NS, [i, 0, 9.81], [0, 0, i])


def test_truncated_mcap_is_readable_up_to_its_last_complete_chunk(tmp_path, caplog):
    from mcap.reader import make_reader

    full = tmp_path / "full.mcap"
    _small_mcap(full)
    data = full.read_bytes()
    with open(full, "rb") as f:
        chunk_indexes = make_reader(f).get_summary().chunk_indexes
    # Which left stamps each chunk holds, from the official reader's chunk index.
    left_chunks = [
        (ci.chunk_start_offset + ci.chunk_length, ci.message_start_time)
        for ci in chunk_indexes
        if 1 in ci.message_index_offsets  # channel 1 is /cam/left/image
    ]
    with open(full, "rb") as f:
        rig_end = min(a.offset + a.length for a in make_reader(f).get_summary().attachment_indexes)
    cut_path = tmp_path / "cut.mcap"
    cuts = sorted(set(np.linspace(200, len(data) - 1, 60).astype(int).tolist()))
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        expected = [t for end, t in left_chunks if end <= cut]
        with caplog.at_level(logging.WARNING), open_session(cut_path) as s:
            got = s.stamps("left").tolist()
            assert got == expected, f"cut at byte {cut}"
            for i, t in enumerate(got):
                np.testing.assert_array_equal(s.image("left", i), _frame(t // FRAME_NS))
            assert s.rig_yaml == (RIG_YAML if cut >= rig_end else None)
    assert any(
        "without its summary" in r.message or "truncated" in r.message for r in caplog.records
    )


def test_damaged_chunk_is_reported_and_the_rest_is_read(tmp_path):
    path = tmp_path / "s.mcap"
    with SessionWriter(path, chunk_size=1, image_encoding="raw") as w:  # zstd chunks with CRCs
        for i in range(6):
            w.write_image("left", i * FRAME_NS, _frame(i))
    with open_session(path) as s:
        loc = s._loc["left"][2]
        chunk = s._chunks[int(loc[0])]
    data = bytearray(path.read_bytes())
    data[chunk.data_offset + chunk.data_length // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    # Opening does not decompress image chunks; the damage shows when frame 2 is read.
    with open_session(path) as s:
        with pytest.raises(SessionError, match=r"chunk at byte \d+ .*(damaged|decompressed)"):
            s.image("left", 2)
        for k in (0, 1, 3, 4, 5):
            np.testing.assert_array_equal(s.image("left", k), _frame(k))


def test_imu_samples_of_a_damaged_chunk_get_one_warning_for_the_chunk(tmp_path, caplog):
    """40 IMU samples in each of three chunks, the middle one damaged: its samples are
    skipped with one warning naming the chunk's offset and their count (there was one
    warning a sample), and the samples of the other chunks are read."""
    path = tmp_path / "s.mcap"
    with SessionWriter(path, chunk_size=1 << 20, chunk_interval_s=1e6) as w:
        for c in range(3):
            for k in range(40):
                w.write_imu((c * 40 + k) * 5_000_000, [c, k, 9.81], [0, 0, 0])
            w.flush()
    with open_session(path) as s:
        chunks = sorted({int(k) for k, _ in s._loc["imu"]})
        assert len(chunks) == 3
        middle = s._chunks[chunks[1]]
    data = bytearray(path.read_bytes())
    data[middle.data_offset + middle.data_length // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        imu = s.imu()
        assert s.skipped["imu"] == 40
    np.testing.assert_array_equal(imu.accel_mps2[:, 0], [0] * 40 + [2] * 40)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    skipped = [m for m in warnings if "skipped" in m and "/imu" in m]
    assert skipped == [f"{path} topic /imu: 40 records in the damaged chunk at byte "
                       f"{middle.file_offset} (t_ns {middle.start_ns}..{middle.end_ns}) skipped"]
    assert len(warnings) <= 2, warnings  # the chunk's own report, and its IMU samples


def test_damaged_uncompressed_message_is_skipped_by_pairs(tmp_path, caplog):
    path = tmp_path / "s.mcap"
    with SessionWriter(path, chunk_size=1) as w:
        for i in range(4):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(i))
    with open_session(path) as s:
        k, off = (int(v) for v in s._loc["left"][1])
        chunk = s._chunks[k]
    data = bytearray(path.read_bytes())
    start = chunk.data_offset + off + 9 + 22 + 40  # inside the PNG bytes of frame 1
    data[start : start + 64] = b"\x00" * 64
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        with pytest.raises(SessionError, match=f"t_ns={FRAME_NS}"):
            s.image("left", 1)
        pairs = list(s.pairs())
    assert [p.t_ns for p in pairs] == [0, 2 * FRAME_NS, 3 * FRAME_NS]
    assert any(f"skipping pair at t_ns={FRAME_NS}" in r.message for r in caplog.records)


_CHILD = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from sea3d.io.session import SessionWriter
    path, fmt = sys.argv[1], sys.argv[2]
    def frame(i):
        return np.random.default_rng(i).integers(0, 256, size=(12, 16, 3), dtype=np.uint8)
    with SessionWriter(path, format=fmt, chunk_size=1) as w:
        i = 0
        while True:
            w.write_stereo(i * 33333333, frame(i), frame(100 + i))
            print(i, flush=True)
            i += 1
            time.sleep(0.002)
    """
)


def _start_child(path: Path, fmt: str) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=SRC)
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path), fmt], stdout=subprocess.PIPE, text=True, env=env
    )


def _wait_for_frames(proc: subprocess.Popen[str], n: int) -> int:
    assert proc.stdout is not None
    last = -1
    while last < n:
        line = proc.stdout.readline()
        assert line, "writer process died early"
        last = int(line)
    return last


@pytest.mark.parametrize("fmt", ["mcap", "folder"])
def test_sigkill_midway_leaves_every_written_frame_readable(tmp_path, fmt):
    path = tmp_path / ("k.mcap" if fmt == "mcap" else "k_dir")
    proc = _start_child(path, fmt)
    last = _wait_for_frames(proc, 15)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    with open_session(path) as s:
        stamps = s.stamps("left").tolist()
        # Everything the child reported as written is there, as a prefix without holes.
        assert len(stamps) >= last + 1
        assert stamps == [i * 33333333 for i in range(len(stamps))]
        for i in range(len(stamps)):
            np.testing.assert_array_equal(s.image("left", i), _frame(i))
        for p in s.pairs():
            np.testing.assert_array_equal(p.right, _frame(100 + p.t_ns // 33333333))
    if fmt == "folder":  # no half-written image under a final name
        for f in (path / "left").iterdir():
            assert f.name.endswith(".png") or f.name.endswith(".tmp")


def test_sigterm_closes_the_mcap_file_with_its_summary(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "t.mcap"
    proc = _start_child(path, "mcap")
    last = _wait_for_frames(proc, 10)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    with open_session(path) as s:
        assert s.complete
        n = s.stamps("left").size
        assert n >= last + 1
        assert summary.statistics.channel_message_counts[1] == n


def test_folder_with_odd_names_duplicates_and_leftover_temp_files(tmp_path, caplog):
    path = tmp_path / "s"
    with SessionWriter(path, format="folder") as w:
        for i in range(3):
            w.write_image("left", 100 + i, _frame(i))
    left = path / "left"
    (left / "frame_7.png").write_bytes((left / "100.png").read_bytes())
    (left / "0101.png").write_bytes((left / "100.png").read_bytes())  # duplicate of stamp 101
    (left / ".105.png.tmp").write_bytes(b"\x89PNG half")
    (left / "notes.txt").write_text("x")
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert s.stamps("left").tolist() == [100, 101, 102]
        np.testing.assert_array_equal(s.image("left", 101), _frame(1))  # the first name wins
    text = "\n".join(r.message for r in caplog.records)
    assert "frame_7.png: name is not an integer stamp" in text
    assert "0101.png has the same stamp as 101.png (t_ns=101); ignored" in text
    assert ".105.png.tmp: incomplete write" in text


def test_folder_images_of_different_sizes_are_named_with_their_stamp(tmp_path, caplog):
    path = tmp_path / "s"
    with SessionWriter(path, format="folder") as w:
        for i in range(3):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(i))
    with SessionWriter(tmp_path / "other", format="folder") as w:
        w.write_image("left", 5, _frame(9, shape=(10, 10, 3)))
    os.replace(tmp_path / "other" / "left" / "5.png", path / "left" / f"{FRAME_NS}.png")
    (path / "checksums.csv").unlink()  # as in the paper's folders, which have neither
    (path / "session.json").unlink()
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        with pytest.raises(
            SessionError, match=rf"{FRAME_NS}\.png \(t_ns={FRAME_NS}\) is \(10, 10, 3\)"
        ):
            s.image("left", 1)
        assert [p.t_ns for p in s.pairs()] == [0, 2 * FRAME_NS]


def test_csv_rows_that_are_torn_bad_or_out_of_order_are_reported(tmp_path, caplog):
    path = tmp_path / "s"
    path.mkdir()
    (path / "imu.csv").write_text(
        "t_ns,ax,ay,az,wx,wy,wz\n"
        "300,1,2,3,4,5,6\n"
        "100,1,2,3,4,5,6\n"
        "200,1,2,x,4,5,6\n"
        "200,1,2,3,4,5,6\n"
        "400,1,2,3"
    )
    (path / "sonar.csv").write_text("t_ns,range_m,confidence\n5,1.5,0.9\n5,2.5,0.1\n")
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert s.imu().t_ns.tolist() == [100, 200, 300]
        assert s.sonar().range_m.tolist() == [1.5]
        assert s.stamps("left").size == 0
    text = "\n".join(r.message for r in caplog.records)
    assert "imu.csv line 4" in text and "imu.csv line 6" in text and "torn last line" in text
    assert "out of order" in text
    assert "sonar.csv: 1 duplicate stamps (first t_ns=5)" in text


def test_mcap_with_out_of_order_and_duplicate_messages_is_sorted_with_warnings(tmp_path, caplog):
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    msgdef, _ = store.generate_msgdef("sensor_msgs/msg/Range", ros_version=2)
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        sid = w.register_schema("sensor_msgs/msg/Range", "ros2msg", msgdef.encode())
        cid = w.register_channel("/sonar", "cdr", sid)
        hdr = store.types["std_msgs/msg/Header"]
        tm = store.types["builtin_interfaces/msg/Time"]
        for t, r in ((30, 3.0), (10, 1.0), (20, 2.0), (20, 9.0)):
            msg = store.types["sensor_msgs/msg/Range"](
                header=hdr(stamp=tm(sec=0, nanosec=t), frame_id="s"),
                radiation_type=0,
                field_of_view=0.5,
                min_range=0.1,
                max_range=50.0,
                range=r,
            )
            w.add_message(
                cid,
                log_time=t,
                publish_time=t,
                data=bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Range")),
            )
        w.finish()
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        son = s.sonar()
        assert son.t_ns.tolist() == [10, 20, 30]
        assert son.range_m.tolist() == [1.0, 2.0, 3.0]
        assert np.isnan(son.confidence).all()
    text = "\n".join(r.message for r in caplog.records)
    assert "topic /sonar: stamps out of order, going back 1 times" in text
    assert "1 duplicate stamps (first t_ns=20)" in text


def test_a_damaged_first_image_does_not_condemn_the_rest_of_the_stream(tmp_path, caplog):
    path = tmp_path / "s"
    with SessionWriter(path, format="folder") as w:
        for i in range(4):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(i))
    (path / "left" / "0.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        np.testing.assert_array_equal(s.image("left", 2), _frame(2))
        assert [p.t_ns for p in s.pairs()] == [FRAME_NS, 2 * FRAME_NS, 3 * FRAME_NS]
    assert any("0.png (t_ns=0) is damaged: 15 bytes" in r.message for r in caplog.records)


def test_a_damaged_record_length_midway_loses_only_that_chunk(tmp_path, caplog):
    path = tmp_path / "s.mcap"
    with SessionWriter(path, chunk_size=1) as w:  # one chunk per message
        for i in range(8):
            w.write_image("left", i * FRAME_NS, _frame(i))
    with open_session(path) as s:
        k = int(s._loc["left"][3][0])
        chunk_at = s._chunks[k].file_offset
    data = bytearray(path.read_bytes())
    data[chunk_at + 1 : chunk_at + 9] = (2**62).to_bytes(8, "little")  # absurd record length
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert s.stamps("left").tolist() == [i * FRAME_NS for i in (0, 1, 2, 4, 5, 6, 7)]
        for i, frame in enumerate((0, 1, 2, 4, 5, 6, 7)):
            np.testing.assert_array_equal(s.image("left", i), _frame(frame))
    assert any("through the summary" in r.message for r in caplog.records)


def test_a_folder_cut_at_a_line_or_file_boundary_is_still_reported_by_verify(tmp_path):
    from sea3d.io.session import verify_session

    path = tmp_path / "s"
    with SessionWriter(path, format="folder") as w:
        for i in range(4):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(i))
            w.write_imu(i * FRAME_NS, [0, 0, 9.81], [0, 0, 0])
    assert verify_session(path)["ok"]
    lines = (path / "imu.csv").read_text().splitlines(keepends=True)
    (path / "imu.csv").write_text("".join(lines[:-1]))  # no torn line: nothing to see in it
    report = verify_session(path)
    assert not report["ok"] and any("session.json counts 4 imu" in p for p in report["problems"])
    sums = (path / "checksums.csv").read_text().splitlines(keepends=True)
    (path / "checksums.csv").write_text("".join(sums[:3]))
    report = verify_session(path)
    assert any("have no line in checksums.csv" in p for p in report["problems"])
