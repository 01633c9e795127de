"""Live monitor: a small web page with the left and right images, a disparity preview and the
recorder's figures, served by the standard library's ``http.server``.

Endpoints (all GET):

=========================  ====================================================================
``/``                      the page (polls JPEG frames and ``/stats.json``; ``?mode=mjpeg``
                           uses the MJPEG streams instead)
``/stats.json``            the provider's figures plus the frame sequence numbers
``/frame/left.jpg``        latest left image, downscaled (``/frame/right.jpg`` likewise); the
                           ``X-Frame-Seq`` header holds its sequence number
``/frame/disparity.jpg``   low-resolution disparity preview of the latest pair (OpenCV SGBM
                           on the raw, unrectified images: a focus/overlap check, not depth)
``/stream/left.mjpg``      MJPEG stream (``multipart/x-mixed-replace``), also right
``/live.json``             with a live reconstruction (``sea3d live``): its status, mesh size
                           and trajectory positions (404 without one)
``/live/mesh.ply``         the live mesh published so far, binary PLY (503 before the first)
=========================  ====================================================================

The server listens on loopback (127.0.0.1) unless another address is given explicitly; it
has no authentication, so only expose it on a trusted tether network.

It serves a crowd: one thread per connection behind a listen backlog of
:data:`LISTEN_BACKLOG`, at most :data:`MAX_BUSY_HANDLERS` requests worked on at once (the
rest wait, they are not refused), socket timeouts so a stalled client cannot hold a thread,
at most :data:`MAX_MJPEG_STREAMS` MJPEG streams, and bounded work per request: each preview
JPEG is encoded once per frame and the disparity preview at most every 0.3 s, by one request
while the others take the last one.

A provider is anything with ``stats() -> dict`` and ``latest(stream) -> (seq, record) | None``:
the :class:`~sea3d.capture.recorder.Recorder`, or :class:`SessionPlayer` for replay.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlparse

import cv2
import numpy as np

from sea3d.errors import ConfigError

__all__ = ["MonitorProvider", "MonitorServer", "SessionPlayer", "json_safe", "parse_address"]

_log = logging.getLogger(__name__)

LISTEN_BACKLOG = 1024
MAX_BUSY_HANDLERS = 32
MAX_MJPEG_STREAMS = 16
SOCKET_TIMEOUT_S = 10.0


class MonitorProvider(Protocol):
    """What the monitor needs from a recorder or a player."""

    def stats(self) -> dict[str, Any]: ...

    def latest(self, stream: str) -> tuple[int, Any] | None: ...


def parse_address(text: str, *, default_port: int = 8080) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT``, ``PORT`` or ``HOST`` to (host, port); host defaults to
    127.0.0.1.

    Raises:
        ConfigError: for a port that is not a number in 0..65535.
    """
    host, port_text = "127.0.0.1", str(default_port)
    if text.isdigit():
        port_text = text
    elif ":" in text:
        h, _, port_text = text.rpartition(":")
        host = h.strip("[]") or host
    elif text:
        host = text
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ConfigError(f"monitor address {text!r}: port must be a number 0..65535")
    return host, int(port_text)


def json_safe(obj: Any) -> Any:
    """Copy of ``obj`` with NaN/inf floats as None and numpy scalars as Python numbers, so
    that browsers can parse it (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>sea3d monitor</title>
<style>
 body { font-family: sans-serif; background: #0b1e2d; color: #e6f0f5; margin: 12px; }
 .row { display: flex; gap: 8px; flex-wrap: wrap; }
 figure { margin: 0; } figcaption { font-size: 12px; color: #9ab; }
 img { background: #123; max-width: 48vw; }
 table { border-collapse: collapse; margin-top: 8px; font-size: 14px; }
 td { padding: 2px 10px; border-bottom: 1px solid #234; }
 .warn { color: #ffb347; }
</style></head>
<body>
<h3>sea3d monitor <span id="state"></span></h3>
<div class="row">
 <figure><img id="img-left" alt="left"><figcaption>left, frames shown:
  <span id="shown-left">0</span> (<span id="distinct-left">0</span> different)</figcaption></figure>
 <figure><img id="img-right" alt="right"><figcaption>right, frames shown:
  <span id="shown-right">0</span> (<span id="distinct-right">0</span> different)</figcaption>
 </figure>
 <figure><img id="img-disparity" alt="disparity" width="320"><figcaption>disparity preview
  (raw images, low resolution)</figcaption></figure>
</div>
<table>
 <tr><td>elapsed</td><td id="stat-elapsed">-</td></tr>
 <tr><td>frames left / right</td><td><span id="stat-frames-left">-</span> /
   <span id="stat-frames-right">-</span></td></tr>
 <tr><td>fps left / right</td><td><span id="stat-fps-left">-</span> /
   <span id="stat-fps-right">-</span></td></tr>
 <tr><td>dropped left / right</td><td><span id="stat-dropped-left">-</span> /
   <span id="stat-dropped-right">-</span></td></tr>
 <tr><td>disk free</td><td id="stat-disk">-</td></tr>
 <tr><td>IMU accel m/s&sup2; / gyro rad/s</td><td id="stat-imu">-</td></tr>
 <tr><td>range m (confidence)</td><td id="stat-range">-</td></tr>
 <tr><td>stop reason</td><td id="stat-stop">-</td></tr>
</table>
<div id="live" style="display:none">
<h4>live reconstruction <a href="/live/mesh.ply">mesh.ply</a></h4>
<div class="row"><canvas id="live-path" width="320" height="320"
 style="background:#123"></canvas>
<table>
 <tr><td>frames / tracked / fused</td><td id="live-frames">-</td></tr>
 <tr><td>depth frames dropped</td><td id="live-dropped">-</td></tr>
 <tr><td>odometry</td><td id="live-odometry">-</td></tr>
 <tr><td>latency to fusion / mesh (p50)</td><td id="live-latency">-</td></tr>
 <tr><td>mesh vertices / triangles</td><td id="live-mesh">-</td></tr>
 <tr><td>stop reason</td><td id="live-stop">-</td></tr>
</table></div></div>
<script>
"use strict";
const mjpeg = new URLSearchParams(location.search).get("mode") === "mjpeg";
const shown = {left: 0, right: 0};
const distinct = {left: 0, right: 0};
const lastSeq = {left: null, right: null};
function fmt(v, d) { return (v === null || v === undefined) ? "-" : Number(v).toFixed(d); }
function show(side) {
  shown[side] += 1;
  document.getElementById("shown-" + side).textContent = shown[side];
  document.getElementById("distinct-" + side).textContent = distinct[side];
}
async function pollImage(side) {
  const img = document.getElementById("img-" + side);
  if (mjpeg) { img.onload = () => show(side); img.src = "/stream/" + side + ".mjpg"; return; }
  try {
    const r = await fetch("/frame/" + side + ".jpg", {cache: "no-store"});
    if (r.ok) {
      const seq = r.headers.get("X-Frame-Seq");
      if (seq !== lastSeq[side]) { distinct[side] += 1; lastSeq[side] = seq; }
      const url = URL.createObjectURL(await r.blob());
      await new Promise((done) => { img.onload = img.onerror = done; img.src = url; });
      URL.revokeObjectURL(url);
      show(side);
    }
  } catch (e) { /* server gone or frame not ready */ }
  setTimeout(() => pollImage(side), 100);
}
function pollDisparity() {
  const img = document.getElementById("img-disparity");
  img.onload = img.onerror = () => setTimeout(pollDisparity, 500);
  img.src = "/frame/disparity.jpg?t=" + Date.now();
}
async function pollStats() {
  try {
    const s = await (await fetch("/stats.json", {cache: "no-store"})).json();
    const set = (id, v) => { document.getElementById(id).textContent = v; };
    set("state", s.running ? (s.mode === "replay" ? "(replaying " + (s.source || "") + ")"
        : s.mode === "live" ? "(live reconstruction)" : "(recording)") : "(stopped)");
    set("stat-elapsed", fmt(s.elapsed_s, 1) + " s");
    for (const side of ["left", "right"]) {
      set("stat-frames-" + side, s.frames[side] ?? 0);
      set("stat-fps-" + side, fmt(s.fps[side], 1));
      set("stat-dropped-" + side, s.dropped[side] ?? 0);
    }
    set("stat-disk", fmt(s.disk_free_bytes / 1e9, 2) + " GB" +
        (s.disk_left_s ? " (" + fmt(s.disk_left_s / 60, 0) + " min left)" : ""));
    set("stat-imu", s.imu ? s.imu.accel_mps2.map(v => fmt(v, 3)).join(", ") + " / " +
        s.imu.gyro_radps.map(v => fmt(v, 3)).join(", ") : "-");
    set("stat-range", s.sonar ? fmt(s.sonar.range_m, 3) + " (" + fmt(s.sonar.confidence, 2) + ")"
        : "-");
    set("stat-stop", s.stop_reason || "-");
    document.body.dataset.statsPolls = String(Number(document.body.dataset.statsPolls || 0) + 1);
  } catch (e) { /* server gone: keep the last figures */ }
  setTimeout(pollStats, 250);
}
function drawPath(xyz) {
  const c = document.getElementById("live-path"), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (xyz.length < 2) { return; }
  const xs = xyz.map(p => p[0]), zs = xyz.map(p => p[2]);
  const x0 = Math.min(...xs), z0 = Math.min(...zs);
  const span = Math.max(Math.max(...xs) - x0, Math.max(...zs) - z0, 1e-3);
  const k = (c.width - 20) / span;
  g.strokeStyle = "#7fd"; g.beginPath();
  xyz.forEach((p, i) => { const u = 10 + (p[0] - x0) * k, v = c.height - 10 - (p[2] - z0) * k;
    if (i) { g.lineTo(u, v); } else { g.moveTo(u, v); } });
  g.stroke();
}
async function pollLive() {
  try {
    const r = await fetch("/live.json", {cache: "no-store"});
    if (r.status === 404) { return; }
    const s = await r.json();
    const set = (id, v) => { document.getElementById(id).textContent = v; };
    document.getElementById("live").style.display = "";
    set("live-frames", s.frames + " / " + s.tracked + " / " + s.fused);
    set("live-dropped", s.depth_dropped ?? "-");
    set("live-odometry", s.odometry_status || "-");
    set("live-latency", fmt(s.latency_p50_s, 2) + " s / " + fmt(s.mesh_latency_p50_s, 2) + " s");
    set("live-mesh", s.mesh_vertices + " / " + s.mesh_triangles);
    set("live-stop", s.stop_reason || (s.running ? "running" : "-"));
    drawPath(s.trajectory_xyz || []);
  } catch (e) { /* server gone */ }
  setTimeout(pollLive, 500);
}
pollImage("left"); pollImage("right"); pollDisparity(); pollStats(); pollLive();
</script></body></html>
"""


def _preview(image: np.ndarray, width: int) -> np.ndarray:
    """RGB/grey uint8/uint16 image -> BGR uint8 at most ``width`` pixels wide."""
    img = image
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    h, w = img.shape[:2]
    if w > width:
        img = cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    return img


class _FrameCache:
    """JPEG encodings of the latest frames, made once per sequence number by one request at
    a time (the others take the last encoding instead of piling up on the CPU)."""

    def __init__(self, provider: MonitorProvider, preview_width: int, disparity_width: int) -> None:
        self.provider = provider
        self.preview_width = preview_width
        self.disparity_width = disparity_width
        self._jpeg: dict[str, tuple[int, bytes]] = {}
        self._disp: tuple[tuple[int, int], bytes] | None = None
        self._disp_time = 0.0
        self._lock = threading.Lock()
        self._encoding = {s: threading.Lock() for s in ("left", "right")}
        self._disparity_busy = threading.Lock()

    def frame(self, stream: str) -> tuple[int, bytes] | None:
        latest = self.provider.latest(stream)
        if latest is None:
            return None
        seq, rec = latest
        with self._lock:
            cached = self._jpeg.get(stream)
        if cached is not None and cached[0] == seq:
            return cached
        busy = self._encoding.setdefault(stream, threading.Lock())
        if not busy.acquire(blocking=cached is None):
            return cached  # another request is encoding the new frame: serve the last one
        try:
            with self._lock:
                cached = self._jpeg.get(stream)
            if cached is not None and cached[0] == seq:
                return cached
            ok, buf = cv2.imencode(
                ".jpg", _preview(rec.image, self.preview_width), [cv2.IMWRITE_JPEG_QUALITY, 80]
            )
            if not ok:
                return cached
            out = (seq, buf.tobytes())
            with self._lock:
                self._jpeg[stream] = out
            return out
        finally:
            busy.release()

    def disparity(self) -> bytes | None:
        left, right = self.provider.latest("left"), self.provider.latest("right")
        if left is None or right is None:
            return None
        key = (left[0], right[0])
        with self._lock:
            cached = self._disp
            fresh = cached is not None and (
                cached[0] == key or time.monotonic() - self._disp_time < 0.3
            )
        if cached is not None and fresh:
            return cached[1]
        if not self._disparity_busy.acquire(blocking=cached is None):
            return cached[1] if cached is not None else None
        try:
            return self._compute_disparity(left[1].image, right[1].image, key)
        finally:
            self._disparity_busy.release()

    def _compute_disparity(
        self, left: np.ndarray, right: np.ndarray, key: tuple[int, int]
    ) -> bytes | None:
        gl = cv2.cvtColor(_preview(left, self.disparity_width), cv2.COLOR_BGR2GRAY)
        gr = cv2.cvtColor(_preview(right, self.disparity_width), cv2.COLOR_BGR2GRAY)
        if gl.shape != gr.shape:
            gr = cv2.resize(gr, (gl.shape[1], gl.shape[0]))
        num_disp = max(16, (gl.shape[1] // 8) // 16 * 16)
        sgbm = cv2.StereoSGBM.create(
            minDisparity=0,
            numDisparities=num_disp,
            blockSize=5,
            P1=8 * 25,
            P2=32 * 25,
            uniquenessRatio=10,
        )
        disp = sgbm.compute(gl, gr).astype(np.float32) / 16.0  # SGBM's fixed point, x16
        valid = disp > 0
        scaled = np.zeros(disp.shape, np.uint8)
        scaled[valid] = np.clip(disp[valid] * (255.0 / num_disp), 0, 255).astype(np.uint8)
        color = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
        color[~valid] = 0
        ok, buf = cv2.imencode(".jpg", color, [cv2.IMWRITE_JPEG_QUALITY, 80])
        if not ok:
            return None
        with self._lock:
            self._disp = (key, buf.tobytes())
            self._disp_time = time.monotonic()
            return self._disp[1]


class _CrowdServer(ThreadingHTTPServer):
    """``ThreadingHTTPServer`` with a real listen backlog (the standard library's is 5: 200
    concurrent clients saw 31 s latencies and timeouts)."""

    request_queue_size = LISTEN_BACKLOG
    daemon_threads = True
    allow_reuse_address = True


class MonitorServer:
    """Serve the monitor page for a provider in a background thread.

    Args:
        provider: a :class:`~sea3d.capture.recorder.Recorder` or :class:`SessionPlayer`.
        host: address to listen on; 127.0.0.1 unless the user asks for another.
        port: TCP port (0 picks a free one; see :attr:`url`).
        preview_width: width of the JPEG previews in pixels.
        disparity_width: width of the disparity preview in pixels.
        live: a live reconstruction's feed (:class:`~sea3d.pipeline.live_publish.LiveFeed`:
            ``live_state() -> dict`` and ``mesh_ply() -> bytes | None``) for ``/live.json``
            and ``/live/mesh.ply``, or None.

    Raises:
        ConfigError: if the address cannot be bound.
    """

    def __init__(
        self,
        provider: MonitorProvider,
        host: str = "127.0.0.1",
        port: int = 8080,
        *,
        preview_width: int = 640,
        disparity_width: int = 320,
        live: Any = None,
    ) -> None:
        self.provider = provider
        self.live = live
        self.cache = _FrameCache(provider, preview_width, disparity_width)
        self._stopping = threading.Event()
        handler = self._make_handler()
        self._busy = threading.BoundedSemaphore(MAX_BUSY_HANDLERS)
        self._streams = threading.BoundedSemaphore(MAX_MJPEG_STREAMS)
        try:
            self.httpd = _CrowdServer((host, port), handler)
        except OSError as err:
            raise ConfigError(f"cannot serve the monitor on {host}:{port}: {err}") from err
        if not _is_loopback(host):
            _log.warning(
                "monitor listens on %s, reachable from other machines; it has no authentication",
                host,
            )
        self.host, self.port = host, int(self.httpd.server_address[1])
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The page's address."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> MonitorServer:
        """Start serving in a daemon thread; returns self."""
        self._thread = threading.Thread(
            target=self.httpd.serve_forever, name="sea3d-monitor", daemon=True
        )
        self._thread.start()
        _log.info("monitor at %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving and close the socket."""
        self._stopping.set()
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def __enter__(self) -> MonitorServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _stats(self) -> dict[str, Any]:
        stats = dict(self.provider.stats())
        seqs = {}
        for s in ("left", "right"):
            latest = self.provider.latest(s)
            seqs[s] = None if latest is None else latest[0]
        stats["frame_seq"] = seqs
        return stats

    def _make_handler(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "sea3d-monitor"
            timeout = SOCKET_TIMEOUT_S  # a stalled client cannot hold its thread for ever

            def log_message(self, format: str, *args: Any) -> None:
                _log.debug("monitor: " + format, *args)

            def _send(
                self, status: int, body: bytes, ctype: str, extra: dict[str, str] | None = None
            ) -> None:
                self.send_response(status)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                for k, v in (extra or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                path = urlparse(self.path).path
                if path in ("/stream/left.mjpg", "/stream/right.mjpg"):
                    if not server._streams.acquire(blocking=False):
                        self._send(503, b"too many MJPEG streams", "text/plain")
                        return
                    try:
                        self._mjpeg(path[8:-5])
                    except (BrokenPipeError, ConnectionResetError, TimeoutError):
                        pass
                    finally:
                        server._streams.release()
                    return
                with server._busy:
                    self._get(path)

            def _get(self, path: str) -> None:
                try:
                    if path in ("/", "/index.html"):
                        self._send(200, _PAGE.encode(), "text/html; charset=utf-8")
                    elif path == "/stats.json":
                        body = json.dumps(json_safe(server._stats())).encode()
                        self._send(200, body, "application/json")
                    elif path in ("/frame/left.jpg", "/frame/right.jpg"):
                        frame = server.cache.frame(path[7:-4])
                        if frame is None:
                            self._send(503, b"no frame yet", "text/plain")
                        else:
                            self._send(200, frame[1], "image/jpeg", {"X-Frame-Seq": str(frame[0])})
                    elif path == "/live.json":
                        if server.live is None:
                            self._send(404, b"no live reconstruction", "text/plain")
                        else:
                            body = json.dumps(json_safe(server.live.live_state())).encode()
                            self._send(200, body, "application/json")
                    elif path == "/live/mesh.ply":
                        ply = server.live.mesh_ply() if server.live is not None else None
                        if ply is None:
                            self._send(503, b"no live mesh yet", "text/plain")
                        else:
                            self._send(200, ply, "application/octet-stream")
                    elif path == "/frame/disparity.jpg":
                        disp = server.cache.disparity()
                        if disp is None:
                            self._send(503, b"no stereo pair yet", "text/plain")
                        else:
                            self._send(200, disp, "image/jpeg")
                    else:
                        self._send(404, b"not found", "text/plain")
                except (BrokenPipeError, ConnectionResetError, TimeoutError):
                    pass

            def _mjpeg(self, stream: str) -> None:
                boundary = "sea3dframe"
                self.send_response(HTTPStatus.OK)
                self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={boundary}")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                last = -1
                while not server._stopping.is_set():
                    frame = server.cache.frame(stream)
                    if frame is None or frame[0] == last:
                        time.sleep(0.03)
                        continue
                    last = frame[0]
                    head = (
                        f"--{boundary}\r\nContent-Type: image/jpeg\r\n"
                        f"Content-Length: {len(frame[1])}\r\nX-Frame-Seq: {frame[0]}\r\n\r\n"
                    )
                    self.wfile.write(head.encode() + frame[1] + b"\r\n")
                    self.wfile.flush()

        return Handler


class SessionPlayer:
    """Replay a recorded session for the monitor (``sea3d monitor SESSION``).

    Plays the stereo pairs in a loop at ``speed`` times real time in a background thread and
    offers the same ``stats()`` / ``latest()`` interface as the recorder; IMU and range show the
    samples nearest to the current frame.

    Args:
        path: the session.
        speed: 1.0 real time; larger is faster.
        loop: start again at the end.

    Raises:
        SessionError: unreadable session; ConfigError for a non-positive speed.
    """

    def __init__(self, path: str | Path, *, speed: float = 1.0, loop: bool = True) -> None:
        from sea3d.io.session import open_session

        if speed <= 0:
            raise ConfigError(f"replay speed must be > 0, got {speed}")
        self.session = open_session(path)
        self.speed, self.loop = speed, loop
        self.match = self.session.match_pairs()
        self.imu = self.session.imu()
        self.sonar = self.session.sonar()
        self._latest: dict[str, tuple[int, Any]] = {}
        self._shown = 0
        self._recent: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self._disk_free_at = -10.0
        self._disk_free_value = 0
        self.running = False

    def start(self) -> SessionPlayer:
        """Start playing in a daemon thread; returns self."""
        self.running = True
        self._thread = threading.Thread(target=self._play, name="sea3d-player", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop playing and close the session."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.running = False
        self.session.close()

    def _play(self) -> None:
        from sea3d.capture.sources import ImageFrame
        from sea3d.errors import SessionError

        ls = self.session.stamps("left")
        n = len(self.match)
        while not self._stop.is_set() and n:
            t_wall0 = time.monotonic()
            t_stamp0 = int(ls[self.match.left_index[0]])
            for k in range(n):
                if self._stop.is_set():
                    return
                i, j = int(self.match.left_index[k]), int(self.match.right_index[k])
                t_ns = int(ls[i])
                due = t_wall0 + (t_ns - t_stamp0) * 1e-9 / self.speed
                self._stop.wait(max(0.0, due - time.monotonic()))
                try:
                    left = self.session.image("left", i, by="index")
                    right = self.session.image("right", j, by="index")
                except SessionError as err:
                    _log.warning("monitor replay: skipping pair at t_ns=%d: %s", t_ns, err)
                    continue
                self._shown += 1
                self._latest["left"] = (self._shown, ImageFrame(t_ns, left))
                self._latest["right"] = (self._shown, ImageFrame(t_ns, right))
                self._recent = [*self._recent[-30:], time.monotonic()]
            if not self.loop:
                break
        self.running = False

    def latest(self, stream: str) -> tuple[int, Any] | None:
        """(sequence number, ImageFrame) of the frame on show, or None."""
        return self._latest.get(stream)

    def _nearest(self, t_all: np.ndarray, t_ns: int) -> int | None:
        if t_all.size == 0:
            return None
        j = int(np.clip(np.searchsorted(t_all, t_ns), 0, t_all.size - 1))
        if j > 0 and abs(int(t_all[j - 1]) - t_ns) < abs(int(t_all[j]) - t_ns):
            j -= 1
        return j

    def _disk_free(self, measure: Any) -> int:
        now = time.monotonic()
        if now - self._disk_free_at > 1.0:  # at most one statvfs a second, however many ask
            self._disk_free_value = int(measure(self.session.path))
            self._disk_free_at = now
        return self._disk_free_value

    def stats(self) -> dict[str, Any]:
        """Figures in the recorder's layout: frames shown, fps, unpaired as drops, disk free."""
        from sea3d.io.disk_space import disk_free_bytes

        rec = self._recent[-10:]
        fps = (len(rec) - 1) / (rec[-1] - rec[0]) if len(rec) >= 2 and rec[-1] > rec[0] else 0.0
        cur = self._latest.get("left")
        t_ns = cur[1].t_ns if cur else None
        imu = sonar = None
        if t_ns is not None:
            k = self._nearest(self.imu.t_ns, t_ns)
            if k is not None:
                imu = {
                    "t_ns": int(self.imu.t_ns[k]),
                    "accel_mps2": self.imu.accel_mps2[k].tolist(),
                    "gyro_radps": self.imu.gyro_radps[k].tolist(),
                }
            k = self._nearest(self.sonar.t_ns, t_ns)
            if k is not None:
                sonar = {
                    "t_ns": int(self.sonar.t_ns[k]),
                    "range_m": float(self.sonar.range_m[k]),
                    "confidence": float(self.sonar.confidence[k]),
                }
        return {
            "running": self.running,
            "elapsed_s": time.monotonic() - self._t0,
            "frames": {"left": self._shown, "right": self._shown},
            "dropped": {"left": self.match.unpaired_left, "right": self.match.unpaired_right},
            "fps": {"left": fps, "right": fps},
            "disk_free_bytes": self._disk_free(disk_free_bytes),
            "disk_left_s": None,
            "imu": imu,
            "sonar": sonar,
            "t_ns": t_ns,
            "pairs": len(self.match),
            "stop_reason": None,
            "mode": "replay",
            "source": str(self.session.path),
        }
