"""Reference disparity of a planar calibration board seen by a rectified stereo pair.

A chessboard's inner corners are found independently in both views (saddle points, refined to
subpixel), so their disparities are a measurement that owes nothing to dense matching. In a
rectified pinhole pair a plane's disparity is an affine function of the pixel,
``d(u, v) = a u + b v + c`` (``1 / Z`` is affine on the image of a plane and ``d = f B / Z``), so
a least-squares plane through the corners' disparities gives a reference disparity for every
pixel the board covers. Its residual says how flat the board and how good the corners are;
the corners' row differences say how good the rectification is. Relative depth errors need no
scale: ``|Z - Z_ref| / Z_ref = |d_ref / d - 1|``, so boards of unknown square size serve.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import StereoError

__all__ = [
    "BoardDisparity",
    "BoardStereoSet",
    "board_reference_disparity",
    "find_board_corners",
    "rectified_board_set",
    "relative_depth_errors",
]


@dataclass(frozen=True, kw_only=True, eq=False)
class BoardDisparity:
    """The board's reference disparity in the rectified left view.

    Attributes:
        disparity_px: (H, W) float32, the plane's disparity inside the hull of the inner
            corners, NaN elsewhere.
        plane: ``(a, b, c)`` of ``d = a u + b v + c``.
        fit_rms_px: RMS of the corners' disparities about the plane, px.
        row_rms_px: RMS of the corners' row differences ``v_left - v_right``, px.
        n_corners: corners used.
    """

    disparity_px: NDArray[np.float32]
    plane: tuple[float, float, float]
    fit_rms_px: float
    row_rms_px: float
    n_corners: int

    @property
    def mask(self) -> NDArray[np.bool_]:
        """(H, W) bool: the pixels with a reference disparity."""
        return np.isfinite(self.disparity_px)


def find_board_corners(image: np.ndarray, pattern: tuple[int, int]) -> NDArray[np.float64] | None:
    """Inner corners of a chessboard (``pattern`` = inner corners per row and column), refined
    to subpixel with ``cv2.cornerSubPix``; ``(N, 2)`` float64 pixels, or None if not found."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if grey.dtype != np.uint8:
        grey = np.clip(grey, 0, 255).astype(np.uint8)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    ok, corners = cv2.findChessboardCorners(grey, pattern, flags=flags)
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    refined = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1), crit)
    return np.asarray(refined, dtype=np.float64).reshape(-1, 2)


def board_reference_disparity(
    corners_left: np.ndarray, corners_right: np.ndarray, shape: tuple[int, int]
) -> BoardDisparity:
    """Fit the board plane to corner disparities in a rectified pair.

    Args:
        corners_left, corners_right: (N, 2) the same corners in the rectified left and right
            views, in the same order (the right list is reversed here if that order fits the
            rows better, as OpenCV may number a board from either end).
        shape: ``(H, W)`` of the rectified images.

    Raises:
        StereoError: fewer than 4 corners, or lists of different lengths.
    """
    cl = np.asarray(corners_left, dtype=np.float64).reshape(-1, 2)
    cr: NDArray[np.float64] = np.asarray(corners_right, dtype=np.float64).reshape(-1, 2)
    if len(cl) != len(cr) or len(cl) < 4:
        raise StereoError(f"need the same >= 4 corners in both views, got {len(cl)} and {len(cr)}")
    if np.abs(cl[:, 1] - cr[::-1, 1]).mean() < np.abs(cl[:, 1] - cr[:, 1]).mean():
        cr = np.ascontiguousarray(cr[::-1])
    d = cl[:, 0] - cr[:, 0]
    a_mat = np.column_stack([cl[:, 0], cl[:, 1], np.ones(len(cl))])
    coef, *_ = np.linalg.lstsq(a_mat, d, rcond=None)
    fit_rms = float(np.sqrt(np.mean((a_mat @ coef - d) ** 2)))
    row_rms = float(np.sqrt(np.mean((cl[:, 1] - cr[:, 1]) ** 2)))
    h, w = shape
    hull = cv2.convexHull(np.round(cl).astype(np.int32))
    inside = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ref = coef[0] * uu + coef[1] * vv + coef[2]
    disp = np.where(inside.astype(bool), ref, np.nan).astype(np.float32)
    return BoardDisparity(disparity_px=disp, plane=(float(coef[0]), float(coef[1]), float(coef[2])),
                          fit_rms_px=fit_rms, row_rms_px=row_rms, n_corners=len(cl))


def relative_depth_errors(
    disparity_px: np.ndarray, reference: BoardDisparity
) -> NDArray[np.float64]:
    """``|Z - Z_ref| / Z_ref = |d_ref / d - 1|`` on the board's pixels, in board-pixel order;
    inf where the estimate is missing or not positive."""
    d = np.asarray(disparity_px, dtype=np.float64)[reference.mask]
    r = reference.disparity_px[reference.mask].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(r / d - 1.0)
    err[~(np.isfinite(d) & (d > 0))] = np.inf
    return err


@dataclass(frozen=True, kw_only=True, eq=False)
class BoardStereoSet:
    """Rectified pairs of a chessboard stereo set with the board's reference disparity.

    Built with plain OpenCV (calibrateCamera per camera with ``CALIB_FIX_K3``, stereoCalibrate
    with the intrinsics fixed, stereoRectify with ``CALIB_ZERO_DISPARITY``), so the reference
    owes nothing to sea3d's calibration or matching.

    Attributes:
        names: pair names.
        left, right: rectified images, one per pair.
        references: :class:`BoardDisparity` per pair.
        rms_px: ``(left, right, stereo)`` calibration RMS reprojection errors, px.
        baseline: ``|T|`` in board squares.
    """

    names: list[str]
    left: list[np.ndarray]
    right: list[np.ndarray]
    references: list[BoardDisparity]
    rms_px: tuple[float, float, float]
    baseline: float


def rectified_board_set(
    pairs: list[tuple[str, np.ndarray, np.ndarray]], pattern: tuple[int, int]
) -> BoardStereoSet:
    """Calibrate a stereo rig from its own board views and rectify the pairs that show the
    board in both views.

    Args:
        pairs: ``(name, left, right)`` raw images (RGB or grey, uint8).
        pattern: inner corners of the board per row and column.

    Raises:
        StereoError: fewer than 3 pairs with the board in both views.
    """
    obj = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : pattern[0], 0 : pattern[1]].T.reshape(-1, 2)
    found = []
    per_cam: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
    for name, left, right in pairs:
        cl, cr = find_board_corners(left, pattern), find_board_corners(right, pattern)
        for lst, c in zip(per_cam, (cl, cr), strict=True):
            if c is not None:
                lst.append(c.astype(np.float32))
        if cl is not None and cr is not None:
            found.append((name, left, right, cl, cr))
    if len(found) < 3:
        raise StereoError(f"the board is in both views of only {len(found)} pairs; need 3")
    h, w = pairs[0][1].shape[:2]
    flags = cv2.CALIB_FIX_K3
    intr = []
    rms = []
    for corners in per_cam:
        err, k, dist, _, _ = cv2.calibrateCamera(  # type: ignore[call-overload]
            [obj] * len(corners), corners, (w, h), None, None, flags=flags
        )
        intr.append((k, dist))
        rms.append(float(err))
    (k1, d1), (k2, d2) = intr
    err, _, _, _, _, rot, t, _, _ = cv2.stereoCalibrate(
        [obj] * len(found), [f[3].astype(np.float32) for f in found],
        [f[4].astype(np.float32) for f in found], k1, d1, k2, d2, (w, h),
        flags=cv2.CALIB_FIX_INTRINSIC,
    )
    rms.append(float(err))
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(k1, d1, k2, d2, (w, h), rot, t,
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    maps = [cv2.initUndistortRectifyMap(k, dist, r, p, (w, h), cv2.CV_32FC1)
            for k, dist, r, p in ((k1, d1, r1, p1), (k2, d2, r2, p2))]
    names, lefts, rights, refs = [], [], [], []
    for name, left, right, cl, cr in found:
        rl = cv2.remap(left, maps[0][0], maps[0][1], cv2.INTER_LINEAR)
        rr = cv2.remap(right, maps[1][0], maps[1][1], cv2.INTER_LINEAR)
        ul = cv2.undistortPoints(cl.reshape(-1, 1, 2), k1, d1, R=r1, P=p1).reshape(-1, 2)
        ur = cv2.undistortPoints(cr.reshape(-1, 1, 2), k2, d2, R=r2, P=p2).reshape(-1, 2)
        names.append(name)
        lefts.append(rl)
        rights.append(rr)
        refs.append(board_reference_disparity(ul, ur, (h, w)))
    return BoardStereoSet(names=names, left=lefts, right=rights, references=refs,
                          rms_px=(rms[0], rms[1], rms[2]), baseline=float(np.linalg.norm(t)))
