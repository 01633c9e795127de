"""Streams that stop when told, in bounded memory, and keep what they received.

Loopback only (127.0.0.1); every process is bounded in time and killed on failure.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sea3d.capture import stream as st
from sea3d.io.session import SessionWriter, open_session

W, H, STEP_NS = 160, 96, 50_000_000
STARTUP_S = 20.0  # a loaded 2-core machine imports av, numpy and OpenCV in a few seconds


def _frames(n: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 256, size=(H, W + n, 3), dtype=np.uint8)
    return [(1_000_000_000 + k * STEP_NS, base[:, k : k + W].copy(), base[:, k : k + W].copy())
            for k in range(n)]  # fmt: skip


def _session(path: Path, n: int = 20) -> Path:
    with SessionWriter(path) as w:
        for t, left, right in _frames(n):
            w.write_stereo(t, left, right)
    return path


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _sea3d(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "sea3d", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        **kw,
    )


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


class _Listener:
    """A bare UDP socket on loopback: when the first datagram came, and how many."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.url = f"udp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.first: float | None = None
        self.count = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                self.sock.recv(65536)
            except TimeoutError:
                continue
            self.count += 1
            self.first = self.first or time.monotonic()

    def wait_first(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while self.first is None and time.monotonic() < end:
            time.sleep(0.05)
        return self.first is not None

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.sock.close()


def _finish(proc: subprocess.Popen, timeout_s: float) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"did not stop within {timeout_s} s; stderr: {err[-500:]}")
    return proc.returncode, out, err


@pytest.fixture
def listener():
    lis = _Listener()
    yield lis
    lis.close()


def test_a_looped_stream_sends_at_once_and_stops_at_its_duration(tmp_path, listener):
    src = _session(tmp_path / "dive.mcap")
    t0 = time.monotonic()
    proc = _sea3d("stream", str(src), "--to", listener.url, "--loop", "--duration", "4")
    try:
        assert listener.wait_first(STARTUP_S), "no datagram sent"
        rss = [_rss_mb(proc.pid)]
        while proc.poll() is None and time.monotonic() - t0 < STARTUP_S + 8:
            rss.append(_rss_mb(proc.pid))
            time.sleep(0.3)
        rc, out, _err = _finish(proc, 10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0
    assert "duration of 4 s reached" in out
    # bounded memory: the replay is streamed pair by pair, never listed whole (it was
    # 1.77 GB after 7 minutes); 20 small frames and the codecs stay far under 600 MB
    assert max(rss) < 600, rss
    assert listener.count > 10


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_looped_stream_stops_on_a_signal(tmp_path, listener, sig):
    src = _session(tmp_path / "dive.mcap")
    proc = _sea3d("stream", str(src), "--to", listener.url, "--loop")
    try:
        assert listener.wait_first(STARTUP_S), "no datagram sent"
        proc.send_signal(sig)
        rc, out, _err = _finish(proc, 10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0
    assert f"stopped by {signal.Signals(sig).name}" in out


def test_receive_with_no_data_stops_after_its_idle_timeout_and_writes_nothing(tmp_path):
    out_path = tmp_path / "r2.mcap"
    t0 = time.monotonic()
    proc = _sea3d("stream", "receive", f"udp://127.0.0.1:{_port()}", "-o", str(out_path),
                  "--idle-timeout", "2")  # fmt: skip
    rc, out, err = _finish(proc, STARTUP_S + 10)
    assert rc == 0
    assert time.monotonic() - t0 >= 2.0
    assert "nothing received" in err
    assert "wrote" not in out and "nothing written" in out
    assert not out_path.exists()


def test_receive_stopped_by_sigterm_with_no_data_does_not_claim_a_file(tmp_path):
    out_path = tmp_path / "r2.mcap"
    proc = _sea3d("stream", "receive", f"udp://127.0.0.1:{_port()}", "-o", str(out_path))
    try:
        _wait_for(proc, "receiving on")
        proc.send_signal(signal.SIGTERM)
        rc, out, _err = _finish(proc, 10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0 and "wrote" not in out and not out_path.exists()


def _wait_for(proc: subprocess.Popen, text: str) -> None:
    """Read stderr lines until ``text`` shows (the process is ready)."""
    assert proc.stderr is not None
    end = time.monotonic() + STARTUP_S
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    proc.kill()
    pytest.fail(f"never printed {text!r}")


def test_a_receiver_killed_after_a_complete_stream_keeps_every_frame(tmp_path):
    url = f"udp://127.0.0.1:{_port()}"
    out_path = tmp_path / "topside.mcap"
    proc = _sea3d("stream", "receive", url, "-o", str(out_path))
    try:
        _wait_for(proc, "receiving on")
        frames = _frames(20)
        # a small stream (under the demuxer's 64 KB probe): it must not wait in probing
        summary = st.StreamSender(st.StreamConfig(url=url, bitrate_kbps=150)).run(iter(frames))
        assert summary.frames == 20
        time.sleep(3.0)  # the stream is over; the receiver still waits for more
        proc.send_signal(signal.SIGTERM)
        rc, out, _err = _finish(proc, 15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0 and f"wrote {out_path}" in out
    with open_session(out_path) as s:
        assert s.stamps("left").tolist() == [t for t, _, _ in frames]


def test_sender_and_receiver_report_the_same_bit_rate():
    url = f"udp://127.0.0.1:{_port()}"
    frames = _frames(30)
    got: list[st.ReceivedFrame] = []
    with st.StreamReceiver(url, idle_timeout_s=2.0) as rx:
        thread = threading.Thread(target=lambda: got.extend(rx.frames()), daemon=True)
        thread.start()
        time.sleep(0.3)
        sent = st.StreamSender(st.StreamConfig(url=url, bitrate_kbps=1500)).run(iter(frames))
        thread.join(20)
        assert not thread.is_alive()
        received = rx.summary()
    assert len(got) == 30
    # the sender ran as fast as it could, the receiver got bursts: over the frames' own
    # time both must be the same figure (it was 3,259 against 47,393)
    assert received["bytes"] == sent.bytes_sent
    assert received["kbps"] == pytest.approx(sent.kbps, rel=1e-6)


def test_a_receiver_stopped_with_a_backlog_still_hands_out_what_it_received():
    """A slow consumer (1080p decode on a loaded machine) stopped by SIGTERM after the whole
    stream arrived: the queued datagrams are demuxed, decoded and handed out, not dropped."""
    url = f"udp://127.0.0.1:{_port()}"
    frames = _frames(20)
    got: list[st.ReceivedFrame] = []
    with st.StreamReceiver(url) as rx:

        def consume() -> None:
            for f in rx.frames():
                got.append(f)
                time.sleep(0.15)  # slower than the stream

        thread = threading.Thread(target=consume, daemon=True)
        thread.start()
        time.sleep(0.3)
        st.StreamSender(st.StreamConfig(url=url, bitrate_kbps=1500)).run(iter(frames))
        time.sleep(0.5)
        assert len(got) < 20  # the backlog is there when the stop comes
        rx.request_stop("stopped by SIGTERM")
        thread.join(25)  # DRAIN_S (15 s) and some
        assert not thread.is_alive()
    assert [f.t_ns for f in got] == [t for t, _, _ in frames]
