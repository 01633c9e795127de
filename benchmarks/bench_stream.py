"""Tether stream on loopback: bandwidth, end-to-end latency and image quality, at 960x540 and
1920x1080 per camera (left and right side by side), against the raw MCAP rate.

For each size the sender (``StreamSender``, libx264 or a hardware encoder) and the receiver
(``StreamReceiver``) run in this process, on 127.0.0.1, paced at 10 frames per second.
Printed per size, median of ``--repeats`` runs:

- kbit/s on the wire (UDP payload) at the target bit rate;
- end-to-end latency, ms: from handing the frame to the encoder to the decoded frame at the
  receiver (both on this machine's clock; the SEI carries the send time);
- PSNR of the decoded left and right images against the source frames at the stream size;
- sender CPU ms per frame (convert + encode) and the whole process's CPU seconds per second;

and, on the same frames, the references: the raw MCAP rate (PNG, the recorder's default: what
sending the recording would need), raw RGB, and JPEG quality 80 (the Foxglove live view).

Frames: the real Sea3D lake frames (left = frame k, right = frame k+1) from
``$SEA3D_TEST_DATA/underwater/sea3d_field_left``, else synthetic textured frames. Usage::

    python benchmarks/bench_stream.py                 # 40 frames, 3 repeats
    python benchmarks/bench_stream.py --repeats 5 --kbps 2000 4000 8000
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from sea3d.capture.stream import StreamConfig, StreamReceiver, StreamSender
from sea3d.io.session import SessionWriter

FPS = 10.0


def load_frames(n: int) -> tuple[list[np.ndarray], str]:
    root = Path(
        os.environ.get(
            "SEA3D_TEST_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
        )
    )
    folder = root / "underwater" / "sea3d_field_left"
    files = sorted(folder.glob("*.jpg"))[: n + 1] if folder.is_dir() else []
    if len(files) >= 2:
        imgs = [cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB) for f in files]
        return [cv2.resize(i, (1920, 1080)) for i in imgs], f"real Sea3D lake frames ({folder})"
    rng = np.random.default_rng(0)
    imgs = []
    for _ in range(n + 1):
        noise = rng.normal(0, 1, size=(135, 240, 3)).astype(np.float32)
        img = cv2.resize(cv2.GaussianBlur(noise, (0, 0), 3), (1920, 1080))
        imgs.append(np.clip(img * 60 + 128, 0, 255).astype(np.uint8))
    return imgs, "synthetic textured frames"


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_once(frames: list[np.ndarray], size: tuple[int, int], kbps: float, n: int) -> dict:
    url = f"udp://127.0.0.1:{free_udp_port()}"
    w, h = size
    pairs = [(frames[k], frames[k + 1]) for k in range(n)]
    small = [
        (cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA),
         cv2.resize(b, (w, h), interpolation=cv2.INTER_AREA))
        for a, b in pairs
    ]  # fmt: skip
    rx = StreamReceiver(url, idle_timeout_s=1.5, on_event=lambda _m: None)
    got = []
    th = threading.Thread(target=lambda: got.extend(rx.frames()), daemon=True)
    th.start()

    def paced():
        t0 = time.monotonic()
        for k, (a, b) in enumerate(pairs):
            delay = t0 + k / FPS - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            yield round(k * 1e9 / FPS), a, b

    cfg = StreamConfig(url=url, bitrate_kbps=kbps, size_px=size, fps=FPS)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    summary = StreamSender(cfg).run(paced())
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    th.join(15)
    rx.close()
    p = [
        min(psnr(f.left, small[f.seq][0]), psnr(f.right, small[f.seq][1]))
        for f in got
        if f.seq >= 0 and f.left is not None and f.right is not None
    ]
    lat = [f.latency_ms for f in got if f.latency_ms is not None]
    return {
        "encoder": summary.encoder,
        "kbps": summary.kbps,
        "latency_ms": float(np.median(lat)) if lat else float("nan"),
        "latency_p90_ms": float(np.percentile(lat, 90)) if lat else float("nan"),
        "psnr_db": float(np.median(p)) if p else float("nan"),
        "encode_ms": summary.encode_ms_median,
        "cpu_per_s": cpu / wall,
        "received": len(got),
        "sent": summary.frames,
    }


def references(frames: list[np.ndarray], size: tuple[int, int], n: int) -> dict:
    w, h = size
    small = [cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames[: n + 1]]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "raw.mcap"
        with SessionWriter(path, image_encoding="png") as wr:
            for k in range(n):
                wr.write_stereo(k * 100_000_000, small[k], small[k + 1])
        mcap_bytes = path.stat().st_size
    jpeg_bytes, jpeg_psnr = 0, []
    for k in range(n):
        for img in (small[k], small[k + 1]):
            _ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 80])
            jpeg_bytes += buf.size
            jpeg_psnr.append(psnr(cv2.imdecode(buf, 1)[..., ::-1], img))
    per_s = FPS / n
    return {
        "mcap_png_kbps": mcap_bytes * 8 / 1000 * per_s,
        "raw_rgb_kbps": w * h * 3 * 2 * 8 / 1000 * FPS,
        "jpeg80_kbps": jpeg_bytes * 8 / 1000 * per_s,
        "jpeg80_psnr_db": float(np.median(jpeg_psnr)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kbps", type=float, nargs="+", default=[4000.0])
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    frames, what = load_frames(args.frames)
    n = min(args.frames, len(frames) - 1)
    print(
        f"frames: {what}; {n} stereo pairs at {FPS:g} fps, loopback 127.0.0.1, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )
    print(f"{'size/camera':>12} {'target':>7} {'kbit/s':>8} {'lat ms':>7} {'p90 ms':>7} "
          f"{'PSNR dB':>8} {'enc ms':>7} {'CPU/s':>6} {'recv':>7}  encoder")  # fmt: skip
    for size in ((960, 540), (1920, 1080)):
        first_kbps = 0.0
        for kbps in args.kbps:
            runs = [run_once(frames, size, kbps, n) for _ in range(args.repeats)]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0] if k != "encoder"}
            first_kbps = first_kbps or med["kbps"]
            print(
                f"{size[0]:>6}x{size[1]:<5} {kbps:>7.0f} {med['kbps']:>8.0f} "
                f"{med['latency_ms']:>7.1f} {med['latency_p90_ms']:>7.1f} {med['psnr_db']:>8.2f} "
                f"{med['encode_ms']:>7.1f} {med['cpu_per_s']:>6.2f} "
                f"{int(med['received']):>3}/{int(med['sent']):<3}  {runs[0]['encoder']}"
            )
        ref = references(frames, size, n)
        print(
            f"{'':>12} reference, same frames: raw MCAP (PNG) {ref['mcap_png_kbps']:.0f} kbit/s "
            f"({ref['mcap_png_kbps'] / first_kbps:.0f}x the first stream above), raw RGB "
            f"{ref['raw_rgb_kbps']:.0f} kbit/s, JPEG q80 {ref['jpeg80_kbps']:.0f} kbit/s at "
            f"{ref['jpeg80_psnr_db']:.2f} dB"
        )


if __name__ == "__main__":
    main()
