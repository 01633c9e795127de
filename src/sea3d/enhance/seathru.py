"""Sea-thru colour restoration with a metric range map (Akkaynak and Treibitz, CVPR 2019).

The revised underwater image formation model (Akkaynak and Treibitz, CVPR 2018), per channel c
and pixel x at range z (metres along the line of sight), in **linear** RGB::

    I_c = D_c + B_c,   D_c = J_c exp(-beta_D_c(z) z),   B_c = B_inf_c (1 - exp(-beta_B_c z))

Sea-thru inverts it in three stages, each of which can be switched off (:class:`SeathruConfig`):

1. **Backscatter** (Sea-thru Sec. 4.2, Eq. 10). The range is cut into ``range_bins`` (10) equal
   bins between its 0.5th and 99.5th percentiles; in each bin the pixels whose RGB sum is in the
   lowest ``dark_percentile`` (1 %) are taken as almost pure backscatter, and per channel::

       B_c(z) = B_inf_c (1 - exp(-beta_B_c z)) + J'_c exp(-beta_D'_c z)

   is fitted to them by bounded non-linear least squares (``backscatter_fit="eq10"``;
   ``B_inf, J'`` in [0, 1], ``beta_B, beta_D'`` in [0, 5] 1/m, as in the paper). The second
   term absorbs the dark pixels' own (non-zero) signal; the backscatter removed is the first,
   ``D = max(I - B_inf (1 - exp(-beta_B z)), 0)``. Where the darkest pixels are not black
   (sand, no shadows) that fit lets their signal into ``B_inf``; the default
   ``backscatter_fit="envelope"`` takes instead the highest ``B_inf (1 - exp(-beta_B z))``
   that stays at or below the dark level of every bin (backscatter cannot exceed the darkest
   pixel at its range).
2. **Attenuation** (Sec. 4.3). The illuminant is the local space average colour of ``D``
   (Ebner's LSAC): the fixed point of ``a(x) = p D(x) + (1 - p) mean_{N(x)} a`` over the
   4-neighbours ``N(x)`` whose range differs from ``z(x)`` by at most
   ``lsac_range_tolerance * z(x)`` (so averages do not cross range edges), solved exactly as one
   sparse linear system at a working resolution of ``work_max_side_px``; ``E = f a`` with
   ``f = 2`` (Eq. 12-13). The default ``attenuation="illuminant"`` restores ``J = D / E``
   directly (the illuminant map, filled harmonically where there is no range). With
   ``attenuation="fit"`` ``beta_D(z) = a exp(b z) + c exp(d z)`` (Eq. 11) is fitted by
   minimising ``|| z - (-log E) / beta_D(z) ||`` (Eq. 14) with ``a, c >= 0``, ``b, d <= 0``.
   Where the scene spans little range this two-term fit is weakly identified: unless it lowers
   the residual by 5 % it is replaced by a constant ``beta_D``. ``J = D exp(beta_D(z) z)``
   (Eq. 8), the gain capped at ``max_restore_gain``.
3. **White balance** of ``J`` by grey world (as the paper does), then an exposure that puts the
   ``white_point_percentile`` (99.5th) of the brightest channel at 1.
4. **Denoising** (ours; ``denoise``): the restoration multiplies the noise of far, attenuated
   pixels by its gain; the result is blended towards a copy with smoothed chroma (2 px) and
   luminance (0.8 px) in proportion to the log of the gain applied to the input's noise (fully
   at 8x).

The range map must be in the image's pixel grid: float32 metres, NaN (or <= 0) where unknown.
Unknown range is **never treated as far**: the fits use only pixels with range; for the
restoration, holes are filled from the surrounding range (``holes="inpaint"``, a harmonic
membrane fill at the working resolution, exact for linear ramps) or left out
(``holes="mask"``: those pixels get only the white balance and exposure). A stereo depth map
(z along the optical axis) becomes range with :func:`depth_to_range`.

Fitting and applying are separate (:func:`fit_seathru`, :func:`apply_seathru`), so a model
fitted on the left image restores the right one with its own range, and a stereo pair keeps one
colour. :func:`seathru` does both.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.optimize import OptimizeResult, least_squares
from scipy.sparse.linalg import splu

from sea3d._typing import F32, F64, BoolArray
from sea3d.enhance._formation import (
    area_down,
    backscatter_envelope,
    balance,
    fill_range,
    harmonic_fill,
    require_range_grid,
    work_size,
)
from sea3d.enhance._image import (
    as_unit_float,
    encode,
    from_linear,
    luminance,
    require_rgb,
    saturated_mask,
    to_linear,
)
from sea3d.enhance.colour import channel_gains
from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.water import WaterModel, fit_water_model, restore
from sea3d.errors import EnhanceError

__all__ = [
    "SeathruConfig",
    "SeathruModel",
    "SeathruResult",
    "apply_seathru",
    "depth_to_range",
    "fit_seathru",
    "range_from_points",
    "seathru",
]

_log = logging.getLogger(__name__)


_MIN_POINTS = 64
# Linear luminance below which a pixel counts as black (about 6/255 in sRGB).
_BLACK = 2e-3


@dataclass(frozen=True, kw_only=True)
class SeathruModel:
    """A fitted Sea-thru model: enough to restore any image of the same water with its range.

    Attributes:
        backscatter: per channel ``(B_inf, beta_B_per_m, J_prime, beta_D_prime_per_m)``, or
            None (stage off).
        attenuation: per channel ``(a, b, c, d)`` of ``beta_D(z) = a e^{bz} + c e^{dz}``
            (1/m, b and d in 1/m too); None with ``attenuation`` not ``fit``.
        attenuation_kind: ``two-term``, ``constant``, ``illuminant`` or ``none``.
        range_fit_m: ``(z_lo, z_hi)`` range span the fits saw, metres.
        wb_gains: ``(3,)`` white-balance gains (linear).
        exposure_gain: final scale (linear).
        notes: what the fit did on the way (fallbacks).
    """

    backscatter: tuple[tuple[float, float, float, float], ...] | None
    attenuation: tuple[tuple[float, float, float, float], ...] | None
    attenuation_kind: str
    range_fit_m: tuple[float, float]
    wb_gains: tuple[float, float, float]
    exposure_gain: float
    notes: tuple[str, ...] = ()

    def backscatter_rgb(self, range_m: np.ndarray) -> F64:
        """``(N, 3)`` backscatter ``B_c(z) = B_inf_c (1 - exp(-beta_B_c z))`` at ranges ``(N,)``
        metres (zeros if off). The residual term ``J' exp(-beta_D' z)`` of the fit models the
        dark pixels' own signal and is not part of the backscatter."""
        z = np.asarray(range_m, dtype=np.float64).reshape(-1, 1)
        if self.backscatter is None:
            return np.zeros((z.shape[0], 3))
        p = np.asarray(self.backscatter, dtype=np.float64)  # (3, 4)
        return p[:, 0] * (1.0 - np.exp(-p[:, 1] * z))

    def beta_d_per_m(self, range_m: np.ndarray) -> F64:
        """``(N, 3)`` ``beta_D(z)`` at ranges ``(N,)``, with z held inside the fitted span."""
        z = np.asarray(range_m, dtype=np.float64).reshape(-1, 1)
        if self.attenuation is None:
            return np.zeros((z.shape[0], 3))
        zc = np.clip(z, self.range_fit_m[0], self.range_fit_m[1])
        p = np.asarray(self.attenuation, dtype=np.float64)
        return _beta_model(zc, p[:, 0], p[:, 1], p[:, 2], p[:, 3])

    def as_dict(self) -> dict[str, object]:
        """Plain dict (JSON)."""
        return {
            "backscatter_B_inf_betaB_Jprime_betaDprime": self.backscatter,
            "attenuation_a_b_c_d": self.attenuation,
            "attenuation_kind": self.attenuation_kind,
            "range_fit_m": self.range_fit_m,
            "wb_gains": self.wb_gains,
            "exposure_gain": self.exposure_gain,
            "notes": list(self.notes),
        }


@dataclass(frozen=True, kw_only=True, eq=False)
class SeathruResult:
    """Restored image and what was done.

    Attributes:
        image: restored image, the input's dtype and encoding.
        model: the model used (a :class:`~sea3d.enhance.water.WaterModel` for
            ``attenuation="water-model"``).
        restored: ``(H, W)`` bool, pixels whose water was removed (with ``holes="mask"``, the
            pixels with range; otherwise all).
        range_filled: ``(H, W)`` bool, pixels whose range was inpainted.
        status: ``ok``, or ``fallback-grey-world`` when the restoration came out empty (more
            than half of the pixels with range turned black; logged).
    """

    image: np.ndarray
    model: SeathruModel | WaterModel
    restored: BoolArray
    range_filled: BoolArray
    status: str = "ok"
    notes: tuple[str, ...] = field(default_factory=tuple)


# ------------------------------------------------------------------------------ models


def _backscatter_model(z: F64, b_inf: F64, beta_b: F64, j_p: F64, beta_dp: F64) -> F64:
    return b_inf * (1.0 - np.exp(-beta_b * z)) + j_p * np.exp(-beta_dp * z)


def _beta_model(z: F64, a: F64, b: F64, c: F64, d: F64) -> F64:
    return a * np.exp(b * z) + c * np.exp(d * z)


def depth_to_range(
    depth_m: np.ndarray, fx_px: float, fy_px: float, cx_px: float, cy_px: float
) -> F32:
    """Range (distance along the line of sight) from pinhole depth (z along the optical axis):
    ``r = z sqrt(1 + ((u - cx) / fx)^2 + ((v - cy) / fy)^2)``; NaN stays NaN.

    Args:
        depth_m: ``(H, W)`` float depth, metres, NaN invalid (e.g. rectified stereo depth).
        fx_px: the focal length along u of that grid's pinhole (rectified intrinsics).
        fy_px: its focal length along v.
        cx_px: its principal point's u.
        cy_px: its principal point's v.

    Raises:
        EnhanceError: a non-2-D map or non-positive focal lengths.
    """
    z = np.asarray(depth_m, dtype=np.float32)
    if z.ndim != 2:
        raise EnhanceError(f"depth must be an (H, W) map, got shape {z.shape}")
    if not (fx_px > 0 and fy_px > 0):
        raise EnhanceError(f"focal lengths must be > 0, got {fx_px}, {fy_px}")
    h, w = z.shape
    x = (np.arange(w, dtype=np.float32) - np.float32(cx_px)) / np.float32(fx_px)
    y = (np.arange(h, dtype=np.float32) - np.float32(cy_px)) / np.float32(fy_px)
    scale = np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2).astype(np.float32)
    return (z * scale).astype(np.float32)


def range_from_points(
    points_cam: np.ndarray, camera: object, shape: tuple[int, int] | None = None
) -> F32:
    """A range map in a camera's own pixel grid from 3D points in its frame (e.g. a stereo
    point cloud): each point goes to its nearest pixel (``camera.project``, so port cameras
    work), the nearest point wins, pixels no point reaches are NaN.

    Args:
        points_cam: ``(N, 3)`` points in the camera frame, metres.
        camera: a :class:`~sea3d.geometry.camera.CameraModel`.
        shape: ``(H, W)``; default the camera's image size.

    Returns:
        ``(H, W)`` float32 range (distance from the camera centre), metres.
    """
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    h, w = shape if shape is not None else (camera.height, camera.width)  # type: ignore[attr-defined]
    out = np.full(h * w, np.inf)
    if pts.shape[0]:
        keep = np.all(np.isfinite(pts), axis=1) & (pts[:, 2] > 0)
        pts = pts[keep]
        uv, vis = camera.project(pts)  # type: ignore[attr-defined]
        u = np.rint(uv[:, 0])
        v = np.rint(uv[:, 1])
        ok = vis & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = (v[ok] * w + u[ok]).astype(np.int64)
        np.minimum.at(out, idx, np.linalg.norm(pts[ok], axis=1))
    out[~np.isfinite(out)] = np.nan
    return out.reshape(h, w).astype(np.float32)


# ------------------------------------------------------------------------------ inputs


@dataclass(frozen=True, eq=False)
class _Inputs:
    lin: F32  # (H, W, 3) linear
    dtype: np.dtype
    z: F32  # (H, W), NaN invalid
    valid: BoolArray  # finite positive range
    usable: BoolArray  # valid and unclipped


def _inputs(image: object, range_m: object, config: SeathruConfig, what: str) -> _Inputs:
    if config.water_model:
        raise EnhanceError("a per-image Sea-thru model needs the per-image attenuation it was "
                           "fitted with, not 'water-model'")
    img, dtype = as_unit_float(image, what)
    require_rgb(img, "Sea-thru", what)
    z = np.asarray(range_m, dtype=np.float32)
    require_range_grid(z, img.shape, what)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, np.float32(np.nan)).astype(np.float32)
    if not valid.any():
        raise EnhanceError(
            "range map has no valid pixel (all NaN or <= 0); Sea-thru needs range, use a "
            "white balance (grey-world) instead"
        )
    frac = float(valid.mean())
    need = max(config.min_valid_fraction, _MIN_POINTS / valid.size)
    if frac < need:
        raise EnhanceError(
            f"range map is valid on only {100 * frac:.2f} % of the pixels; Sea-thru needs at "
            f"least {100 * need:.2f} %"
        )
    usable = valid & ~saturated_mask(img, config.saturation_level)
    if usable.sum() < max(_MIN_POINTS, config.min_valid_fraction * valid.sum()):
        raise EnhanceError(
            f"{what} is saturated: {100 * (1 - usable.sum() / valid.sum()):.1f} % of the "
            "pixels with range are clipped; nothing to restore"
        )
    return _Inputs(to_linear(img, config.encoding), dtype, z, valid, usable)


# ------------------------------------------------------------------------------ stage 1


def _fit_backscatter(
    inputs: Sequence[_Inputs], config: SeathruConfig, notes: list[str]
) -> tuple[tuple[float, float, float, float], ...]:
    z_all = np.concatenate([inp.z[inp.usable] for inp in inputs])
    rgb_all = np.concatenate([inp.lin[inp.usable] for inp in inputs])
    step = max(1, z_all.size // 400_000)
    z_all, rgb_all = z_all[::step].astype(np.float64), rgb_all[::step].astype(np.float64)
    z_lo, z_hi = np.percentile(z_all, [0.5, 99.5])
    edges = np.linspace(z_lo, z_hi, config.range_bins + 1)
    zs, vals, wts = [], [], []
    bright = rgb_all.sum(axis=1)
    for k in range(config.range_bins):
        sel = np.flatnonzero((z_all >= edges[k]) & (z_all <= edges[k + 1]))
        if sel.size < 20:
            continue
        # The darkest dark_percentile % of the bin (exactly that many, ties or not).
        n_dark = max(1, round(sel.size * config.dark_percentile / 100.0))
        dark = sel[np.argpartition(bright[sel], n_dark - 1)[:n_dark]]
        zs.append(z_all[dark])
        vals.append(rgb_all[dark])
        # Each bin weighs the same however many pixels it holds (near bins hold most).
        wts.append(np.full(n_dark, 1.0 / np.sqrt(n_dark)))
    if not zs:
        notes.append("backscatter: no populated range bin; constant backscatter")
        zs, vals, wts = [z_all], [rgb_all], [np.ones(z_all.size)]
    z: F64 = np.concatenate(zs).astype(np.float64)
    v: F64 = np.concatenate(vals).astype(np.float64)
    wt: F64 = np.concatenate(wts).astype(np.float64)
    params = []
    if config.backscatter_fit == "envelope" and len(zs) >= 2:
        zk = np.array([np.median(b) for b in zs])
        qk = np.array([np.mean(b, axis=0) for b in vals])
        for c in range(3):
            b_inf, beta_b = backscatter_envelope(zk, qk[:, c], b_inf_max=1.0, steps=300)
            params.append((b_inf, beta_b, 0.0, 0.0))
        return tuple(params)
    for c in range(3):
        params.append(_fit_backscatter_channel(z, v[:, c], wt, notes, c))
    return tuple(params)


def _fit_backscatter_channel(
    z: F64, v: F64, wt: F64, notes: list[str], channel: int
) -> tuple[float, float, float, float]:
    def resid(p: F64) -> F64:
        return np.asarray(wt * (_backscatter_model(z, p[0], p[1], p[2], p[3]) - v))

    lo, hi = np.zeros(4), np.array([1.0, 5.0, 1.0, 5.0])
    best = None
    top = float(np.clip(np.percentile(v, 95), 1e-4, 1.0))
    if np.ptp(z) > 1e-6 and z.size >= 8:
        starts = [
            (beta_b, j0, beta_d)
            for beta_b in (0.3, 2.0)
            for j0, beta_d in ((0.0, 1.0), (0.3 * top, 0.5), (top, 1.5))
        ]
        best = _best_fit(resid, [[top, beta_b, j0, beta_d] for beta_b, j0, beta_d in starts],
                         (lo, hi))
    if best is None:
        notes.append(f"backscatter: channel {channel} not fitted; constant level")
        level = float(np.clip(np.median(v), 0.0, 1.0))
        # B_inf (1 - e^{-5 z}) ~ B_inf beyond 1 m: a constant level.
        return (level, 5.0, 0.0, 0.0)
    return tuple(float(x) for x in best.x)  # type: ignore[return-value]


# ------------------------------------------------------------------------------ stage 2


def local_space_average(
    d_work: F32, z_work: F32, valid: BoolArray, p: float, tolerance: float
) -> F32:
    """Ebner's local space average colour, the fixed point of
    ``a = p D + (1 - p) mean_{N(x)} a`` over range-gated 4-neighbours, solved directly.

    Args:
        d_work: ``(h, w, 3)`` direct signal (linear).
        z_work: ``(h, w)`` range, metres.
        valid: ``(h, w)`` bool pixels that take part.
        p: update weight in (0, 1).
        tolerance: neighbours must lie within ``tolerance * z`` in range.

    Returns:
        ``(h, w, 3)`` float32 local averages, NaN outside ``valid``.
    """
    h, w = valid.shape
    idx = np.full((h, w), -1, dtype=np.int64)
    n = int(valid.sum())
    idx[valid] = np.arange(n)
    rows, cols = [], []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ys, ye = max(0, -dy), h - max(0, dy)
        xs, xe = max(0, -dx), w - max(0, dx)
        a_i = idx[ys:ye, xs:xe]
        b_i = idx[ys + dy : ye + dy, xs + dx : xe + dx]
        za = z_work[ys:ye, xs:xe]
        zb = z_work[ys + dy : ye + dy, xs + dx : xe + dx]
        with np.errstate(invalid="ignore"):
            ok = (a_i >= 0) & (b_i >= 0) & (np.abs(za - zb) <= tolerance * za)
        rows.append(a_i[ok])
        cols.append(b_i[ok])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    count = np.bincount(r, minlength=n).astype(np.float64)
    lonely = np.flatnonzero(count == 0)
    r = np.concatenate([r, lonely])
    c = np.concatenate([c, lonely])
    count[lonely] = 1.0
    m = sp.csr_matrix((1.0 / count[r], (r, c)), shape=(n, n))
    a_mat = (sp.identity(n, format="csr") - (1.0 - p) * m).tocsc()
    rhs = p * d_work[valid].astype(np.float64)
    sol = splu(a_mat).solve(rhs)
    out = np.full((h, w, 3), np.nan, dtype=np.float32)
    out[valid] = sol.astype(np.float32)
    return out


def _illuminant(
    d_lin: F32, inp: _Inputs, config: SeathruConfig
) -> tuple[F32, F32, BoolArray, tuple[int, int]]:
    h, w = inp.valid.shape
    size = work_size(h, w, config.work_max_side_px)
    d_work, ok_d = area_down(d_lin, inp.usable, size, min_cover=0.5)
    z_work, ok_z = area_down(inp.z, inp.usable, size, min_cover=0.5)
    ok = ok_d & ok_z
    if ok.sum() < _MIN_POINTS:
        raise EnhanceError("too few pixels with range at the working resolution to fit")
    a = local_space_average(d_work, z_work, ok, config.lsac_p, config.lsac_range_tolerance)
    return (config.lsac_f * a).astype(np.float32), z_work, ok, size


def _fit_attenuation(
    illuminants: Sequence[tuple[F32, F32, BoolArray]], config: SeathruConfig, notes: list[str]
) -> tuple[tuple[tuple[float, float, float, float], ...], str]:
    """Eq. 14 over the working pixels of every frame's illuminant ``(E, z, ok)``, pooled."""
    z_pts = np.concatenate([z_work[ok] for _e, z_work, ok in illuminants]).astype(np.float64)
    e_pts = np.concatenate([e_work[ok] for e_work, _z, ok in illuminants]).astype(np.float64)
    n = z_pts.size
    if n > config.fit_pixels:
        sel = np.linspace(0, n - 1, config.fit_pixels).astype(np.int64)
        z_pts, e_pts = z_pts[sel], e_pts[sel]
    params: list[tuple[float, float, float, float]] = []
    kinds = []
    for c in range(3):
        e = e_pts[:, c]
        use = (e > 1e-4) & (e < 1.0 - 1e-4)
        z, y = z_pts[use], -np.log(e[use])  # y = beta_D(z) z
        if z.size < 16:
            notes.append(f"attenuation: channel {c} has no usable illuminant; beta_D = 0")
            params.append((0.0, 0.0, 0.0, 0.0))
            kinds.append("constant")
            continue
        if config.attenuation == "fit-scaled":
            params.append(_fit_attenuation_scaled(z, y))
            kinds.append("constant" if params[-1][2] == 0.0 else "two-term")
            continue
        beta0 = float(np.sum(y * y) / max(np.sum(z * y), 1e-12))  # argmin sum (z - y/beta)^2
        cost1 = 0.5 * float(np.sum((z - y / beta0) ** 2))

        def resid(p: F64, z: F64 = z, y: F64 = y) -> F64:
            beta = np.maximum(_beta_model(z, p[0], p[1], p[2], p[3]), 1e-6)
            return np.asarray(z - y / beta)

        best = _best_fit(resid, [[beta0, 0.0, 0.0, -1.0], [0.5 * beta0, -0.1, 0.5 * beta0, -1.0]],
                         ([0.0, -10.0, 0.0, -10.0], [50.0, 0.0, 50.0, 0.0]))
        if best is not None and best.cost < 0.95 * cost1:
            params.append(tuple(float(v) for v in best.x))  # type: ignore[arg-type]
            kinds.append("two-term")
        else:
            params.append((beta0, 0.0, 0.0, 0.0))
            kinds.append("constant")
    if "two-term" not in kinds:
        notes.append("attenuation: two-term fit not better than a constant beta_D (shallow scene)")
    kind = "two-term" if all(k == "two-term" for k in kinds) else (
        "constant" if all(k == "constant" for k in kinds) else "mixed"
    )
    return tuple(params), kind


def _fit_attenuation_scaled(z: F64, y: F64) -> tuple[float, float, float, float]:
    """``-log E = beta_D(z) z - kappa`` with a free per-channel ``kappa`` (the illuminant's
    unknown scale: exposure, light level, mean albedo), least squares in ``log E``. A constant
    ``beta_D`` is a linear regression; the two-term form is kept only if it lowers the residual
    by 5 %."""
    a_mat = np.stack([z, -np.ones_like(z)], axis=1)
    (beta0, kappa0), *_ = np.linalg.lstsq(a_mat, y, rcond=None)
    beta0 = max(float(beta0), 0.0)
    cost1 = 0.5 * float(np.sum((beta0 * z - kappa0 - y) ** 2))

    def resid(p: F64) -> F64:
        return np.asarray(_beta_model(z, p[0], p[1], p[2], p[3]) * z - p[4] - y)

    best = _best_fit(resid, [[beta0, 0.0, 0.0, -1.0, kappa0],
                             [0.5 * beta0, -0.1, 0.5 * beta0, -1.0, kappa0]],
                     ([0.0, -10.0, 0.0, -10.0, -50.0], [50.0, 0.0, 50.0, 0.0, 50.0]))
    if best is not None and best.cost < 0.95 * cost1:
        return (float(best.x[0]), float(best.x[1]), float(best.x[2]), float(best.x[3]))
    return (beta0, 0.0, 0.0, 0.0)


def _best_fit(resid: Callable[[F64], F64], starts: Sequence[Sequence[float]],
              bounds: tuple[Sequence[float] | F64, Sequence[float] | F64]) -> OptimizeResult | None:
    """The bounded least-squares fit (trust region, at most 300 evaluations) of ``resid`` with
    the lowest cost over the start points ``starts``; None when none ends at finite
    parameters."""
    best = None
    for x0 in starts:
        try:
            r = least_squares(resid, np.asarray(x0, dtype=np.float64), bounds=bounds,
                              method="trf", max_nfev=300)
        except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - defensive
            continue
        if np.all(np.isfinite(r.x)) and (best is None or r.cost < best.cost):
            best = r
    return best


# ------------------------------------------------------------------------------ holes


def _fill_range(inp: _Inputs, config: SeathruConfig) -> F32:
    """Range with holes filled at the working resolution."""
    return fill_range(inp.z, inp.valid, config.work_max_side_px, min_cover=0.5)


# ------------------------------------------------------------------------------ public


Frames = Sequence[tuple[np.ndarray, np.ndarray]]
"""``(image, range_m)`` pairs of the same water: one frame, a stereo pair, or a dive's."""


def fit_seathru(frames: Frames, config: SeathruConfig | None = None) -> SeathruModel | WaterModel:
    """Fit Sea-thru to one frame or many frames of the same water: every stage pools the
    samples of all frames (the pixels with range of each image, each with its own range), so
    one frame and a dive are the same fit, fed one or many samples.

    Args:
        frames: ``(image, range_m)`` pairs: ``(H, W, 3)`` RGB ``uint8``/``uint16``/float
            ``[0, 1]`` in ``config.encoding`` and ``(H, W)`` float range along the line of
            sight in the image's pixel grid, metres, NaN (or <= 0) where unknown.
        config: :class:`~sea3d.enhance.config.SeathruConfig` (default settings if None).

    Returns:
        A :class:`~sea3d.enhance.water.WaterModel` for ``attenuation="water-model"`` (with a
        status; see :func:`~sea3d.enhance.water.fit_water_model`), else a
        :class:`SeathruModel`.

    Raises:
        EnhanceError: no frame, a one-channel image, a range map of another size, one with no
            (or too few) valid pixels, or an image whose pixels with range are all clipped.
    """
    config = config or SeathruConfig()
    if config.water_model:
        return fit_water_model(frames, config)
    return _fit(_frame_inputs(frames, config), config)


def _frame_inputs(frames: Frames, config: SeathruConfig) -> list[_Inputs]:
    items = list(frames)
    if not items:
        raise EnhanceError("Sea-thru needs at least one (image, range) frame to fit")
    return [_inputs(img, rng, config, "image" if len(items) == 1 else f"image {k}")
            for k, (img, rng) in enumerate(items)]


def _fit(inputs: Sequence[_Inputs], config: SeathruConfig) -> SeathruModel:
    notes: list[str] = []
    z_use = np.concatenate([inp.z[inp.usable] for inp in inputs])
    z_span = (float(np.percentile(z_use, 0.5)), float(np.percentile(z_use, 99.5)))
    bs = _fit_backscatter(inputs, config, notes) if config.backscatter else None
    model0 = SeathruModel(
        backscatter=bs, attenuation=None, attenuation_kind="none", range_fit_m=z_span,
        wb_gains=(1.0, 1.0, 1.0), exposure_gain=1.0,
    )
    d_lins = [_direct(inp.lin, inp.z, inp.valid, model0) for inp in inputs]
    att = None
    kind = "none"
    e_fulls: list[F32 | None] = [None] * len(inputs)
    if config.attenuation != "none":
        illuminants = [_illuminant(d, inp, config)[:3] for d, inp in zip(d_lins, inputs,
                                                                          strict=True)]
        if config.attenuation in ("fit", "fit-scaled"):
            att, kind = _fit_attenuation(illuminants, config, notes)
        else:
            kind = "illuminant"
            e_fulls = [_upsample_illuminant(e, ok, (inp.z.shape[0], inp.z.shape[1]))
                       for (e, _z, ok), inp in zip(illuminants, inputs, strict=True)]
    model1 = SeathruModel(
        backscatter=bs, attenuation=att, attenuation_kind=kind, range_fit_m=z_span,
        wb_gains=(1.0, 1.0, 1.0), exposure_gain=1.0,
    )
    j_use = np.concatenate([
        _restore(d, inp.z, inp.valid, model1, config, e)[0][inp.usable]
        for d, inp, e in zip(d_lins, inputs, e_fulls, strict=True)
    ])
    gains, exposure = balance(j_use, config)
    model = SeathruModel(
        backscatter=bs, attenuation=att, attenuation_kind=kind, range_fit_m=z_span,
        wb_gains=(float(gains[0]), float(gains[1]), float(gains[2])), exposure_gain=exposure,
        notes=tuple(notes),
    )
    for note in notes:
        _log.info("sea-thru: %s", note)
    return model


def _upsample_illuminant(e_work: F32, ok: BoolArray, shape: tuple[int, int]) -> F32:
    """The working-resolution illuminant at full size; pixels outside ``ok`` are filled
    harmonically in log space."""
    log_e = np.log(np.maximum(np.where(ok[..., None], e_work, 1.0), 1e-6))
    filled = np.stack([harmonic_fill(log_e[..., c], ok) for c in range(3)], axis=2)
    h, w = shape
    return np.exp(cv2.resize(filled, (w, h), interpolation=cv2.INTER_LINEAR)).astype(np.float32)


def _direct(lin: F32, z: F32, where: BoolArray, model: SeathruModel) -> F32:
    """``D = max(I - B(z), 0)`` on ``where`` (elsewhere the input)."""
    out = lin.copy()
    if model.backscatter is None:
        return out
    b = model.backscatter_rgb(z[where]).astype(np.float32)
    out[where] = np.maximum(lin[where] - b, 0.0)
    return out


def _restore(
    d_lin: F32, z: F32, where: BoolArray, model: SeathruModel, config: SeathruConfig,
    e_full: F32 | None,
) -> tuple[F32, F32]:
    """``J = D exp(beta_D(z) z)`` (or ``D / E``) on ``where``; elsewhere ``D``. Also returns
    the ``(H, W, 3)`` per-channel gain applied to ``D`` (1 elsewhere)."""
    out = d_lin.copy()
    gain_map = np.ones_like(d_lin)
    if model.attenuation is not None:
        zz = z[where].astype(np.float64)
        gain = np.exp(np.minimum(model.beta_d_per_m(zz) * zz[:, None], 60.0))
        gain = np.minimum(gain, config.max_restore_gain).astype(np.float32)
        out[where] = d_lin[where] * gain
        gain_map[where] = gain
    elif e_full is not None:
        gain = 1.0 / np.maximum(e_full[where], np.float32(1.0 / config.max_restore_gain))
        out[where] = d_lin[where] * gain
        gain_map[where] = gain
    return out, gain_map


def _denoise(out_lin: F32, noise_gain: F32, config: SeathruConfig) -> F32:
    """Blend towards a smoothed copy (chroma ``sigma_c``, luminance ``sigma_l``) in proportion
    to the log of the gain the restoration applied to the input's noise, so near,
    little-amplified pixels keep their detail and far, strongly amplified ones lose their
    noise."""
    y_out = luminance(out_lin)
    g = cv2.GaussianBlur(noise_gain.astype(np.float32), (0, 0), 3.0)
    w = np.clip(np.log2(np.maximum(g, 1.0)) / np.log2(config.denoise_full_gain), 0.0, 1.0)
    chroma: F32 = (out_lin - y_out[..., None]).astype(np.float32)
    if config.denoise_chroma_sigma_px > 0:
        chroma = np.asarray(
            cv2.GaussianBlur(chroma, (0, 0), config.denoise_chroma_sigma_px), dtype=np.float32
        )
    y_s = (
        cv2.GaussianBlur(y_out, (0, 0), config.denoise_luma_sigma_px)
        if config.denoise_luma_sigma_px > 0
        else y_out
    )
    smooth = y_s[..., None] + chroma
    return (w[..., None] * smooth + (1.0 - w[..., None]) * out_lin).astype(np.float32)


def apply_seathru(
    image: np.ndarray,
    range_m: np.ndarray,
    model: SeathruModel | WaterModel,
    config: SeathruConfig | None = None,
) -> SeathruResult:
    """Restore one image with a fitted model and the image's own range map (any frame of the
    water the model was fitted to, e.g. the right image of a pair with the pair's model).

    Args:
        image: ``(H, W, 3)`` RGB in ``config.encoding``.
        range_m: ``(H, W)`` range, metres, NaN where unknown.
        model: from :func:`fit_seathru`.
        config: the settings the model was fitted with (holes, caps, encoding); default
            settings of the model's kind if None.

    Returns:
        :class:`SeathruResult`; a water model's result that would have come out black, NaN or
        saturated is refused (``refused-…``, the white-balanced input instead), a per-image
        one falls back to grey world (``fallback-grey-world``).

    Raises:
        EnhanceError: as :func:`fit_seathru`, or a config of the other kind than the model.
    """
    if isinstance(model, WaterModel):
        got = restore(image, range_m, model, config)
        none = np.zeros(np.shape(range_m), dtype=bool)
        return SeathruResult(
            image=got.image, model=model, status=got.status, notes=got.notes,
            restored=none if got.restored is None else got.restored,
            range_filled=none if got.range_filled is None else got.range_filled,
        )
    config = config or SeathruConfig()
    inp = _inputs(image, range_m, config, "image")
    return _apply(inp, model, config)


def _apply(inp: _Inputs, model: SeathruModel, config: SeathruConfig) -> SeathruResult:
    h, w = inp.valid.shape
    if config.holes == "inpaint":
        z = _fill_range(inp, config)
        where = np.isfinite(z) & (z > 0)
    else:
        z = inp.z
        where = inp.valid
    filled = where & ~inp.valid
    d = _direct(inp.lin, z, where, model)
    e_full = None
    if model.attenuation_kind == "illuminant":
        # The illuminant map is this image's own, over every pixel that has (filled) range.
        sat = saturated_mask(from_linear(inp.lin, config.encoding), config.saturation_level)
        filled_inp = _Inputs(inp.lin, inp.dtype, np.where(where, z, np.nan).astype(np.float32),
                             where, where & ~sat)
        e_work, _z_work, ok, _size = _illuminant(d, filled_inp, config)
        e_full = _upsample_illuminant(e_work, ok, (h, w))
    j, gain = _restore(d, z, where, model, config, e_full)
    scale = np.asarray(model.wb_gains, dtype=np.float32) * np.float32(model.exposure_gain)
    out_lin = j * scale
    if config.denoise:
        out_lin = _denoise(out_lin, np.max(gain * scale, axis=2), config)
    status = "ok"
    notes = list(model.notes)
    y_in = luminance(inp.lin)[inp.usable]
    y_out = luminance(np.clip(out_lin, 0, 1))[inp.usable]
    blackened = float(np.mean(y_out < _BLACK)) - float(np.mean(y_in < _BLACK))
    if not np.all(np.isfinite(out_lin)) or blackened > 0.5:
        # The backscatter estimate swallowed the signal (e.g. a flat, featureless view):
        # say so and give the grey-world result rather than a black image.
        status = "fallback-grey-world"
        notes.append("restoration came out empty; fell back to grey world")
        _log.warning("sea-thru: restoration came out empty; fell back to grey world")
        gains = channel_gains([inp.lin], p=1.0, masks=[inp.usable]).astype(np.float32)
        out_lin = inp.lin * gains
    out = encode(out_lin, inp.dtype, config.encoding)
    return SeathruResult(
        image=out, model=model, restored=where, range_filled=filled, status=status,
        notes=tuple(notes),
    )


def seathru(
    image: np.ndarray, range_m: np.ndarray, config: SeathruConfig | None = None
) -> SeathruResult:
    """Fit Sea-thru to ``image`` with ``range_m`` and restore it: :func:`fit_seathru` on this
    one frame, then :func:`apply_seathru`.

    Args:
        image: ``(H, W, 3)`` RGB, ``uint8``/``uint16``/float ``[0, 1]``, sRGB unless
            ``config.encoding == "linear"``.
        range_m: ``(H, W)`` float32 range along the line of sight, metres, NaN where unknown
            (see :func:`depth_to_range` for stereo depth).
        config: :class:`~sea3d.enhance.config.SeathruConfig`.

    Returns:
        :class:`SeathruResult` with the restored image (input dtype), the fitted model and
        masks.

    Raises:
        EnhanceError: as :func:`fit_seathru`.
    """
    config = config or SeathruConfig()
    if config.water_model:
        return apply_seathru(image, range_m, fit_water_model([(image, range_m)], config), config)
    inputs = _frame_inputs([(image, range_m)], config)
    return _apply(inputs[0], _fit(inputs, config), config)
