"""The pieces of the revised underwater image formation model (Akkaynak and Treibitz, CVPR
2018) that every Sea-thru fit and inversion uses: the range map's checks, its holes filled, the
dark-pixel envelope of the backscatter, and the white-point exposure.

Range is metres along each pixel's line of sight, ``(H, W)`` float32 in the image's own pixel
grid, NaN (or <= 0) where unknown.
"""

from __future__ import annotations

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from sea3d._typing import F32, F64, BoolArray
from sea3d.enhance.colour import channel_gains
from sea3d.enhance.config import SeathruConfig
from sea3d.errors import EnhanceError

__all__ = [
    "area_down",
    "backscatter_envelope",
    "balance",
    "fill_range",
    "harmonic_fill",
    "require_range_grid",
    "white_point_exposure",
    "work_size",
]

BETA_B_LIMITS_PER_M = (0.01, 5.0)
"""The span of ``beta_B`` the envelope searches (the Sea-thru paper bounds it to [0, 5] 1/m)."""


def _wxh(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else str(shape)


def require_range_grid(z: np.ndarray, image_shape: tuple[int, ...], what: str) -> None:
    """Raise unless the range map ``z`` is ``(H, W)`` in the pixel grid of an image of shape
    ``image_shape``.

    Raises:
        EnhanceError: a range map that is not 2-D, or of another size than the image (named
            ``what`` in the message).
    """
    if z.ndim != 2:
        raise EnhanceError(f"range map must be (H, W), got shape {z.shape}")
    if z.shape != tuple(image_shape[:2]):
        raise EnhanceError(
            f"range map is {_wxh(z.shape)} but {what} is {_wxh(image_shape)}; it must be in "
            "the image's pixel grid"
        )


def backscatter_envelope(
    zk: F64, qk: F64, *, b_inf_max: float, steps: int
) -> tuple[float, float]:
    """The highest saturating curve ``B_inf (1 - exp(-beta_B z))`` that stays at or below the
    dark level ``qk`` of every range bin (backscatter cannot exceed the darkest pixels at its
    range; Sea-thru, CVPR 2019, Sec. 4.2): for each ``beta_B`` of a log grid of ``steps``
    values over :data:`BETA_B_LIMITS_PER_M` the highest feasible ``B_inf`` is
    ``min_k qk / (1 - exp(-beta_B zk))`` (held in ``[0, b_inf_max]``); the ``beta_B`` whose
    curve lies highest over the bins (largest sum) wins.

    Args:
        zk: ``(K,)`` range of each bin, metres.
        qk: ``(K,)`` dark level of each bin, one channel, linear.
        b_inf_max: the largest ``B_inf``.
        steps: grid points of ``beta_B``.

    Returns:
        ``(B_inf, beta_B_per_m)``.
    """
    best = (-1.0, 0.0, BETA_B_LIMITS_PER_M[0])
    for beta_b in np.geomspace(BETA_B_LIMITS_PER_M[0], BETA_B_LIMITS_PER_M[1], steps):
        f = 1.0 - np.exp(-beta_b * zk)
        b_inf = float(np.clip(np.min(qk / np.maximum(f, 1e-9)), 0.0, b_inf_max))
        obj = float(np.sum(b_inf * f))
        if obj > best[0]:
            best = (obj, b_inf, float(beta_b))
    return best[1], best[2]


def balance(
    j: np.ndarray, config: SeathruConfig, beta_d_per_m: F64 | None = None
) -> tuple[F64, float]:
    """The white balance and exposure of the restored samples ``j`` (``(N, 3)`` linear, every
    fitted frame's pixels with range pooled, so a pair or a dive keeps one colour), as
    ``config.white_balance`` and ``config.exposure`` say. ``beta_d_per_m``: the identified
    wideband attenuation (``locus`` needs it; ``auto`` keeps ``J`` with it, balances by grey
    world without).

    Returns:
        ``((3,) gains, exposure)``.
    """
    wb = config.white_balance
    if wb == "auto":
        wb = "none" if beta_d_per_m is not None else "grey-world"
    if wb == "locus" and beta_d_per_m is None:
        wb = "grey-world"
    if wb == "grey-world":
        gains = channel_gains([j], p=1.0, max_gain=config.max_restore_gain)
    elif wb == "locus" and beta_d_per_m is not None:
        gains = _locus_gains(j, beta_d_per_m, config.max_restore_gain)
    else:
        gains = np.ones(3)
    exposure = 1.0
    if config.exposure == "white-point":
        exposure = white_point_exposure(j, gains, config.white_point_percentile)
    return gains, exposure


def _locus_gains(j: np.ndarray, beta_d: F64, max_gain: float) -> F64:
    """Gains ``exp(beta_D d)`` for the water column ``d >= 0`` (metres) above the scene that
    makes the restored samples closest to grey (least variance of the log channel means): the
    ambient light reaching the scene has crossed ``d`` metres of the same water, so its colour
    lies on that one-parameter locus (1 at ``d = 0``: white light)."""
    mean = np.mean(np.asarray(j, dtype=np.float64), axis=0)  # the gains are per channel
    if not np.all(mean > 1e-6):
        return np.ones(3)
    d_grid = np.linspace(0.0, 30.0, 301)[:, None]
    g_all = np.minimum(np.exp(beta_d[None, :] * d_grid), max_gain)
    spread = np.var(np.log(g_all * mean[None, :]), axis=1)
    best_d = float(d_grid[int(np.argmin(spread)), 0])
    g = np.minimum(np.exp(beta_d * best_d), max_gain)
    return np.asarray(g / np.exp(np.mean(np.log(g))))


def white_point_exposure(j: np.ndarray, gains: np.ndarray, percentile: float) -> float:
    """The scale that maps the ``percentile`` of the brightest channel of the balanced samples
    ``j * gains`` (``(N, 3)`` linear) to 1, held in ``[1/50, 50]``; 1 for no (or black)
    samples."""
    top = np.max(j * gains, axis=1)
    wp = float(np.percentile(top, percentile)) if top.size else 0.0
    return float(np.clip(1.0 / wp, 1.0 / 50.0, 50.0)) if wp > 1e-6 else 1.0


# ------------------------------------------------------------------------------ holes


def work_size(h: int, w: int, max_side: int) -> tuple[int, int]:
    """``(width, height)`` of an ``h x w`` image scaled so its longer side is at most
    ``max_side`` (never enlarged, at least 2)."""
    s = min(1.0, max_side / max(h, w))
    return max(2, round(w * s)), max(2, round(h * s))


def area_down(
    values: np.ndarray, valid: BoolArray, size: tuple[int, int], min_cover: float
) -> tuple[F32, BoolArray]:
    """Area-average ``values`` (``(H, W)`` or ``(H, W, 3)``) over its ``valid`` pixels to
    ``size`` (width, height); a working pixel is valid when at least ``min_cover`` of its area
    is. Values outside the valid working pixels are not meaningful."""
    wv = valid.astype(np.float32)
    vals = np.where(valid[..., None] if values.ndim == 3 else valid, values, 0).astype(np.float32)
    num = cv2.resize(vals, size, interpolation=cv2.INTER_AREA)
    den = cv2.resize(wv, size, interpolation=cv2.INTER_AREA)
    ok = den >= min_cover
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / (den[..., None] if num.ndim == 3 else den)
    return out.astype(np.float32), ok


def harmonic_fill(values: np.ndarray, valid: BoolArray) -> F32:
    """Fill the invalid pixels of a 2-D map by harmonic (membrane) interpolation of the valid
    ones: each filled pixel is the mean of its in-image 4-neighbours, solved as one sparse
    system. Linear ramps are filled exactly.

    Raises:
        EnhanceError: no valid pixel at all.
    """
    v = np.asarray(values, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool)
    if not ok.any():
        raise EnhanceError("nothing to fill from: no valid pixel")
    out = np.where(ok, v, 0.0)
    holes = ~ok
    n = int(holes.sum())
    if n == 0:
        return out.astype(np.float32)
    h, w = v.shape
    idx = np.full((h, w), -1, dtype=np.int64)
    idx[holes] = np.arange(n)
    hy, hx = np.nonzero(holes)
    deg = np.zeros(n)
    rhs = np.zeros(n)
    rows, cols = [], []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ny, nx = hy + dy, hx + dx
        inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        i = np.flatnonzero(inside)
        deg[i] += 1.0
        j = idx[ny[inside], nx[inside]]
        unknown = j >= 0
        rows.append(i[unknown])
        cols.append(j[unknown])
        known = i[~unknown]
        np.add.at(rhs, known, out[ny[inside][~unknown], nx[inside][~unknown]])
    r = np.concatenate([np.arange(n), *rows])
    c = np.concatenate([np.arange(n), *cols])
    d = np.concatenate([deg + 1e-9, -np.ones(sum(len(x) for x in rows))])
    # The tiny diagonal term keeps a hole with no valid neighbour anywhere (impossible when
    # each hole component touches a valid pixel) from making the system singular.
    a_mat = sp.csr_matrix((d, (r, c)), shape=(n, n)).tocsc()
    out[holes] = splu(a_mat).solve(rhs + 1e-9 * float(v[ok].mean()))
    return out.astype(np.float32)


def fill_range(z: F32, valid: BoolArray, max_side_px: int, min_cover: float) -> F32:
    """The range map with its holes filled by :func:`harmonic_fill` at a working resolution
    (longer side ``max_side_px``; a working pixel holds range when ``min_cover`` of its area
    does), brought back to full size; pixels with range keep theirs.

    Raises:
        EnhanceError: no working pixel holds range.
    """
    if valid.all():
        return z
    h, w = valid.shape
    small, ok = area_down(z, valid, work_size(h, w, max_side_px), min_cover)
    filled = harmonic_fill(np.where(ok, small, np.float32(0)), ok)
    up = cv2.resize(filled, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.where(valid, z, up).astype(np.float32)
