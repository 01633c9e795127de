"""The tether stream: H.264 in MPEG-TS over UDP on loopback (127.0.0.1 only), with each
frame's stamps in an SEI message.

Expected values: stamps and frame counts are exact (the SEI carries them); image quality is
PSNR against the source frames at the streamed size, thresholds from libx264 ultrafast on a
smooth moving texture at about 1 bit per pixel (measured 36-40 dB; the threshold leaves room).
"""

from __future__ import annotations

import os
import socket
import stat
import sys
import threading
import time
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from sea3d.capture import stream as st
from sea3d.cli import main
from sea3d.errors import CaptureError, ConfigError
from sea3d.io import h264
from sea3d.io.session import SessionWriter, open_session

W, H, N, STEP_NS = 320, 180, 24, 50_000_000
PSNR_MIN_DB = 30.0
PSNR_HALF_SIZE_MIN_DB = 26.0  # the same texture at half size is twice as busy (measured 29 dB)


def _frames(n: int = N) -> list[tuple[int, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(0)
    big = cv2.GaussianBlur(rng.random((H, W + 2 * n + 16, 3)).astype(np.float32), (0, 0), 4)
    big = ((big - big.min()) / (big.max() - big.min()) * 255).astype(np.uint8)
    return [
        (1_000_000_000 + k * STEP_NS, big[:, k : k + W].copy(), big[:, k + 12 : k + 12 + W].copy())
        for k in range(n)
    ]


def _paced(frames, fps=20.0):
    t0 = time.monotonic()
    for k, f in enumerate(frames):
        delay = t0 + k / fps - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield f


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


class _Collect:
    def __init__(self, url, **kw):
        self.rx = st.StreamReceiver(url, **kw)
        self.frames: list[st.ReceivedFrame] = []
        self.events: list[str] = []
        self.rx.on_event = self.events.append
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        for f in self.rx.frames():
            self.frames.append(f)

    def finish(self, timeout=20):
        self.thread.join(timeout)
        self.rx.close()
        return self.frames


# ----------------------------------------------------------------------------- SEI


@pytest.mark.parametrize("t_ns", [0, 1, 256, 2**40, 2**63 - 1])
def test_frame_meta_round_trips_through_the_sei_with_emulation_prevention(t_ns):
    meta = h264.FrameMeta(layout=0, seq=3, t_ns=t_ns, sent_ns=0, width=1920, height=1080)
    nal = h264.sei_nal(meta)
    body = nal[4:]
    for i in range(len(body) - 2):  # no start code may appear inside the NAL
        assert body[i : i + 3] not in (b"\x00\x00\x00", b"\x00\x00\x01", b"\x00\x00\x02")
    au = b"\x00\x00\x00\x01\x67abc\x00\x00\x01\x68de\x00\x00\x01\x65slice-data"
    with_meta = h264.insert_frame_meta(au, meta)
    assert h264.find_frame_meta(with_meta) == meta
    types = [t for _s, _e, t in h264.nal_units(with_meta)]
    assert types == [7, 8, 6, 5]  # SPS, PPS, our SEI, then the slice
    assert h264.find_frame_meta(au) is None


def test_decoders_ignore_the_sei():
    ctx = av.CodecContext.create("libx264", "w")
    ctx.width, ctx.height, ctx.pix_fmt = 64, 48, "yuv420p"
    ctx.options = {"preset": "ultrafast", "tune": "zerolatency"}
    ctx.open()
    img = np.full((48, 64, 3), 90, np.uint8)
    frame = av.VideoFrame.from_ndarray(img, "rgb24").reformat(format="yuv420p")
    frame.pts = 0
    data = b"".join(bytes(p) for p in [*ctx.encode(frame), *ctx.encode(None)])
    meta = h264.FrameMeta(layout=1, seq=0, t_ns=5, sent_ns=6, width=64, height=48)

    def decode(b):
        dec = av.CodecContext.create("h264", "r")
        out = [f.to_ndarray(format="rgb24") for f in [*dec.decode(av.Packet(b)), *dec.decode(None)]]
        return out[0]

    np.testing.assert_array_equal(decode(data), decode(h264.insert_frame_meta(data, meta)))


def test_access_units_are_split_at_their_delimiters():
    aud = b"\x00\x00\x00\x01\x09\xf0"
    units = [aud + b"\x00\x00\x01\x65" + bytes([k]) * 5 for k in range(1, 4)]
    buf = bytearray(b"".join(units))
    got = h264.split_access_units(buf)
    assert got == units[:2] and bytes(buf) == units[2]  # the last one may still grow


# ----------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    "url", ["tcp://127.0.0.1:5000", "udp://127.0.0.1", "udp://:5000", "udp://127.0.0.1:0"]
)
def test_bad_urls_are_refused(url):
    with pytest.raises(ConfigError, match=r"udp://HOST:PORT|host and a port"):
        st.StreamConfig(url=url)


def test_auto_falls_back_to_libx264_and_says_what_it_tried():
    choice = st.pick_encoder(st.StreamConfig(url="udp://127.0.0.1:5000"), 64, 48, 10.0)
    names = [n for n, _ in choice.tried]
    if choice.hardware:
        pytest.skip(f"this machine has a hardware encoder: {choice.name}")
    assert choice.name == "libx264"
    assert names == list(st.HARDWARE_ENCODERS)  # every candidate was tried, in order
    assert all(why for _, why in choice.tried)


def test_an_encoder_asked_for_by_name_that_is_missing_is_named():
    cfg = st.StreamConfig(url="udp://127.0.0.1:5000", encoder="h264_v4l2m2m")
    with pytest.raises(CaptureError, match="h264_v4l2m2m is not available"):
        st.pick_encoder(cfg, 64, 48, 10.0)


# ----------------------------------------------------------------------------- loopback


def test_loopback_keeps_every_frame_its_stamps_and_the_picture():
    frames = _frames()
    url = f"udp://127.0.0.1:{_free_udp_port()}"
    rx = _Collect(url, idle_timeout_s=1.0)
    cfg = st.StreamConfig(url=url, bitrate_kbps=1500, fps=20)
    summary = st.StreamSender(cfg).run(_paced(frames))
    got = rx.finish()
    assert summary.frames == N and summary.encoder in ("libx264", *st.HARDWARE_ENCODERS)
    assert [f.t_ns for f in got] == [t for t, _, _ in frames]
    assert [f.seq for f in got] == list(range(N))
    for f, (_, left, right) in zip(got, frames, strict=True):
        assert _psnr(f.left, left) > PSNR_MIN_DB and _psnr(f.right, right) > PSNR_MIN_DB
        assert f.latency_ms is not None and 0 < f.latency_ms < 2000
    s = rx.rx.summary()
    assert s["lost"] == 0 and s["bytes"] == summary.bytes_sent
    assert any("stopped" in e for e in rx.events)


def test_size_and_one_camera():
    frames = _frames(8)
    url = f"udp://127.0.0.1:{_free_udp_port()}"
    rx = _Collect(url, idle_timeout_s=1.0)
    cfg = st.StreamConfig(url=url, size_px=(161, 91), cameras="right", fps=20)
    summary = st.StreamSender(cfg).run(_paced(frames))
    got = rx.finish()
    assert (summary.width, summary.height) == (160, 90)  # even sizes for 4:2:0
    assert len(got) == 8 and all(f.left is None and f.right.shape == (90, 160, 3) for f in got)
    small = cv2.resize(frames[3][2], (160, 90), interpolation=cv2.INTER_AREA)
    assert _psnr(got[3].right, small) > PSNR_HALF_SIZE_MIN_DB
    assert _psnr(got[3].right, cv2.resize(frames[3][1], (160, 90))) < PSNR_HALF_SIZE_MIN_DB - 6


def test_sender_without_a_receiver_finishes():
    frames = _frames(6)
    cfg = st.StreamConfig(url=f"udp://127.0.0.1:{_free_udp_port()}", fps=20)
    summary = st.StreamSender(cfg).run(iter(frames))
    assert summary.frames == 6 and summary.bytes_sent > 0


def test_a_receiver_that_joins_late_starts_at_a_keyframe():
    frames = _frames(40)
    port = _free_udp_port()
    url = f"udp://127.0.0.1:{port}"
    cfg = st.StreamConfig(url=url, fps=20, keyframe_s=0.5)
    sender = st.StreamSender(cfg)
    collected: dict[str, _Collect] = {}

    def start_receiver_late(meta, _img):
        if meta.seq == 12:
            collected["rx"] = _Collect(url, idle_timeout_s=1.0)

    sender.frame_callback = start_receiver_late
    sender.run(_paced(frames))
    got = collected["rx"].finish()
    assert 0 < len(got) <= 28
    assert got[0].seq >= 12 and got[0].seq % 10 == 0  # a keyframe every 10 frames
    assert [f.seq for f in got] == list(range(got[0].seq, 40))


def test_receiver_port_that_is_taken_is_named():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        with pytest.raises(CaptureError, match=rf"udp://127\.0\.0\.1:{port}"):
            st.StreamReceiver(f"udp://127.0.0.1:{port}")


# ----------------------------------------------------------------------------- GStreamer path


@pytest.fixture
def fake_gst(tmp_path, monkeypatch):
    script = Path(__file__).with_name("fake_gst.py")
    for tool, mode in (("gst-launch-1.0", "launch"), ("gst-inspect-1.0", "inspect")):
        path = tmp_path / tool
        path.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{script}" {mode} "$@"\n')
        path.chmod(path.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")


def test_gstreamer_hardware_path_is_found_and_streams(fake_gst):
    frames = _frames(10)
    url = f"udp://127.0.0.1:{_free_udp_port()}"
    cfg = st.StreamConfig(url=url, fps=20, encoder="auto")
    choice = st.pick_encoder(cfg, 2 * W, H, 20.0)
    if choice.name == "h264_nvenc":
        pytest.skip("NVENC opens here and comes first")
    assert choice.name == "gst:nvv4l2h264enc" and choice.hardware
    rx = _Collect(url, idle_timeout_s=1.5)
    summary = st.StreamSender(cfg).run(_paced(frames))
    got = rx.finish()
    assert summary.encoder == "gst:nvv4l2h264enc" and summary.hardware
    assert [f.t_ns for f in got] == [t for t, _, _ in frames]
    assert _psnr(got[5].left, frames[5][1]) > PSNR_MIN_DB


# ----------------------------------------------------------------------------- CLI


def _session(path: Path, frames) -> None:
    with SessionWriter(path) as w:
        for t, left, right in frames:
            w.write_stereo(t, left, right)


def test_cli_session_to_session_and_a_stream_that_stops(tmp_path, capsys):
    frames = _frames(12)
    src = tmp_path / "dive.mcap"
    _session(src, frames)
    out = tmp_path / "topside.mcap"
    ts = tmp_path / "topside.ts"
    url = f"udp://127.0.0.1:{_free_udp_port()}"
    url2 = f"udp://127.0.0.1:{_free_udp_port()}"
    rcs: dict[str, int] = {}
    rx1 = threading.Thread(
        target=lambda: rcs.update(
            a=main(["stream", "receive", url, "-o", str(out), "--idle-timeout", "3"])
        )
    )
    rx1.start()
    time.sleep(0.3)
    assert main(["stream", str(src), "--to", url, "--speed", "2", "--json"]) == 0
    rx1.join(20)
    assert rcs["a"] == 0
    err = capsys.readouterr().err
    assert "stopped: no data for" in err  # the stream that stops: said once, output kept
    with open_session(out) as s:
        assert s.stamps("left").tolist() == [t for t, _, _ in frames]
        assert s.stamps("right").size == 12
        assert _psnr(s.image("left", 4), frames[4][1]) > PSNR_MIN_DB
    # .ts: the H.264 as it came, playable by any player
    rx2 = threading.Thread(
        target=lambda: rcs.update(
            b=main(["stream", "receive", url2, "-o", str(ts), "--idle-timeout", "3"])
        )
    )
    rx2.start()
    time.sleep(0.3)
    assert main(["stream", str(src), "--to", url2, "--speed", "0", "--size", "160x90"]) == 0
    rx2.join(20)
    with av.open(str(ts)) as c:
        pics = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(pics) == 12 and pics[0].shape == (90, 320, 3)


def test_cli_errors_are_one_line(capsys):
    assert main(["stream", "receive"]) == 2
    assert "needs the address" in capsys.readouterr().err
    assert main(["stream", "dive.mcap"]) == 2
    assert "--to udp://HOST:PORT" in capsys.readouterr().err


# ----------------------------------------------------------------------------- live sources


def test_live_pairs_pair_each_left_frame_with_the_newest_right():
    from sea3d.capture.sources import ArraySource

    frames = _frames(8)
    left = ArraySource([f[1] for f in frames], rate_hz=20, count=8, speed=1.0, t0_ns=0)
    right = ArraySource([f[2] for f in frames], rate_hz=20, count=8, speed=1.0, t0_ns=0)
    got = list(st.live_pairs(left, right))
    assert [t for t, _, _ in got] == [k * STEP_NS for k in range(8)]
    with_right = [r for _, _, r in got if r is not None]
    assert len(with_right) >= 6  # the first left frame may come before any right one
    for t, lft, _ in got:
        np.testing.assert_array_equal(lft, frames[t // STEP_NS][1])


def test_live_pairs_report_a_failing_camera():
    from sea3d.capture.sources import CallableSource

    def broken():
        raise CaptureError("camera '/dev/video9': 30 grabs failed in a row; camera lost")

    with pytest.raises(CaptureError, match="camera lost"):
        list(st.live_pairs(CallableSource(broken), None))


def test_show_without_a_gui_serves_the_monitor_page(tmp_path, capsys):
    import urllib.request

    if hasattr(cv2, "imshow"):
        try:
            cv2.namedWindow("probe")
            cv2.destroyAllWindows()
            pytest.skip("this OpenCV has a GUI")
        except cv2.error:
            pass
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        http_port = s.getsockname()[1]
    url = f"udp://127.0.0.1:{_free_udp_port()}"
    argv = ["stream", "receive", url, "--show", "--address", f"127.0.0.1:{http_port}",
            "--idle-timeout", "3"]  # fmt: skip
    rc: dict[str, int] = {}
    th = threading.Thread(target=lambda: rc.update(v=main(argv)))
    th.start()
    time.sleep(0.3)
    seen: dict[str, bytes] = {}

    def grab(meta, _img):
        if meta.seq == 15:
            with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/frame/right.jpg") as r:
                seen["jpg"] = r.read()

    sender = st.StreamSender(st.StreamConfig(url=url, fps=20))
    sender.frame_callback = grab
    sender.run(_paced(_frames(20)))
    th.join(20)
    assert rc["v"] == 0 and seen["jpg"][:2] == b"\xff\xd8"
    assert "monitor page" in capsys.readouterr().err
