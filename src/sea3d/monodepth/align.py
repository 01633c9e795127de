"""Make a monocular network's relative output metric: robust scale and shift against sparse
metric depth (a depth map with holes, stereo depth of the same view, or SfM points).

Networks such as Depth-Anything and MiDaS predict inverse depth up to an unknown scale and
shift, so the fit is done in inverse depth (``1/z = s p + t``); a network that predicts
relative depth is fitted in depth (``z = s p + t``), a metric one by scale alone (``z = s p``).
The fit is RANSAC on pairs of samples (inliers: relative error below ``threshold_rel``), then
iteratively reweighted least squares with a Huber loss on the inliers, all in relative error
(a sample at 10 m counts as much as one at 1 m). Then :func:`fill_holes` keeps the sparse
(e.g. stereo) depth where it exists and takes the aligned network depth elsewhere: stereo-guided
dense depth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, F64
from sea3d.errors import MonoDepthError

__all__ = [
    "Alignment",
    "align_depth",
    "fill_holes",
    "read_alignment_depth",
    "sparse_depth_from_points",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class Alignment:
    """How a network's output was aligned to sparse metric depth.

    Attributes:
        status: ``ok`` or ``failed`` (too few sparse samples, no consistent fit); ``message``
            says why.
        message: one line for the user.
        kind: ``inverse``, ``depth`` or ``metric`` (what the output was taken to be).
        scale, shift: the fit (``1/z = scale p + shift`` for ``inverse``, ``z = scale p + shift``
            for ``depth``, ``z = scale p`` for ``metric``).
        samples: valid sparse samples.
        inliers: samples within ``threshold_rel`` of the fit.
        median_rel_error: median ``|z_aligned - z_sparse| / z_sparse`` over all samples.
    """

    status: str
    message: str
    kind: str
    scale: float
    shift: float
    samples: int
    inliers: int
    median_rel_error: float


def _apply(pred: F64, kind: str, s: float, t: float, min_depth_m: float) -> F64:
    with np.errstate(divide="ignore", invalid="ignore"):
        if kind == "inverse":
            inv = s * pred + t
            z = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.nan)
        else:
            z = s * pred + t
    z = np.where(np.isfinite(z) & (z >= min_depth_m), z, np.nan)
    return np.asarray(z, dtype=np.float64)


def _weighted_fit(x: F64, y: F64, w: F64, with_shift: bool) -> tuple[float, float]:
    if with_shift:
        A = np.column_stack([x, np.ones_like(x)]) * w[:, None]
        sol, *_ = np.linalg.lstsq(A, y * w, rcond=None)
        return float(sol[0]), float(sol[1])
    den = float(np.sum((w * x) ** 2))
    return (float(np.sum(w * w * x * y) / den) if den > 0 else float("nan")), 0.0


def align_depth(
    prediction: np.ndarray,
    sparse_depth_m: np.ndarray,
    *,
    kind: str = "inverse",
    threshold_rel: float = 0.05,
    iterations: int = 300,
    max_samples: int = 50_000,
    min_samples: int = 10,
    min_depth_m: float = 1e-3,
    seed: int = 0,
    ransac_subset: int = 4000,
) -> tuple[F32, Alignment]:
    """Align a network's output to sparse metric depth.

    Args:
        prediction: ``(H, W)`` the network's raw output.
        sparse_depth_m: ``(H, W)`` metric depth, metres, NaN (or <= 0) where unknown.
        kind: ``inverse``, ``depth`` or ``metric`` (see the module docstring).
        threshold_rel: RANSAC inlier threshold, relative depth error.
        iterations: RANSAC iterations.
        max_samples: at most this many sparse samples are used (a seeded random subset).
        min_samples: fewer valid samples than this: ``status="failed"``.
        min_depth_m: aligned depths below this are invalid.
        seed: RANSAC's random generator seed.
        ransac_subset: samples each RANSAC hypothesis is scored on.

    Returns:
        ``(depth_m, alignment)``: ``(H, W)`` float32 metres (NaN invalid; all NaN when the fit
        failed) and the :class:`Alignment`.

    Raises:
        MonoDepthError: shapes differ or ``kind`` is unknown.
    """
    pred = np.asarray(prediction, dtype=np.float64)
    sparse = np.asarray(sparse_depth_m, dtype=np.float64)
    if pred.shape != sparse.shape or pred.ndim != 2:
        raise MonoDepthError(f"prediction {pred.shape} and sparse depth {sparse.shape} must be "
                             "the same (H, W)")
    if kind not in ("inverse", "depth", "metric"):
        raise MonoDepthError(f"kind must be inverse, depth or metric, got {kind!r}")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(sparse) & (sparse > 0) & np.isfinite(pred)
    idx = np.flatnonzero(ok)
    rng = np.random.default_rng(seed)
    if len(idx) > max_samples:
        idx = rng.choice(idx, max_samples, replace=False)
    n = len(idx)
    nan_map = np.full(pred.shape, np.nan, np.float32)
    finite_pred = int(np.count_nonzero(np.isfinite(pred)))
    if n < min_samples and finite_pred == 0:
        return nan_map, Alignment(status="failed", message=f"the network produced no finite "
                                  f"depth: all {pred.size} values of its output are NaN or "
                                  "infinite (a broken model or input?)", kind=kind,
                                  scale=float("nan"), shift=float("nan"), samples=0, inliers=0,
                                  median_rel_error=float("nan"))
    if n < min_samples:
        return nan_map, Alignment(status="failed", message=f"only {n} sparse depth samples "
                                  f"(at least {min_samples} are needed)", kind=kind,
                                  scale=float("nan"), shift=float("nan"), samples=n, inliers=0,
                                  median_rel_error=float("nan"))
    x = pred.ravel()[idx]
    z = sparse.ravel()[idx]
    with_shift = kind != "metric"
    y = 1.0 / z if kind == "inverse" else z  # fitted quantity; its relative error ~ depth's

    def rel_err(s: float, t: float) -> F64:
        return np.asarray(np.abs(s * x + t - y) / np.abs(y), dtype=np.float64)

    # RANSAC hypotheses are scored on a random subset (enough to rank them), the refinement
    # uses every sample.
    score = rng.choice(n, min(n, ransac_subset), replace=False)
    xs, ys = x[score], y[score]
    best_in = -1
    best = (float("nan"), 0.0)
    need = 2 if with_shift else 1
    for _ in range(iterations):
        pick = rng.choice(n, need, replace=False)
        if with_shift:
            x1, x2 = x[pick]
            y1, y2 = y[pick]
            if abs(x2 - x1) < 1e-12 * (abs(x1) + abs(x2) + 1e-30):
                continue
            s = (y2 - y1) / (x2 - x1)
            t = y1 - s * x1
        else:
            if x[pick[0]] == 0:
                continue
            s, t = y[pick[0]] / x[pick[0]], 0.0
        if not s > 0:  # the output must grow with the fitted quantity
            continue
        cnt = int(np.count_nonzero(np.abs(s * xs + t - ys) < threshold_rel * np.abs(ys)))
        if cnt > best_in:
            best_in, best = cnt, (float(s), float(t))
    if best_in < need:
        return nan_map, Alignment(status="failed", message="no consistent positive scale "
                                  "between the network and the sparse depth (is "
                                  "output_kind right?)", kind=kind,
                                  scale=float("nan"), shift=float("nan"), samples=n, inliers=0,
                                  median_rel_error=float("nan"))
    s, t = best
    inl = rel_err(s, t) < threshold_rel
    for _ in range(5):
        r = rel_err(s, t)
        w = np.where(inl, np.sqrt(np.minimum(1.0, threshold_rel / np.maximum(r, 1e-15))), 0.0)
        s, t = _weighted_fit(x, y, w / np.abs(y), with_shift)
        inl = rel_err(s, t) < 2 * threshold_rel
    depth = _apply(pred, kind, s, t, min_depth_m)
    zf = depth.ravel()[idx]
    with np.errstate(invalid="ignore"):
        med = float(np.nanmedian(np.abs(zf - z) / z)) if np.isfinite(zf).any() else float("nan")
    n_in = int(np.count_nonzero(rel_err(s, t) < threshold_rel))
    status = "ok"
    msg = (f"aligned ({kind}): scale {s:.6g}, shift {t:.6g}, {n_in}/{n} samples within "
           f"{100 * threshold_rel:.0f} %, median relative error {100 * med:.2f} %")
    if not s > 0:
        status, msg = "failed", (f"the fitted scale {s:.4g} is not positive: the output does not "
                                 f"grow with {'inverse ' if kind == 'inverse' else ''}depth "
                                 "(is output_kind right?)")
    log.info(msg)
    out = depth.astype(np.float32) if status == "ok" else nan_map
    return out, Alignment(status=status, message=msg, kind=kind, scale=float(s), shift=float(t),
                          samples=n, inliers=n_in, median_rel_error=med)


def fill_holes(sparse_depth_m: np.ndarray, dense_depth_m: np.ndarray) -> tuple[F32, NDArray[
        np.bool_]]:
    """Sparse (e.g. stereo) depth where it is valid, the dense (aligned network) depth
    elsewhere.

    Returns:
        ``(depth_m (H, W) float32, filled (H, W) bool)``: ``filled`` marks pixels taken from the
        dense map.

    Raises:
        MonoDepthError: shapes differ.
    """
    a = np.asarray(sparse_depth_m, dtype=np.float32)
    b = np.asarray(dense_depth_m, dtype=np.float32)
    if a.shape != b.shape:
        raise MonoDepthError(f"sparse {a.shape} and dense {b.shape} depth differ in shape")
    with np.errstate(invalid="ignore"):
        have = np.isfinite(a) & (a > 0)
    filled = ~have & np.isfinite(b)
    return np.where(have, a, b).astype(np.float32), filled


def sparse_depth_from_points(points_cam: F64, K: F64, width: int, height: int) -> F32:
    """Sparse depth of 3D points in a pinhole camera (nearest point per pixel).

    Args:
        points_cam: ``(N, 3)`` points in the camera frame, metres.
        K: ``(3, 3)`` intrinsics (our pixel convention: integer values at pixel centres).
        width, height: image size.

    Returns:
        ``(H, W)`` float32 depth (z), NaN where no point projects.
    """
    p0 = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    p = p0[np.isfinite(p0).all(axis=1) & (p0[:, 2] > 0)]
    u = np.round(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]).astype(np.int64)
    ok = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    out = np.full(height * width, np.inf)
    np.minimum.at(out, v[ok] * width + u[ok], p[ok, 2])
    out[~np.isfinite(out)] = np.nan
    return out.reshape(height, width).astype(np.float32)


def read_alignment_depth(path: str | Path, width: int, height: int, *, rig: Any = None) -> F32:
    """Read metric depth to align a network's output of the raw image (``width x height``)
    to, on that image's own pixel grid.

    The file's grid sidecar (:func:`sea3d.io.depth_files.read_depth_grid`) decides: raw-left
    depth (or a file that says nothing) must be the image's size; rectified-left depth is
    resampled onto the raw left grid with ``rig`` (the rig it came from) and refused without
    one.

    Returns:
        ``(height, width)`` float32 depth along the raw left optical axis, metres, NaN holes.

    Raises:
        MonoDepthError: one line naming the file: another size, rectified depth without its
            rig, or depth from another rig.
        StereoError: an unreadable depth file or sidecar.
    """
    from sea3d.io.depth_files import read_depth, read_depth_grid, rig_identity

    depth = read_depth(path)
    grid = read_depth_grid(path)
    have = f"{depth.shape[1]}x{depth.shape[0]}"
    if grid is not None and (grid.width_px, grid.height_px) != depth.shape[::-1]:
        raise MonoDepthError(f"depth {path} is {have} but its sidecar says "
                             f"{grid.width_px}x{grid.height_px}")
    if grid is None or grid.kind == "raw-left":
        if depth.shape != (height, width):
            where = f"the {grid.describe()} grid" if grid is not None else have
            raise MonoDepthError(f"depth {path} lives on {where} but the image is "
                                 f"{width}x{height}")
        return depth
    if rig is None:
        raise MonoDepthError(
            f"depth {path} lives on the {grid.describe()} grid, not on the image's own "
            "pixels: give the rig to resample it; write raw-view depth (the raw grid) with "
            "sea3d depth"
        )
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.rectify.depth_grid import rectified_depth_to_raw
    from sea3d.stereo.recipe import StereoDepth

    if grid.rig_id and grid.rig_id != rig_identity(rig_to_yaml(rig)):
        raise MonoDepthError(f"depth {path} came from another rig (rig {grid.rig_id[:8]})")
    if (rig.width, rig.height) != (width, height):
        raise MonoDepthError(f"the rig is {rig.width}x{rig.height} but the image is "
                             f"{width}x{height}")
    maps = StereoDepth(rig).maps  # the rectification sea3d depth uses with this rig
    K = np.asarray(grid.K, dtype=np.float64)
    if not np.allclose(K, maps.P_left[:3, :3], rtol=1e-3, atol=1e-3 * max(width, height)):
        raise MonoDepthError(f"depth {path} lives on a rectified grid (fx {K[0, 0]:.1f}) that "
                             f"this rig's rectification (fx {maps.P_left[0, 0]:.1f}) does not "
                             "give; write raw-view depth (the raw grid) with sea3d depth")
    return rectified_depth_to_raw(depth, K, maps.R_rect_left_left, rig.left, quantity="depth")
