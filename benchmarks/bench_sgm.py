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
triangulation) against the simulator's depth maps: median and p90 of ``|z - z_true| / z``;
then, on the same frames, each sea3d kernel's CPU time per frame (one extra pass with every
kernel timed, after the timed runs) and the rates that say what bounds the matcher: cost cells
of the full range (``H * W * D``) per CPU-second for both engines, path-cell updates per
CPU-second of the aggregation, and the path sweep's time per pixel and path on the dive's
full-size volume against a volume small enough to stay in the L1 cache (the same time in both
means the sweep is bound by arithmetic, not by memory bandwidth).

Each run adds its rows (date, load, figures) to the table in the section of
``benchmarks/results/stereo.md`` between the ``bench_sgm`` markers and replaces the details
of the latest run there (command, machine, rates, stages); ``--no-record`` only prints.

    PYTHONPATH=src python benchmarks/bench_sgm.py [--repeats 3] [--textures noise,multiscale]
        [--session out/bench_process/lake_640x360_80 --frames 6] [--no-record]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "stereo.md"
BEGIN = "<!-- bench_sgm: begin (written by benchmarks/bench_sgm.py; each run adds its rows) -->"
END = "<!-- bench_sgm: end -->"


def noise_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 256, (height, width + 64)).astype(np.uint8),
                            (3, 3), 0)
    gt = np.full((height, width), 64.0, np.float32)
    return base[:, :width].copy(), base[:, 64:].copy(), gt


def multiscale_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from bench_stereo import synthetic_pair

    return synthetic_pair(width, height)


def dive(session: str, n_frames: int, repeats: int) -> dict:
    """The ``dive`` texture (see the module docstring); returns its figures."""
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
    out: dict = {"name": root.name, "size": f"{maps.width}x{maps.height}", "d_max": d_max,
                 "frames": len(rect), "repeats": repeats, "wall": mw, "cpu": mc, "depth": {}}
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
        out["depth"][name] = (float(np.median(e)), float(np.percentile(e, 90)), dens)
        print(f"  {name:12s} wall {mw[name]:6.4f} s  CPU {mc[name]:6.4f} s  depth error median "
              f"{np.median(e):.3f} % p90 {np.percentile(e, 90):.3f} %  with depth {dens:5.1f} %")
    print(f"  sea3d / 3WAY: wall {mw['sea3d'] / mw['opencv-3way']:.2f}x, CPU "
          f"{mc['sea3d'] / mc['opencv-3way']:.2f}x")
    out.update(kernel_profile(rect, engines["sea3d"]))
    cells = maps.width * maps.height * (d_max + 1)
    out["full_cells"] = cells
    print(f"  cost cells of the full range per CPU-second: sea3d "
          f"{cells / mc['sea3d'] / 1e9:.2f} G, 3WAY {cells / mc['opencv-3way'] / 1e9:.2f} G")
    print("  sea3d kernels, CPU ms per frame: " + ", ".join(
        f"{k} {1000 * v:.1f}" for k, v in out["kernels"].items()))
    print(f"  aggregation: {out['path_cells'] / 1e6:.1f} M path-cell updates a frame "
          f"({out['searched_cells'] / 1e6:.2f} M cells searched over the levels), "
          f"{out['path_cells'] / out['kernels']['sweeps'] / 1e9:.2f} G per CPU-second")
    out.update(sweep_bound(maps.height, maps.width))
    print(f"  path sweep per pixel and path: {out['sweep_ns_full']:.2f} ns on a {maps.width}x"
          f"{maps.height} volume, {out['sweep_ns_l1']:.2f} ns on a 64x48 one (in L1)")
    return out


_KERNELS = {  # kernel -> stage it is counted in
    "census_transform": "census", "band_costs": "costs", "sweep": "sweeps",
    "select_disparity": "select", "refine_subpixel": "refine", "band_from_coarse": "bands",
    "invalidate_left_border": "select", "valid_and_zeroed": "refine slope",
    "slope_from_sums": "refine slope", "median_nan": "median", "remove_speckles": "speckles",
    "fill_holes": "fill", "sepFilter2D": "refine slope", "GaussianBlur": "presmooth",
}


def kernel_profile(rect: list, config: object) -> dict:
    """One more pass over the frames with every kernel of sea3d's matcher timed (process
    time, all threads): CPU per frame and stage, cells searched and path-cell updates."""
    import sea3d.stereo.sgm as sgm_module
    from sea3d.stereo import _sgm_kernels as K
    from sea3d.stereo import match

    cpu: dict[str, float] = {}
    counts = {"searched": 0, "path": 0}
    saved = []

    def timed(owner: object, name: str) -> None:
        fn = getattr(owner, name)
        saved.append((owner, name, fn))

        def run(*a: object, **kw: object) -> object:
            c0 = time.process_time()
            r = fn(*a, **kw)
            stage = _KERNELS[name]
            cpu[stage] = cpu.get(stage, 0.0) + time.process_time() - c0
            if name == "band_costs":
                counts["searched"] += r.size
            if name == "sweep":
                counts["path"] += a[0].size  # type: ignore[attr-defined]
            return r

        setattr(owner, name, run)

    class _Cv2:  # sgm's cv2 with its two filters timed
        def __getattr__(self, attr: str) -> object:
            return getattr(cv2, attr)

    proxy = _Cv2()
    for name in ("sepFilter2D", "GaussianBlur"):
        setattr(proxy, name, getattr(cv2, name))
    saved.append((sgm_module, "cv2", sgm_module.cv2))
    sgm_module.cv2 = proxy  # type: ignore[assignment]
    for name in ("sepFilter2D", "GaussianBlur"):
        timed(proxy, name)
    for name in ("census_transform", "band_costs", "sweep", "select_disparity",
                 "refine_subpixel", "band_from_coarse", "invalidate_left_border",
                 "valid_and_zeroed", "slope_from_sums"):
        timed(K, name)
    for name in ("median_nan", "remove_speckles", "fill_holes"):
        timed(sgm_module, name)
    try:
        c0 = time.process_time()
        for rl, rr in rect:
            match(rl, rr, config)  # type: ignore[arg-type]
        total = time.process_time() - c0
    finally:
        for owner, name, fn in reversed(saved):
            setattr(owner, name, fn)
    n = len(rect)
    kernels = {k: v / n for k, v in sorted(cpu.items(), key=lambda kv: -kv[1])}
    kernels["rest"] = total / n - sum(kernels.values())
    return {"kernels": kernels, "searched_cells": counts["searched"] / n,
            "path_cells": counts["path"] / n}


def sweep_bound(h: int, w: int, repeats: int = 5) -> dict:
    """The path sweep alone (one-chunk bands, 4 directions each way, one thread) per pixel and
    path on an ``h x w`` volume and on a 64x48 one that stays in the L1 cache."""
    import numba

    from sea3d.stereo import _sgm_kernels as K

    out = {}
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for key, (hh, ww) in (("sweep_ns_full", (h, w)), ("sweep_ns_l1", (48, 64))):
            rng = np.random.default_rng(0)
            cost = rng.integers(0, 64, hh * ww * 16).astype(np.uint8)
            lo = np.zeros(hh * ww, np.int32)
            nch = np.ones(hh * ww, np.int32)
            offs = K.band_offsets(nch)
            guide = rng.integers(0, 256, hh * ww).astype(np.uint8)
            lut = K.p2_table(9, 100, 12.0)
            total = np.empty(cost.size, np.int16)
            n = max(1, 2_000_000 // (hh * ww))
            best = np.inf
            for _ in range(repeats):
                c0 = time.process_time()
                for _ in range(n):
                    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
                        for p0, so, si, n_outer, n_inner, s in K.path_sweeps(hh, ww, dy, dx):
                            group = 8 if dy == 0 else max(64, -(-ww // 8))
                            K.sweep(cost, lo, nch, offs, guide, total, 9, lut, p0, so, si,
                                    n_outer, n_inner, s, group, True)
                best = min(best, (time.process_time() - c0) / n)
            out[key] = 1e9 * best / (hh * ww * 8)
    finally:
        numba.set_num_threads(threads)
    return out


def _machine() -> str:
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} CPUs, {platform.system()}"


def _tree() -> str:
    """The commit the sources were at (``+`` when they had changes on top), or ``?``."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "src"], cwd=root,
                               check=True, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"
    return head + ("+" if dirty else "")


_HEADER = ("| run (UTC, commit), load before / after | frames | sea3d CPU s (wall) | "
           "3WAY CPU s (wall) | sea3d / 3WAY CPU (wall) | accuracy sea3d | accuracy 3WAY |")


def record(load: tuple[float, float], dive_out: dict | None, textures: list[dict]) -> None:
    """Add this run's rows to the table of the ``bench_sgm`` section of
    benchmarks/results/stereo.md (rows of earlier runs are kept; the run column names the
    commit the sources were at) and replace the section's details of the latest run
    (command, machine, rates, stages)."""
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    cmd = "PYTHONPATH=src python benchmarks/bench_sgm.py " + shlex.join(sys.argv[1:])
    run = f"{now} ({_tree()}), {load[0]:.2f} / {load[1]:.2f}"
    rows = []
    if dive_out is not None:
        d = dive_out
        c, w = d["cpu"], d["wall"]
        acc = {e: f"depth error {v[0]:.3f} / {v[1]:.3f} % (median / p90), {v[2]:.1f} % with "
               "depth" for e, v in d["depth"].items()}
        rows.append(
            f"| {run} | dive {d['name']}, {d['size']}, 0..{d['d_max']}, {d['frames']} x "
            f"{d['repeats']} | {c['sea3d']:.4f} ({w['sea3d']:.4f}) | {c['opencv-3way']:.4f} "
            f"({w['opencv-3way']:.4f}) | {c['sea3d'] / c['opencv-3way']:.2f}x "
            f"({w['sea3d'] / w['opencv-3way']:.2f}x) | {acc['sea3d']} | {acc['opencv-3way']} |")
    for t in textures:
        c, w = t["cpu"], t["wall"]
        rows.append(
            f"| {run} | {t['texture']}, {t['size']}, 0..255, {t['repeats']} | "
            f"{c['sea3d']:.3f} ({w['sea3d']:.3f}) | {c['opencv-3way']:.3f} "
            f"({w['opencv-3way']:.3f}) | {c['sea3d'] / c['opencv-3way']:.2f}x "
            f"({w['sea3d'] / w['opencv-3way']:.2f}x) | bad-2 {t['bad2']['sea3d']:.3f} % dense, "
            f"{t['bad2_matched']:.3f} % matched | bad-2 {t['bad2']['opencv-3way']:.3f} % |")
    text = RESULTS.read_text()
    earlier: list[str] = []
    if BEGIN in text and END in text:
        old = text.split(BEGIN, 1)[1].split(END, 1)[0]
        earlier = [ln for ln in old.splitlines() if ln.startswith("| 20")]
    lines = [BEGIN, "", "### `bench_sgm.py` runs", "",
             "Written by the script, a row per run and input: medians per frame of the "
             "interleaved runs, CPU as process time (all threads), wall in brackets; the load "
             "average before and after the run (wall times depend on it, CPU times much less).",
             "", _HEADER, "|---|---|---|---|---|---|---|", *earlier, *rows, "",
             f"Latest run ({now} UTC): `{cmd.strip()}` on {_machine()}."]
    if dive_out is not None:
        d = dive_out
        k = d["kernels"]
        lines += [
            "",
            f"On the dive's frames: cost cells of the full range per CPU-second, sea3d "
            f"{d['full_cells'] / d['cpu']['sea3d'] / 1e9:.2f} G, 3WAY "
            f"{d['full_cells'] / d['cpu']['opencv-3way'] / 1e9:.2f} G. sea3d searches "
            f"{d['searched_cells'] / 1e6:.2f} M cells a frame over its pyramid levels and its "
            f"aggregation makes {d['path_cells'] / 1e6:.1f} M path-cell updates, "
            f"{d['path_cells'] / k['sweeps'] / 1e9:.2f} G per CPU-second. The path sweep alone "
            f"(one thread) takes {d['sweep_ns_full']:.2f} ns per pixel and path of 16 "
            f"candidates on a {d['size']} volume and {d['sweep_ns_l1']:.2f} ns on a 64x48 one "
            "that stays in the L1 cache.",
            "",
            "sea3d's CPU per frame by stage (ms, a separate pass with every kernel timed): "
            + ", ".join(f"{name} {1000 * v:.1f}" for name, v in k.items()) + ".",
        ]
    lines += ["", END]
    section = "\n".join(lines)
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        text = head + section + rest.split(END, 1)[1]
    else:
        anchor = "\n## Speed and memory"
        at = text.find(anchor)
        at = len(text) if at < 0 else at + 1
        text = text[:at] + section + "\n\n" + text[at:]
    RESULTS.write_text(text)
    print(f"\nrecorded in {RESULTS}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--textures", default="noise,multiscale")
    ap.add_argument("--session", help="a simulated session for the dive frames")
    ap.add_argument("--frames", type=int, default=6, help="dive frames (with --session)")
    ap.add_argument("--no-record", action="store_true",
                    help="print only; do not write benchmarks/results/stereo.md")
    args = ap.parse_args()

    from sea3d.eval import disparity_metrics
    from sea3d.stereo import make_config, match
    from sea3d.stereo.sgm import warm_up

    warm_up()
    engines = {"sea3d": make_config("sea3d", 255), "opencv-3way": make_config("opencv-3way", 255)}
    load0 = os.getloadavg()[0]
    print(f"{args.width}x{args.height}, disparities 0..255, {os.cpu_count()} CPUs, medians of "
          f"{args.repeats} interleaved runs; load before {load0:.2f}")
    dive_out = dive(args.session, args.frames, args.repeats) if args.session else None
    textures = []
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
        textures.append({"texture": texture, "size": f"{args.width}x{args.height}",
                         "repeats": args.repeats, "cpu": mc, "wall": mw,
                         "bad2": {e: disparity_metrics(last[e].disparity_px, gt).bad_2
                                  for e in engines}, "bad2_matched": mm.bad_2})
    load1 = os.getloadavg()[0]
    print(f"\nload after {load1:.2f}")
    if not args.no_record:
        record((load0, load1), dive_out, textures)


if __name__ == "__main__":
    main()
