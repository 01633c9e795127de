"""Live monitor: HTTP endpoints, loopback default, replay player, and a real headless Chromium
that must show changing frames and the recorder's own figures."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import threading
import time
import urllib.error
import urllib.request
from typing import Any

import cv2
import numpy as np
import pytest

from sea3d.capture.monitor import MonitorServer, SessionPlayer, json_safe, parse_address
from sea3d.capture.recorder import Recorder, RecorderConfig
from sea3d.capture.sources import ArraySource, CallableSource, ImageFrame
from sea3d.errors import ConfigError
from sea3d.io.session import SessionWriter, SonarSample


class _Provider:
    def __init__(self) -> None:
        self.frames: dict[str, tuple[int, Any]] = {}
        self.figures: dict[str, Any] = {
            "running": True,
            "frames": {"left": 0},
            "sonar": {"range_m": 1.0, "confidence": float("nan")},
        }

    def stats(self) -> dict[str, Any]:
        return self.figures

    def latest(self, stream: str) -> tuple[int, Any] | None:
        return self.frames.get(stream)


def _get(url: str) -> tuple[int, dict[str, str], bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as err:
        return err.code, dict(err.headers), err.read()


def test_endpoints_serve_page_stats_frames_disparity_and_mjpeg():
    rng = np.random.default_rng(0)
    p = _Provider()
    with MonitorServer(p, "127.0.0.1", 0, preview_width=64) as srv:
        assert srv.url.startswith("http://127.0.0.1:")
        status, _, body = _get(srv.url)
        assert status == 200 and b'id="stat-frames-left"' in body
        assert _get(srv.url + "frame/left.jpg")[0] == 503  # nothing captured yet
        status, _, body = _get(srv.url + "stats.json")
        stats = json.loads(body)  # strict JSON: NaN became null
        assert stats["sonar"]["confidence"] is None and stats["frame_seq"]["left"] is None
        # A textured pair with a 6 px shift: the disparity preview has valid pixels.
        base = rng.integers(0, 256, size=(96, 128), dtype=np.uint8)
        base = cv2.GaussianBlur(base, (3, 3), 0)
        left = np.dstack([base] * 3)
        right = np.dstack([np.roll(base, -6, axis=1)] * 3)
        p.frames = {"left": (5, ImageFrame(1, left)), "right": (5, ImageFrame(1, right))}
        status, headers, body = _get(srv.url + "frame/left.jpg")
        assert status == 200 and headers["X-Frame-Seq"] == "5"
        jpg = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert jpg.shape == (48, 64, 3)  # downscaled to preview_width
        status, _, body = _get(srv.url + "frame/disparity.jpg")
        disp = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert status == 200 and disp is not None and (disp.max(axis=2) > 40).mean() > 0.3
        assert _get(srv.url + "nope")[0] == 404
        with urllib.request.urlopen(srv.url + "stream/right.mjpg", timeout=10) as r:
            assert r.headers["Content-Type"].startswith("multipart/x-mixed-replace")
            head = r.read(200)
            assert b"--sea3dframe" in head and b"X-Frame-Seq: 5" in head


def test_address_parsing_defaults_to_loopback():
    assert parse_address("") == ("127.0.0.1", 8080)
    assert parse_address("9000") == ("127.0.0.1", 9000)
    assert parse_address(":9001") == ("127.0.0.1", 9001)
    assert parse_address("0.0.0.0:8081") == ("0.0.0.0", 8081)
    assert parse_address("[::1]:8082") == ("::1", 8082)
    with pytest.raises(ConfigError, match="port must be a number"):
        parse_address("localhost:http")
    assert json_safe({"a": [np.float32(1.5), math.inf]}) == {"a": [1.5, None]}


def test_session_player_replays_pairs_with_nearest_imu_and_range(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "s.mcap"
    imgs = [rng.integers(0, 256, size=(8, 8), dtype=np.uint8) for _ in range(4)]
    with SessionWriter(path) as w:
        for k, img in enumerate(imgs):
            w.write_stereo(k * 10_000_000, img, img)
            w.write_sonar(k * 10_000_000 + 1, 5.0 + k, 0.5)
    player = SessionPlayer(path, speed=1.0, loop=False).start()
    deadline = time.monotonic() + 10
    while player.running and time.monotonic() < deadline:
        time.sleep(0.01)
    stats = player.stats()
    player.stop()
    assert stats["frames"]["left"] == 4 and stats["pairs"] == 4
    assert stats["t_ns"] == 30_000_000 and stats["sonar"]["range_m"] == 8.0


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    return None


def _dump_dom(exe: str, url: str, budget_ms: int) -> str:
    out = subprocess.run(
        [
            exe,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            f"--virtual-time-budget={budget_ms}",
            "--dump-dom",
            url,
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def _text(dom: str, element_id: str) -> str:
    m = re.search(rf'id="{element_id}"[^>]*>([^<]*)<', dom)
    assert m is not None, f"#{element_id} missing from the page"
    return m.group(1).strip()


@pytest.mark.browser
def test_monitor_page_in_headless_chromium_shows_new_frames_and_the_recorders_figures(tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8) for _ in range(4)]
    sonar_it = iter(range(10_000))

    def sonar() -> SonarSample | None:
        k = next(sonar_it)
        time.sleep(0.05)
        return SonarSample(k * 50_000_000, 2.5 + 0.001 * k, 0.75)

    rec = Recorder(
        RecorderConfig(out_path=tmp_path / "m.mcap", min_free_bytes=0),
        {
            "left": ArraySource(imgs, rate_hz=20.0, speed=1.0),  # until stopped
            "right": ArraySource(imgs, rate_hz=20.0, speed=1.0),
            "sonar": CallableSource(sonar, kind="sonar"),
        },
    )
    with MonitorServer(rec, "127.0.0.1", 0) as srv:
        result: dict[str, Any] = {}
        worker = threading.Thread(target=lambda: result.update(summary=rec.run()))
        worker.start()
        while rec.stats()["frames"]["left"] < 3 and worker.is_alive():
            time.sleep(0.02)
        live = _dump_dom(exe, srv.url, 1500)  # while recording
        rec.request_stop("stopped by test")
        worker.join(timeout=60)
        final = _dump_dom(exe, srv.url, 1500)  # after the recorder stopped
    summary = result["summary"]
    # Live: the page fetched several different frames (distinct sequence numbers).
    assert _text(live, "state") == "(recording)"
    assert int(_text(live, "distinct-left")) >= 3 and int(_text(live, "distinct-right")) >= 3
    assert float(_text(live, "stat-fps-left")) > 0
    # Stopped: the page's figures are the recorder's.
    assert _text(final, "state") == "(stopped)"
    assert int(_text(final, "stat-frames-left")) == summary.frames["left"] > 0
    assert int(_text(final, "stat-frames-right")) == summary.frames["right"]
    assert int(_text(final, "stat-dropped-left")) == summary.dropped["left"]
    assert _text(final, "stat-stop") == summary.stop_reason
    last = rec.stats()["sonar"]
    assert _text(final, "stat-range") == f"{last['range_m']:.3f} ({last['confidence']:.2f})"
    assert _text(final, "stat-disk").endswith("GB") or "min left" in _text(final, "stat-disk")


@pytest.mark.browser
def test_monitor_page_says_replaying_not_recording_for_a_session(tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    rng = np.random.default_rng(0)
    path = tmp_path / "s.mcap"
    with SessionWriter(path) as w:
        for k in range(20):
            img = rng.integers(0, 256, size=(24, 32, 3), dtype=np.uint8)
            w.write_stereo(k * 50_000_000, img, img)
    player = SessionPlayer(path, speed=1.0).start()
    try:
        with MonitorServer(player, "127.0.0.1", 0) as srv:
            assert player.stats()["mode"] == "replay"
            dom = _dump_dom(exe, srv.url, 800)
    finally:
        player.stop()
    assert _text(dom, "state") == f"(replaying {path})"


def test_sea3d_monitor_command_serves_a_session_until_interrupted(tmp_path):
    import os
    import signal
    import sys
    from pathlib import Path

    rng = np.random.default_rng(0)
    path = tmp_path / "s"
    with SessionWriter(path, format="folder") as w:
        for k in range(5):
            img = rng.integers(0, 256, size=(8, 8, 3), dtype=np.uint8)
            w.write_stereo(k * 50_000_000, img, img)
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2] / "src"))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sea3d",
            "monitor",
            str(path),
            "--address",
            "127.0.0.1:0",
            "--duration",
            "60",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert proc.stderr is not None
        line = ""
        while "monitor at" not in line:
            line = proc.stderr.readline()
            assert line, "sea3d monitor exited early"
        url = re.search(r"http://\S+/", line).group(0)  # type: ignore[union-attr]
        assert url.startswith("http://127.0.0.1:")
        deadline = time.monotonic() + 20
        stats: dict[str, Any] = {}
        while time.monotonic() < deadline:
            stats = json.loads(_get(url + "stats.json")[2])
            if stats["frames"]["left"] >= 2:
                break
            time.sleep(0.05)
        assert stats["frames"]["left"] >= 2 and stats["pairs"] == 5
        assert _get(url + "frame/left.jpg")[0] == 200
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
