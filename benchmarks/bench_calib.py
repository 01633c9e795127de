"""Calibration benchmark: sea3d next to OpenCV's own calls on the same input, per stage.

Sets:
  1. OpenCV's 13-pair 640x480 stereo set (``calib/opencv_9x6`` in the test data), detected here.
  2. A synthetic 40-pair 1920x1080 set: the paper's camera with OpenCV distortion, a 9x6 board
     of 60 mm squares at 0.6-2.5 m, corners projected with 0.15 px noise (``--rendered``
     renders the images with the simulator, ``sea3d.sim``, and detects them instead: slower).
  3. Port calibration on a synthetic 20-pair 1920x1080 in-water set through the paper's domes
     (no OpenCV counterpart exists; CALIBMAR is C++/Qt).

Timings are medians of ``--repeat`` runs (default 3), wall clock, in this process. Run:

    PYTHONPATH=src python benchmarks/bench_calib.py [--data ../shared/data] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sea3d.calib.port import calibrate_port_rig
from sea3d.calib.stereo import StereoCalibConfig, calibrate_stereo, orient_consistently
from sea3d.calib.synthetic import BoardRenderer, board_poses, synthetic_detections
from sea3d.calib.targets import Detection, DetectionStatus, detect_board, parse_board
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction import DomePort
from sea3d.refraction.presets import paper_rig


def timed(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Median wall time of ``repeat`` calls and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def row(stage: str, ours_s: float, ref_s: float | None, note: str = "") -> None:
    ref = f"{ref_s * 1e3:10.1f}" if ref_s is not None else f"{'-':>10}"
    ratio = f"{ours_s / ref_s:7.2f}" if ref_s else f"{'-':>7}"
    print(f"  {stage:<34}{ours_s * 1e3:10.1f}{ref}{ratio}  {note}")


def header(title: str) -> None:
    print(f"\n{title}")
    print(f"  {'stage':<34}{'sea3d ms':>10}{'OpenCV ms':>10}{'ratio':>7}  notes")


def opencv_detect(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    found, c = cv2.findChessboardCorners(gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                         | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    return cv2.cornerSubPix(gray, c, (11, 11), (-1, -1), crit)


def opencv_stereo(left: list[Detection], right: list[Detection],
                  size: tuple[int, int]) -> dict[str, Any]:
    """The plain OpenCV pipeline on the same detections, timed per call."""
    obj = [d.points_board_m.astype(np.float32) for d in left]
    uv_l = [d.corners_px.astype(np.float32) for d in left]
    uv_r = [d.corners_px.astype(np.float32) for d in right]
    t0 = time.perf_counter()
    rl, K1, d1, _, _ = cv2.calibrateCamera(obj, uv_l, size, None, None)
    rr, K2, d2, _, _ = cv2.calibrateCamera(obj, uv_r, size, None, None)
    t_mono = time.perf_counter() - t0
    t0 = time.perf_counter()
    rms_fixed, *_ = cv2.stereoCalibrate(obj, uv_l, uv_r, K1, d1, K2, d2, size,
                                        flags=cv2.CALIB_FIX_INTRINSIC)
    t_fixed = time.perf_counter() - t0
    t0 = time.perf_counter()
    rms_joint, *_ = cv2.stereoCalibrate(obj, uv_l, uv_r, K1.copy(), d1.copy(), K2.copy(),
                                        d2.copy(), size, flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    t_joint = time.perf_counter() - t0
    return {"t_mono": t_mono, "t_fixed": t_fixed, "t_joint": t_joint, "rms_fixed": rms_fixed,
            "rms_joint": rms_joint, "rms_mono": (rl, rr)}


def paired(left: list[Detection], right: list[Detection]) -> tuple[list[Detection],
                                                                    list[Detection]]:
    keep = [k for k in range(len(left)) if left[k].ok and right[k].ok]
    # Checkerboard corner order can differ by 180 degrees between the two images of a pair.
    return [left[k] for k in keep], [orient_consistently(left[k], right[k]) for k in keep]


def stereo_section(title: str, left: list[Detection], right: list[Detection],
                   size: tuple[int, int], repeat: int, truth: StereoRig | None = None) -> None:
    header(title)
    pl, pr = paired(left, right)
    t_ref = [opencv_stereo(pl, pr, size) for _ in range(repeat)]
    ref = {k: statistics.median([r[k] for r in t_ref]) for k in ("t_mono", "t_fixed",
                                                                  "t_joint")}
    cfg = StereoCalibConfig()
    results = [calibrate_stereo(left, right, cfg) for _ in range(repeat)]
    res = results[-1]
    tim = {k: statistics.median([r.timings_s.get(k, 0.0) for r in results])
           for k in ("fit", "rejection", "holdout", "total")}
    row("mono + joint stereo fit", tim["fit"], ref["t_mono"] + ref["t_joint"],
        f"RMS {res.rms_px:.4f} px (after rejection) vs OpenCV joint "
        f"{t_ref[-1]['rms_joint']:.4f} px, fixed-intrinsics {t_ref[-1]['rms_fixed']:.4f} px")
    row("  (OpenCV stereoCalibrate FIX_INTRINSIC)", ref["t_mono"] + ref["t_fixed"], None)
    row("outlier rejection", tim["rejection"], None,
        f"{len(res.views_rejected)} of {len(left)} pairs left out")
    row("leave-one-pair-out holdout", tim["holdout"], None,
        f"holdout {res.holdout_px:.4f} px over {len(res.views)} folds")
    row("calibrate_stereo total", tim["total"], ref["t_mono"] + ref["t_joint"],
        f"verdict: {res.verdict}")
    if truth is not None and res.left is not None:
        left_true = truth.left
        assert isinstance(left_true, PinholeCamera)
        print(f"  accuracy: fx error {100 * (res.left.fx / left_true.fx - 1):+.3f} %, "
              f"baseline error {(res.baseline_m - truth.baseline_m) * 1e3:+.3f} mm")


def set_13(data: Path, repeat: int) -> None:
    folder = data / "calib" / "opencv_9x6"
    if not folder.is_dir():
        print(f"\n[skip] {folder} not found")
        return
    board = parse_board("checkerboard:9x6:25mm")
    paths_l = sorted(folder.glob("left*.jpg"))
    paths_r = sorted(folder.glob("right*.jpg"))
    grays = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths_l + paths_r]
    header("OpenCV 9x6 set: 13 pairs, 640x480 - detection per image")
    t_ours, dets = timed(lambda: [detect_board(g, board) for g in grays], repeat)
    t_cv, cv_dets = timed(lambda: [opencv_detect(g, (9, 6)) for g in grays], repeat)
    n = len(grays)
    row("detect (sector-based + fallback)", t_ours / n, t_cv / n,
        f"found {sum(d.ok for d in dets)}/{n}; OpenCV classic+cornerSubPix found "
        f"{sum(c is not None for c in cv_dets)}/{n}")
    named = [d.with_name(p.name) for d, p in zip(dets, paths_l + paths_r, strict=True)]
    left, right = named[:len(paths_l)], named[len(paths_l):]
    # OpenCV's plain pipeline on its own (classic) detections, for the README's 0.45 px.
    ids, pts = board.object_points()
    cv_named = [Detection(status=DetectionStatus.DETECTED if c is not None
                          else DetectionStatus.NOT_FOUND,
                          corners_px=(c.reshape(-1, 2).astype(np.float64) if c is not None
                                      else np.zeros((0, 2))),
                          ids=ids if c is not None else ids[:0],
                          points_board_m=pts if c is not None else pts[:0], image_size=(640, 480),
                          name=p.name, ambiguous_order=True)
                for c, p in zip(cv_dets, paths_l + paths_r, strict=True)]
    cl, cr = paired(cv_named[:len(paths_l)], cv_named[len(paths_l):])
    plain = opencv_stereo(cl, cr, (640, 480))
    print(f"  OpenCV's own pipeline (classic detections, calibrateCamera, stereoCalibrate): "
          f"stereo RMS {plain['rms_joint']:.4f} px (intrinsic guess), "
          f"{plain['rms_fixed']:.4f} px (fixed intrinsics); mono "
          f"{plain['rms_mono'][0]:.3f} / {plain['rms_mono'][1]:.3f} px")
    stereo_section("OpenCV 9x6 set: 13 pairs - calibration stages (same detections)", left,
                   right, (640, 480), repeat)


def synthetic_rig() -> StereoRig:
    base = paper_rig("none")
    assert isinstance(base.left, PinholeCamera)
    dist = [-0.12, 0.08, 0.0004, -0.0003, -0.02]
    left = PinholeCamera(fx=base.left.fx, fy=base.left.fy, cx=base.left.cx, cy=base.left.cy,
                         width=1920, height=1080, dist=dist)
    right = PinholeCamera(fx=base.left.fx * 0.995, fy=base.left.fy * 0.995, cx=955.0, cy=540.0,
                          width=1920, height=1080, dist=dist)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.003, -0.01, 0.002]))[0]
    T[:3, 3] = [0.107, 0.0005, -0.001]
    return StereoRig(left=left, right=right, T_left_right=T)


def set_40(repeat: int, rendered: bool) -> None:
    rng = np.random.default_rng(0)
    rig = synthetic_rig()
    board = parse_board("checkerboard:9x6:60mm")
    poses = board_poses(rig.left, board, 40, rng, distance_range_m=(0.6, 2.5), max_tilt_deg=40,
                        also_inside=[(rig.right, rig.T_right_left)])
    if rendered:
        header("simulated 40 pairs, 1920x1080, rendered in air - detection per image")
        try:
            from sea3d.sim import render_calibration_set

            t0 = time.perf_counter()
            cal = render_calibration_set(rig, "checkerboard:9x6:60mm", 40, medium="air",
                                         seed=0, distance_range_m=(0.6, 2.5), supersample=2)
            images = [np.asarray(im) for im in cal.lefts + cal.rights]
            print(f"  (sea3d.sim rendered 80 images in {time.perf_counter() - t0:.1f} s)")
        except ImportError:
            images = []
            for cam, T_cl in ((rig.left, np.eye(4)), (rig.right, rig.T_right_left)):
                r = BoardRenderer(cam, board, texture_px_per_m=3000.0, supersample=1)
                images += [r.render(T_cl @ T, blur_px=0.8) for T in poses]
        t_ours, dets = timed(lambda: [detect_board(g, board) for g in images], 1)
        grays = [cv2.cvtColor(g, cv2.COLOR_RGB2GRAY) if g.ndim == 3 else g for g in images]
        t_cv, cv_dets = timed(lambda: [opencv_detect(g, (9, 6)) for g in grays], 1)
        n = len(images)
        row("detect (sector-based + fallback)", t_ours / n, t_cv / n,
            f"found {sum(d.ok for d in dets)}/{n}; OpenCV {sum(c is not None for c in cv_dets)}"
            f"/{n}")
        named = [d.with_name(f"{'lr'[k // 40]}{k % 40:02d}") for k, d in enumerate(dets)]
        left, right = named[:40], named[40:]
    else:
        views = synthetic_detections([rig.left, rig.right], board, poses, rng,
                                     T_cam_left=[np.eye(4), rig.T_right_left], noise_px=0.15,
                                     partial_ok=False)
        left = [v.detections[0] for v in views]
        right = [v.detections[1] for v in views]
    stereo_section("synthetic 40 pairs, 1920x1080 - calibration stages", left, right,
                   (1920, 1080), repeat, truth=rig)


def set_port(repeat: int) -> None:
    rng = np.random.default_rng(1)
    centre_l, centre_r = (-0.54e-3, 0.58e-3, 2.10e-3), (1.5e-3, -2.0e-3, -1.0e-3)
    rig = paper_rig("dome", dome_center_left_m=centre_l, dome_center_right_m=centre_r)
    board = parse_board("checkerboard:9x6:95mm")
    poses = board_poses(rig.left, board, 20, rng, distance_range_m=(0.5, 2.5), max_tilt_deg=40)
    views = synthetic_detections([rig.left, rig.right], board, poses, rng,
                                 T_cam_left=[np.eye(4), rig.T_right_left], noise_px=0.15)
    left = [v.detections[0] for v in views]
    right = [v.detections[1] for v in views]
    start = DomePort(center_m=np.zeros(3), inner_radius_m=31.25e-3, thickness_m=3.1e-3)
    header("port calibration: 20 in-water pairs through the paper's domes, 1920x1080")
    t, res = timed(lambda: calibrate_port_rig(paper_rig("none"), start, start, left, right),
                   repeat)
    row("2 dome fits + extrinsics + joint", t, None, res.message)
    for side, r, c in (("left", res.left, centre_l), ("right", res.right, centre_r)):
        err = (r.dome_center_m - np.asarray(c)) * 1e3
        print(f"  {side}: dome centre error ({err[0]:+.3f}, {err[1]:+.3f}, {err[2]:+.3f}) mm, "
              f"std ({', '.join(f'{v * 1e3:.3f}' for v in r.dome_center_std_m)}) mm")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=os.environ.get("SEA3D_TEST_DATA", "../shared/data"))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--rendered", action="store_true",
                        help="render and detect the 40-pair set instead of projecting corners")
    args = parser.parse_args(argv)
    print(f"sea3d calibration benchmark; OpenCV {cv2.__version__}, numpy {np.__version__}, "
          f"{os.cpu_count()} CPUs; medians of {args.repeat} runs")
    set_13(Path(args.data), args.repeat)
    set_40(args.repeat, args.rendered)
    set_port(max(1, args.repeat // 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
