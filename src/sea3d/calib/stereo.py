"""Stereo calibration of a pinhole pair from board detections, with automatic rejection of bad
views, a leave-one-pair-out holdout error, image coverage and plain-words guidance.

The pipeline (``docs/calibration.md``):

1. Pair the left and right detections; keep the corners both images saw.
2. Calibrate each camera (``cv2.calibrateCamera``), then refine both cameras and the stereo
   extrinsics jointly (``cv2.stereoCalibrateExtended`` with ``CALIB_USE_INTRINSIC_GUESS``).
3. Reject the worst view while its RMS is above ``max(median + k * 1.4826 * MAD, ratio *
   median)`` of the per-view RMS values, and recalibrate; every rejection keeps its reason.
4. Holdout: for each view, recalibrate without it and measure the reprojection error of that
   pair with its board pose fitted to both images and the rig held fixed.

The same calibration runs in water; refraction is then absorbed into the pinhole parameters
(the paper's first in-water approach); see :mod:`sea3d.calib.port` for the refractive model.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import scipy.sparse
from numpy.typing import NDArray
from scipy.optimize import least_squares

from sea3d._text import plural
from sea3d._typing import FloatArray
from sea3d.calib._lm import levenberg_marquardt
from sea3d.calib._verdict import verdict as calibration_verdict
from sea3d.calib.targets import Detection
from sea3d.errors import CalibrationError, ConfigError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T

__all__ = [
    "CalibrationStatus",
    "CameraCalibration",
    "DetectorTrial",
    "RejectedView",
    "StereoCalibConfig",
    "StereoCalibration",
    "ViewStats",
    "calibrate_stereo",
    "calibrate_stereo_best",
    "opencv_reference_stereo",
]

log = logging.getLogger(__name__)


_DISTORTION_FLAGS = {
    # k1 k2 p1 p2 k3 (OpenCV's default five coefficients)
    "standard": 0,
    # k1 k2 p1 p2, k3 held at zero: fewer parameters for few or narrow views
    "simple": cv2.CALIB_FIX_K3,
    # k1..k6 p1 p2: the rational model, for wide lenses or refraction absorbed in water
    "rational": cv2.CALIB_RATIONAL_MODEL,
}


class CalibrationStatus(enum.StrEnum):
    """Outcome of a calibration."""

    OK = "ok"  #: converged; see the guidance for how far to trust it
    FAILED = "failed"  #: no usable estimate; ``message`` says why


@dataclass(frozen=True, kw_only=True)
class StereoCalibConfig:
    """Settings of :func:`calibrate_stereo` (also the CLI's options).

    Attributes:
        distortion: ``"standard"`` (k1 k2 p1 p2 k3), ``"simple"`` (k3 = 0) or ``"rational"``
            (8 coefficients; useful in water, where refraction is absorbed).
        min_views: fewest usable pairs to calibrate from.
        reject_outliers: drop views whose RMS is far above the others.
        mad_k: rejection threshold in robust standard deviations (1.4826 MAD) above the median.
        min_ratio: a view is never rejected below ``min_ratio * median`` per-view RMS.
        min_reject_px: nor below this RMS: on clean data a view at 0.1 px is no outlier even
            when the median is 0.05 px.
        max_rejected_fraction: at most this share of the usable views is rejected.
        holdout: compute the leave-one-pair-out holdout error.
        opencv_start: also start the final joint refinement from OpenCV's ``stereoCalibrate``
            and keep the lower minimum (slower; guarantees an RMS no worse than OpenCV's).
        coverage_cells: ``(cols, rows)`` of the grid used for image coverage.
        min_common_corners: fewest corners seen in both images for a pair to be used.
    """

    distortion: str = "standard"
    min_views: int = 6
    reject_outliers: bool = True
    mad_k: float = 3.0
    min_ratio: float = 1.5
    min_reject_px: float = 0.25
    max_rejected_fraction: float = 0.3
    holdout: bool = True
    opencv_start: bool = False
    coverage_cells: tuple[int, int] = (8, 6)
    min_common_corners: int = 6

    def __post_init__(self) -> None:
        if self.distortion not in _DISTORTION_FLAGS:
            raise ConfigError(f"distortion must be one of {sorted(_DISTORTION_FLAGS)}; got "
                              f"{self.distortion!r}")
        if self.min_views < 3:
            raise ConfigError(f"min_views must be at least 3; got {self.min_views}")
        if not (0.0 <= self.max_rejected_fraction < 1.0):
            raise ConfigError("max_rejected_fraction must be in [0, 1)")
        if self.mad_k <= 0 or self.min_ratio < 1.0:
            raise ConfigError("mad_k must be positive and min_ratio at least 1")


@dataclass(frozen=True, kw_only=True, eq=False)
class CameraCalibration:
    """Intrinsics of one camera.

    Attributes:
        K: ``(3, 3)`` float64 camera matrix, pixels.
        dist: ``(n,)`` float64 OpenCV distortion coefficients (5 or 8).
        image_size: ``(width, height)`` pixels.
        rms_px: reprojection RMS over the used views after the joint stereo refinement, pixels.
        coverage: share of the ``coverage_cells`` grid cells holding at least one used corner.
        coverage_counts: ``(rows, cols)`` int64 corner counts per grid cell.
    """

    K: FloatArray
    dist: FloatArray
    image_size: tuple[int, int]
    rms_px: float
    coverage: float
    coverage_counts: NDArray[np.int64]

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def to_dict(self) -> dict[str, Any]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "dist": [float(v) for v in self.dist], "rms_px": self.rms_px,
                "coverage": self.coverage,
                "width": self.image_size[0], "height": self.image_size[1]}


@dataclass(frozen=True, kw_only=True)
class RejectedView:
    """A pair left out of the calibration, and why."""

    left: str
    right: str
    reason: str


@dataclass(frozen=True, kw_only=True, eq=False)
class ViewStats:
    """One used pair.

    Attributes:
        left, right: image names.
        rms_left_px, rms_right_px: reprojection RMS in each image, pixels.
        holdout_px: RMS of this pair when left out of the calibration (NaN if not computed).
        distance_m: distance from the left camera to the board's centre, metres.
        tilt_deg: angle between the board normal and the left camera's optical axis, degrees.
        corners_left_px, corners_right_px: ``(N, 2)`` detected corners.
        residuals_left_px, residuals_right_px: ``(N, 2)`` projected minus detected, pixels.
    """

    left: str
    right: str
    rms_left_px: float
    rms_right_px: float
    holdout_px: float
    distance_m: float
    tilt_deg: float
    corners_left_px: FloatArray
    corners_right_px: FloatArray
    residuals_left_px: FloatArray
    residuals_right_px: FloatArray

    @property
    def rms_px(self) -> float:
        return math.sqrt(0.5 * (self.rms_left_px**2 + self.rms_right_px**2))


@dataclass(frozen=True, kw_only=True)
class DetectorTrial:
    """One checkerboard detector tried by :func:`calibrate_stereo_best`.

    Attributes:
        detector: its name (:data:`sea3d.calib.targets.CHECKER_DETECTORS`).
        status: ``"ok"``, ``"failed"`` or ``"error"`` (too few pairs, ...).
        message: the calibration's message.
        rms_px: reprojection RMS of its calibration (on its own corners), pixels.
        holdout_px: its leave-one-pair-out error over the pairs it used, pixels.
        common_holdout_px: its leave-one-pair-out error over the pairs every detector used
            (what the choice compares), pixels.
        pairs_used: pairs its calibration used.
    """

    detector: str
    status: str
    message: str = ""
    rms_px: float = math.nan
    holdout_px: float = math.nan
    common_holdout_px: float = math.nan
    pairs_used: int = 0

    def to_dict(self) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {"detector": self.detector, "status": self.status, "message": self.message,
                "rms_px": num(self.rms_px), "holdout_px": num(self.holdout_px),
                "common_holdout_px": num(self.common_holdout_px),
                "pairs_used": self.pairs_used}


@dataclass(frozen=True, kw_only=True, eq=False)
class StereoCalibration:
    """Result of :func:`calibrate_stereo`.

    Attributes:
        status: :class:`CalibrationStatus`; on ``FAILED`` only ``message``, ``detections`` and
            ``views_rejected`` are meaningful.
        message: what happened, in words.
        left, right: per-camera intrinsics.
        T_left_right: ``(4, 4)`` float64, maps right-camera points into the left camera frame
            (metres).
        rms_px: joint stereo reprojection RMS over both images of every used view, pixels.
        holdout_px: leave-one-pair-out RMS, pixels (NaN if not computed).
        views: statistics of the used pairs.
        views_rejected: pairs left out, each with its reason.
        detections: ``(name, status, message)`` of every image, left then right.
        guidance: plain-words advice: what to capture next and whether to trust the result.
        verdict: ``"trusted"``, ``"usable with care"`` or ``"not trusted"``.
        config: the settings used.
        timings_s: seconds per stage: ``fit`` (mono + joint refinement), ``rejection``
            (refits after rejections), ``opencv_start``, ``holdout``, ``total``.
        detector: the checkerboard detector whose corners were used, when
            :func:`calibrate_stereo_best` chose it (empty otherwise).
        detector_reason: why it was chosen, in words.
        detector_trials: every detector tried, with its errors.
    """

    status: CalibrationStatus
    message: str
    left: CameraCalibration | None = None
    right: CameraCalibration | None = None
    T_left_right: FloatArray = field(default_factory=lambda: np.eye(4))
    rms_px: float = math.nan
    holdout_px: float = math.nan
    views: tuple[ViewStats, ...] = ()
    views_rejected: tuple[RejectedView, ...] = ()
    detections: tuple[tuple[str, str, str], ...] = ()
    guidance: tuple[str, ...] = ()
    verdict: str = "not trusted"
    config: StereoCalibConfig = field(default_factory=StereoCalibConfig)
    timings_s: dict[str, float] = field(default_factory=dict)
    detector: str = ""
    detector_reason: str = ""
    detector_trials: tuple[DetectorTrial, ...] = ()

    @property
    def ok(self) -> bool:
        return self.status is CalibrationStatus.OK

    @property
    def baseline_m(self) -> float:
        """Distance between the camera centres, metres."""
        return float(np.linalg.norm(self.T_left_right[:3, 3]))

    def to_rig(self) -> StereoRig:
        """The calibrated rig (pinhole cameras).

        Raises:
            CalibrationError: the calibration failed (there is no rig to give).
        """
        if not self.ok or self.left is None or self.right is None:
            raise CalibrationError(f"no rig: calibration failed ({self.message})")
        w, h = self.left.image_size
        return StereoRig(left=PinholeCamera.from_K(self.left.K, w, h, self.left.dist),
                         right=PinholeCamera.from_K(self.right.K, w, h, self.right.dist),
                         T_left_right=self.T_left_right)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the ``--json`` output)."""
        def num(x: float) -> float | None:
            return None if not math.isfinite(x) else float(x)

        out: dict[str, Any] = {
            "status": str(self.status), "message": self.message,
            "rms_px": num(self.rms_px), "holdout_px": num(self.holdout_px),
            "baseline_m": num(self.baseline_m) if self.ok else None,
            "views_used": len(self.views),
            "views_rejected": [{"left": r.left, "right": r.right, "reason": r.reason}
                               for r in self.views_rejected],
            "verdict": self.verdict, "guidance": list(self.guidance),
        }
        if self.left is not None and self.right is not None:
            out["left"] = self.left.to_dict()
            out["right"] = self.right.to_dict()
            out["T_left_right"] = self.T_left_right.tolist()
            out["views"] = [{"left": v.left, "right": v.right, "rms_left_px": v.rms_left_px,
                             "rms_right_px": v.rms_right_px, "holdout_px": num(v.holdout_px),
                             "distance_m": v.distance_m, "tilt_deg": v.tilt_deg}
                            for v in self.views]
        if self.detector:
            out["detector"] = {"chosen": self.detector, "reason": self.detector_reason,
                               "trials": [t.to_dict() for t in self.detector_trials]}
        out["detections"] = [{"image": n, "status": s, "message": m}
                             for n, s, m in self.detections]
        return out


# ---------------------------------------------------------------------- helpers
@dataclass
class _Pair:
    left: str
    right: str
    obj: NDArray[np.float32]  # (N, 1, 3)
    uv_l: NDArray[np.float32]  # (N, 1, 2)
    uv_r: NDArray[np.float32]


def orient_consistently(det_l: Detection, det_r: Detection) -> Detection:
    """Checkerboards: make the right image's corner order agree with the left's.

    A checkerboard's corners can come back in either of two 180-degree-rotated orders; in a
    stereo pair both images see nearly the same view, so the right order is the one whose first-
    to-last corner direction agrees with the left image's.
    """
    if not (det_l.ambiguous_order and det_r.ambiguous_order) or len(det_l) != len(det_r) or (
            len(det_l) < 2):
        return det_r
    dir_l = det_l.corners_px[-1] - det_l.corners_px[0]
    dir_r = det_r.corners_px[-1] - det_r.corners_px[0]
    if float(dir_l @ dir_r) >= 0:
        return det_r
    return dataclasses.replace(det_r, corners_px=det_r.corners_px[::-1].copy())


def _check_sizes(dets: Sequence[Detection], side: str) -> tuple[int, int]:
    sizes: dict[tuple[int, int], list[str]] = {}
    for i, d in enumerate(dets):
        if d.image_size != (0, 0):
            sizes.setdefault(d.image_size, []).append(d.name or f"{side}[{i}]")
    if not sizes:
        raise CalibrationError(f"no readable {side} images")
    if len(sizes) > 1:
        parts = "; ".join(f"{w}x{h}: {', '.join(n[:3])}{' ...' if len(n) > 3 else ''}"
                          for (w, h), n in sizes.items())
        raise CalibrationError(f"{side} images have mixed sizes ({parts}); calibrate one image "
                               f"size at a time")
    return next(iter(sizes))


def _coverage(corners: Sequence[FloatArray], size: tuple[int, int],
              cells: tuple[int, int]) -> tuple[float, NDArray[np.int64]]:
    w, h = size
    nx, ny = cells
    counts = np.zeros((ny, nx), dtype=np.int64)
    for uv in corners:
        ix = np.clip((uv[:, 0] + 0.5) * nx / w, 0, nx - 1).astype(int)
        iy = np.clip((uv[:, 1] + 0.5) * ny / h, 0, ny - 1).astype(int)
        np.add.at(counts, (iy, ix), 1)
    return float((counts > 0).mean()), counts


def _project(obj: NDArray[Any], rvec: NDArray[Any], tvec: NDArray[Any], K: FloatArray,
             dist: FloatArray) -> FloatArray:
    uv, _ = cv2.projectPoints(obj.reshape(-1, 1, 3).astype(np.float64), rvec, tvec, K, dist)
    return np.asarray(uv, dtype=np.float64).reshape(-1, 2)


def _rms(res: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if len(res) else math.nan


@dataclass
class _Fit:
    K1: FloatArray
    d1: FloatArray
    K2: FloatArray
    d2: FloatArray
    R: FloatArray  # R_right_left
    T: FloatArray  # t_right_left (3,)
    rvecs: list[FloatArray]  # board -> left camera
    tvecs: list[FloatArray]
    rms: float


def _free_dist(flags: int) -> tuple[int, list[int]]:
    """Number of distortion coefficients and the indices left free by ``flags``."""
    if flags & cv2.CALIB_RATIONAL_MODEL:
        return 8, list(range(8))
    if flags & cv2.CALIB_FIX_K3:
        return 5, [0, 1, 2, 3]
    return 5, list(range(5))


def _refine_stereo(pairs: Sequence[_Pair], fit: _Fit, flags: int,
                   max_nfev: int = 200, ftol: float = 1e-12) -> _Fit:
    """Joint Levenberg-Marquardt refinement of both cameras, the rig and all board poses.

    Minimises the squared pixel residuals of every corner in both images (the quantity OpenCV's
    ``stereoCalibrate`` reports) with the analytic Jacobians of ``cv2.projectPoints`` and
    ``cv2.composeRT``. Parameters: fx fy cx cy and the free distortion coefficients of each
    camera, ``R_right_left``/``t_right_left`` (Rodrigues vector, metres) and the board pose in
    the left camera for every view (``6V``).
    """
    n_dist, free = _free_dist(flags)
    nf = len(free)
    n_cam = 4 + nf
    d1 = np.zeros(n_dist)
    d1[:min(n_dist, fit.d1.size)] = fit.d1[:n_dist]
    d2 = np.zeros(n_dist)
    d2[:min(n_dist, fit.d2.size)] = fit.d2[:n_dist]
    if flags & cv2.CALIB_FIX_K3 and not flags & cv2.CALIB_RATIONAL_MODEL:
        d1[4] = d2[4] = 0.0
    V = len(pairs)
    objs = [p.obj.reshape(-1, 3).astype(np.float64) for p in pairs]
    uvl = [p.uv_l.reshape(-1, 2).astype(np.float64) for p in pairs]
    uvr = [p.uv_r.reshape(-1, 2).astype(np.float64) for p in pairs]
    counts = [len(o) for o in objs]
    offs = np.concatenate([[0], np.cumsum([4 * c for c in counts])])
    n_res = int(offs[-1])
    rig0 = 2 * n_cam
    pose0 = rig0 + 6
    n_par = pose0 + 6 * V

    def unpack(x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        K1 = np.array([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1.0]])
        K2 = np.array([[x[n_cam], 0, x[n_cam + 2]], [0, x[n_cam + 1], x[n_cam + 3]],
                       [0, 0, 1.0]])
        dd1, dd2 = d1.copy(), d2.copy()
        dd1[free] = x[4:n_cam]
        dd2[free] = x[n_cam + 4:2 * n_cam]
        return K1, dd1, K2, dd2

    x0 = np.concatenate([
        [fit.K1[0, 0], fit.K1[1, 1], fit.K1[0, 2], fit.K1[1, 2]], d1[free],
        [fit.K2[0, 0], fit.K2[1, 1], fit.K2[0, 2], fit.K2[1, 2]], d2[free],
        cv2.Rodrigues(fit.R)[0].ravel(), fit.T.ravel(),
        *[np.concatenate([r, t]) for r, t in zip(fit.rvecs, fit.tvecs, strict=True)]])
    cam_cols = [6, 7, 8, 9, *[10 + i for i in free]]  # projectPoints jacobian: fx fy cx cy dist

    # Sparsity pattern of the Jacobian, fixed for the problem: per view, the left rows touch
    # camera 1 and the view's pose, the right rows camera 2, the view's pose and the rig.
    pat_rows, pat_cols = [], []
    for v in range(V):
        n = counts[v]
        a = int(offs[v])
        pcol = pose0 + 6 * v
        cols_l = np.r_[0:n_cam, pcol:pcol + 6]
        cols_r = np.r_[n_cam:2 * n_cam, pcol:pcol + 6, rig0:rig0 + 6]
        rl = np.arange(a, a + 2 * n)
        rr = np.arange(a + 2 * n, a + 4 * n)
        pat_rows += [np.repeat(rl, cols_l.size), np.repeat(rr, cols_r.size)]
        pat_cols += [np.tile(cols_l, rl.size), np.tile(cols_r, rr.size)]
    rows_idx = np.concatenate(pat_rows)
    cols_idx = np.concatenate(pat_cols)

    def evaluate(x: FloatArray, want_jac: bool) -> tuple[FloatArray, Any]:
        K1, dd1, K2, dd2 = unpack(x)
        rv_rig, tv_rig = x[rig0:rig0 + 3], x[rig0 + 3:rig0 + 6]
        res = np.empty(n_res)
        blocks = []
        for v in range(V):
            rv, tv = x[pose0 + 6 * v:pose0 + 6 * v + 3], x[pose0 + 6 * v + 3:pose0 + 6 * v + 6]
            n = counts[v]
            a = int(offs[v])
            uv_l, J_l = cv2.projectPoints(objs[v], rv, tv, K1, dd1)
            rv3, tv3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = \
                cv2.composeRT(rv, tv, rv_rig, tv_rig)
            uv_r, J_r = cv2.projectPoints(objs[v], rv3, tv3, K2, dd2)
            res[a:a + 2 * n] = (uv_l.reshape(-1, 2) - uvl[v]).ravel()
            res[a + 2 * n:a + 4 * n] = (uv_r.reshape(-1, 2) - uvr[v]).ravel()
            if not want_jac:
                continue
            Jr_r, Jr_t = J_r[:, 0:3], J_r[:, 3:6]
            left_block = np.concatenate([J_l[:, cam_cols], J_l[:, 0:6]], axis=1)
            right_block = np.concatenate([
                J_r[:, cam_cols],
                Jr_r @ dr3dr1 + Jr_t @ dt3dr1, Jr_r @ dr3dt1 + Jr_t @ dt3dt1,
                Jr_r @ dr3dr2 + Jr_t @ dt3dr2, Jr_r @ dr3dt2 + Jr_t @ dt3dt2], axis=1)
            blocks += [left_block.ravel(), right_block.ravel()]
        if not want_jac:
            return res, None
        jac = scipy.sparse.csr_matrix((np.concatenate(blocks), (rows_idx, cols_idx)),
                                      shape=(n_res, n_par))
        return res, jac

    sol = levenberg_marquardt(evaluate, x0, max_iter=max_nfev, ftol=ftol)
    log.debug("stereo refinement: %s after %d steps", sol.message, sol.iterations)
    x = sol.x
    K1, dd1, K2, dd2 = unpack(x)
    res = sol.residuals
    return _Fit(K1=K1, d1=dd1, K2=K2, d2=dd2,
                R=np.asarray(cv2.Rodrigues(x[rig0:rig0 + 3])[0], dtype=np.float64),
                T=x[rig0 + 3:rig0 + 6].copy(),
                rvecs=[x[pose0 + 6 * v:pose0 + 6 * v + 3].copy() for v in range(V)],
                tvecs=[x[pose0 + 6 * v + 3:pose0 + 6 * v + 6].copy() for v in range(V)],
                rms=float(np.sqrt(np.mean(res.reshape(-1, 2) ** 2) * 2)))


def _initial_fit(pairs: Sequence[_Pair], size: tuple[int, int], flags: int) -> _Fit:
    """Mono calibrations (OpenCV), then the rig from the median of the per-view relative poses."""
    obj: list[Any] = [p.obj for p in pairs]
    uv_l: list[Any] = [p.uv_l for p in pairs]
    uv_r: list[Any] = [p.uv_r for p in pairs]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    _, K1, d1, rv1, tv1 = cv2.calibrateCamera(obj, uv_l, size, None, None,  # type: ignore[call-overload]
                                              flags=flags, criteria=criteria)
    _, K2, d2, rv2, tv2 = cv2.calibrateCamera(obj, uv_r, size, None, None,  # type: ignore[call-overload]
                                              flags=flags, criteria=criteria)
    rels = []
    for a, b, c, d in zip(rv1, tv1, rv2, tv2, strict=True):
        Rl, Rr = cv2.Rodrigues(a)[0], cv2.Rodrigues(c)[0]
        R = Rr @ Rl.T
        rels.append(np.concatenate([cv2.Rodrigues(R)[0].ravel(),
                                    (np.ravel(d) - R @ np.ravel(b))]))
    med = np.median(np.asarray(rels), axis=0)
    return _Fit(K1=K1, d1=d1.ravel(), K2=K2, d2=d2.ravel(), R=cv2.Rodrigues(med[:3])[0],
                T=med[3:], rvecs=[np.ravel(r).astype(np.float64) for r in rv1],
                tvecs=[np.ravel(t).astype(np.float64) for t in tv1], rms=math.nan)


def _opencv_start_fit(pairs: Sequence[_Pair], size: tuple[int, int], flags: int) -> _Fit | None:
    """Joint refinement started from OpenCV's own ``stereoCalibrate`` solution.

    The cost surface is flat along the distortion coefficients and LM paths can end in
    different local minima; OpenCV's path is a second start, and the caller keeps the lower of
    the two, so the result is never worse than OpenCV's.
    """
    start = _initial_fit(pairs, size, flags)
    try:
        out = cv2.stereoCalibrateExtended(  # type: ignore[call-overload]
            [p.obj for p in pairs], [p.uv_l for p in pairs], [p.uv_r for p in pairs],
            start.K1.copy(), start.d1.copy(), start.K2.copy(), start.d2.copy(), size,
            None, None, flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10))
    except cv2.error as err:
        log.debug("OpenCV stereoCalibrate start failed: %s", err.msg)
        return None
    cv_start = _Fit(K1=out[1], d1=out[2].ravel(), K2=out[3], d2=out[4].ravel(), R=out[5],
                    T=np.ravel(out[6]), rvecs=[np.ravel(r).astype(np.float64) for r in out[9]],
                    tvecs=[np.ravel(t).astype(np.float64) for t in out[10]], rms=math.nan)
    return _refine_stereo(pairs, cv_start, flags)


def _fit(pairs: Sequence[_Pair], size: tuple[int, int], flags: int,
         init: _Fit | None = None, skip: int | None = None, ftol: float = 1e-12,
         max_iter: int = 200) -> _Fit:
    """Initial mono calibrations (unless ``init``), then the joint stereo refinement.

    With ``init`` and ``skip``, ``init`` holds poses for all of ``pairs`` and ``skip`` names
    the view that ``pairs`` no longer holds (holdout folds start from the full solution).
    """
    if init is None:
        start = _initial_fit(pairs, size, flags)
    else:
        keep = [k for k in range(len(init.rvecs)) if k != skip]
        start = _Fit(K1=init.K1, d1=init.d1, K2=init.K2, d2=init.d2, R=init.R, T=init.T,
                     rvecs=[init.rvecs[k] for k in keep], tvecs=[init.tvecs[k] for k in keep],
                     rms=init.rms)
    return _refine_stereo(pairs, start, flags, ftol=ftol, max_nfev=max_iter)


def _view_residuals(fit: _Fit, pair: _Pair, rvec: FloatArray,
                    tvec: FloatArray) -> tuple[FloatArray, FloatArray]:
    obj = pair.obj.reshape(-1, 3).astype(np.float64)
    res_l = _project(obj, rvec, tvec, fit.K1, fit.d1) - pair.uv_l.reshape(-1, 2)
    R_l = cv2.Rodrigues(rvec)[0]
    R_r = fit.R @ R_l
    t_r = fit.R @ tvec + fit.T
    res_r = _project(obj, cv2.Rodrigues(R_r)[0], t_r, fit.K2, fit.d2) - pair.uv_r.reshape(-1, 2)
    return res_l, res_r


def _holdout_pose(fit: _Fit, pair: _Pair) -> tuple[FloatArray, FloatArray]:
    """Board pose in the left camera fitted to both images of a pair with the rig fixed."""
    obj = pair.obj.reshape(-1, 3).astype(np.float64)
    _ok, rvec, tvec = cv2.solvePnP(obj, pair.uv_l.reshape(-1, 1, 2).astype(np.float64), fit.K1,
                                  fit.d1, flags=cv2.SOLVEPNP_ITERATIVE)
    x0 = np.concatenate([np.ravel(rvec), np.ravel(tvec)])

    def fun(x: FloatArray) -> FloatArray:
        rl, rr = _view_residuals(fit, pair, x[:3], x[3:])
        return np.concatenate([rl.ravel(), rr.ravel()])

    sol = least_squares(fun, x0, method="lm", x_scale="jac")
    return sol.x[:3], sol.x[3:]


def _pose_stats(rvec: FloatArray, tvec: FloatArray, obj: FloatArray) -> tuple[float, float]:
    R = cv2.Rodrigues(rvec)[0]
    centre = R @ obj.reshape(-1, 3).mean(axis=0) + tvec
    normal = R[:, 2]
    tilt = math.degrees(math.acos(min(1.0, abs(float(normal[2])))))
    return float(np.linalg.norm(centre)), tilt


def _missing(dets: Sequence[Detection], camera: str, show: int = 4) -> str:
    """``left: a.png, b.png and 3 more`` (or ``left: none``): the images without a board."""
    names = [d.name or str(i) for i, d in enumerate(dets) if not d.ok]
    if not names:
        return f"{camera}: none"
    more = f" and {len(names) - show} more" if len(names) > show else ""
    return f"{camera}: {', '.join(names[:show])}{more}"


def _pairs_from_detections(left: Sequence[Detection], right: Sequence[Detection],
                           cfg: StereoCalibConfig) -> tuple[list[_Pair], list[RejectedView]]:
    pairs: list[_Pair] = []
    rejected: list[RejectedView] = []
    for i, (dl, dr) in enumerate(zip(left, right, strict=True)):
        nl, nr = dl.name or f"left[{i}]", dr.name or f"right[{i}]"
        problems = []
        if not dl.ok:
            problems.append(f"left image: {dl.status} ({dl.message})")
        if not dr.ok:
            problems.append(f"right image: {dr.status} ({dr.message})")
        if problems:
            rejected.append(RejectedView(left=nl, right=nr, reason="; ".join(problems)))
            continue
        dr = orient_consistently(dl, dr)
        common, il, ir = np.intersect1d(dl.ids, dr.ids, return_indices=True)
        if len(common) < cfg.min_common_corners:
            rejected.append(RejectedView(
                left=nl, right=nr,
                reason=f"only {len(common)} corners seen in both images (need "
                       f"{cfg.min_common_corners})"))
            continue
        pairs.append(_Pair(
            left=nl, right=nr,
            obj=dl.points_board_m[il].reshape(-1, 1, 3).astype(np.float32),
            uv_l=dl.corners_px[il].reshape(-1, 1, 2).astype(np.float32),
            uv_r=dr.corners_px[ir].reshape(-1, 1, 2).astype(np.float32)))
    return pairs, rejected


def _robust_threshold(errors: FloatArray, cfg: StereoCalibConfig) -> tuple[float, float, float]:
    med = float(np.median(errors))
    mad = 1.4826 * float(np.median(np.abs(errors - med)))
    return max(med + cfg.mad_k * mad, cfg.min_ratio * med, cfg.min_reject_px), med, mad


def _pair_image_size(left: Sequence[Detection], right: Sequence[Detection]) -> tuple[int, int]:
    """The one image size of all left and right images.

    Raises:
        CalibrationError: left and right counts differ, or the images have mixed sizes.
    """
    if len(left) != len(right):
        raise CalibrationError(
            f"got {len(left)} left and {len(right)} right images; calibration needs pairs "
            f"(left[i] with right[i])")
    size_l = _check_sizes(left, "left")
    size_r = _check_sizes(right, "right")
    if size_l != size_r:
        raise CalibrationError(f"left images are {size_l[0]}x{size_l[1]} but right images are "
                               f"{size_r[0]}x{size_r[1]}")
    return size_l


def _reject_outliers(fit: _Fit, pairs: list[_Pair], rejected: list[RejectedView],
                     size: tuple[int, int], flags: int, cfg: StereoCalibConfig) -> _Fit | str:
    """Drop the worst pair and refit while its reprojection RMS is an outlier.

    ``pairs`` and ``rejected`` are updated in place. Returns the last fit, or the failure
    message when OpenCV's refit fails.
    """
    n_usable = len(pairs)
    max_reject = math.floor(cfg.max_rejected_fraction * n_usable)
    n_outliers = 0
    while cfg.reject_outliers:
        per_view = []
        for k, p in enumerate(pairs):
            rl, rr = _view_residuals(fit, p, fit.rvecs[k], fit.tvecs[k])
            per_view.append(math.sqrt(0.5 * (_rms(rl) ** 2 + _rms(rr) ** 2)))
        errs = np.asarray(per_view)
        thr, med, mad = _robust_threshold(errs, cfg)
        worst = int(np.argmax(errs))
        if errs[worst] <= thr or n_outliers >= max_reject or len(pairs) - 1 < cfg.min_views:
            break
        p = pairs.pop(worst)
        reason = (f"reprojection RMS {errs[worst]:.2f} px is above the outlier limit "
                  f"{thr:.2f} px (median {med:.2f} px + {cfg.mad_k:g} x robust spread "
                  f"{mad:.2f} px, at least {cfg.min_ratio:g} x median and "
                  f"{cfg.min_reject_px:g} px); a blurred image, a "
                  f"misdetected corner or a bent board")
        log.info("rejecting %s / %s: %s", p.left, p.right, reason)
        rejected.append(RejectedView(left=p.left, right=p.right, reason=reason))
        n_outliers += 1
        try:
            fit = _fit(pairs, size, flags)
        except cv2.error as err:
            return f"OpenCV calibration failed: {err.msg}"
    return fit


def _holdout_errors(fit: _Fit, pairs: list[_Pair], size: tuple[int, int], flags: int,
                    cfg: StereoCalibConfig) -> tuple[FloatArray, float]:
    """Leave-one-pair-out reprojection errors.

    Returns ``((P,) per-pair holdout RMS px, NaN where not computed; overall holdout RMS px)``.
    """
    holdout = np.full(len(pairs), np.nan)
    holdout_sq: list[FloatArray] = []
    if cfg.holdout and len(pairs) > cfg.min_views - 1 and len(pairs) >= 4:
        for k in range(len(pairs)):
            rest = pairs[:k] + pairs[k + 1:]
            try:
                fold = _fit(rest, size, flags, init=fit, skip=k, ftol=1e-8, max_iter=4)
                rv, tv = _holdout_pose(fold, pairs[k])
                rl, rr = _view_residuals(fold, pairs[k], rv, tv)
            except cv2.error as err:
                log.warning("holdout fold without %s failed: %s", pairs[k].left, err.msg)
                continue
            both = np.concatenate([rl, rr])
            holdout[k] = _rms(both)
            holdout_sq.append(np.sum(both**2, axis=1))
    holdout_px = float(np.sqrt(np.mean(np.concatenate(holdout_sq)))) if holdout_sq else math.nan
    return holdout, holdout_px


def _views_and_cameras(
    fit: _Fit, pairs: list[_Pair], holdout: FloatArray, size: tuple[int, int],
    cfg: StereoCalibConfig,
) -> tuple[list[ViewStats], CameraCalibration, CameraCalibration, float]:
    """Each used pair's figures, both cameras' intrinsics with coverage, and the overall RMS px."""
    views = []
    all_l, all_r, used_l, used_r = [], [], [], []
    for k, p in enumerate(pairs):
        rl, rr = _view_residuals(fit, p, fit.rvecs[k], fit.tvecs[k])
        all_l.append(rl)
        all_r.append(rr)
        used_l.append(p.uv_l.reshape(-1, 2).astype(np.float64))
        used_r.append(p.uv_r.reshape(-1, 2).astype(np.float64))
        dist_m, tilt = _pose_stats(fit.rvecs[k], fit.tvecs[k], p.obj.astype(np.float64))
        views.append(ViewStats(left=p.left, right=p.right, rms_left_px=_rms(rl),
                               rms_right_px=_rms(rr), holdout_px=float(holdout[k]),
                               distance_m=dist_m, tilt_deg=tilt,
                               corners_left_px=used_l[-1], corners_right_px=used_r[-1],
                               residuals_left_px=rl, residuals_right_px=rr))
    cov_l, counts_l = _coverage(used_l, size, cfg.coverage_cells)
    cov_r, counts_r = _coverage(used_r, size, cfg.coverage_cells)
    res_l, res_r = np.concatenate(all_l), np.concatenate(all_r)
    cam_l = CameraCalibration(K=fit.K1, dist=fit.d1, image_size=size, rms_px=_rms(res_l),
                              coverage=cov_l, coverage_counts=counts_l)
    cam_r = CameraCalibration(K=fit.K2, dist=fit.d2, image_size=size, rms_px=_rms(res_r),
                              coverage=cov_r, coverage_counts=counts_r)
    rms = _rms(np.concatenate([res_l, res_r]))
    return views, cam_l, cam_r, rms


def calibrate_stereo(left: Sequence[Detection], right: Sequence[Detection],
                     config: StereoCalibConfig | None = None) -> StereoCalibration:
    """Calibrate a stereo pair from board detections.

    Args:
        left: one :class:`~sea3d.calib.targets.Detection` per left image, in pair order
            (``left[i]`` and ``right[i]`` were taken together); names (``Detection.name``) are
            used in messages.
        right: one per right image, likewise.
        config: settings; defaults to :class:`StereoCalibConfig()`.

    Returns:
        A :class:`StereoCalibration`; ``status`` is ``FAILED`` with a reason when OpenCV's
        optimisation fails or gives no finite result.

    Raises:
        CalibrationError: the input cannot be calibrated: left and right counts differ, the
            images have mixed sizes, or fewer than ``config.min_views`` pairs have the board in
            both images (the message names the files and what was found in them).
    """
    cfg = config or StereoCalibConfig()
    size = _pair_image_size(left, right)
    dets = tuple((d.name or f"{side}[{i}]", str(d.status), d.message)
                 for side, ds in (("left", left), ("right", right)) for i, d in enumerate(ds))
    pairs, rejected = _pairs_from_detections(left, right, cfg)
    if len(pairs) < cfg.min_views:
        found_l = sum(d.ok for d in left)
        found_r = sum(d.ok for d in right)
        raise CalibrationError(
            f"the board was found in {found_l} of {len(left)} left and {found_r} of "
            f"{len(right)} right images, giving {plural(len(pairs), 'usable pair')}; at least "
            f"{cfg.min_views} are needed (not found in {_missing(left, 'left')}; "
            f"{_missing(right, 'right')})")
    flags = _DISTORTION_FLAGS[cfg.distortion]
    timings: dict[str, float] = {}
    t_start = t0 = time.perf_counter()
    try:
        fit = _fit(pairs, size, flags)
    except cv2.error as err:
        return StereoCalibration(status=CalibrationStatus.FAILED,
                                 message=f"OpenCV calibration failed: {err.msg}",
                                 views_rejected=tuple(rejected), detections=dets, config=cfg)
    timings["fit"] = time.perf_counter() - t0
    T_right_left0 = np.eye(4)
    T_right_left0[:3, :3], T_right_left0[:3, 3] = fit.R, fit.T
    swapped = swapped_message(invert_T(T_right_left0))
    if swapped:
        return StereoCalibration(status=CalibrationStatus.FAILED, message=swapped,
                                 views_rejected=tuple(rejected), detections=dets, config=cfg,
                                 guidance=(swapped,), timings_s=timings)
    t0 = time.perf_counter()
    refit = _reject_outliers(fit, pairs, rejected, size, flags, cfg)
    if isinstance(refit, str):
        return StereoCalibration(status=CalibrationStatus.FAILED, message=refit,
                                 views_rejected=tuple(rejected), detections=dets, config=cfg)
    fit = refit
    timings["rejection"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if cfg.opencv_start:
        alt = _opencv_start_fit(pairs, size, flags)
        if alt is not None:
            log.debug("stereo refinement: own start %.5f px, OpenCV start %.5f px", fit.rms,
                      alt.rms)
            if alt.rms < fit.rms:
                fit = alt
    if not (np.isfinite(fit.K1).all() and np.isfinite(fit.K2).all() and np.isfinite(fit.T).all()
            and math.isfinite(fit.rms)):
        return StereoCalibration(status=CalibrationStatus.FAILED,
                                 message="calibration gave non-finite parameters",
                                 views_rejected=tuple(rejected), detections=dets, config=cfg)

    timings["opencv_start"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    holdout, holdout_px = _holdout_errors(fit, pairs, size, flags, cfg)
    timings["holdout"] = time.perf_counter() - t0
    views, cam_l, cam_r, rms = _views_and_cameras(fit, pairs, holdout, size, cfg)
    T_right_left = np.eye(4)
    T_right_left[:3, :3] = fit.R
    T_right_left[:3, 3] = fit.T
    T_left_right: FloatArray = np.asarray(np.linalg.inv(T_right_left), dtype=np.float64)
    result = StereoCalibration(
        status=CalibrationStatus.OK,
        message=f"calibrated from {plural(len(pairs), 'pair')} of {len(left)}",
        left=cam_l, right=cam_r, T_left_right=T_left_right, rms_px=rms, holdout_px=holdout_px,
        views=tuple(views), views_rejected=tuple(rejected), detections=dets, config=cfg)
    verdict, guidance = assess(result)
    timings["total"] = time.perf_counter() - t_start
    return dataclasses.replace(result, verdict=verdict, guidance=tuple(guidance),
                               timings_s=timings)


_TIE_FRACTION = 0.02


def calibrate_stereo_best(candidates: Mapping[str, tuple[Sequence[Detection],
                                                         Sequence[Detection]]],
                          config: StereoCalibConfig | None = None) -> StereoCalibration:
    """Calibrate with the corners of each checkerboard detector and keep the one whose
    calibration predicts held-out views best.

    Which detector gives the most accurate calibration depends on the images (blur, contrast,
    square size in pixels): on OpenCV's 9x6 set the classic detector's corners refined by
    ``cornerSubPix`` beat the sector-based detector's, on other sets the reverse (see
    ``docs/calibration.md``). The RMS on a detector's own corners does not tell: a detector
    whose errors the model can absorb gets a low RMS and a poor calibration. The
    leave-one-pair-out holdout error does: each pair is predicted by a calibration that never
    saw it. The detectors are compared on the pairs that every one of them used (so a detector
    is not favoured for having left the hard views out); with fewer than 3 such pairs, on
    their own holdout errors. Within 2 % of the lowest error, the earliest candidate wins.

    Args:
        candidates: ``{detector name: (left detections, right detections)}``, in order of
            preference (the first wins ties); names appear in messages.
        config: settings; the holdout error is computed whatever ``config.holdout`` says.

    Returns:
        The chosen detector's :class:`StereoCalibration`, with ``detector``,
        ``detector_reason`` and ``detector_trials`` filled in.

    Raises:
        CalibrationError: no candidates, or none of them can be calibrated (the first
            candidate's error is raised).
    """
    if not candidates:
        raise CalibrationError("no detections to calibrate from")
    cfg = dataclasses.replace(config or StereoCalibConfig(), holdout=True)
    results: dict[str, StereoCalibration] = {}
    errors: dict[str, CalibrationError] = {}
    for name, (left, right) in candidates.items():
        try:
            results[name] = calibrate_stereo(left, right, cfg)
        except CalibrationError as err:
            errors[name] = err
            log.info("detector %s: %s", name, err)
    usable = {n: r for n, r in results.items() if r.ok and math.isfinite(r.holdout_px)}
    if not results:
        raise next(iter(errors.values()))
    if not usable:
        first = next(iter(results.values()))
        return first
    per_pair = {n: {(v.left, v.right): v.holdout_px for v in r.views
                    if math.isfinite(v.holdout_px)} for n, r in usable.items()}
    common = set.intersection(*(set(d) for d in per_pair.values()))
    n_common = len(common)
    if n_common >= 3:
        scores = {n: math.sqrt(float(np.mean([d[k] ** 2 for k in sorted(common)])))
                  for n, d in per_pair.items()}
    else:
        scores = {n: r.holdout_px for n, r in usable.items()}
    order = list(candidates)
    best = min(scores.values())
    # Within 2 % of the best the earlier candidate wins: differences that small are noise, and
    # the preferred detector usually finds the board in more images.
    chosen = next(n for n in order if n in scores and scores[n] <= best * (1 + _TIE_FRACTION))
    trials = []
    for name in candidates:
        if name in results:
            r = results[name]
            trials.append(DetectorTrial(
                detector=name, status=str(r.status), message=r.message, rms_px=r.rms_px,
                holdout_px=r.holdout_px, common_holdout_px=scores.get(name, math.nan)
                if n_common >= 3 else math.nan, pairs_used=len(r.views)))
        else:
            trials.append(DetectorTrial(detector=name, status="error",
                                        message=str(errors[name])))
    others = [f"{scores[n]:.3f} px with {n}" for n in order if n in scores and n != chosen]
    where = (f"on the {n_common} pairs every detector used" if n_common >= 3
             else "on the pairs each used")
    reason = (f"{chosen}: holdout error {scores[chosen]:.3f} px {where}"
              + (f", against {', '.join(others)}" if others else "")
              + (f" (within {_TIE_FRACTION:.0%} of the lowest: the preferred detector is kept)"
                 if scores[chosen] > best else "")
              + (f"; {', '.join(sorted(errors))} could not calibrate" if errors else ""))
    failed = [n for n in results if n not in usable]
    if failed:
        reason += f"; {', '.join(failed)} failed"
    log.info("detector chosen: %s", reason)
    return dataclasses.replace(results[chosen], detector=chosen, detector_reason=reason,
                               detector_trials=tuple(trials))


def swapped_message(T_left_right: FloatArray) -> str:
    """A one-line explanation when the calibrated right camera sits to the left of the left
    camera (the images named left are the right camera's), else ``""``.

    sea3d's left camera is the one whose image shows a point further right (disparity
    ``u_left - u_right >= 0``): the right camera's centre has a positive x in the left frame.
    A baseline mostly along -x means the two sides were exchanged (as in the StereoPi set's
    upstream names, ``MAPPING.csv``); rigs with a mostly vertical baseline are not judged.
    """
    t = np.asarray(T_left_right, dtype=np.float64)[:3, 3]
    norm = float(np.linalg.norm(t))
    if norm == 0 or t[0] >= 0 or abs(float(t[0])) < 0.7 * norm:
        return ""
    return (f"left and right look swapped: the camera of the right images sits "
            f"{abs(float(t[0])) * 1e3:.1f} mm to the left of the left one (its centre at x = "
            f"{float(t[0]) * 1e3:.1f} mm in the left camera frame); exchange the left and right "
            f"images")


_REGION_NAMES = {(0, 0): "top-left", (0, 1): "top", (0, 2): "top-right",
                 (1, 0): "left", (1, 1): "centre", (1, 2): "right",
                 (2, 0): "bottom-left", (2, 1): "bottom", (2, 2): "bottom-right"}


def _empty_regions(counts: NDArray[np.int64]) -> list[str]:
    ny, nx = counts.shape
    names = []
    for (ry, rx), name in _REGION_NAMES.items():
        block = counts[ry * ny // 3:(ry + 1) * ny // 3, rx * nx // 3:(rx + 1) * nx // 3]
        if block.size and (block > 0).mean() < 0.5:
            names.append(name)
    return names


def assess(result: StereoCalibration) -> tuple[str, list[str]]:
    """Plain-words guidance for a calibration: what to capture next and how far to trust it.

    Returns:
        ``(verdict, sentences)``; verdict is ``"trusted"``, ``"usable with care"`` or
        ``"not trusted"``.
    """
    if not result.ok or result.left is None or result.right is None:
        return "not trusted", [f"Calibration failed: {result.message}"]
    notes: list[str] = []
    severity = 0  # 0 trusted, 1 care, 2 not trusted
    worst_cov = min(result.left.coverage, result.right.coverage)
    regions = sorted(set(_empty_regions(result.left.coverage_counts))
                     | set(_empty_regions(result.right.coverage_counts)))
    if worst_cov < 0.7 or regions:
        where = ", ".join(regions) if regions else "the image edges"
        notes.append(f"Detected corners cover {worst_cov:.0%} of the image; capture views with "
                     f"the board near the {where} of the image, where lens distortion is "
                     f"strongest.")
        severity = max(severity, 1 if worst_cov >= 0.4 else 2)
    tilts = np.array([v.tilt_deg for v in result.views])
    if tilts.size and float(np.max(tilts)) < 30.0:
        notes.append(f"The board was never tilted by more than {np.max(tilts):.0f} degrees; "
                     f"capture views with the board tilted 30-50 degrees to the left, right, "
                     f"up and down, which fixes the focal length.")
        severity = max(severity, 1)
    dists = np.array([v.distance_m for v in result.views])
    if dists.size and float(dists.max() / max(dists.min(), 1e-9)) < 1.5:
        notes.append(f"All views were taken at {dists.min():.2f}-{dists.max():.2f} m; capture "
                     f"some at longer range (the range you will work at) and some closer.")
        severity = max(severity, 1)
    if result.rms_px > 1.0:
        notes.append(f"The reprojection RMS of {result.rms_px:.2f} px is high (good "
                     f"calibrations reach 0.1-0.5 px); check focus, motion blur and that the "
                     f"board is flat.")
        severity = max(severity, 2 if result.rms_px > 2.0 else 1)
    if math.isfinite(result.holdout_px):
        ratio = result.holdout_px / max(result.rms_px, 1e-9)
        if ratio > 2.5 or result.holdout_px > 2.0:
            notes.append(f"The holdout error ({result.holdout_px:.2f} px) is {ratio:.1f} x the "
                         f"RMS: the model fits the views it saw much better than new ones, so "
                         f"it is over-fitted. Add views or use the simple distortion model.")
            severity = max(severity, 2)
        elif ratio > 1.6:
            notes.append(f"The holdout error ({result.holdout_px:.2f} px) is {ratio:.1f} x the "
                         f"RMS; more varied views would make the result steadier.")
            severity = max(severity, 1)
    return calibration_verdict(notes, severity, subject="calibration",
                               trusted_because="low error on held-out views and good coverage",
                               n_pairs=len(result.views), pairs_to_capture="15-25 pairs",
                               n_rejected=len(result.views_rejected))


def opencv_reference_stereo(left: Sequence[Detection], right: Sequence[Detection],
                            *, fix_intrinsic: bool = True,
                            distortion: str = "standard") -> dict[str, float]:
    """Plain OpenCV on the same detections, for comparison: ``calibrateCamera`` per camera,
    then ``stereoCalibrate`` (with ``CALIB_FIX_INTRINSIC`` unless ``fix_intrinsic`` is False).
    No view rejection.

    Returns:
        ``{"rms_px", "left_rms_px", "right_rms_px", "baseline_m", "views"}`` as OpenCV reports
        them (``rms_px`` is stereoCalibrate's own RMS).
    """
    cfg = StereoCalibConfig(distortion=distortion, min_views=3)
    pairs, _ = _pairs_from_detections(left, right, cfg)
    size = _check_sizes(left, "left")
    obj = [p.obj for p in pairs]
    flags = _DISTORTION_FLAGS[distortion]
    rms_l, K1, d1, _, _ = cv2.calibrateCamera(obj, [p.uv_l for p in pairs], size, None, None,  # type: ignore[call-overload]
                                              flags=flags)
    rms_r, K2, d2, _, _ = cv2.calibrateCamera(obj, [p.uv_r for p in pairs], size, None, None,  # type: ignore[call-overload]
                                              flags=flags)
    sflags = flags | (cv2.CALIB_FIX_INTRINSIC if fix_intrinsic else cv2.CALIB_USE_INTRINSIC_GUESS)
    rms, *_rest, T, _E, _F = cv2.stereoCalibrate(obj, [p.uv_l for p in pairs],
                                                  [p.uv_r for p in pairs], K1, d1, K2, d2, size,
                                                  flags=sflags)
    return {"rms_px": float(rms), "left_rms_px": float(rms_l), "right_rms_px": float(rms_r),
            "baseline_m": float(np.linalg.norm(T)), "views": float(len(pairs))}


