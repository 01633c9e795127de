"""Disparity accuracy against ground truth (Middlebury-style).

Conventions: both maps are ``(H, W)`` float32 pixels of the left view; NaN (or, in the ground
truth, 0) means unknown. Errors are ``|d_est - d_gt|`` over pixels where both are known;
``density`` tells what share of the known ground truth the estimate covers, so an engine that
throws away its hard pixels cannot hide behind a low error: compare errors at equal density, or
use the ``*_all`` figures, which count a missing estimate as a bad pixel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sea3d.errors import StereoError

__all__ = ["DisparityMetrics", "disparity_metrics"]

BAD_THRESHOLDS_PX = (0.5, 1.0, 2.0, 4.0)


@dataclass(frozen=True, kw_only=True)
class DisparityMetrics:
    """Disparity error figures; percentages in [0, 100], pixels in px.

    ``bad_X``: share of pixels (known in both maps) with error above X px.
    ``bad_X_all``: the same over all known ground-truth pixels, missing estimates counted bad.
    """

    bad_0_5: float
    bad_1: float
    bad_2: float
    bad_4: float
    bad_0_5_all: float
    bad_1_all: float
    bad_2_all: float
    bad_4_all: float
    epe_px: float
    """Mean absolute error (end-point error) over pixels known in both maps."""
    rmse_px: float
    density: float
    """Share of known ground-truth pixels with a valid estimate, percent."""
    n_gt: int
    """Number of known ground-truth pixels."""

    def as_dict(self) -> dict[str, float | int]:
        """Plain dict, e.g. for JSON output."""
        return asdict(self)


def disparity_metrics(
    estimate: np.ndarray,
    ground_truth: np.ndarray,
    mask: np.ndarray | None = None,
) -> DisparityMetrics:
    """Compare an estimated disparity map with ground truth.

    Args:
        estimate: (H, W) float px, NaN invalid.
        ground_truth: (H, W) float px, NaN or 0 unknown.
        mask: optional (H, W) bool; only True pixels are evaluated (e.g. non-occluded).

    Returns:
        :class:`DisparityMetrics` (NaN errors when no pixel is known in both).

    Raises:
        StereoError: shapes differ or the ground truth has no known pixel.
    """
    est = np.asarray(estimate, dtype=np.float64)
    gt = np.asarray(ground_truth, dtype=np.float64)
    if est.shape != gt.shape or est.ndim != 2:
        raise StereoError(
            f"estimate {est.shape} and ground truth {gt.shape} must be equal (H, W) shapes"
        )
    known = np.isfinite(gt) & (gt > 0)
    if mask is not None:
        if mask.shape != gt.shape:
            raise StereoError(f"mask shape {mask.shape} differs from ground truth {gt.shape}")
        known &= mask.astype(bool)
    n_gt = int(known.sum())
    if n_gt == 0:
        raise StereoError("ground truth has no known pixel (all 0 or NaN)")
    both = known & np.isfinite(est)
    err = np.abs(est[both] - gt[both])
    n_both = int(both.sum())
    vals: dict[str, float] = {}
    for t in BAD_THRESHOLDS_PX:
        key = "bad_" + (str(t).replace(".", "_") if t != int(t) else str(int(t)))
        nbad = int((err > t).sum())
        vals[key] = 100.0 * nbad / n_both if n_both else float("nan")
        vals[key + "_all"] = 100.0 * (nbad + n_gt - n_both) / n_gt
    return DisparityMetrics(
        **vals,
        epe_px=float(err.mean()) if n_both else float("nan"),
        rmse_px=float(np.sqrt((err**2).mean())) if n_both else float("nan"),
        density=100.0 * n_both / n_gt,
        n_gt=n_gt,
    )
