"""Calibration accuracy: sea3d's default against plain OpenCV on every set, by holdout error.

Plain OpenCV is the tutorial pipeline: ``findChessboardCorners`` (adaptive threshold, image
normalisation) + ``cornerSubPix`` (11x11 window, 30 iterations, 0.001 px), ``calibrateCamera``
per camera (k1 k2 p1 p2 k3) and ``stereoCalibrate`` with ``CALIB_FIX_INTRINSIC``, on every pair
found in both images. sea3d's default is what ``sea3d calibrate stereo`` does: every
checkerboard detector (``detect_checkerboard_all``), ``calibrate_stereo_best`` (rejection of
outlier pairs, the detector with the lowest holdout error kept).

Holdout, the same for both, measured here (not with sea3d's code): each pair that both
pipelines detected is left out in turn; each pipeline calibrates from all its other pairs (sea3d
chooses its detector again inside every fold, unless ``--choose-once``); the left-out pair is
predicted with its board pose fitted to both images (``solvePnP``, then Levenberg-Marquardt over
both images with the rig fixed) and scored by the RMS of both images' residuals against the
pipeline's own corners. Printed: the RMS and the median over those pairs, and, for simulated
sets, the error against the true rig (depth of points at 0.8-3 m triangulated from their true
pixels, and the left camera's pixel error).

Sets: OpenCV's 9x6 set; the StereoPi rig in air (32 pairs, 6x9 board) and in the sea (Panama,
Bermuda; side-by-side frames split in halves); simulated sets rendered by ``sea3d.sim``
(``--no-sim`` skips them).

    PYTHONPATH=src python benchmarks/bench_calib_accuracy.py [--data ../shared/data]
        [--sets opencv_9x6 stereopi_air ...] [--choose-once] [--sim-views 20]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from sea3d.calib.stereo import StereoCalibConfig, calibrate_stereo_best
from sea3d.calib.targets import (
    CHECKER_DETECTORS,
    Detection,
    DetectionStatus,
    detect_checkerboard_all,
    parse_board,
)

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


@dataclass
class CalSet:
    name: str
    pattern: tuple[int, int]
    lefts: list[tuple[str, np.ndarray]]  # (name, grey image)
    rights: list[tuple[str, np.ndarray]]
    truth: Any = None  # the true StereoRig for simulated sets


@dataclass
class Rig:
    K1: np.ndarray
    d1: np.ndarray
    K2: np.ndarray
    d2: np.ndarray
    R: np.ndarray  # R_right_left
    T: np.ndarray  # t_right_left


# ------------------------------------------------------------------------------------- sets
def _grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img


def real_sets(data: Path, wanted: list[str]) -> list[CalSet]:
    out = []
    folder = data / "calib" / "opencv_9x6"
    if "opencv_9x6" in wanted and folder.is_dir():
        out.append(CalSet("opencv_9x6 (13 pairs, 640x480)", (9, 6),
                          [(p.name, _grey(p)) for p in sorted(folder.glob("left*.jpg"))],
                          [(p.name, _grey(p)) for p in sorted(folder.glob("right*.jpg"))]))
    folder = data / "underwater_stereo" / "stereopi_inair_calib"
    if "stereopi_air" in wanted and folder.is_dir():
        out.append(CalSet("stereopi in air (32 pairs, 640x480)", (6, 9),
                          [("left/" + p.name, _grey(p))
                           for p in sorted((folder / "left").glob("*.png"))],
                          [("right/" + p.name, _grey(p))
                           for p in sorted((folder / "right").glob("*.png"))]))
    for key, sub, label in (("panama", "stereopi_panama_sea", "stereopi Panama sea"),
                            ("bermuda", "stereopi_bermuda1_sea", "stereopi Bermuda sea")):
        folder = data / "underwater_stereo" / sub / "sbs"
        if key not in wanted or not folder.is_dir():
            continue
        lefts, rights = [], []
        for p in sorted(folder.glob("*.png")):
            img = _grey(p)
            half = img.shape[1] // 2
            lefts.append(("L" + p.name, np.ascontiguousarray(img[:, :half])))
            rights.append(("R" + p.name, np.ascontiguousarray(img[:, half:])))
        h, w = lefts[0][1].shape
        out.append(CalSet(f"{label} ({len(lefts)} pairs, {w}x{h})", (6, 9), lefts, rights))
    return out


def sim_sets(views: int, wanted: list[str]) -> list[CalSet]:
    from sea3d.geometry.pinhole import PinholeCamera
    from sea3d.geometry.rig import StereoRig
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import render_calibration_set

    out = []
    size = (1280, 720)
    if "sim_air" in wanted:
        base = paper_rig("none", size_px=size)
        assert isinstance(base.left, PinholeCamera)
        dist = [-0.12, 0.08, 0.0004, -0.0003, -0.02]
        left = PinholeCamera(fx=base.left.fx, fy=base.left.fy, cx=base.left.cx, cy=base.left.cy,
                             width=size[0], height=size[1], dist=dist)
        right = PinholeCamera(fx=base.left.fx * 0.995, fy=base.left.fy * 0.995,
                              cx=base.left.cx + 4.0, cy=base.left.cy - 2.0, width=size[0],
                              height=size[1], dist=dist)
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(np.array([0.003, -0.01, 0.002]))[0]
        T[:3, 3] = [0.107, 0.0005, -0.001]
        rig = StereoRig(left=left, right=right, T_left_right=T)
        cal = render_calibration_set(rig, "checkerboard:9x6:60mm", views, medium="air", seed=3,
                                     distance_range_m=(0.6, 2.5), water="clear")
        out.append(_from_cal(f"simulated in air, sensor noise ({views} pairs, 1280x720)", cal,
                             rig))
    if "sim_water" in wanted:
        rig = paper_rig("dome").scaled(*size)
        cal = render_calibration_set(rig, "checkerboard:9x6:60mm", views, medium="water",
                                     seed=4, distance_range_m=(0.6, 2.5), water="coastal")
        out.append(_from_cal(f"simulated in coastal water, domes ({views} pairs, 1280x720)",
                             cal, rig))
    return out


def _from_cal(name: str, cal: Any, rig: Any) -> CalSet:
    grey = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in cal.lefts + cal.rights]
    n = len(cal.lefts)
    return CalSet(name, cal.board.corner_grid,
                  [(f"left{k:02d}", grey[k]) for k in range(n)],
                  [(f"right{k:02d}", grey[n + k]) for k in range(n)], truth=rig)


# ------------------------------------------------------------------------- plain OpenCV
def opencv_detect(gray: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    found, c = cv2.findChessboardCorners(gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                         | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    return np.asarray(cv2.cornerSubPix(gray, c, (11, 11), (-1, -1), SUBPIX_CRITERIA),
                      dtype=np.float64).reshape(-1, 2)


def orient(uv_l: np.ndarray, uv_r: np.ndarray) -> np.ndarray:
    """The right corners in the left's order (checkerboard order can be reversed)."""
    if float((uv_l[-1] - uv_l[0]) @ (uv_r[-1] - uv_r[0])) < 0:
        return uv_r[::-1].copy()
    return uv_r


def opencv_fit(obj: np.ndarray, pairs: list[tuple[np.ndarray, np.ndarray]],
               size: tuple[int, int]) -> Rig:
    objs = [obj.astype(np.float32)] * len(pairs)
    ul = [p[0].astype(np.float32) for p in pairs]
    ur = [p[1].astype(np.float32) for p in pairs]
    _, K1, d1, _, _ = cv2.calibrateCamera(objs, ul, size, None, None)
    _, K2, d2, _, _ = cv2.calibrateCamera(objs, ur, size, None, None)
    _, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(objs, ul, ur, K1, d1, K2, d2, size,
                                                        flags=cv2.CALIB_FIX_INTRINSIC)
    return Rig(K1, d1.ravel(), K2, d2.ravel(), R, T.ravel())


# ------------------------------------------------------------------------------- sea3d
def sea3d_fit(cands: dict[str, tuple[list[Detection], list[Detection]]],
              keep: list[int]) -> tuple[Rig | None, str]:
    sub = {n: ([lr[0][k] for k in keep], [lr[1][k] for k in keep]) for n, lr in cands.items()}
    res = calibrate_stereo_best(sub, StereoCalibConfig())
    if not res.ok or res.left is None or res.right is None:
        return None, res.detector
    T_rl = np.linalg.inv(res.T_left_right)
    return Rig(res.left.K, res.left.dist, res.right.K, res.right.dist, T_rl[:3, :3],
               T_rl[:3, 3]), res.detector


# ---------------------------------------------------------------------- prediction, truth
def predict_rms(rig: Rig, obj: np.ndarray, uv_l: np.ndarray, uv_r: np.ndarray) -> float:
    """RMS over both images of a pair predicted by ``rig``: the board pose alone is fitted."""
    _ok, rv, tv = cv2.solvePnP(obj, uv_l, rig.K1, rig.d1)

    def residuals(x: np.ndarray) -> np.ndarray:
        pl, _ = cv2.projectPoints(obj, x[:3], x[3:], rig.K1, rig.d1)
        R_l = cv2.Rodrigues(x[:3])[0]
        rv_r = cv2.Rodrigues(rig.R @ R_l)[0]
        pr, _ = cv2.projectPoints(obj, rv_r, rig.R @ x[3:] + rig.T, rig.K2, rig.d2)
        return np.concatenate([(pl.reshape(-1, 2) - uv_l).ravel(),
                               (pr.reshape(-1, 2) - uv_r).ravel()])

    sol = least_squares(residuals, np.concatenate([rv.ravel(), tv.ravel()]), method="lm")
    r = sol.fun.reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1))))


def truth_errors(rig: Rig, truth: Any) -> tuple[float, float]:
    """(median |depth error| %, RMS left pixel error) of ``rig`` against the true rig, over
    points at 0.8, 1.5 and 3 m behind a 16x9 grid of the true left image."""
    w, h = truth.width, truth.height
    u, v = np.meshgrid((np.arange(16) + 0.5) * w / 16, (np.arange(9) + 0.5) * h / 9)
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    rays = truth.left.unproject(uv)
    depth_err, px_err = [], []
    for z in (0.8, 1.5, 3.0):
        t = (z - rays.origins[:, 2]) / rays.directions[:, 2]
        pts = rays.origins + t[:, None] * rays.directions
        uv_l, ok_l = truth.left.project(pts)
        pts_r = pts @ truth.T_right_left[:3, :3].T + truth.T_right_left[:3, 3]
        uv_r, ok_r = truth.right.project(pts_r)
        ok = ok_l & ok_r & (uv_r[:, 0] >= 0) & (uv_r[:, 0] < w)
        est_l, _ = cv2.projectPoints(pts[ok], np.zeros(3), np.zeros(3), rig.K1, rig.d1)
        px_err.append(np.linalg.norm(est_l.reshape(-1, 2) - uv_l[ok], axis=1))
        nl = cv2.undistortPoints(uv_l[ok].reshape(-1, 1, 2), rig.K1, rig.d1).reshape(-1, 2)
        nr = cv2.undistortPoints(uv_r[ok].reshape(-1, 1, 2), rig.K2, rig.d2).reshape(-1, 2)
        P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
        P2 = np.hstack([rig.R, rig.T.reshape(3, 1)])
        X = cv2.triangulatePoints(P1, P2, nl.T, nr.T)
        z_est = X[2] / X[3]
        depth_err.append(np.abs(z_est - pts[ok, 2]) / pts[ok, 2])
    return (100 * float(np.median(np.concatenate(depth_err))),
            float(np.sqrt(np.mean(np.concatenate(px_err) ** 2))))


# ------------------------------------------------------------------------------ run a set
def run_set(cs: CalSet, choose_once: bool, log: Callable[[str], None]) -> None:
    board = parse_board(f"checkerboard:{cs.pattern[0]}x{cs.pattern[1]}:25mm")
    _ids, obj = board.object_points()
    h, w = cs.lefts[0][1].shape
    size = (w, h)
    t0 = time.perf_counter()
    cands: dict[str, tuple[list[Detection], list[Detection]]] = {
        n: ([], []) for n in CHECKER_DETECTORS}
    cv_corners: list[tuple[np.ndarray | None, np.ndarray | None]] = []
    for (nl, gl), (nr, gr) in zip(cs.lefts, cs.rights, strict=True):
        dl, dr = detect_checkerboard_all(gl, board), detect_checkerboard_all(gr, board)
        for n in CHECKER_DETECTORS:
            cands[n][0].append(dl[n].with_name(nl))
            cands[n][1].append(dr[n].with_name(nr))
        cv_corners.append((opencv_detect(gl, cs.pattern), opencv_detect(gr, cs.pattern)))
    t_detect = time.perf_counter() - t0
    n = len(cs.lefts)
    cv_ok = [k for k in range(n) if cv_corners[k][0] is not None and cv_corners[k][1] is not None]
    full = calibrate_stereo_best(cands, StereoCalibConfig())
    chosen = full.detector
    found = [k for k in range(n)
             if cands[chosen][0][k].status is DetectionStatus.DETECTED
             and cands[chosen][1][k].status is DetectionStatus.DETECTED]
    common = [k for k in cv_ok if k in found]
    log(f"\n{cs.name}: board found in both images of {len(cv_ok)} pairs by plain OpenCV, "
        f"{len(found)} by sea3d ({chosen}); {len(common)} in common (detection "
        f"{t_detect:.0f} s)")
    log(f"  sea3d's choice on the whole set: {full.detector_reason}")
    ho_cv, ho_s3, choices = [], [], []
    t0 = time.perf_counter()
    for k in common:
        ul, ur = cv_corners[k]
        assert ul is not None and ur is not None
        train = [(cv_corners[j][0], orient(cv_corners[j][0], cv_corners[j][1]))
                 for j in cv_ok if j != k]
        rig_cv = opencv_fit(obj, train, size)
        ho_cv.append(predict_rms(rig_cv, obj, ul, orient(ul, ur)))
        keep = [j for j in range(n) if j != k]
        if choose_once:
            rig_s3, pick = sea3d_fit({chosen: cands[chosen]}, keep)
            pick = chosen
        else:
            rig_s3, pick = sea3d_fit(cands, keep)
        choices.append(pick)
        det_l, det_r = cands[pick][0][k], cands[pick][1][k]
        if rig_s3 is None or not (det_l.ok and det_r.ok):
            ho_s3.append(math.nan)
            continue
        ho_s3.append(predict_rms(rig_s3, obj, det_l.corners_px, orient(det_l.corners_px,
                                                                      det_r.corners_px)))
    a_cv, a_s3 = np.asarray(ho_cv), np.asarray(ho_s3)
    both = np.isfinite(a_s3)
    picks = {p: choices.count(p) for p in sorted(set(choices))}
    log(f"  holdout over {int(both.sum())} pairs ({time.perf_counter() - t0:.0f} s; sea3d's "
        f"detector per fold: {picks})")
    log(f"  {'':<26}{'RMS px':>9}{'median px':>11}")
    cv_rms = float(np.sqrt(np.mean(a_cv[both] ** 2)))
    s3_rms = float(np.sqrt(np.mean(a_s3[both] ** 2)))
    log(f"  {'plain OpenCV':<26}{cv_rms:9.3f}{np.median(a_cv[both]):11.3f}")
    log(f"  {'sea3d default':<26}{s3_rms:9.3f}{np.median(a_s3[both]):11.3f}"
        f"   ratio {s3_rms / cv_rms:.2f} (RMS), "
        f"{np.median(a_s3[both]) / np.median(a_cv[both]):.2f} (median)")
    for t in full.detector_trials:
        log(f"    sea3d {t.detector:<18} RMS {t.rms_px:.3f} px on its corners, own holdout "
            f"{t.holdout_px:.3f} px, {t.pairs_used} pairs used")
    if cs.truth is not None and full.left is not None and full.right is not None:
        T_rl = np.linalg.inv(full.T_left_right)
        rig_s3 = Rig(full.left.K, full.left.dist, full.right.K, full.right.dist, T_rl[:3, :3],
                     T_rl[:3, 3])
        rig_cv = opencv_fit(obj, [(cv_corners[j][0], orient(cv_corners[j][0], cv_corners[j][1]))
                                  for j in cv_ok], size)
        for label, r in (("plain OpenCV", rig_cv), ("sea3d default", rig_s3)):
            dz, px = truth_errors(r, cs.truth)
            log(f"  against the true rig, {label:<14}: median depth error {dz:.3f} % at "
                f"0.8-3 m, left pixel error {px:.3f} px RMS")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=os.environ.get("SEA3D_TEST_DATA", "../shared/data"))
    parser.add_argument("--sets", nargs="+", default=["opencv_9x6", "stereopi_air", "panama",
                                                      "bermuda", "sim_air", "sim_water"])
    parser.add_argument("--choose-once", action="store_true",
                        help="choose sea3d's detector once on the whole set (faster; the "
                             "left-out pair then takes part in the choice)")
    parser.add_argument("--sim-views", type=int, default=20)
    args = parser.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"sea3d calibration accuracy against plain OpenCV; OpenCV {cv2.__version__}, "
          f"{os.cpu_count()} CPUs, load average {load:.1f}", flush=True)
    sets = real_sets(Path(args.data), args.sets)
    for cs in sets:
        run_set(cs, args.choose_once, lambda s: print(s, flush=True))
    for cs in sim_sets(args.sim_views, args.sets):
        run_set(cs, args.choose_once, lambda s: print(s, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
