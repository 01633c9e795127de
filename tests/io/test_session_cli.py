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
