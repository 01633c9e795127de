"""``sea3d record`` end to end: replay sources in, summary out, SIGTERM stops cleanly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, open_session
from sea3d.refraction.presets import paper_rig

RIG_YAML = rig_to_yaml(paper_rig("dome"))

SRC = str(Path(__file__).resolve().parents[2] / "src")


def _session(path: Path, n: int = 12) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(16, 20, 3), dtype=np.uint8) for _ in range(n)]
    with SessionWriter(path, rig_yaml=RIG_YAML) as w:
        for k, img in enumerate(imgs):
            w.write_stereo(k * 33_333_333, img, img[:, ::-1].copy())
        for k in range(40):
            w.write_imu(k * 10_000_000, [0, 0, 9.81], [0.01 * k, 0, 0])
        for k in range(4):
            w.write_sonar(k * 100_000_000, 3.0 + k, 0.9)
    return imgs


@pytest.mark.parametrize("out_name", ["out.mcap", "out_dir"])
def test_record_from_replay_sources_prints_a_summary_and_writes_the_session(
    tmp_path, capsys, out_name
):
    src = tmp_path / "in.mcap"
    imgs = _session(src)
    out = tmp_path / out_name
    status = main(
        [
            "record",
            "--left",
            f"session:{src}",
            "--right",
            f"session:{src}",
            "--imu",
            f"session:{src}",
            "--sonar",
            f"session:{src}",
            "--out",
            str(out),
            "--replay-speed",
            "0",
            "--block",
            "--min-free-gb",
            "0",
            "--json",
        ]
    )
    assert status == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == {"left": 12, "right": 12, "imu": 40, "sonar": 4}
    assert summary["dropped"] == {"left": 0, "right": 0, "imu": 0, "sonar": 0}
    with open_session(out) as s:
        assert s.rig_yaml == RIG_YAML
        for k in range(12):
            np.testing.assert_array_equal(s.image("left", k), imgs[k])
        assert s.info()["imu"]["count"] == 40


def test_record_stops_cleanly_on_sigterm_and_reports(tmp_path):
    src = tmp_path / "in"
    _session(src)
    out = tmp_path / "live.mcap"
    env = dict(os.environ, PYTHONPATH=SRC)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sea3d",
            "record",
            "--left",
            f"folder:{src}/left",
            "--right",
            f"folder:{src}/right",
            "--out",
            str(out),
            "--min-free-gb",
            "0",
            "--replay-speed",
            "0.05",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    # Folder replay at 1/20 of real time lasts 8 s; wait for the file, then stop it.
    deadline = time.monotonic() + 30
    while not out.exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "stopped by SIGTERM" in stdout and "written" in stdout
    with open_session(out) as s:
        assert s.complete
        n = s.stamps("left").size
        assert f"left   {n:>7} written" in stdout


def test_record_rejects_unknown_sources_and_bad_rig(tmp_path, capsys):
    assert (
        main(
            [
                "record",
                "--left",
                "nonsense",
                "--right",
                "nonsense",
                "--out",
                str(tmp_path / "x.mcap"),
            ]
        )
        == 2
    )
    assert "cannot tell what source" in capsys.readouterr().err
    assert (
        main(
            [
                "record",
                "--left",
                "0",
                "--right",
                "1",
                "--rig",
                str(tmp_path / "none.yaml"),
                "--out",
                str(tmp_path / "x.mcap"),
            ]
        )
        == 2
    )
    assert "none.yaml: rig file not found" in capsys.readouterr().err
    # A rig that cannot be used is refused before anything is recorded.
    bad = tmp_path / "thick_dome.yaml"
    bad.write_text(RIG_YAML.replace("thickness_m: 0.0031", "thickness_m: 10.0", 1))
    utf16 = tmp_path / "utf16.yaml"
    utf16.write_bytes(RIG_YAML.encode("utf-16-le"))
    for rig, why in ((bad, "not below the inner radius"), (utf16, "not UTF-8 text")):
        args = ["record", "--left", "0", "--right", "1", "--rig", str(rig), "--out"]
        assert main([*args, str(tmp_path / "y.mcap")]) == 2
        err = capsys.readouterr().err
        assert why in err and rig.name in err and "Traceback" not in err
        assert not (tmp_path / "y.mcap").exists()


@pytest.mark.parametrize("out_name", ["killed.mcap", "killed_dir"])
def test_a_recorder_killed_with_sigkill_leaves_a_readable_session(tmp_path, out_name):
    src = tmp_path / "in.mcap"
    imgs = _session(src)
    out = tmp_path / out_name
    env = dict(os.environ, PYTHONPATH=SRC)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sea3d",
            "record",
            "--left",
            f"session:{src}",
            "--right",
            f"session:{src}",
            "--out",
            str(out),
            "--min-free-gb",
            "0",
            "--replay-speed",
            "0.1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    try:
        deadline = time.monotonic() + 30
        n = 0
        while n < 3 and time.monotonic() < deadline:  # until a chunk / 3 frames are on disk
            time.sleep(0.05)
            if out.exists():
                try:
                    with open_session(out) as s:
                        n = int(s.stamps("left").size)
                except Exception:
                    n = 0
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert n >= 3
    with open_session(out) as s:
        stamps = s.stamps("left")
        assert stamps.size >= 3
        for k in range(int(stamps.size)):
            np.testing.assert_array_equal(s.image("left", k), imgs[k])
