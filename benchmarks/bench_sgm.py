"""sea3d's SGM against OpenCV MODE_SGBM_3WAY on two 1080p textures.

- ``noise``: 3x3-blurred uniform noise at a constant disparity of 64 (the input of
  ``bench_stereo_gpu.py --cpu-only``);
- ``multiscale``: the docs' synthetic scene (``bench_stereo.py``: fine blurred noise plus a
  coarse pattern, a slanted plane at 40-90 px and a box at 200 px, brightness change).

Both searched over 0..255, the engines interleaved in one process after a warm-up; prints
medians of ``--repeats`` runs of wall and CPU time (process time, all threads), their ratios,
bad-2 % against the known disparity (over pixels known in both maps, and sea3d's matched
pixels only), and sea3d's stage timings.

``--session DIR`` adds the ``dive``: rectified frames of a simulated session (e.g.
``out/bench_process/lake_640x360_80``, made by ``bench_process.py``), both engines over the
disparity range ``bench_process.py`` gives them (depth from 0.5 m: 0..79 at 640x360), OpenCV
as configured by default (grey 5x5 blocks, P1/P2 8/32 x 25, uniqueness 10, speckles 100/2, as
in the paper's chain of ``bench_process.py``); timed per frame pair on the
rectified images, and the depth of each engine (same rectification, same refractive
triangulation) against the simulator's depth maps: median and p90 of ``|z - z_true| / z``.

    PYTHONPATH=src python benchmarks/bench_sgm.py [--repeats 3] [--textures noise,multiscale]
        [--session out/bench_process/lake_640x360_80 --frames 6]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import cv2
import numpy as np


def noise_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 256, (height, width + 64)).astype(np.uint8),
                            (3, 3), 0)
    gt = np.full((height, width), 64.0, np.float32)
    return base[:, :width].copy(), base[:, 64:].copy(), gt


def multiscale_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from bench_stereo import synthetic_pair

    return synthetic_pair(width, height)


def dive(session: str, n_frames: int, repeats: int) -> None:
    """The ``dive`` texture: see the module docstring."""
    from pathlib import Path

    import tifffile

    from sea3d.io.rig_file import rig_from_yaml
    from sea3d.io.session import open_session
    from sea3d.rectify import rectify_images
    from sea3d.stereo import OpenCVSgbmConfig, match
    from sea3d.stereo.depth import compute_depth
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    root = Path(session)
    with open_session(root) as s:
        rig = rig_from_yaml(s.rig_yaml, "the session's rig")
        stereo = StereoDepth(rig, DepthConfig(min_depth_m=0.5))
        pairs = s.match_pairs()
        stamps = s.stamps("left")
        picks = np.linspace(0, len(pairs) - 1, n_frames).round().astype(int)
        raw = [(s.image("left", int(pairs.left_index[i]), by="index"),
                s.image("right", int(pairs.right_index[i]), by="index"),
                int(stamps[int(pairs.left_index[i])])) for i in picks]
    maps = stereo.maps
    d_max = stereo.max_disparity_px
    engines = {"sea3d": stereo.engine_config,
               "opencv-3way": OpenCVSgbmConfig(max_disparity_px=d_max, mode="sgbm_3way")}
    rect = [rectify_images(maps, left, right) for left, right, _ in raw]
    wall: dict[str, list[float]] = {e: [] for e in engines}
    cpu: dict[str, list[float]] = {e: [] for e in engines}
    for _ in range(repeats):
        for rl, rr in rect:
            for name, cfg in engines.items():
                c0, t0 = time.process_time(), time.perf_counter()
                match(rl, rr, cfg)
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
    print(f"\ndive ({root.name}, {maps.width}x{maps.height}, disparities 0..{d_max}, "
          f"{len(rect)} frames x {repeats}; medians per frame):")
    mw = {e: statistics.median(v) for e, v in wall.items()}
    mc = {e: statistics.median(v) for e, v in cpu.items()}
    for name, cfg in engines.items():
        errs = []
        for left, right, t_ns in raw:
            res = compute_depth(maps, left, right, cfg, max_depth_m=stereo.max_depth_m,
                                tables=stereo.tables)
            gt = tifffile.imread(root / "gt" / "depth" / f"{t_ns}.tiff")
            v, u = np.nonzero(np.isfinite(res.depth_m))
            ry = np.clip(np.round(maps.map_left_y[v, u]).astype(int), 0, gt.shape[0] - 1)
            rx = np.clip(np.round(maps.map_left_x[v, u]).astype(int), 0, gt.shape[1] - 1)
            z = gt[ry, rx]
            ok = np.isfinite(z)
            errs.append(100 * np.abs(res.points_left[ok, 2] - z[ok]) / z[ok])
        e = np.concatenate(errs)
        dens = 100 * len(e) / (len(raw) * maps.width * maps.height)
        print(f"  {name:12s} wall {mw[name]:6.4f} s  CPU {mc[name]:6.4f} s  depth error median "
              f"{np.median(e):.3f} % p90 {np.percentile(e, 90):.3f} %  with depth {dens:5.1f} %")
    print(f"  sea3d / 3WAY: wall {mw['sea3d'] / mw['opencv-3way']:.2f}x, CPU "
          f"{mc['sea3d'] / mc['opencv-3way']:.2f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--textures", default="noise,multiscale")
    ap.add_argument("--session", help="a simulated session for the dive frames")
    ap.add_argument("--frames", type=int, default=6, help="dive frames (with --session)")
    args = ap.parse_args()

    from sea3d.eval import disparity_metrics
    from sea3d.stereo import make_config, match
    from sea3d.stereo.sgm import warm_up

    warm_up()
    engines = {"sea3d": make_config("sea3d", 255), "opencv-3way": make_config("opencv-3way", 255)}
    print(f"{args.width}x{args.height}, disparities 0..255, {os.cpu_count()} CPUs, medians of "
          f"{args.repeats} interleaved runs; load before {os.getloadavg()[0]:.2f}")
    if args.session:
        dive(args.session, args.frames, args.repeats)
    for texture in filter(None, args.textures.split(",")):
        left, right, gt = {"noise": noise_pair, "multiscale": multiscale_pair}[texture](
            args.width, args.height)
        wall: dict[str, list[float]] = {e: [] for e in engines}
        cpu: dict[str, list[float]] = {e: [] for e in engines}
        last = {}
        for _ in range(args.repeats):
            for name, cfg in engines.items():
                c0, t0 = time.process_time(), time.perf_counter()
                last[name] = match(left, right, cfg)  # type: ignore[arg-type]
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
        mw = {e: statistics.median(v) for e, v in wall.items()}
        mc = {e: statistics.median(v) for e, v in cpu.items()}
        print(f"\n{texture}:")
        for name in engines:
            m = disparity_metrics(last[name].disparity_px, gt)
            print(f"  {name:12s} wall {mw[name]:6.3f} s  CPU {mc[name]:6.3f} s  bad-2 "
                  f"{m.bad_2:6.3f} %  density {m.density:5.1f} %")
        res = last["sea3d"]
        mm = disparity_metrics(np.where(res.measured, res.disparity_px, np.nan), gt)
        print(f"  sea3d matched pixels: bad-2 {mm.bad_2:.3f} % density {mm.density:.1f} %")
        print(f"  sea3d / 3WAY: wall {mw['sea3d'] / mw['opencv-3way']:.2f}x, CPU "
              f"{mc['sea3d'] / mc['opencv-3way']:.2f}x")
        print("  sea3d stages (last run, s): " + ", ".join(
            f"{k} {v:.3f}" for k, v in res.timings_s.items()))
    print(f"\nload after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
