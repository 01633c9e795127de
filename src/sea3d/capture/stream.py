"""The tether stream: H.264 over UDP from the vehicle to the top side, as the paper did with
GStreamer, here with PyAV (FFmpeg).

Why PyAV and not GStreamer: PyAV is a pinned wheel (no system packages, the same build on a
laptop, a Jetson and CI), runs in our process so every frame keeps its sensor stamp and its
send time (for the end-to-end latency) in an SEI message (:mod:`sea3d.io.h264`), and FFmpeg's
encoders cover the hardware that FFmpeg reaches (NVENC on NVIDIA GPUs, V4L2 M2M on the
Raspberry Pi and other SoCs, Quick Sync). The Jetson's encoder is reached through GStreamer
only, so ``encoder="gst"`` pipes raw frames through ``gst-launch-1.0 ... nvv4l2h264enc`` and
takes the H.264 back; everything else stays the same.

On the wire: one H.264 stream (left and right side by side, or one camera) in MPEG-TS, in UDP
datagrams of 1316 bytes (7 TS packets), the usual layout that ffplay, VLC and GStreamer
(``udpsrc ! tsdemux ! h264parse ! avdec_h264``) receive as it is. Low-latency settings: no
B-frames, ``tune=zerolatency``, a keyframe every second (a receiver that joins, or loses
packets, recovers within a second), the TS muxer flushing every packet and writing the PES
length so the demuxer need not wait for the next frame.

- :class:`StreamSender` encodes pairs from any source (cameras, a session replay) and sends.
- :class:`StreamReceiver` receives, decodes, splits the pair again and hands out frames with
  their stamps; it can also remux the stream to ``.ts`` / ``.mkv`` without re-encoding or
  write the decoded frames into a session (see ``sea3d stream receive``).
"""

from __future__ import annotations

import io
import itertools
import logging
import os
import queue
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from functools import partial
from typing import Any

import cv2
import numpy as np

from sea3d.capture.sources import ImageFrame, Source
from sea3d.errors import CaptureError, ConfigError
from sea3d.io import h264

__all__ = [
    "EncoderChoice",
    "ReceivedFrame",
    "StreamConfig",
    "StreamReceiver",
    "StreamSender",
    "StreamSummary",
    "live_pairs",
    "parse_udp_url",
    "pick_encoder",
    "session_pairs",
]

_log = logging.getLogger(__name__)

DATAGRAM_BYTES = 1316  # 7 MPEG-TS packets of 188 bytes: fits a 1500-byte Ethernet MTU
PTS_HZ = 90_000  # MPEG-TS clock
# Tried in this order by encoder="auto"; libx264 always works.
HARDWARE_ENCODERS = ("h264_nvenc", "gst", "h264_v4l2m2m", "h264_qsv")
_GST_ENCODERS = ("nvv4l2h264enc", "omxh264enc")


def parse_udp_url(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port).

    Raises:
        ConfigError: another scheme, a missing host or a port outside 1..65535.
    """
    scheme, sep, rest = url.partition("://")
    if scheme.lower() != "udp" or not sep:
        raise ConfigError(f"stream address must look like udp://HOST:PORT, got {url!r}")
    rest = rest.split("?", 1)[0].rstrip("/")
    host, _, port_text = rest.rpartition(":")
    host = host.strip("[]")
    if not host or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ConfigError(f"stream address {url!r}: need a host and a port 1..65535")
    return host, int(port_text)


# ----------------------------------------------------------------------------- config


@dataclass(frozen=True, kw_only=True)
class StreamConfig:
    """How to stream.

    Attributes:
        url: ``udp://HOST:PORT`` of the receiver.
        bitrate_kbps: target bit rate of the whole stream (both cameras), kbit/s.
        size_px: ``(width, height)`` of each camera in the stream (None: as captured);
            rounded down to even numbers (4:2:0 chroma).
        fps: nominal frame rate, for rate control and the keyframe interval (None: measured
            from the first frames' stamps, else 10).
        keyframe_s: seconds between keyframes.
        encoder: ``auto`` (hardware first, then libx264), ``libx264``, ``h264_nvenc``,
            ``h264_v4l2m2m``, ``h264_qsv`` or ``gst`` (GStreamer's Jetson encoder).
        preset: libx264 speed preset (``ultrafast`` ... ``medium``).
        cameras: ``both`` (side by side), ``left`` or ``right``.
    """

    url: str
    bitrate_kbps: float = 4000.0
    size_px: tuple[int, int] | None = None
    fps: float | None = None
    keyframe_s: float = 1.0
    encoder: str = "auto"
    preset: str = "ultrafast"
    cameras: str = "both"

    def __post_init__(self) -> None:
        parse_udp_url(self.url)
        if not self.bitrate_kbps > 0:
            raise ConfigError(f"bit rate must be > 0 kbit/s, got {self.bitrate_kbps}")
        if self.size_px is not None and (self.size_px[0] < 16 or self.size_px[1] < 16):
            raise ConfigError(f"stream size must be at least 16x16, got {self.size_px}")
        if self.fps is not None and not self.fps > 0:
            raise ConfigError(f"fps must be > 0, got {self.fps}")
        if not self.keyframe_s > 0:
            raise ConfigError(f"keyframe interval must be > 0 s, got {self.keyframe_s}")
        if self.cameras not in ("both", "left", "right"):
            raise ConfigError(f"cameras must be both, left or right, got {self.cameras!r}")
        if self.encoder not in ("auto", "libx264", *HARDWARE_ENCODERS):
            raise ConfigError(
                f"unknown encoder {self.encoder!r}; choose auto, libx264, "
                + ", ".join(HARDWARE_ENCODERS)
            )


# ----------------------------------------------------------------------------- encoders


@dataclass(frozen=True)
class EncoderChoice:
    """The encoder in use and what was tried before it.

    Attributes:
        name: FFmpeg encoder name, or ``gst:<element>`` for the GStreamer path.
        hardware: True for a hardware encoder.
        tried: ``(name, why it was not used)`` for each candidate that failed.
    """

    name: str
    hardware: bool
    tried: tuple[tuple[str, str], ...] = ()


def _ffmpeg_options(name: str, cfg: StreamConfig, fps: float, gop: int) -> dict[str, str]:
    kbps = int(cfg.bitrate_kbps)
    if name == "libx264":
        return {
            "preset": cfg.preset,
            "tune": "zerolatency",
            "x264-params": (
                f"keyint={gop}:min-keyint={gop}:scenecut=0:bframes=0:"
                f"vbv-maxrate={kbps}:vbv-bufsize={max(kbps // 2, 1)}"
            ),
        }
    if name == "h264_nvenc":
        return {"preset": "p1", "tune": "ull", "zerolatency": "1", "rc": "cbr", "bf": "0"}
    if name == "h264_qsv":
        return {"preset": "veryfast", "bf": "0"}
    return {}


def _open_ffmpeg_encoder(
    name: str, cfg: StreamConfig, width: int, height: int, fps: float, gop: int
) -> Any:
    import av

    ctx: Any = av.CodecContext.create(name, "w")
    ctx.width, ctx.height = width, height
    ctx.pix_fmt = "yuv420p" if name in ("libx264",) else "nv12"
    ctx.time_base = Fraction(1, PTS_HZ)
    ctx.framerate = Fraction(fps).limit_denominator(1000)
    ctx.bit_rate = int(cfg.bitrate_kbps * 1000)
    ctx.gop_size = gop
    ctx.max_b_frames = 0
    ctx.options = _ffmpeg_options(name, cfg, fps, gop)
    ctx.open()
    return ctx


def _gst_element() -> str | None:
    exe = shutil.which("gst-inspect-1.0")
    if exe is None or shutil.which("gst-launch-1.0") is None:
        return None
    for element in _GST_ENCODERS:
        try:
            r = subprocess.run([exe, element], capture_output=True, timeout=10, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        if r.returncode == 0:
            return element
    return None


def pick_encoder(cfg: StreamConfig, width: int, height: int, fps: float) -> EncoderChoice:
    """Choose the encoder: the one asked for, or with ``auto`` the first hardware encoder that
    opens at this size (NVENC, the Jetson's through GStreamer, V4L2 M2M, Quick Sync), else
    libx264. Probing opens each candidate (a build may list an encoder the machine lacks).

    Raises:
        CaptureError: an encoder asked for by name does not open here (the reason is named).
    """
    import av

    wanted = HARDWARE_ENCODERS if cfg.encoder == "auto" else (cfg.encoder,)
    tried: list[tuple[str, str]] = []
    gop = max(1, round(cfg.keyframe_s * fps))
    av.logging.set_level(av.logging.PANIC)  # probing failures are reported below
    try:
        for name in wanted:
            if name == "gst":
                element = _gst_element()
                if element is None:
                    tried.append(("gst", f"no gst-launch-1.0 with {' or '.join(_GST_ENCODERS)}"))
                    continue
                return EncoderChoice(f"gst:{element}", True, tuple(tried))
            try:
                _open_ffmpeg_encoder(name, cfg, width, height, fps, gop)
            except Exception as err:
                tried.append((name, str(err).split(":", 1)[0][:120] or type(err).__name__))
                continue
            return EncoderChoice(name, name != "libx264", tuple(tried))
    finally:
        av.logging.set_level(None)
    if cfg.encoder != "auto":
        raise CaptureError(f"encoder {cfg.encoder} is not available here: {tried[-1][1]}")
    return EncoderChoice("libx264", False, tuple(tried))


class _GstEncoder:
    """Raw RGB frames into ``gst-launch-1.0 ... <hardware encoder> ...``, H.264 access
    units (AUD-delimited Annex B) back from its stdout."""

    def __init__(self, element: str, cfg: StreamConfig, width: int, height: int, fps: float):
        gop = max(1, round(cfg.keyframe_s * fps))
        rate = Fraction(fps).limit_denominator(1000)
        kbps = int(cfg.bitrate_kbps)
        if element == "nvv4l2h264enc":
            enc = (
                f"nvvidconv ! video/x-raw(memory:NVMM),format=NV12 ! nvv4l2h264enc "
                f"bitrate={kbps * 1000} iframeinterval={gop} idrinterval={gop} "
                "insert-sps-pps=true insert-aud=true maxperf-enable=true preset-level=1"
            )
        else:
            enc = f"videoconvert ! {element} target-bitrate={kbps * 1000}"
        pipeline = (
            f"fdsrc fd=0 ! rawvideoparse width={width} height={height} format=rgb "
            f"framerate={rate.numerator}/{rate.denominator} ! {enc} ! h264parse config-interval=-1 "
            "! video/x-h264,stream-format=byte-stream,alignment=au ! fdsink fd=1 sync=false"
        )
        exe = shutil.which("gst-launch-1.0") or "gst-launch-1.0"
        try:
            self.proc = subprocess.Popen(
                [exe, "-q", *pipeline.split()],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
            )
        except OSError as err:
            raise CaptureError(f"cannot start GStreamer ({exe}): {err}") from err
        self._buf = bytearray()
        self._out: queue.Queue[bytes | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, name="sea3d-gst-out", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        while True:
            chunk = self.proc.stdout.read1(1 << 16)  # type: ignore[attr-defined]
            if not chunk:
                break
            self._buf += chunk
            for au in h264.split_access_units(self._buf):
                self._out.put(au)
        if self._buf:
            self._out.put(bytes(self._buf))
        self._out.put(None)

    def encode(self, rgb: np.ndarray) -> list[bytes]:
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(np.ascontiguousarray(rgb).tobytes())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError) as err:
            err_text = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
            raise CaptureError(
                f"GStreamer encoder stopped: {err}; {err_text.strip()[:300]}"
            ) from err
        out = []
        while True:
            try:
                au = self._out.get_nowait()
            except queue.Empty:
                break
            if au is not None:
                out.append(au)
        return out

    def close(self) -> list[bytes]:
        if self.proc.stdin is not None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        out = []
        while True:
            try:
                au = self._out.get(timeout=5)
            except queue.Empty:
                break
            if au is None:
                break
            out.append(au)
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        return out


# ----------------------------------------------------------------------------- transport


class _UdpSink(io.RawIOBase):
    """File-like sink for the TS muxer that sends fixed-size datagrams (never raises on a
    missing receiver: UDP has none to miss; send errors are counted)."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except socket.gaierror as err:
            raise CaptureError(f"cannot resolve stream host {host!r}: {err}") from err
        family, _, _, _, addr = infos[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.addr = addr
        self._buf = bytearray()
        self.bytes_sent = 0
        self.datagrams = 0
        self.send_errors = 0

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        data = memoryview(b).cast("B")
        self._buf += data
        while len(self._buf) >= DATAGRAM_BYTES:
            self._send(bytes(self._buf[:DATAGRAM_BYTES]))
            del self._buf[:DATAGRAM_BYTES]
        return len(data)

    def _send(self, datagram: bytes) -> None:
        try:
            self.sock.sendto(datagram, self.addr)
            self.bytes_sent += len(datagram)
            self.datagrams += 1
        except OSError as err:  # e.g. ECONNREFUSED from a receiver that went away
            self.send_errors += 1
            if self.send_errors in (1, 100, 10000):
                _log.warning(
                    "stream: sending to %s failed (%d times): %s", self.addr, self.send_errors, err
                )

    def flush(self) -> None:
        if self._buf:
            self._send(bytes(self._buf))
            self._buf.clear()

    def close(self) -> None:
        self.flush()
        self.sock.close()
        super().close()


# ----------------------------------------------------------------------------- pair sources


Pair = tuple[int, np.ndarray | None, np.ndarray | None]


def session_pairs(
    path: str | os.PathLike[str], *, speed: float = 1.0, loop: bool = False
) -> Iterator[Pair]:
    """``(t_ns, left, right)`` of a session's stereo pairs, paced at ``speed`` times real time
    (0: as fast as possible); with ``loop`` the replay starts again at the end (stamps keep
    growing by the session's length).

    Raises:
        SessionError: an unreadable session.
    """
    from sea3d.io.session import open_session

    lap_ns = 0
    while True:
        with open_session(path) as s:
            stamps = s.stamps("left")
            span = int(stamps[-1] - stamps[0]) if stamps.size > 1 else 0
            step = int(np.median(np.diff(stamps))) if stamps.size > 1 else 100_000_000
            t_wall0 = time.monotonic()
            t0: int | None = None
            n = 0
            for pair in s.pairs():
                if t0 is None:
                    t0 = pair.t_ns
                if speed > 0:
                    due = t_wall0 + (pair.t_ns - t0) * 1e-9 / speed
                    delay = due - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    elif delay < -0.25:  # fell behind (slow decode or encode): no burst
                        t_wall0 -= delay
                n += 1
                yield pair.t_ns + lap_ns, pair.left, pair.right
        if not loop or n == 0:
            return
        lap_ns += span + step


def _news(
    seq: dict[str, int], lead: str, last: int, ended: set[str], errors: list[BaseException]
) -> bool:
    return seq[lead] != last or lead in ended or bool(errors)


def live_pairs(
    left: Source | None, right: Source | None, *, stop: threading.Event | None = None
) -> Iterator[Pair]:
    """Pairs from two live sources (either may be None), one per left frame (or right frame
    when there is no left), with the newest frame of the other camera. Each source is read in
    its own thread, so a slow encoder makes frames be skipped, never queued.

    Raises:
        CaptureError: a source fails.
    """
    stop = stop or threading.Event()
    latest: dict[str, ImageFrame] = {}
    errors: list[BaseException] = []
    ended: set[str] = set()
    cond = threading.Condition()
    lead = "left" if left is not None else "right"
    seq = {"left": 0, "right": 0}

    def pump(name: str, src: Source) -> None:
        try:
            with src:
                while not stop.is_set():
                    rec = src.read()
                    if rec is None:
                        break
                    if not isinstance(rec, ImageFrame):
                        raise CaptureError(f"{name} source {src.name} delivered no image")
                    with cond:
                        latest[name] = rec
                        seq[name] += 1
                        cond.notify_all()
        except BaseException as err:
            errors.append(err)
        finally:
            with cond:
                ended.add(name)
                cond.notify_all()

    threads = [
        threading.Thread(target=pump, args=(n, s), name=f"sea3d-stream-{n}", daemon=True)
        for n, s in (("left", left), ("right", right))
        if s is not None
    ]
    for t in threads:
        t.start()
    last = 0
    try:
        while not stop.is_set():
            with cond:
                cond.wait_for(partial(_news, seq, lead, last, ended, errors), 0.5)
                if errors:
                    raise errors[0]
                if seq[lead] == last:
                    if lead in ended:
                        return
                    continue
                last = seq[lead]
                lf = latest.get("left")
                rf = latest.get("right")
            t_ns = (lf if lead == "left" else rf).t_ns  # type: ignore[union-attr]
            yield t_ns, None if lf is None else lf.image, None if rf is None else rf.image
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=2)


# ----------------------------------------------------------------------------- sender


@dataclass(frozen=True, kw_only=True)
class StreamSummary:
    """What a sender did.

    Attributes:
        url: where it sent.
        encoder: the encoder used; ``hardware``: whether it is one.
        encoders_tried: ``name: reason`` for the candidates that failed.
        width, height: one camera's size in the stream; ``layout``: both, left or right.
        frames: frames sent; ``skipped``: frames the sources gave that had no camera image.
        bytes_sent: UDP payload bytes; ``kbps``: their rate over ``duration_s``.
        send_errors: datagrams the OS refused (a receiver that went away, on loopback).
        duration_s: from the first frame to the last.
        encode_ms_median: median time to convert and encode a frame.
        stop_reason: why it stopped.
    """

    url: str
    encoder: str
    hardware: bool
    encoders_tried: dict[str, str]
    width: int
    height: int
    layout: str
    frames: int
    skipped: int
    bytes_sent: int
    kbps: float
    send_errors: int
    duration_s: float
    encode_ms_median: float
    stop_reason: str

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-ready)."""
        return asdict(self)


def stream_kbps(
    n_bytes: int, t_first_ns: int | None, t_last_ns: int | None, frames: int, wall_s: float
) -> float:
    """Bit rate of a stream in kbit/s over its own time: the span of the frames' stamps plus
    one frame interval (``span * frames / (frames - 1)``); the wall-clock ``wall_s`` when
    fewer than two stamped frames are known. Sender and receiver both report this, so their
    figures agree whatever the pacing, buffering and bursts between them."""
    if t_first_ns is not None and t_last_ns is not None and frames >= 2 and t_last_ns > t_first_ns:
        span_s = (t_last_ns - t_first_ns) * 1e-9 * frames / (frames - 1)
        return n_bytes * 8 / 1000 / span_s
    return n_bytes * 8 / 1000 / wall_s if wall_s > 0 else 0.0


def _is_idr(access_unit: bytes) -> bool:
    return any(t == 5 for _s, _e, t in h264.nal_units(access_unit))


def _even(v: int) -> int:
    return max(2, v - (v % 2))


def _open_mpegts(sink: _UdpSink, width: int, height: int, fps: float) -> tuple[Any, Any]:
    """Open a low-latency MPEG-TS muxer on ``sink`` with one H.264 stream of ``PTS_HZ`` ticks.

    Returns:
        The PyAV output container and its video stream.
    """
    import av

    out = av.open(
        sink,
        "w",
        format="mpegts",
        container_options={
            "flush_packets": "1",
            "omit_video_pes_length": "0",
            "max_delay": "0",
        },
    )
    vstream = out.add_mux_stream(
        "h264", rate=Fraction(fps).limit_denominator(1000), width=width, height=height
    )
    vstream.time_base = Fraction(1, PTS_HZ)
    return out, vstream


class StreamSender:
    """Encode ``(t_ns, left, right)`` pairs as H.264 and send them as MPEG-TS over UDP.

    Args:
        config: :class:`StreamConfig`.
        clock: wall clock for ``sent_ns`` (``time.time_ns``).

    Raises:
        ConfigError: a bad URL or values (from the config).
    """

    def __init__(self, config: StreamConfig, *, clock: Callable[[], int] = time.time_ns) -> None:
        self.config = config
        self.host, self.port = parse_udp_url(config.url)
        self.clock = clock
        self._stop = threading.Event()
        self._reason = ""
        self.frames_sent = 0
        self.choice: EncoderChoice | None = None
        self.frame_callback: Callable[[h264.FrameMeta, np.ndarray], None] | None = None

    def request_stop(self, reason: str = "stopped by user") -> None:
        """Stop after the current frame (thread- and signal-safe)."""
        if not self._stop.is_set():
            self._reason = reason
            self._stop.set()

    def _layout_image(self, left: np.ndarray | None, right: np.ndarray | None) -> np.ndarray | None:
        cfg = self.config
        views = {"both": (left, right), "left": (left,), "right": (right,)}[cfg.cameras]
        if any(v is None for v in views):
            return None
        out = []
        for img in views:
            assert img is not None
            if img.dtype == np.uint16:
                img = (img >> 8).astype(np.uint8)
            if img.ndim == 2:
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
            w, h = self._size
            if (img.shape[1], img.shape[0]) != (w, h):
                img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            out.append(img)
        return out[0] if len(out) == 1 else np.ascontiguousarray(np.hstack(out))

    def _first_pairs(self, it: Iterator[Pair]) -> tuple[list[Pair], float]:
        """Read the first pair (two without a configured rate); set the sent size.

        Returns:
            The pairs read (to be sent first) and the frame rate, Hz: the configured one, else
            from the first two stamps, else 10, clamped to [0.5, 240].

        Raises:
            CaptureError: the source gave no frames, or the first has no camera image.
        """
        cfg = self.config
        first: list[Pair] = []
        for item in it:  # the first pair fixes the size; two stamps estimate the rate
            first.append(item)
            if len(first) == 2 or cfg.fps is not None:
                break
        if not first:
            raise CaptureError(f"stream: the source gave no frames to send to {cfg.url}")
        ref = first[0][1] if first[0][1] is not None else first[0][2]
        if ref is None:
            raise CaptureError("stream: the first frame has no camera image")
        w0, h0 = (ref.shape[1], ref.shape[0]) if cfg.size_px is None else cfg.size_px
        self._size = (_even(int(w0)), _even(int(h0)))
        fps = cfg.fps
        if fps is None:
            fps = (
                1e9 / (first[1][0] - first[0][0])
                if len(first) == 2 and first[1][0] > first[0][0]
                else 10.0
            )
        return first, float(min(max(fps, 0.5), 240.0))

    def run(self, pairs: Iterator[Pair], *, duration_s: float | None = None) -> StreamSummary:
        """Send until the pairs end, ``duration_s`` passes or :meth:`request_stop` is called.

        Raises:
            CaptureError: no encoder opens, or the sources fail.
        """
        import av

        cfg = self.config
        it = iter(pairs)
        first, fps = self._first_pairs(it)
        ncam = 2 if cfg.cameras == "both" else 1
        width, height = self._size[0] * ncam, self._size[1]
        self.choice = choice = pick_encoder(cfg, width, height, fps)
        for name, why in choice.tried:
            _log.debug("stream: encoder %s not used: %s", name, why)
        _log.info(
            "stream: %s, %dx%d at %.1f fps, %g kbit/s to %s",
            choice.name,
            width,
            height,
            fps,
            cfg.bitrate_kbps,
            cfg.url,
        )
        layout = {"both": h264.LAYOUT_BOTH, "left": h264.LAYOUT_LEFT, "right": h264.LAYOUT_RIGHT}[
            cfg.cameras
        ]
        sink = _UdpSink(self.host, self.port)
        out, vstream = _open_mpegts(sink, width, height, fps)
        gop = max(1, round(cfg.keyframe_s * fps))
        gst: _GstEncoder | None = None
        enc: Any = None
        if choice.name.startswith("gst:"):
            gst = _GstEncoder(choice.name[4:], cfg, width, height, fps)
        else:
            enc = _open_ffmpeg_encoder(choice.name, cfg, width, height, fps, gop)
        t_first: int | None = None
        t_last: int | None = None
        last_pts = -1
        encode_ms: list[float] = []
        skipped = 0
        seq = 0
        wall0 = time.monotonic()
        pending: dict[int, h264.FrameMeta] = {}

        def send_units(units: list[tuple[bytes, int, bool]]) -> None:
            for data, pts, key in units:
                meta = pending.pop(pts, None)
                if meta is not None:
                    try:
                        data = h264.insert_frame_meta(data, meta)
                    except Exception as err:  # an access unit without a slice: send as is
                        _log.debug("stream: no SEI for pts %d: %s", pts, err)
                pkt = av.Packet(data)
                pkt.stream = vstream
                pkt.pts = pkt.dts = pts
                pkt.time_base = Fraction(1, PTS_HZ)
                pkt.is_keyframe = key
                out.mux(pkt)
                sink.flush()
                self.frames_sent += 1

        def packets_of(frame_pkts: Any) -> list[tuple[bytes, int, bool]]:
            return [(bytes(p), int(p.pts), bool(p.is_keyframe)) for p in frame_pkts]

        try:
            for t_ns, left, right in itertools.chain(first, it):
                if self._stop.is_set():
                    break
                if duration_s is not None and time.monotonic() - wall0 >= duration_s:
                    self.request_stop(f"duration of {duration_s:g} s reached")
                    break
                t0 = time.perf_counter()
                img = self._layout_image(left, right)
                if img is None:
                    skipped += 1
                    continue
                if t_first is None:
                    t_first = int(t_ns)
                t_last = int(t_ns)
                pts = max(last_pts + 1, round((int(t_ns) - t_first) * PTS_HZ / 1e9))
                last_pts = pts
                meta = h264.FrameMeta(
                    layout=layout, seq=seq, t_ns=int(t_ns), sent_ns=self.clock(),
                    width=self._size[0], height=self._size[1],
                )  # fmt: skip
                seq += 1
                pending[pts] = meta
                if self.frame_callback is not None:
                    self.frame_callback(meta, img)
                if gst is not None:
                    aus = gst.encode(img)
                    # the pipe gives access units in order; their pts are the frames' in order
                    keys = sorted(pending)
                    send_units(
                        [(au, keys[k], _is_idr(au)) for k, au in enumerate(aus) if k < len(keys)]
                    )
                else:
                    yuv = np.asarray(cv2.cvtColor(img, cv2.COLOR_RGB2YUV_I420), dtype=np.uint8)
                    frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
                    if enc.pix_fmt != "yuv420p":
                        frame = frame.reformat(format=enc.pix_fmt)
                    frame.pts = pts
                    frame.time_base = Fraction(1, PTS_HZ)
                    send_units(packets_of(enc.encode(frame)))
                encode_ms.append((time.perf_counter() - t0) * 1000)
            else:
                self._reason = self._reason or "the source ended"
            if gst is not None:
                keys = sorted(pending)
                send_units(
                    [(au, keys[k], False) for k, au in enumerate(gst.close()) if k < len(keys)]
                )
            elif enc is not None:
                send_units(packets_of(enc.encode(None)))
        finally:
            try:
                out.close()
            finally:
                sink.close()
        duration = time.monotonic() - wall0
        return StreamSummary(
            url=cfg.url,
            encoder=choice.name,
            hardware=choice.hardware,
            encoders_tried=dict(choice.tried),
            width=self._size[0],
            height=self._size[1],
            layout=cfg.cameras,
            frames=self.frames_sent,
            skipped=skipped,
            bytes_sent=sink.bytes_sent,
            kbps=stream_kbps(sink.bytes_sent, t_first, t_last, self.frames_sent, duration),
            send_errors=sink.send_errors,
            duration_s=duration,
            encode_ms_median=float(np.median(encode_ms)) if encode_ms else 0.0,
            stop_reason=self._reason or "stopped",
        )


# ----------------------------------------------------------------------------- receiver


@dataclass(frozen=True, kw_only=True)
class ReceivedFrame:
    """One decoded frame.

    Attributes:
        t_ns: the sensor stamp sent with it (the arrival time when the sender sent none).
        seq: the sender's frame counter (-1 when unknown).
        left, right: RGB uint8 images of each camera (None when not in the stream).
        sent_ns: sender wall clock at encoding (None when unknown).
        received_ns: receiver wall clock when the frame was decoded.
        latency_ms: ``received_ns - sent_ns`` in milliseconds (None when unknown).
    """

    t_ns: int
    seq: int
    left: np.ndarray | None = field(repr=False)
    right: np.ndarray | None = field(repr=False)
    sent_ns: int | None
    received_ns: int
    latency_ms: float | None


# A receiver asked to stop still demuxes, decodes and writes what it had received, for at
# most this long (a backlog of 1080p frames on a slow machine takes seconds).
DRAIN_S = 15.0


class _UdpSource(io.RawIOBase):
    """File-like UDP source for the TS demuxer. A thread drains the socket into a queue (so
    the kernel buffer never overflows while a frame decodes); ``readinto`` waits, tells the
    owner when the stream goes idle or resumes, and ends (EOF) when asked to stop."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        stop: threading.Event,
        on_idle: Callable[[float], bool],
        on_resume: Callable[[], None],
        idle_after_s: float,
    ) -> None:
        super().__init__()
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            self.sock.bind((host, port))
        except OSError as err:
            self.sock.close()
            raise CaptureError(
                f"cannot receive on udp://{host}:{port}: {err.strerror or err}"
            ) from err
        self.sock.settimeout(0.1)
        self.stop = stop
        self.on_idle, self.on_resume = on_idle, on_resume
        self.idle_after_s = idle_after_s
        self.q: queue.Queue[bytes] = queue.Queue(maxsize=20000)
        self.bytes_received = 0
        self.started_s = time.monotonic()
        self.first_byte_s: float | None = None
        self.last_byte_s: float | None = None
        self._pending = b""
        self._idle = False
        self._ended = False
        self._drain_until: float | None = None
        self._pump = threading.Thread(target=self._run, name="sea3d-stream-rx", daemon=True)
        self._pump.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            self._keep(data)
        # Asked to stop: what already reached the socket is received too (and then demuxed,
        # decoded and written by the owner: a stopped receiver keeps what was sent to it).
        self.sock.setblocking(False)
        while True:
            try:
                data = self.sock.recv(65536)
            except OSError:  # BlockingIOError: nothing more; or the socket is closed
                return
            self._keep(data)

    def _keep(self, data: bytes) -> None:
        now = time.monotonic()
        self.bytes_received += len(data)
        self.first_byte_s = self.first_byte_s or now
        self.last_byte_s = now
        try:
            self.q.put_nowait(data)
        except queue.Full:
            _log.warning("stream: receive queue full; a datagram was dropped")

    @property
    def ended(self) -> bool:
        """True once an idle timeout ended the stream."""
        return self._ended

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        while not self._pending:
            if self._ended:
                return 0
            if self.stop.is_set():  # drain what was received, for at most DRAIN_S
                if self._drain_until is None:
                    self._pump.join(timeout=1.0)
                    self._drain_until = time.monotonic() + DRAIN_S
                try:
                    if time.monotonic() > self._drain_until:
                        raise queue.Empty
                    self._pending = self.q.get_nowait()
                except queue.Empty:
                    self._ended = True
                    return 0
                continue
            try:
                self._pending = self.q.get(timeout=0.1)
            except queue.Empty:
                # Before the first datagram the quiet time counts from the start, so that an
                # idle timeout also ends a receiver that never heard anything.
                quiet = time.monotonic() - (self.last_byte_s or self.started_s)
                if quiet >= self.idle_after_s:
                    if not self.on_idle(quiet):
                        self._ended = True
                        return 0
                    self._idle = True
                continue
            if self._idle:
                self._idle = False
                self.on_resume()
        view = memoryview(b).cast("B")
        n = min(len(view), len(self._pending))
        view[:n] = self._pending[:n]
        self._pending = self._pending[n:]
        return n

    def close(self) -> None:
        self.stop.set()
        self._pump.join(timeout=2)
        self.sock.close()
        super().close()


class StreamReceiver:
    """Receive sea3d's tether stream (or any H.264 MPEG-TS over UDP).

    Use :meth:`frames` to iterate over decoded frames; :meth:`summary` has the figures. The
    receiver keeps waiting when the stream stops (it says so through ``on_event``) and goes on
    when it comes back; with ``idle_timeout_s`` it ends after that long without data.

    Args:
        url: ``udp://HOST:PORT`` to listen on (HOST is the local address: 127.0.0.1, 0.0.0.0).
        idle_timeout_s: end after this many seconds without data (None: wait for ever).
        remux_path: also write the received H.264, not re-encoded, into this ``.ts`` or
            ``.mkv`` file (exactly what came over the link).
        on_event: called with one-line messages (stream stopped / resumed / restarted).

    Raises:
        ConfigError: a bad URL. CaptureError: the address cannot be bound.
    """

    def __init__(
        self,
        url: str,
        *,
        idle_timeout_s: float | None = None,
        remux_path: str | os.PathLike[str] | None = None,
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        self.url = url
        self.host, self.port = parse_udp_url(url)
        self.idle_timeout_s = idle_timeout_s
        self.remux_path = None if remux_path is None else os.fspath(remux_path)
        self.on_event = on_event or (lambda msg: _log.warning("%s", msg))
        self._stop = threading.Event()
        self._said_idle = False
        self.counters: dict[str, Any] = {
            "frames": 0,
            "lost": 0,
            "restarts": 0,
            "decode_errors": 0,
            "bytes": 0,
            "kbps": 0.0,
            "latency_ms": [],
            "stopped_reason": None,
        }
        self._latest: dict[str, tuple[int, ImageFrame]] = {}
        self._recent: list[float] = []
        self._t_first: int | None = None  # stamps of the sender's frames, for kbit/s
        self._t_last: int | None = None
        self._stamped = 0
        self._t0 = time.monotonic()
        self._source = _UdpSource(
            self.host,
            self.port,
            stop=self._stop,
            on_idle=self._idle,
            on_resume=self._resume,
            idle_after_s=min(2.0, idle_timeout_s) if idle_timeout_s else 2.0,
        )
        self.running = True

    def _idle(self, quiet_s: float) -> bool:
        never = self._source.last_byte_s is None
        if never and self.idle_timeout_s is not None and quiet_s >= self.idle_timeout_s:
            self.counters["stopped_reason"] = (
                f"no data arrived in {self.idle_timeout_s:g} s (is the sender running?)"
            )
            self.on_event(f"nothing received on {self.url} in {quiet_s:.1f} s; ending")
            return False
        if never:
            return True  # not started yet: a stream that has not begun has not stopped
        if self.idle_timeout_s is not None and quiet_s >= self.idle_timeout_s:
            self.counters["stopped_reason"] = f"no data for {self.idle_timeout_s:g} s"
            self.on_event(f"stream from {self.url} stopped: no data for {quiet_s:.1f} s; ending")
            return False
        if not self._said_idle:
            self._said_idle = True
            self.on_event(f"stream from {self.url} stopped: no data for {quiet_s:.1f} s; waiting")
        return True

    def _resume(self) -> None:
        if self._said_idle:
            self._said_idle = False
            self.on_event(f"stream from {self.url} resumed")

    def request_stop(self, reason: str = "stopped by user") -> None:
        """End :meth:`frames` soon (thread- and signal-safe)."""
        if not self._stop.is_set():
            self.counters["stopped_reason"] = self.counters["stopped_reason"] or reason
            self._stop.set()

    def close(self) -> None:
        """Release the socket."""
        self.request_stop("closed")
        self._source.close()
        self.running = False

    def __enter__(self) -> StreamReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # MonitorProvider protocol, for --show through the monitor page
    def latest(self, stream: str) -> tuple[int, Any] | None:
        """(sequence number, ImageFrame) of the newest decoded image of ``stream``."""
        return self._latest.get(stream)

    def stats(self) -> dict[str, Any]:
        """Live figures in the recorder's layout, for the monitor page (``--show``)."""
        now = time.monotonic()
        rec = [t for t in self._recent if now - t <= 2.0]
        fps = (len(rec) - 1) / (rec[-1] - rec[0]) if len(rec) >= 2 and rec[-1] > rec[0] else 0.0
        n = self.counters["frames"]
        lost = self.counters["lost"]
        return {
            "running": self.running,
            "elapsed_s": now - self._t0,
            "frames": {"left": n, "right": n},
            "dropped": {"left": lost, "right": lost},
            "fps": {"left": fps, "right": fps},
            "disk_free_bytes": None,
            "disk_left_s": None,
            "imu": None,
            "sonar": None,
            "stop_reason": self.counters["stopped_reason"],
            "stream": self.summary(),
        }

    def summary(self) -> dict[str, Any]:
        """Figures so far: frames, lost, restarts, decode errors, bytes, kbit/s, latency."""
        lat = self.counters["latency_ms"]
        return {
            "url": self.url,
            "frames": self.counters["frames"],
            "lost": self.counters["lost"],
            "restarts": self.counters["restarts"],
            "decode_errors": self.counters["decode_errors"],
            "bytes": self._source.bytes_received,
            "kbps": self._kbps(),
            "latency_ms_median": float(np.median(lat)) if lat else None,
            "latency_ms_p90": float(np.percentile(lat, 90)) if lat else None,
            "stopped_reason": self.counters["stopped_reason"],
        }

    def _kbps(self) -> float:
        src = self._source
        if src.first_byte_s is None or src.last_byte_s is None:
            return 0.0
        return stream_kbps(
            src.bytes_received,
            self._t_first,
            self._t_last,
            self._stamped,
            src.last_byte_s - src.first_byte_s,
        )

    def frames(self) -> Iterator[ReceivedFrame]:
        """Decoded frames until stopped, idle past ``idle_timeout_s``, or the socket closes;
        asked to stop, it still hands out what had been received (for at most ``DRAIN_S``).

        Raises:
            CaptureError: the remux file cannot be written.
        """
        import av

        while not self._stop.is_set():
            try:
                container = av.open(
                    self._source,
                    "r",
                    format="mpegts",
                    options={"probesize": "65536", "analyzeduration": "200000"},
                )
            except av.error.EOFError:
                return
            except av.FFmpegError as err:
                if self._stop.is_set() or self._source.ended:
                    return
                self.counters["decode_errors"] += 1
                _log.warning("stream: cannot open the received data yet (%s); retrying", err)
                continue
            try:
                yield from self._demux(container)
            finally:
                container.close()
            return

    def _demux(self, container: Any) -> Iterator[ReceivedFrame]:
        import av

        if not container.streams.video:
            self.on_event(f"stream from {self.url} holds no video")
            return
        vin = container.streams.video[0]
        vin.thread_type = "SLICE"  # frame threads would hold frames back
        remux = None
        vout = None
        if self.remux_path is not None:
            try:
                remux = av.open(self.remux_path, "w")
                vout = remux.add_stream_from_template(vin)
            except (av.FFmpegError, OSError, ValueError) as err:
                raise CaptureError(f"cannot write {self.remux_path}: {err}") from err
        metas: dict[int, h264.FrameMeta] = {}
        last_seq: int | None = None
        try:
            for pkt in container.demux(vin):
                if pkt.size == 0:
                    continue
                data = bytes(pkt)
                meta = h264.find_frame_meta(data)
                if meta is not None and pkt.pts is not None:
                    metas[int(pkt.pts)] = meta
                    if len(metas) > 256:
                        metas.pop(next(iter(metas)))
                if remux is not None and vout is not None:
                    pkt.stream = vout
                    try:
                        remux.mux(pkt)
                    except av.FFmpegError as err:
                        _log.warning("stream: remux skipped a packet: %s", err)
                try:
                    decoded = pkt.decode()
                except av.FFmpegError as err:
                    self.counters["decode_errors"] += 1
                    _log.debug("stream: undecodable packet: %s", err)
                    continue
                for frame in decoded:
                    now = time.time_ns()
                    m = metas.pop(int(frame.pts), None) if frame.pts is not None else None
                    if m is not None and last_seq is not None:
                        if m.seq < last_seq:
                            self.counters["restarts"] += 1
                            self.on_event(f"stream from {self.url} restarted (frame {m.seq})")
                        elif m.seq > last_seq + 1:
                            self.counters["lost"] += m.seq - last_seq - 1
                    if m is not None:
                        last_seq = m.seq
                    yield self._split(frame, m, now)
            try:  # the stream ended: the frames the decoder still holds
                held = vin.decode(None)
            except av.FFmpegError as err:
                _log.debug("stream: flushing the decoder failed: %s", err)
                held = []
            for frame in held:
                now = time.time_ns()
                m = metas.pop(int(frame.pts), None) if frame.pts is not None else None
                yield self._split(frame, m, now)
        finally:
            if remux is not None:
                remux.close()

    def _split(self, frame: Any, m: h264.FrameMeta | None, now: int) -> ReceivedFrame:
        rgb = frame.to_ndarray(format="rgb24")
        left = right = None
        if m is None or m.layout == h264.LAYOUT_BOTH:
            half = rgb.shape[1] // 2
            if m is None:
                left = rgb  # someone else's stream: one picture
            else:
                left, right = rgb[:, :half], rgb[:, half:]
        elif m.layout == h264.LAYOUT_LEFT:
            left = rgb
        else:
            right = rgb
        latency = None if m is None else (now - m.sent_ns) / 1e6
        if m is not None:
            self._t_first = m.t_ns if self._t_first is None else min(self._t_first, m.t_ns)
            self._t_last = m.t_ns if self._t_last is None else max(self._t_last, m.t_ns)
            self._stamped += 1
        if latency is not None:
            self.counters["latency_ms"].append(latency)
        self.counters["frames"] += 1
        t_ns = now if m is None else m.t_ns
        rf = ReceivedFrame(
            t_ns=t_ns,
            seq=-1 if m is None else m.seq,
            left=None if left is None else np.ascontiguousarray(left),
            right=None if right is None else np.ascontiguousarray(right),
            sent_ns=None if m is None else m.sent_ns,
            received_ns=now,
            latency_ms=latency,
        )
        n = self.counters["frames"]
        self._recent = [*self._recent[-60:], time.monotonic()]
        if rf.left is not None:
            self._latest["left"] = (n, ImageFrame(t_ns, rf.left))
        if rf.right is not None:
            self._latest["right"] = (n, ImageFrame(t_ns, rf.right))
        return rf
