"""What a simulated survey writes, and how the ground-truth depth is stored.

Runs ``simulate_survey`` (the lake scene through the paper's dome rig, the ``sea3d sim``
defaults) for a few frames into a temporary folder session, per water type, and prints:

1. bytes per frame on disk of the images (lossless PNG, the session writer's default) and of the
   ground truth, and wall seconds per frame, beside ``estimate_survey_cost`` (what ``sea3d sim``
   prints before it starts);
2. the ground-truth depth maps stored in each candidate format: size against ``.npy``, encoding
   and decoding time, and whether they read back bit for bit (NaN included).

    PYTHONPATH=src python benchmarks/bench_sim_storage.py [--size 1920x1080] [--frames 4]
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import tifffile

from sea3d.io.ground_truth import read_gt_depth
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter
from sea3d.refraction.presets import paper_rig
from sea3d.sim.scene import builtin_scene
from sea3d.sim.survey import (
    SurveyConfig,
    estimate_survey_cost,
    simulate_survey,
)


def folder_bytes(path: Path, pattern: str) -> int:
    return sum(p.stat().st_size for p in path.glob(pattern) if p.is_file())


def survey_section(size: tuple[int, int], frames: int, water: str) -> list[np.ndarray]:
    rig = paper_rig("dome", size_px=size)
    config = SurveyConfig(frames=frames, water=water)
    est = estimate_survey_cost(size[0], size[1], config)
    times: list[float] = []
    last = [time.perf_counter()]

    def tick(_n: int) -> None:
        now = time.perf_counter()
        times.append(now - last[0])
        last[0] = now

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        with SessionWriter(out, format="folder", rig_yaml=rig_to_yaml(rig)) as writer:
            last[0] = time.perf_counter()
            simulate_survey(builtin_scene("lake"), rig, config, writer, out / "gt", progress=tick)
        images = folder_bytes(out / "left", "*.png") + folder_bytes(out / "right", "*.png")
        gt_depth = folder_bytes(out / "gt" / "depth", "*")
        gt_id = folder_bytes(out / "gt" / "object_id", "*")
        depths = [read_gt_depth(p) for p in sorted((out / "gt" / "depth").glob("*"))]
    # The first frame carries the one-time ray generation through the dome.
    per_frame_s = statistics.median(times[1:]) if len(times) > 1 else times[0]
    mb = 1e-6
    print(f"\n{water} water, {size[0]}x{size[1]}, {frames} frames (lake, dome rig)")
    print(f"  {'per frame':<28}{'measured':>12}{'estimate':>12}")
    print(f"  {'images (PNG), MB':<28}{images / frames * mb:12.2f}"
          f"{est.image_bytes / frames * mb:12.2f}")
    print(f"  {'ground truth, MB':<28}{(gt_depth + gt_id) / frames * mb:12.2f}"
          f"{est.gt_bytes / frames * mb:12.2f}   (depth {gt_depth / frames * mb:.2f}, "
          f"object id {gt_id / frames * mb:.3f})")
    print(f"  {'wall s (median, frames 2+)':<28}{per_frame_s:12.2f}{est.seconds / frames:12.2f}"
          f"   (first frame {times[0]:.2f} s: rays through the dome)")
    px = size[0] * size[1]
    print(f"  per pixel of one view: images {images / frames / 2 / px:.2f} B, ground truth "
          f"{(gt_depth + gt_id) / frames / px:.2f} B; wall {per_frame_s / px * 1e6:.2f} s per "
          f"megapixel pair")
    return depths


def encode(name: str, depth: np.ndarray) -> tuple[bytes, float]:
    buf = io.BytesIO()
    t0 = time.perf_counter()
    if name == "npy":
        np.save(buf, depth)
    elif name == "npz (zlib)":
        np.savez_compressed(buf, depth=depth)
    elif name.startswith("tiff"):
        level = int(name.split("level ")[1].rstrip(")"))
        tifffile.imwrite(buf, depth, compression="zlib", predictor=3,
                         compressionargs={"level": level})
    elif name == "png16 mm (lossy)":
        mm = np.where(np.isfinite(depth), np.round(depth * 1000.0), 0).clip(0, 65535)
        _ok, png = cv2.imencode(".png", mm.astype(np.uint16))
        buf.write(png.tobytes())
    return buf.getvalue(), time.perf_counter() - t0


def decode(name: str, raw: bytes) -> np.ndarray:
    if name == "npy":
        return np.asarray(np.load(io.BytesIO(raw)))
    if name == "npz (zlib)":
        return np.asarray(np.load(io.BytesIO(raw))["depth"])
    if name.startswith("tiff"):
        return np.asarray(tifffile.imread(io.BytesIO(raw)))
    mm = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED).astype(np.float32)
    mm[mm == 0] = np.nan
    return mm / np.float32(1000.0)


def format_section(depths: list[np.ndarray]) -> None:
    print(f"\nground-truth depth formats ({len(depths)} maps of {depths[0].shape[1]}x"
          f"{depths[0].shape[0]}; medians)")
    print(f"  {'format':<30}{'MB':>8}{'of npy':>8}{'enc ms':>8}{'dec ms':>8}  lossless")
    names = ["npy", "npz (zlib)", "tiff zlib+pred3 (level 1)", "tiff zlib+pred3 (level 6)",
             "png16 mm (lossy)"]
    ref = statistics.median(len(encode("npy", d)[0]) for d in depths)
    for name in names:
        sizes, enc, dec, exact, err = [], [], [], True, 0.0
        for d in depths:
            raw, t_enc = encode(name, d)
            t0 = time.perf_counter()
            back = decode(name, raw)
            dec.append(time.perf_counter() - t0)
            sizes.append(len(raw))
            enc.append(t_enc)
            exact &= bool(back.dtype == np.float32 and np.array_equal(back, d, equal_nan=True))
            both = np.isfinite(d) & np.isfinite(back)
            if both.any():
                err = max(err, float(np.max(np.abs(back[both] - d[both]))))
        size = statistics.median(sizes)
        note = "bit for bit" if exact else f"no (max error {err * 1e3:.2f} mm)"
        print(f"  {name:<30}{size * 1e-6:8.3f}{size / ref:8.2f}{statistics.median(enc) * 1e3:8.0f}"
              f"{statistics.median(dec) * 1e3:8.0f}  {note}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="960x540", help="WxH (default 960x540)")
    parser.add_argument("--frames", type=int, default=4, help="frames per water type")
    parser.add_argument("--water", nargs="+", default=["coastal", "none"])
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"sea3d simulator storage benchmark; {os.cpu_count()} CPUs, load average {load:.1f}")
    depths: list[np.ndarray] = []
    for water in args.water:
        depths += survey_section((w, h), args.frames, water)
    format_section(depths)
    return 0


if __name__ == "__main__":
    sys.exit(main())
