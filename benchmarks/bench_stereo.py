"""Stereo matching speed and memory: sea3d's SGM against OpenCV StereoSGBM.

Same input, same process: a synthetic 1920x1080 textured scene (a slanted background plane at
40-90 px and a box at 200 px, with a brightness change between the views) matched over 256
disparities (0..255) by sea3d's engine and by OpenCV MODE_SGBM and MODE_SGBM_3WAY. Prints the
median of several timed runs (numba compilation excluded: a warm-up run comes first), the
ratios, the accuracy against the known disparity, and the peak resident memory of each engine
measured in a fresh subprocess (``VmHWM`` from /proc/self/status; tracemalloc cannot see numba's
or OpenCV's buffers).

Run: ``PYTHONPATH=src python benchmarks/bench_stereo.py [--repeats 5] [--width 1920 --height 1080]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ENGINES = ("sea3d", "opencv-sgbm", "opencv-3way")


def synthetic_pair(
    width: int, height: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left, right uint8 RGB and the left view's true disparity (NaN where occluded)."""
    rng = np.random.default_rng(seed)

    def texture(h: int, w: int) -> np.ndarray:
        fine = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.0)
        mid = cv2.resize(rng.random((h // 16, w // 16)).astype(np.float32), (w, h))
        return 255 * (0.6 * (fine - fine.min()) / np.ptp(fine) + 0.4 * mid)

    pad = 400
    bg = texture(height, width + pad)
    fg = texture(height, width + pad)
    c0, c1 = 40.0, 50.0 / width  # background disparity 40 .. 90 px, left to right
    d_fg = 200.0
    y0, y1 = height // 4, 3 * height // 4
    x0, x1 = int(0.45 * width), int(0.75 * width)
    u = np.arange(width, dtype=np.float32)
    ys = np.arange(height, dtype=np.float32)[:, None].repeat(width, 1)
    # left view: background texture at u, box texture at u inside the box
    left = cv2.remap(bg, np.tile(u + pad / 2, (height, 1)), ys, cv2.INTER_LINEAR)
    left[y0:y1, x0:x1] = fg[y0:y1, x0 + pad // 2 : x1 + pad // 2]
    gt = np.tile(c0 + c1 * u, (height, 1)).astype(np.float32)
    gt[y0:y1, x0:x1] = d_fg
    # right view: background point seen at left u_l lands at u_r = u_l - (c0 + c1 u_l)
    u_l = (u + c0) / (1.0 - c1)
    right = cv2.remap(bg, np.tile(u_l + pad / 2, (height, 1)), ys, cv2.INTER_LINEAR)
    rx0, rx1 = int(x0 - d_fg), int(x1 - d_fg)
    right[y0:y1, rx0:rx1] = fg[y0:y1, x0 + pad // 2 : x1 + pad // 2]
    # background pixels of the left view hidden behind the box in the right view
    u_r_bg = u - (c0 + c1 * u)
    hidden = (u_r_bg >= rx0) & (u_r_bg < rx1) & ~((u >= x0) & (u < x1))
    gt[y0:y1][:, hidden] = np.nan
    right = 0.8 * right + 25.0  # brightness and contrast change between the views
    to_rgb = [np.clip(np.dstack([im, im * 0.9, im * 0.7]), 0, 255).astype(np.uint8)
              for im in (left, right)]
    return to_rgb[0], to_rgb[1], gt


def _config(engine: str) -> object:
    from sea3d.stereo import make_config

    return make_config(engine, 255)


def _peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(engine: str, inputs: Path) -> None:
    """Run one engine once (after a warm-up on a tiny pair) and print its peak memory."""
    from sea3d.stereo import match
    from sea3d.stereo.sgm import warm_up

    data = np.load(inputs)
    left, right = data["left"], data["right"]
    if engine == "sea3d":
        warm_up()
    base = _peak_rss_mb()
    res = match(left, right, _config(engine))  # type: ignore[arg-type]
    print(json.dumps({"engine": engine, "peak_rss_mb": _peak_rss_mb(), "before_mb": base,
                      "match_s": res.timings_s["match_s"]}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--worker", choices=ENGINES)
    ap.add_argument("--inputs", type=Path)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.inputs)
        return

    import numba

    from sea3d.eval import disparity_metrics
    from sea3d.stereo import match
    from sea3d.stereo.sgm import warm_up

    left, right, gt = synthetic_pair(args.width, args.height)
    print(f"input: synthetic {args.width}x{args.height} RGB pair, disparities 0..255, "
          f"{os.cpu_count()} CPUs, numba threads {numba.get_num_threads()}, "
          f"OpenCV threads {cv2.getNumThreads()}")
    print(f"numba warm-up (compile or cache load): {warm_up():.2f} s (excluded below)")
    times: dict[str, list[float]] = {e: [] for e in ENGINES}
    last = {}
    for _ in range(args.repeats):
        for engine in ENGINES:  # interleaved, so load changes hit all engines alike
            t0 = time.perf_counter()
            res = match(left, right, _config(engine))  # type: ignore[arg-type]
            times[engine].append(time.perf_counter() - t0)
            last[engine] = res
    med = {e: statistics.median(v) for e, v in times.items()}

    with tempfile.TemporaryDirectory() as tmp:
        inputs = Path(tmp) / "pair.npz"
        np.savez(inputs, left=left, right=right)
        mem = {}
        for engine in ENGINES:
            out = subprocess.run(
                [sys.executable, __file__, "--worker", engine, "--inputs", str(inputs)],
                capture_output=True, text=True, check=True, env=os.environ.copy(),
            )
            mem[engine] = json.loads(out.stdout.strip().splitlines()[-1])

    print(f"\n{'engine':14s} {'median s':>9s} {'min s':>7s} {'vs sea3d':>9s} {'peak RSS MB':>12s} "
          f"{'bad-2 %':>8s} {'density %':>10s}")
    for engine in ENGINES:
        m = disparity_metrics(last[engine].disparity_px, gt)
        print(f"{engine:14s} {med[engine]:9.3f} {min(times[engine]):7.3f} "
              f"{med[engine] / med['sea3d']:8.2f}x {mem[engine]['peak_rss_mb']:12.0f} "
              f"{m.bad_2:8.2f} {m.density:10.1f}")
    print(f"\nsea3d is {med['opencv-sgbm'] / med['sea3d']:.2f}x as fast as MODE_SGBM and "
          f"{med['opencv-3way'] / med['sea3d']:.2f}x as fast as MODE_SGBM_3WAY "
          f"(medians of {args.repeats}).")
    stages = {k: round(v, 3) for k, v in last["sea3d"].timings_s.items()}
    print(f"sea3d stages (last run, s): {stages}")


if __name__ == "__main__":
    main()
