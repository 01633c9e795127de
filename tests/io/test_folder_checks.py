"""Folder sessions are checked on every read, not only by ``verify``.

Each case: what every reader (``open_session``, hence process, convert, odometry, info) hands
out, what ``verify`` says, and what ``convert`` writes.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, convert_session, open_session, verify_session
from sea3d.refraction.presets import paper_rig

FRAME_NS = 100_000_000
RIG = rig_to_yaml(paper_rig("dome"))


def _frame(i: int) -> np.ndarray:
    return np.random.default_rng(i).integers(0, 256, size=(8, 12, 3), dtype=np.uint8)


def _session(path: Path, n: int = 5) -> Path:
    with SessionWriter(path, format="folder", rig_yaml=RIG) as w:
        for i in range(n):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(50 + i))
            w.write_imu(i * FRAME_NS, [0.0, 0.0, 9.81], [0.0, 0.0, 0.01 * i])
            w.write_sonar(i * FRAME_NS + 5, 1.0 + i, 0.9)
    return path


def test_a_renamed_image_is_never_handed_out_at_its_new_stamp(tmp_path, caplog):
    path = _session(tmp_path / "s")
    os.replace(path / "left" / f"{2 * FRAME_NS}.png", path / "left" / f"{2 * FRAME_NS + 5}.png")
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert s.stamps("left").tolist() == [0, FRAME_NS, 3 * FRAME_NS, 4 * FRAME_NS]
        for i, t in enumerate(s.stamps("left").tolist()):
            np.testing.assert_array_equal(s.image("left", i, by="index"), _frame(t // FRAME_NS))
        assert [p.t_ns for p in s.pairs()] == [0, FRAME_NS, 3 * FRAME_NS, 4 * FRAME_NS]
    text = "\n".join(r.message for r in caplog.records)
    assert "no line in checksums.csv" in text and f"{2 * FRAME_NS + 5}.png" in text
    assert "listed in checksums.csv are missing" in text and f"{2 * FRAME_NS}.png" in text
    assert not verify_session(path)["ok"]


def test_convert_never_writes_a_renamed_image_and_reports_it(tmp_path):
    path = _session(tmp_path / "s")
    os.replace(path / "left" / f"{2 * FRAME_NS}.png", path / "left" / f"{2 * FRAME_NS + 5}.png")
    report = convert_session(path, tmp_path / "out.mcap")
    assert report["left"] == 4 and report["right"] == 5
    assert any("no line in checksums.csv" in p for p in report["problems"])
    with open_session(tmp_path / "out.mcap") as out:
        assert 2 * FRAME_NS + 5 not in out.stamps("left").tolist()
        for i, t in enumerate(out.stamps("left").tolist()):
            np.testing.assert_array_equal(out.image("left", i, by="index"), _frame(t // FRAME_NS))


def test_a_deleted_image_is_reported_by_every_reader(tmp_path, caplog):
    path = _session(tmp_path / "s")
    (path / "right" / f"{FRAME_NS}.png").unlink()
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert s.stamps("right").size == 4
        assert any("are missing (deleted or renamed)" in p for p in s.problems)
        assert any("session.json counts 5 right" in p for p in s.problems)
    assert not verify_session(path)["ok"]


@pytest.mark.parametrize("stream", ["imu", "sonar"])
def test_a_deleted_csv_line_is_warned_and_the_intact_readings_kept(tmp_path, caplog, stream):
    path = _session(tmp_path / "s")
    csv = path / f"{stream}.csv"
    lines = csv.read_text().splitlines(keepends=True)
    csv.write_text("".join(lines[:2] + lines[3:]))  # reading 1 gone, at a line boundary
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        series = s.imu() if stream == "imu" else s.sonar()
        assert len(series) == 4
        assert any(f"session.json counts 5 {stream}" in p for p in s.problems)
    report = verify_session(path)
    assert not report["ok"]
    assert any(f"session.json counts 5 {stream}" in p for p in report["problems"])


def test_an_edited_csv_line_is_skipped_by_its_crc(tmp_path, caplog):
    path = _session(tmp_path / "s")
    csv = path / "imu.csv"
    csv.write_text(csv.read_text().replace("9.81", "9.71", 1))
    with caplog.at_level(logging.WARNING), open_session(path) as s:
        assert len(s.imu()) == 4
        assert s.imu().accel_mps2[:, 2].tolist() == [9.81] * 4
    assert not verify_session(path)["ok"]


def test_an_edited_rig_is_refused_naming_the_file(tmp_path):
    path = _session(tmp_path / "s")
    (path / "rig.yaml").write_text(RIG.replace("fx_px: ", "fx_px: 1", 1))
    with open_session(path) as s:
        with pytest.raises(SessionError, match=r"rig\.yaml: the stored rig is damaged"):
            _ = s.rig_yaml
        assert s.rig_status.startswith("damaged")
    assert not verify_session(path)["ok"]


def test_a_rig_line_deleted_from_checksums_still_checks_the_rig_and_is_reported(tmp_path):
    path = _session(tmp_path / "s")
    sums = path / "checksums.csv"
    sums.write_text("".join(ln for ln in sums.read_text().splitlines(True) if "rig," not in ln))
    with open_session(path) as s:
        assert s.rig_yaml == RIG  # checked against session.json's copy of its checksum
    report = verify_session(path)
    assert not report["ok"] and any("line of rig.yaml is missing" in p for p in report["problems"])
    (path / "rig.yaml").write_text(RIG.replace("#", "!", 1))  # and now the rig is damaged too
    with open_session(path) as s, pytest.raises(SessionError, match=r"rig\.yaml"):
        _ = s.rig_yaml


def test_the_drills_rig_flip_with_a_damaged_checksum_line_is_refused(tmp_path):
    """The Hypothesis drill's failure: 'rig' of checksums.csv damaged (the line no longer
    parses) and one '#' of rig.yaml flipped to '!': the rig was read unchecked."""
    path = _session(tmp_path / "s")
    raw = bytearray((path / "rig.yaml").read_bytes())
    raw[raw.index(b"#")] ^= 0x02
    (path / "rig.yaml").write_bytes(bytes(raw))
    sums = bytearray((path / "checksums.csv").read_bytes())
    sums[sums.index(b"rig,") + 1] ^= 0x01
    (path / "checksums.csv").write_bytes(bytes(sums))
    with open_session(path) as s, pytest.raises(SessionError, match=r"rig\.yaml"):
        _ = s.rig_yaml
    # without session.json's copy, the rig cannot be checked at all: refused, not guessed
    meta = json.loads((path / "session.json").read_text())
    meta["rig"] = None
    (path / "session.json").write_text(json.dumps(meta))
    with open_session(path) as s, pytest.raises(SessionError, match=r"cannot be checked"):
        _ = s.rig_yaml


def test_a_deleted_checksums_file_is_a_clear_error(tmp_path):
    path = _session(tmp_path / "s")
    (path / "checksums.csv").unlink()
    with pytest.raises(SessionError, match=r"checksums\.csv is missing"):
        open_session(path)


def test_a_deleted_rig_is_reported_not_taken_for_no_rig(tmp_path):
    path = _session(tmp_path / "s")
    (path / "rig.yaml").unlink()
    with open_session(path) as s, pytest.raises(SessionError, match=r"rig\.yaml is missing"):
        _ = s.rig_yaml


def test_session_info_says_what_was_and_was_not_checked(tmp_path, capsys):
    from sea3d.cli import main

    path = tmp_path / "s.mcap"
    with SessionWriter(path, format="mcap", rig_yaml=RIG) as w:
        for i in range(4):
            w.write_stereo(i * FRAME_NS, _frame(i), _frame(50 + i))
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0x10  # inside the image chunks
    path.write_bytes(bytes(data))
    assert main(["session", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "unchecked chunk CRCs and image data" in out and "session verify" in out
    folder = _session(tmp_path / "f")
    os.replace(folder / "left" / "0.png", folder / "left" / "7.png")
    assert main(["session", "info", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "checked   the image list" in out
    assert "problems  2, first:" in out


# free bytes: the CSVs (or the MCAP preamble and first chunk) fit, the 60 images do not
@pytest.mark.parametrize(("out_name", "room"), [("out", 6_000), ("out.mcap", 20_000)])
def test_a_disk_full_convert_keeps_the_imu_and_sonar(tmp_path, monkeypatch, out_name, room):
    from types import SimpleNamespace

    from sea3d.errors import SessionWriteError

    src = _session(tmp_path / "s", n=30)
    out = tmp_path / out_name
    real = os.statvfs

    def statvfs(path):  # a disk whose free space is what the output has not used yet
        used = (
            sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
            if out.is_dir()
            else (out.stat().st_size if out.exists() else 0)
        )
        st = real(path)
        return SimpleNamespace(f_bavail=max(0, room + 65536 - used), f_frsize=1,
                               f_blocks=st.f_blocks, f_bsize=1)  # fmt: skip

    monkeypatch.setattr(os, "statvfs", statvfs)
    with pytest.raises(SessionWriteError) as err:
        convert_session(src, out)
    assert "full" in str(err.value) or "reserve" in str(err.value)
    monkeypatch.setattr(os, "statvfs", real)
    with open_session(out) as s:
        assert len(s.imu()) == 30 and len(s.sonar()) == 30
        assert s.stamps("left").size + s.stamps("right").size < 60
