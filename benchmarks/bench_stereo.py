"""Stereo matching speed and memory: sea3d's SGM against OpenCV StereoSGBM.

Same input, same process: a synthetic 1920x1080 textured scene (a slanted background plane at
40-90 px and a box at 200 px, with a brightness change between the views) matched over 256
disparities (0..255) by sea3d's engine and by OpenCV MODE_SGBM and MODE_SGBM_3WAY. Prints the
median of several timed runs (numba compilation excluded: a warm-up run comes first), the
ratios, the accuracy against the known disparity, and the peak resident memory of each engine
measured in a fresh subprocess (``VmHWM`` from /proc/self/status; tracemalloc cannot see numba's
or OpenCV's buffers).

Run: ``PYTHONPATH=src python benchmarks/bench_stereo.py [--repeats 5]``;
``--middlebury ../shared/data/stereo_gt``, ``--refraction`` and ``--underwater`` print the
accuracy tables of benchmarks/results/stereo.md instead.
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


MIDDLEBURY = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 15),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 31),
    "cones": ("im2.png", "im6.png", "disp2.png", 4, 63),
    "teddy": ("im2.png", "im6.png", "disp2.png", 4, 63),
}


def most_confident(disparity: np.ndarray, confidence: np.ndarray, gt: np.ndarray,
                   density_percent: float) -> np.ndarray:
    """``disparity`` kept on its most confident pixels, as many as ``density_percent`` of the
    known ground truth; filled pixels (confidence 0) last, nearest to a matched pixel first."""
    known = np.isfinite(gt) & (gt > 0)
    filled = np.isfinite(disparity) & (confidence <= 0)
    dist = cv2.distanceTransform(filled.astype(np.uint8), cv2.DIST_L2, 3)
    rank = np.where(filled, -1e-3 * dist / (1.0 + dist), confidence)
    score = np.where(np.isfinite(disparity) & known, rank, -1.0)[known]
    n = round(density_percent / 100.0 * known.sum())
    keep = np.zeros(score.size, bool)
    keep[np.argsort(-score, kind="stable")[:n]] = True
    mask = np.zeros_like(known)
    mask[known] = keep
    return np.where(mask, disparity, np.nan)


def _middlebury(root: Path, scene: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    ln, rn, gn, scale, md = MIDDLEBURY[scene]
    folder = root / scene
    left = cv2.cvtColor(cv2.imread(str(folder / ln)), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / rn)), cv2.COLOR_BGR2RGB)
    raw = cv2.imread(str(folder / gn), cv2.IMREAD_UNCHANGED)
    gt = np.where(raw > 0, raw / scale, np.nan).astype(np.float32)
    return left, right, gt, md


def middlebury_table(root: Path) -> None:
    """Accuracy of sea3d (default: dense; and matched pixels only) and OpenCV on Middlebury:
    bad-X over pixels known in both maps, all-pixels bad-2 (missing = bad), and sea3d's bad-2
    at each OpenCV engine's density (its most confident pixels)."""
    from sea3d.eval import disparity_metrics
    from sea3d.stereo import OpenCVSgbmConfig, SgmConfig, match

    refs = {
        "OpenCV SGBM w3": ("sgbm", 3), "OpenCV SGBM w5": ("sgbm", 5),
        "OpenCV HH w3": ("hh", 3), "OpenCV HH w5": ("hh", 5),
        "OpenCV SGBM_3WAY w5": ("sgbm_3way", 5),
    }
    print("| scene | engine | bad-0.5 % | bad-1 % | bad-2 % | bad-4 % | EPE px | density % |"
          " bad-2 all % | sea3d bad-2 % at this density |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for scene in MIDDLEBURY:
        left, right, gt, md = _middlebury(root, scene)
        ours = match(left, right, SgmConfig(max_disparity_px=md))
        rows = [("sea3d (default, dense)", ours.disparity_px, ""),
                ("sea3d matched pixels (--no-fill)",
                 match(left, right, SgmConfig(max_disparity_px=md, fill_max_px=0)).disparity_px,
                 "")]
        for name, (mode, block) in refs.items():
            d = match(left, right, OpenCVSgbmConfig(max_disparity_px=md, mode=mode,  # type: ignore[arg-type]
                                                    block_size_px=block)).disparity_px
            dens = disparity_metrics(d, gt).density
            eq = disparity_metrics(most_confident(ours.disparity_px, ours.confidence, gt, dens),
                                   gt)
            rows.append((name, d, f"{eq.bad_2:.2f}"))
        for name, d, eq_s in rows:
            m = disparity_metrics(d, gt)
            print(f"| {scene} | {name} | {m.bad_0_5:.2f} | {m.bad_1:.2f} | {m.bad_2:.2f} | "
                  f"{m.bad_4:.2f} | {m.epe_px:.3f} | {m.density:.1f} | {m.bad_2_all:.2f} | "
                  f"{eq_s} |")


def _render_plane(cam: object, T_left_cam: np.ndarray, depth_m: float, tex: np.ndarray,
                  half_extent_m: float) -> np.ndarray:
    """Ray-cast a camera's view of the textured plane z = depth_m (left frame)."""
    h, w = cam.height, cam.width  # type: ignore[attr-defined]
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = cam.unproject(np.column_stack([uu.ravel(), vv.ravel()]))  # type: ignore[attr-defined]
    o = rays.origins @ T_left_cam[:3, :3].T + T_left_cam[:3, 3]
    dvec = rays.directions @ T_left_cam[:3, :3].T
    s = (depth_m - o[:, 2]) / dvec[:, 2]
    n = tex.shape[0]
    mx = (((o[:, 0] + s * dvec[:, 0]) / half_extent_m + 1) * 0.5 * (n - 1)).reshape(h, w)
    my = (((o[:, 1] + s * dvec[:, 1]) / half_extent_m + 1) * 0.5 * (n - 1)).reshape(h, w)
    img = cv2.remap(tex, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT)
    return np.clip(img, 0, 255).astype(np.uint8)


def refraction_table(width: int, height: int) -> None:
    """Median |depth error| on rendered dome/flat-port planes: refraction-corrected
    triangulation against the pinhole-in-water baseline (the in-air pinholes, f B / d)."""
    from sea3d.geometry.rig import StereoRig
    from sea3d.rectify import rectify_rig
    from sea3d.refraction.presets import paper_rig
    from sea3d.stereo import SgmConfig
    from sea3d.stereo.depth import compute_depth, max_disparity_for_depth

    rng = np.random.default_rng(0)
    n = 2048
    base = cv2.GaussianBlur(rng.random((n, n)).astype(np.float32), (0, 0), 1.5)
    base = (base - base.min()) / np.ptp(base)
    coarse = cv2.resize(rng.random((n // 32, n // 32)).astype(np.float32), (n, n))
    tex = (255 * (0.7 * base + 0.3 * coarse)).astype(np.float32)
    print(f"| port | depth m | corrected median err % | pinhole-in-water median err % |"
          f" virtual pinhole RMS / max px |  ({width}x{height})")
    print("|---|---|---|---|---|")
    for port in ("dome", "flat"):
        rig = paper_rig(port=port, size_px=(width, height))  # type: ignore[arg-type]
        maps = rectify_rig(rig, depth_range_m=(1.0, 5.0))
        naive_rig = StereoRig(left=rig.left.pinhole, right=rig.right.pinhole,  # type: ignore[attr-defined]
                              T_left_right=rig.T_left_right)
        naive = rectify_rig(naive_rig)
        rep = maps.report_left
        assert rep is not None
        for z0 in (1.0, 2.0, 3.0, 5.0):
            left = _render_plane(rig.left, np.eye(4), z0, tex, 1.3 * z0)
            right = _render_plane(rig.right, rig.T_left_right, z0, tex, 1.3 * z0)
            errs = []
            for m in (maps, naive):
                cfg = SgmConfig(max_disparity_px=max_disparity_for_depth(m, 0.8))
                res = compute_depth(m, left, right, cfg)
                errs.append(100 * float(np.median(np.abs(res.points_left[:, 2] - z0))) / z0)
            print(f"| {port} | {z0:.1f} | {errs[0]:.3f} | {errs[1]:.2f} | "
                  f"{rep.rms_px:.3f} / {rep.max_px:.3f} |")


def _look_down(height_m: float, tilt_deg: float) -> np.ndarray:
    """T_world_left of a camera at (0.3, -0.5, height) looking down, pitched forward."""
    t = np.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ rx
    T[:3, 3] = (0.3, -0.5, height_m)
    return T


def underwater_table(width: int, height: int) -> None:
    """sea3d against OpenCV HH on simulated coastal-water pairs of the lake scene (sea3d.sim),
    and refraction-corrected depth through the paper's dome ports against the pinhole-in-water
    baseline, both against the simulator's ground truth."""
    from sea3d.eval import disparity_metrics
    from sea3d.geometry.rig import StereoRig
    from sea3d.rectify import rectify_rig
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import simulate_pair
    from sea3d.stereo import OpenCVSgbmConfig, SgmConfig, match
    from sea3d.stereo.depth import compute_depth, max_disparity_for_depth

    print(f"lake scene, coastal water, {width}x{height}")
    print("| view | engine | bad-1 % | bad-2 % | EPE px | density % |")
    print("|---|---|---|---|---|---|")
    depth_rows = []
    for h_m, tilt in ((1.5, 30.0), (2.5, 45.0)):
        T = _look_down(h_m, tilt)
        rig = paper_rig(port="none", size_px=(width, height))
        left, right, gt = simulate_pair(rig, "lake", T, "coastal", seed=0)
        d_gt = (rig.left.fx * rig.baseline_m / gt.depth_m).astype(np.float32)  # type: ignore[attr-defined]
        md = int(np.ceil((np.nanmax(d_gt) + 1) / 16) * 16) - 1
        engines = {
            "sea3d": SgmConfig(max_disparity_px=md),
            "OpenCV HH w3": OpenCVSgbmConfig(max_disparity_px=md, mode="hh", block_size_px=3),
            "OpenCV HH w5": OpenCVSgbmConfig(max_disparity_px=md, mode="hh"),
        }
        for name, cfg in engines.items():
            m = disparity_metrics(match(left, right, cfg).disparity_px, d_gt)
            print(f"| {h_m} m, {tilt:.0f} deg | {name} | {m.bad_1:.2f} | {m.bad_2:.2f} | "
                  f"{m.epe_px:.3f} | {m.density:.1f} |")
        rigd = paper_rig(port="dome", size_px=(width, height))
        left, right, gt = simulate_pair(rigd, "lake", T, "coastal", seed=0)
        maps = rectify_rig(rigd, depth_range_m=(0.8, 6.0))
        naive = rectify_rig(StereoRig(left=rigd.left.pinhole, right=rigd.right.pinhole,  # type: ignore[attr-defined]
                                      T_left_right=rigd.T_left_right))
        errs = []
        for mp in (maps, naive):
            res = compute_depth(mp, left, right,
                                SgmConfig(max_disparity_px=max_disparity_for_depth(mp, 0.8)))
            v, u = np.nonzero(np.isfinite(res.depth_m))
            ry = np.clip(np.round(mp.map_left_y[v, u]).astype(int), 0, height - 1)
            rx = np.clip(np.round(mp.map_left_x[v, u]).astype(int), 0, width - 1)
            z_gt = gt.depth_m[ry, rx]
            ok = np.isfinite(z_gt)
            errs.append(100 * float(np.median(np.abs(res.points_left[ok, 2] - z_gt[ok])
                                              / z_gt[ok])))
        depth_rows.append((h_m, tilt, float(np.nanmin(gt.depth_m)), float(np.nanmax(gt.depth_m)),
                           *errs))
    print("\n| view | depth range m | refraction-corrected median err % | pinhole-in-water % |")
    print("|---|---|---|---|")
    for h_m, tilt, z0, z1, e_c, e_n in depth_rows:
        print(f"| {h_m} m, {tilt:.0f} deg | {z0:.2f}-{z1:.2f} | {e_c:.2f} | {e_n:.2f} |")


def ablation_tables(data: Path) -> None:
    """The figures behind the design choices in docs/depth.md: the alignment refinement's gain
    on plane depth, its window size on coastal water and Middlebury, and pyramid levels with 4
    or 8 band paths."""
    from bench_stereo_underwater import simulated_pairs

    from sea3d.eval import disparity_metrics
    from sea3d.rectify import rectify_rig
    from sea3d.refraction.presets import paper_rig
    from sea3d.stereo import SgmConfig, match
    from sea3d.stereo.depth import compute_depth, max_disparity_for_depth

    old5 = {"refine_window_px": 5, "refine_row_step": 1, "refine_weight_cutoff": 0.0}
    variants = {
        "no refinement": {"refine_iterations": 0},
        "5 px window (before)": old5,
        "9 px window": {**old5, "refine_window_px": 9},
        "15 px window": {**old5, "refine_window_px": 15},
        "15 px, rows step 3, weighted (default)": {},
    }
    # plane depth error: fronto-parallel textured planes, 480x270 pinhole rig
    rng = np.random.default_rng(0)
    n = 2048
    base = cv2.GaussianBlur(rng.random((n, n)).astype(np.float32), (0, 0), 1.5)
    base = (base - base.min()) / np.ptp(base)
    coarse = cv2.resize(rng.random((n // 32, n // 32)).astype(np.float32), (n, n))
    tex = (255 * (0.7 * base + 0.3 * coarse)).astype(np.float32)
    rig = paper_rig(port="none", size_px=(480, 270))
    maps = rectify_rig(rig)
    print("plane depth error, median |z - z_true| / z % (480x270 pinhole rig, textured planes)")
    print("| refinement | 1 m | 2 m | 3 m | 5 m |")
    print("|---|---|---|---|---|")
    planes = {z0: (_render_plane(rig.left, np.eye(4), z0, tex, 1.3 * z0),
                   _render_plane(rig.right, rig.T_left_right, z0, tex, 1.3 * z0))
              for z0 in (1.0, 2.0, 3.0, 5.0)}
    for name, over in variants.items():
        cells = []
        for z0, (left, right) in planes.items():
            cfg = SgmConfig(max_disparity_px=max_disparity_for_depth(maps, 0.8), **over)  # type: ignore[arg-type]
            res = compute_depth(maps, left, right, cfg)
            cells.append(f"{100 * float(np.median(np.abs(res.points_left[:, 2] - z0))) / z0:.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |")

    print("\nrefinement window: EPE px (matched pixels, --no-fill) on the coastal pairs and "
          "Middlebury")
    pairs = simulated_pairs()
    scenes = {sc: _middlebury(data / "stereo_gt", sc) for sc in MIDDLEBURY}
    print("| refinement | " + " | ".join(p[0] for p in pairs) + " | " + " | ".join(scenes) + " |")
    print("|---|" + "---|" * (len(pairs) + len(scenes)))
    for name, over in variants.items():
        cells = []
        for _, left, right, d_gt, md in pairs:
            cfg = SgmConfig(max_disparity_px=md, fill_max_px=0, **over)  # type: ignore[arg-type]
            m = disparity_metrics(match(left, right, cfg).disparity_px, d_gt)
            cells.append(f"{m.epe_px:.3f}")
        for left, right, gt, md in scenes.values():
            cfg = SgmConfig(max_disparity_px=md, fill_max_px=0, **over)  # type: ignore[arg-type]
            m = disparity_metrics(match(left, right, cfg).disparity_px, gt)
            cells.append(f"{m.epe_px:.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |")

    print("\npyramid levels and paths on the refined levels: bad-2 % (matched pixels) / density %")
    print("| levels, band paths | " + " | ".join(scenes) + " | synthetic 1080p | 1080p CPU s |")
    print("|---|" + "---|" * (len(scenes) + 2))
    left1, right1, gt1 = synthetic_pair(1920, 1080)
    for levels, bp in ((0, 4), (1, 4), (1, 8), (2, 4), (2, 8), (3, 4), (3, 8), (4, 4)):
        cells = []
        for left, right, gt, md in scenes.values():
            if levels > 2:
                cells.append("")
                continue
            cfg = SgmConfig(max_disparity_px=md, fill_max_px=0, pyramid_levels=levels,
                            band_paths=bp)  # type: ignore[arg-type]
            m = disparity_metrics(match(left, right, cfg).disparity_px, gt)
            cells.append(f"{m.bad_2:.2f} / {m.density:.1f}")
        if levels >= 2:
            cfg = SgmConfig(max_disparity_px=255, fill_max_px=0, pyramid_levels=levels,
                            band_paths=bp)  # type: ignore[arg-type]
            c0 = time.process_time()
            m = disparity_metrics(match(left1, right1, cfg).disparity_px, gt1)
            cells += [f"{m.bad_2:.3f} / {m.density:.1f}", f"{time.process_time() - c0:.2f}"]
        else:
            cells += ["", ""]
        print(f"| {levels}, {bp} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--middlebury", type=Path, help="print the accuracy table for this folder "
                    "(e.g. ../shared/data/stereo_gt) instead of timing")
    ap.add_argument("--refraction", action="store_true",
                    help="print the refraction-correction depth table instead of timing")
    ap.add_argument("--underwater", action="store_true",
                    help="print the simulated coastal-water accuracy tables instead of timing")
    ap.add_argument("--ablation", type=Path, metavar="DATA",
                    help="print the refinement and pyramid tables (DATA: ../shared/data)")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--worker", choices=ENGINES)
    ap.add_argument("--inputs", type=Path)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.inputs)
        return
    if args.middlebury:
        middlebury_table(args.middlebury)
        return
    if args.ablation:
        ablation_tables(args.ablation)
        return
    if args.underwater:
        underwater_table(args.width if args.width != 1920 else 640,
                         args.height if args.height != 1080 else 360)
        return
    if args.refraction:
        refraction_table(args.width if args.width != 1920 else 960,
                         args.height if args.height != 1080 else 540)
        return

    import numba

    from sea3d.eval import disparity_metrics
    from sea3d.stereo import match
    from sea3d.stereo.sgm import warm_up

    left, right, gt = synthetic_pair(args.width, args.height)
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"input: synthetic {args.width}x{args.height} RGB pair, disparities 0..255, "
          f"{os.cpu_count()} CPUs, numba threads {numba.get_num_threads()}, "
          f"OpenCV threads {cv2.getNumThreads()}")
    print(f"numba warm-up (compile or cache load): {warm_up():.2f} s (excluded below)")
    times: dict[str, list[float]] = {e: [] for e in ENGINES}
    cpu: dict[str, list[float]] = {e: [] for e in ENGINES}
    last = {}
    for _ in range(args.repeats):
        for engine in ENGINES:  # interleaved, so load changes hit all engines alike
            c0 = time.process_time()
            t0 = time.perf_counter()
            res = match(left, right, _config(engine))  # type: ignore[arg-type]
            times[engine].append(time.perf_counter() - t0)
            cpu[engine].append(time.process_time() - c0)
            last[engine] = res
    med = {e: statistics.median(v) for e, v in times.items()}
    med_cpu = {e: statistics.median(v) for e, v in cpu.items()}

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

    load_after = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\n{'engine':14s} {'wall s':>7s} {'min s':>7s} {'CPU s':>6s} {'wall/3WAY':>10s} "
          f"{'CPU/3WAY':>9s} {'peak RSS MB':>12s} {'bad-2 %':>8s} {'density %':>10s}")
    for engine in ENGINES:
        m = disparity_metrics(last[engine].disparity_px, gt)
        print(f"{engine:14s} {med[engine]:7.3f} {min(times[engine]):7.3f} "
              f"{med_cpu[engine]:6.2f} {med[engine] / med['opencv-3way']:9.2f}x "
              f"{med_cpu[engine] / med_cpu['opencv-3way']:8.2f}x "
              f"{mem[engine]['peak_rss_mb']:12.0f} {m.bad_2:8.2f} {m.density:10.1f}")
    res0 = last["sea3d"]
    mm = disparity_metrics(np.where(res0.measured, res0.disparity_px, np.nan), gt)
    print(f"{'  matched only':14s} {'':7s} {'':7s} {'':6s} {'':10s} {'':9s} {'':12s} "
          f"{mm.bad_2:8.3f} {mm.density:10.1f}   (sea3d without its filled pixels)")
    print(f"load average (1, 5, 15 min) before the runs: {load}; after: {load_after}")
    r_wall = med["sea3d"] / med["opencv-3way"]
    r_cpu = med_cpu["sea3d"] / med_cpu["opencv-3way"]
    print(f"\nsea3d against MODE_SGBM_3WAY (medians of {args.repeats}, interleaved): wall "
          f"{r_wall:.2f}x, CPU {r_cpu:.2f}x; "
          f"against MODE_SGBM: wall {med['sea3d'] / med['opencv-sgbm']:.2f}x, CPU "
          f"{med_cpu['sea3d'] / med_cpu['opencv-sgbm']:.2f}x")
    stages = {k: round(v, 3) for k, v in last["sea3d"].timings_s.items()}
    print(f"sea3d stages (last run, wall s): {stages}")
    bandwidth_floor(left, right, med_cpu["sea3d"])


def _copy_bandwidth_gbs(mbytes: int = 256, repeats: int = 7) -> tuple[float, float]:
    """Best copy (read + write counted) and read-only bandwidth of this machine, GB/s, with
    numpy on one thread (a STREAM-like copy of ``mbytes`` and a sum over it)."""
    a = np.ones(mbytes * 2**20 // 8)
    b = np.empty_like(a)
    copy, read = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        copy.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        np.add.reduce(a)
        read.append(time.perf_counter() - t0)
    return 2 * a.nbytes / min(copy) / 1e9, a.nbytes / min(read) / 1e9


def bandwidth_floor(left: np.ndarray, right: np.ndarray, cpu_s: float) -> None:
    """Bytes the SGM kernels move through their volumes, and the time that takes at this
    machine's measured bandwidth: the floor under sea3d's matching time."""
    from sea3d.stereo import _sgm_kernels as K
    from sea3d.stereo import match

    counts = {"cost": 0, "sweep_set": 0, "sweep_add": 0, "select": 0}
    orig = (K.band_costs, K.sweep, K.select_disparity)

    def costs(*a: object) -> np.ndarray:
        out = orig[0](*a)  # type: ignore[arg-type]
        counts["cost"] += out.size
        return out

    def sweep(*a: object) -> None:
        counts["sweep_add" if a[-1] else "sweep_set"] += a[0].size  # type: ignore[attr-defined]
        orig[1](*a)  # type: ignore[arg-type]

    def select(*a: object) -> object:
        counts["select"] += a[0].size  # type: ignore[attr-defined]
        return orig[2](*a)  # type: ignore[arg-type]

    K.band_costs, K.sweep, K.select_disparity = costs, sweep, select  # type: ignore[assignment]
    try:
        match(left, right, _config("sea3d"))  # type: ignore[arg-type]
    finally:
        K.band_costs, K.sweep, K.select_disparity = orig  # type: ignore[assignment]
    # per cell: costs written (1 B); a sweep reads the cost (1 B) and writes the int16 total
    # (2 B), or reads and writes it (4 B); the selection reads the total (2 B)
    volume = (counts["cost"] + 3 * counts["sweep_set"] + 5 * counts["sweep_add"]
              + 2 * counts["select"])
    h, w = left.shape[:2]
    copy_gbs, read_gbs = _copy_bandwidth_gbs()
    floor_s = volume / (copy_gbs * 1e9)
    print(f"\nmemory-bandwidth floor: the kernels move {volume / 1e6:.0f} MB through their "
          f"cost and sum volumes ({counts['cost'] / 1e6:.1f} M cells searched over all levels; "
          f"{volume / counts['cost']:.1f} B per searched cell, {volume / (h * w * 256):.2f} B per "
          f"pixel and disparity of the 0..255 range); this machine copies {copy_gbs:.1f} GB/s "
          f"(read+write) and reads {read_gbs:.1f} GB/s on one thread now, so moving them takes "
          f"{1000 * floor_s:.0f} ms: {100 * floor_s / cpu_s:.0f} % of sea3d's {cpu_s:.2f} "
          f"CPU-s (the rest is compute: census, path steps, refinement)")


if __name__ == "__main__":
    main()
