"""One water model per dive: fit the revised image formation model once from many frames of
the same water, then restore every frame with one vectorised inversion.

The model (Akkaynak and Treibitz, "A Revised Underwater Image Formation Model", CVPR 2018,
Eq. 1 with wideband coefficients), per channel c, in **linear** RGB, at range z (metres along
the line of sight)::

    I_c = J_c exp(-beta_D_c z) + B_inf_c (1 - exp(-beta_B_c z))

:func:`fit_water_model` pools pixels from every frame it is given (a dive sees the same water
at many ranges; one image rarely spans enough range to separate attenuation from albedo):

1. **Backscatter** (Sea-thru, CVPR 2019, Sec. 4.2): the pooled range is cut into bins between
   its 1st and 99th percentiles; in each bin the darkest ``dark_percentile`` % of pixels bound
   the backscatter from above, and ``B_inf, beta_B`` are the highest saturating curve that
   stays at or below every bin's dark level (as :mod:`sea3d.enhance.seathru`'s ``envelope``).
2. **Wideband attenuation**: with the backscatter removed, ``log D_c = log J_c - beta_D_c z``.
   Over many pixels and frames the albedo does not depend on range, so the per-bin median of
   ``log D_c`` falls on a line of slope ``-beta_D_c``: a robust (soft-L1) weighted line fit over
   the bins, one per channel.
3. **White balance and exposure** over the restored samples of every frame (so the pair and
   the dive keep one colour): grey world by default, as Sea-thru balances its ``J`` (the
   inversion gives the scene under the light that reached it, which crossed the water above;
   other choices in :attr:`~sea3d.enhance.config.SeathruConfig.white_balance`); then the
   ``white_point_percentile`` of the brightest channel to 1.

Each fitted parameter is checked for physical plausibility (:data:`LIMITS`, and for metric
range :data:`PURE_WATER_KD_PER_M`); a failed check is reported by name in ``checks``
(``B_inf`` or ``beta_B`` at a limit: reported only, the status kept) and a fatal one makes
the fit fall back in stated steps, each with its status:

- ``ok``: everything fitted, no fatal check;
- some channel's ``beta_D`` came out below what any natural water has (or at 0): the fit
  could not see the direct signal under the backscatter, so the water is not inverted
  (``backscatter-unidentified``, below); with ``below_floor="floor"`` those
  channels are raised to that floor instead, the other channels and the backscatter kept
  (``attenuation-floor``);
- ``attenuation-unidentified``: ``beta_D`` not identified (range span too narrow, too few
  bins, a ``beta_D`` at its upper limit or outside it): beta_D is not used; the backscatter is
  the joint fit's where that was plausible, else the dark-pixel envelope's; the restoration
  removes backscatter, then white-balances;
- ``backscatter-unidentified``: no usable dark pixels across range either, or a ``beta_D`` below
  the natural-water floor (above): white balance only
  (grey world on the pooled frames);
- a model that cannot be fitted at all (no frame with range) raises :class:`EnhanceError`
  naming the parameter and why.

:func:`restore` applies a model to one image and its range: two look-up tables (sRGB decode,
encode) and a handful of float32 array operations per pixel, well under a second at 1080p.
Range holes near pixels with range (stereo holes) are filled from the surrounding range
(harmonic fill at a working resolution); wide regions without range (open water) and, with
``holes="mask"``, every hole get the white balance and exposure alone.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from sea3d._typing import F64
from sea3d.enhance._formation import (
    backscatter_envelope,
    balance,
    fill_range,
    require_range_grid,
)
from sea3d.enhance._image import (
    DECODE_SRGB_U8,
    Encoding,
    as_unit_float,
    decode,
    encode,
    encode_srgb_table_u8,
    require_rgb,
    saturated_mask,
)
from sea3d.enhance.config import SeathruConfig
from sea3d.errors import EnhanceError

__all__ = [
    "LIMITS",
    "PURE_WATER_KD_PER_M",
    "RestoreResult",
    "WaterFitConfig",
    "WaterModel",
    "fit_water_model",
    "restore",
]

_log = logging.getLogger(__name__)

F32 = NDArray[np.float32]

LIMITS: dict[str, tuple[float, float]] = {
    "beta_D_per_m": (0.0, 5.0),
    "beta_B_per_m": (0.01, 5.0),
    "B_inf": (0.0, 0.95),
}
"""Plausible ranges of the fitted parameters. ``beta_D`` of natural waters spans about
0.02-3 1/m over the visible (Jerlov's types I to 9C; Solonenko and Mobley, Applied Optics
54(17), 2015); the Sea-thru paper bounds ``beta_B`` and ``beta_D`` to [0, 5] 1/m. ``B_inf``
is a veiling light below clipping."""

_SAMPLES_PER_FRAME = 60_000
_MIN_PIXELS = 500


def WaterFitConfig(**settings: Any) -> SeathruConfig:
    """The water model's settings: a :class:`~sea3d.enhance.config.SeathruConfig` with
    ``attenuation="water-model"`` and ``settings``.

    Raises:
        EnhanceError: as :class:`~sea3d.enhance.config.SeathruConfig`.
    """
    return SeathruConfig(attenuation="water-model", **settings)


@dataclass(frozen=True, kw_only=True)
class WaterModel:
    """The water of one dive, in linear RGB.

    Attributes:
        B_inf_rgb: veiling light per channel (R, G, B), linear units.
        beta_B_per_m: backscatter coefficients, 1/m.
        beta_D_per_m: wideband direct-signal attenuation, 1/m (zeros when not identified).
        wb_gains: white-balance gains applied after the inversion.
        exposure_gain: final linear scale.
        range_span_m: the 5th and 95th percentiles of the range the fit saw, metres.
        frames: frames pooled.
        status: ``ok``, ``attenuation-floor``, ``attenuation-unidentified`` or
            ``backscatter-unidentified`` (module docstring).
        checks: every plausibility check that failed, by parameter, and why.
    """

    B_inf_rgb: tuple[float, float, float]
    beta_B_per_m: tuple[float, float, float]
    beta_D_per_m: tuple[float, float, float]
    wb_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure_gain: float = 1.0
    range_span_m: tuple[float, float] = (0.0, 0.0)
    frames: int = 0
    status: str = "ok"
    checks: tuple[str, ...] = field(default_factory=tuple)

    @property
    def has_backscatter(self) -> bool:
        return self.status != "backscatter-unidentified"

    @property
    def has_attenuation(self) -> bool:
        return self.status in ("ok", "attenuation-floor")

    def as_dict(self) -> dict[str, object]:
        """Plain dict (JSON)."""
        d: dict[str, object] = asdict(self)
        d["checks"] = list(self.checks)
        return d


@dataclass(frozen=True, kw_only=True, eq=False)
class RestoreResult:
    """A restored image and what was done.

    Attributes:
        image: ``(H, W, 3)`` restored image, the input's dtype (sRGB).
        status: ``ok``, the model's fallback status, or ``refused-…`` when the result would
            have been empty (then ``image`` is the grey-world balance of the input).
        notes: why, for the frame report.
        restored: ``(H, W)`` bool, the pixels whose water was removed (the others got the
            white balance and exposure only).
        range_filled: ``(H, W)`` bool, the pixels among them whose range was filled.
    """

    image: np.ndarray
    status: str
    notes: tuple[str, ...] = ()
    restored: NDArray[np.bool_] | None = None
    range_filled: NDArray[np.bool_] | None = None


# ------------------------------------------------------------------------------ tables

_Z_STEP_M = 0.005  # range table step: a gain error below 0.5 % at beta_D = 1 1/m


def _range_tables(
    model: WaterModel, scale: F32, z_max_m: float, max_gain: float
) -> tuple[F32, F32]:
    """Per range step, ``gain = G(z) scale`` and ``offset = B(z) G(z) scale`` so that
    ``scale (I - B(z)) G(z) = I gain - offset`` (``(K, 3)`` float32)."""
    z = (np.arange(int(np.ceil(z_max_m / _Z_STEP_M)) + 2) * _Z_STEP_M)[:, None]
    b = np.zeros((z.shape[0], 3))
    if model.has_backscatter:
        b = np.asarray(model.B_inf_rgb) * (1.0 - np.exp(-np.asarray(model.beta_B_per_m) * z))
    g = np.ones((z.shape[0], 3))
    if model.has_attenuation:
        g = np.exp(np.minimum(np.asarray(model.beta_D_per_m) * z, np.log(max_gain)))
    sc = np.asarray(scale, np.float64)
    return (g * sc).astype(np.float32), (b * g * sc).astype(np.float32)


# ------------------------------------------------------------------------------ fitting


def _frame_samples(
    image: np.ndarray, range_m: np.ndarray, config: SeathruConfig, k: int,
    rng: np.random.Generator,
) -> tuple[F64, F64] | None:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        require_rgb(arr[..., 0] if arr.ndim == 3 else arr, "a water model", f"frame {k}")
    z = np.asarray(range_m, dtype=np.float32)
    require_range_grid(z, arr.shape, f"the image of frame {k}")
    lin, _ = decode(arr, config.encoding)
    img01, _ = as_unit_float(arr, "image")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(z) & (z > 0) & ~saturated_mask(img01, config.saturation_level)
    if config.min_texture > 0:
        # Flat pixels (open water, the veiling light itself) hold no albedo to fit, and stereo
        # gives them no trustworthy range: left out.
        y = img01.mean(axis=2).astype(np.float32)
        m1 = cv2.blur(y, (5, 5))
        sd = np.sqrt(np.maximum(cv2.blur(y * y, (5, 5)) - m1 * m1, 0.0))
        ok &= sd >= np.float32(config.min_texture)
    idx = np.flatnonzero(ok.ravel())
    if idx.size < _MIN_PIXELS:
        return None
    if idx.size > _SAMPLES_PER_FRAME:
        idx = rng.choice(idx, _SAMPLES_PER_FRAME, replace=False)
    return z.ravel()[idx].astype(np.float64), lin.reshape(-1, 3)[idx].astype(np.float64)


_QUANTILES = (5.0, 15.0, 30.0, 50.0, 70.0, 85.0, 95.0)


def _fit_channel(
    zk: F64, qk: F64, wk: F64, dark_k: F64, beta_d_fixed: float | None = None
) -> tuple[float, float, float, float]:
    """Fit ``q_kp = B_inf (1 - e^{-beta_B z_k}) + A_p e^{-beta_D z_k}`` to the per-bin
    quantiles ``qk`` ``(K, P)`` of one channel (weights ``wk`` ``(K,)``): for each
    ``(beta_B, beta_D)`` on a grid the rest is linear least squares (variable projection);
    the best grid point is then refined. The backscatter may not exceed the darkest pixels of
    any bin (``dark_k``, ``(K,)``): ``B_inf`` is capped so. With ``beta_d_fixed`` only
    ``beta_B`` (and the linear terms) are fitted. Returns ``(B_inf, beta_B, beta_D, rms)``."""
    n_k, n_p = qk.shape
    sw = np.sqrt(wk)
    y = (qk * sw[:, None]).T.ravel()  # (P*K,)
    best = (np.inf, 0.0, 1.0, 0.0)
    lo_b, hi_b = LIMITS["beta_B_per_m"]
    lo_d, hi_d = LIMITS["beta_D_per_m"]
    grid_b = np.geomspace(lo_b, hi_b, 40)
    grid_d = np.concatenate([[0.0], np.geomspace(0.01, hi_d, 60)])
    if beta_d_fixed is not None:
        grid_d = np.array([beta_d_fixed])

    def solve(a: F64, beta_b: float) -> F64:
        x, *_ = np.linalg.lstsq(a, y, rcond=None)
        x = np.maximum(x, 0.0)
        cap = float(np.min(dark_k / np.maximum(1.0 - np.exp(-beta_b * zk), 1e-9)))
        # Over a short span B_inf and beta_B trade (the curve is almost linear): hold B_inf
        # inside its limit so the grid picks the steeper curve instead.
        cap = min(cap, LIMITS["B_inf"][1])
        if x[0] > cap:  # re-solve the decaying terms with B_inf held at the cap
            x[0] = cap
            rest, *_ = np.linalg.lstsq(a[:, 1:], y - a[:, 0] * cap, rcond=None)
            x[1:] = np.maximum(rest, 0.0)
        return np.asarray(x)

    def design(beta_b: float, beta_d: float) -> F64:
        a = np.zeros((n_p * n_k, 1 + n_p))
        fb = (1.0 - np.exp(-beta_b * zk)) * sw
        fd = np.exp(-beta_d * zk) * sw
        for p in range(n_p):
            a[p * n_k : (p + 1) * n_k, 0] = fb
            a[p * n_k : (p + 1) * n_k, 1 + p] = fd
        return a

    for beta_b in grid_b:
        for beta_d in grid_d:
            a = design(float(beta_b), float(beta_d))
            x = solve(a, float(beta_b))
            cost = float(np.sum((a @ x - y) ** 2))
            if cost < best[0]:
                best = (cost, float(x[0]), float(beta_b), float(beta_d))

    def resid(p: F64) -> F64:
        a = design(float(p[0]), float(p[1]))
        return np.asarray(a @ solve(a, float(p[0])) - y)

    if beta_d_fixed is not None:
        def resid_b(p: F64) -> F64:
            return resid(np.array([p[0], beta_d_fixed]))

        r = least_squares(resid_b, np.array([best[2]]), bounds=([lo_b], [hi_b]),
                          method="trf", max_nfev=100)
        beta_b, beta_d = float(r.x[0]), float(beta_d_fixed)
    else:
        r = least_squares(resid, np.array([best[2], best[3]]),
                          bounds=([lo_b, lo_d], [hi_b, hi_d]), method="trf", max_nfev=200)
        beta_b, beta_d = float(r.x[0]), float(r.x[1])
    x = solve(design(beta_b, beta_d), beta_b)
    rms = float(np.sqrt(np.mean(r.fun**2) / max(np.mean(wk), 1e-12)))
    return float(max(x[0], 0.0)), beta_b, beta_d, rms


def _line_slope(zk: F64, yk: F64, wk: F64) -> float:
    """Robust (soft-L1) weighted slope of ``y = a + s z``."""
    a_mat = np.stack([np.ones_like(zk), zk], axis=1) * np.sqrt(wk)[:, None]
    (a0, s0), *_ = np.linalg.lstsq(a_mat, yk * np.sqrt(wk), rcond=None)
    scale = max(float(np.median(np.abs(yk - a0 - s0 * zk))), 0.02)

    def resid(p: F64) -> F64:
        return np.asarray(np.sqrt(wk) * (yk - p[0] - p[1] * zk))

    r = least_squares(resid, np.array([a0, s0]), loss="soft_l1", f_scale=scale)
    return float(r.x[1])


PURE_WATER_KD_PER_M: tuple[float, float, float] = (0.244, 0.0509, 0.0176)
"""``K_d`` of pure water at 600, 525 and 475 nm (Smith and Baker, "Optical properties of the
clearest natural waters (200-800 nm)", Applied Optics 20(2), 1981, Table 1): no natural
water attenuates less. A fitted ``beta_D`` below half of it (a margin for the channels'
wide bands) is implausible for any water and is reported as such."""


def _implausible(
    b_inf: F64, beta_b: F64, beta_d: F64, config: SeathruConfig
) -> tuple[list[str], list[str]]:
    """The failed checks of a fit, as ``(fatal, reported)``.

    Fatal: a parameter outside its limit (:data:`LIMITS`) or not finite, ``beta_D`` at a limit,
    and, for metric range, a ``beta_D`` below what any natural water has
    (:data:`PURE_WATER_KD_PER_M`). Reported only: ``B_inf`` or ``beta_B`` at a limit (the fit
    ran into it: over a short range span ``B_inf`` and ``beta_B`` trade, and the curve
    ``B(z)`` over the fitted span, which is what the restoration uses, is still what the
    frames determine)."""
    fatal: list[str] = []
    reported: list[str] = []
    for c, name in enumerate("RGB"):
        for key, val in (("B_inf", b_inf[c]), ("beta_B_per_m", beta_b[c]),
                         ("beta_D_per_m", beta_d[c])):
            lo, hi = LIMITS[key]
            tol = 1e-3 * (hi - lo)
            to = fatal if key == "beta_D_per_m" else reported
            if not (np.isfinite(val) and lo <= val <= hi):
                fatal.append(f"{key}[{name}] = {val:.3f} outside [{lo}, {hi}]")
            elif val >= hi - tol:
                to.append(f"{key}[{name}] = {val:.3f} at its upper limit {hi}: the fit ran "
                          "into the bound")
            elif val <= lo + tol and key != "B_inf":
                to.append(f"{key}[{name}] = {val:.3f} at its lower limit {lo}: the fit ran "
                          "into the bound")
        floor = 0.5 * PURE_WATER_KD_PER_M[c]
        if config.metric_range and beta_d[c] < floor:
            fatal.append(f"beta_D_per_m[{name}] = {beta_d[c]:.3f} below {floor:.3f}, half of "
                         "pure water's K_d in that band: implausible for any water (too "
                         "short a range span or too strong a backscatter to see attenuation)")
    return fatal, reported


def _fit_ladder(
    zk: F64, qcs: list[F64], wk: F64, dark: F64, config: SeathruConfig
) -> tuple[F64, F64, F64, str, list[str], bool]:
    """The fit and its first fallback: every parameter free (``ok`` if no fatal check, the
    reported ones in ``checks``); else, where the only fatal checks are a ``beta_D`` below
    the natural-water floor (or at 0), those channels raised to the floor, the others and
    the backscatter kept (``attenuation-floor``: the truth is at least the floor); else
    ``attenuation-unidentified``. Returns ``(B_inf, beta_B, beta_D, status, checks,
    backscatter_ok)``: ``backscatter_ok`` when no fatal check is on ``B_inf`` or ``beta_B``
    (the joint fit's backscatter can be kept without its ``beta_D``)."""
    b_inf, beta_b, beta_d = np.zeros(3), np.zeros(3), np.zeros(3)
    for c in range(3):
        b_inf[c], beta_b[c], beta_d[c], _rms = _fit_channel(zk, qcs[c], wk, dark[:, c])
    fatal, reported = _implausible(b_inf, beta_b, beta_d, config)
    if not fatal:
        return b_inf, beta_b, beta_d, "ok", reported, True
    checks = fatal + reported
    back_ok = not any(c.startswith(("B_inf", "beta_B")) for c in fatal)
    low = [("pure water" in c) or (c.startswith("beta_D") and "lower limit" in c)
           for c in fatal]
    if config.metric_range and all(low) and config.below_floor == "white-balance":
        # Where the fit finds less attenuation than pure water it could not see the direct
        # signal under the backscatter (on the simulated dives that reach this the direct
        # signal is 1-9 % of the pixel and the joint backscatter is off by 1.3-46 times it):
        # neither term is trusted, the dive gets its white balance only.
        return b_inf, beta_b, beta_d, "backscatter-unidentified", checks + [
            "beta_D below the natural-water floor: the direct signal cannot be told from the "
            "backscatter; the water is not inverted (white balance only)"
        ], False
    if config.metric_range and all(low):
        floor = 0.5 * np.asarray(PURE_WATER_KD_PER_M)
        raised = np.maximum(beta_d, floor)
        for c in np.flatnonzero(beta_d < floor):
            # The backscatter again with beta_D held at the floor (fitted with the implausible
            # beta_D, it took up part of the attenuation).
            b_inf[c], beta_b[c], _d, _rms = _fit_channel(zk, qcs[c], wk, dark[:, c],
                                                       beta_d_fixed=float(floor[c]))
        return b_inf, beta_b, raised, "attenuation-floor", checks + [
            f"beta_D raised to the natural-water floor: {np.round(raised, 3).tolist()} 1/m, "
            "the backscatter of those channels fitted again with it"
        ], True
    return b_inf, beta_b, beta_d, "attenuation-unidentified", checks, back_ok


def fit_water_model(
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    config: SeathruConfig | None = None,
) -> WaterModel:
    """Fit one :class:`WaterModel` to many frames of the same water (module docstring).

    Args:
        frames: ``(image, range_m)`` pairs: ``(H, W, 3)`` sRGB ``uint8``/``uint16``/float
            ``[0, 1]`` and ``(H, W)`` float range along the line of sight in the image's own
            pixel grid, metres, NaN (or <= 0) where unknown. Both images of a stereo pair
            may be given, each with its own range.
        config: :class:`~sea3d.enhance.config.SeathruConfig` with
            ``attenuation="water-model"`` (the default when None).

    Returns:
        :class:`WaterModel` with a status; parameters that failed a plausibility check are
        named in ``checks``.

    Raises:
        EnhanceError: no frame given, a range map of another size than its image, or no
            frame with at least 500 pixels with range and unclipped colour (then neither
            ``B_inf`` nor ``beta_D`` can be fitted).
    """
    config = _water_config(config)
    rng = np.random.default_rng(0)
    zs, rgbs = [], []
    n_frames = 0
    for k, (image, range_m) in enumerate(frames):
        n_frames += 1
        got = _frame_samples(image, range_m, config, k, rng)
        if got is not None:
            zs.append(got[0])
            rgbs.append(got[1])
    if n_frames == 0:
        raise EnhanceError("fit_water_model needs at least one (image, range) frame")
    if not zs:
        raise EnhanceError(
            f"cannot fit B_inf or beta_D: none of the {n_frames} frames has {_MIN_PIXELS} "
            "pixels with range and unclipped colour (all holes, another grid, or saturated)"
        )
    z: F64 = np.concatenate(zs)
    rgb: F64 = np.concatenate(rgbs)
    z_lo, z_hi = np.percentile(z, [1.0, 99.0])
    span = (float(np.percentile(z, 5.0)), float(np.percentile(z, 95.0)))
    checks: list[str] = []
    edges = np.linspace(z_lo, z_hi, config.range_bins + 1)
    bin_of = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, config.range_bins - 1)
    inside = (z >= z_lo) & (z <= z_hi)
    bright = rgb.sum(axis=1)
    zk, qk, members = [], [], []
    min_per_bin = max(50, int(100 / config.dark_percentile))
    for b in range(config.range_bins):
        sel = np.flatnonzero(inside & (bin_of == b))
        if sel.size < min_per_bin:
            continue
        n_dark = max(1, round(sel.size * config.dark_percentile / 100.0))
        dark = sel[np.argpartition(bright[sel], n_dark - 1)[:n_dark]]
        zk.append(float(np.median(z[sel])))
        qk.append(rgb[dark].mean(axis=0))
        members.append(sel)
    zk_a, dark_a = np.asarray(zk), np.asarray(qk).reshape(-1, 3)
    ratio = span[1] / max(span[0], 1e-6)
    b_inf: F64 = np.zeros(3)
    beta_b: F64 = np.full(3, LIMITS["beta_B_per_m"][1])
    beta_d: F64 = np.zeros(3)
    status = "ok"
    keep_back = False
    if len(zk) < 2:
        checks.append(f"B_inf: only {len(zk)} populated range bin(s); 2 are needed")
        status = "backscatter-unidentified"
    elif ratio < config.min_range_ratio or len(zk) < config.min_bins:
        checks.append(
            f"beta_D: range spans {span[0]:.2f}-{span[1]:.2f} m (ratio {ratio:.2f}, "
            f"{len(zk)} bins; need {config.min_range_ratio} and {config.min_bins}): "
            "attenuation cannot be told from albedo"
        )
        status = "attenuation-unidentified"
    else:
        # Albedo quantiles do not depend on range over a dive, and the model is monotone in
        # J at fixed z: every quantile of I follows B(z) + A_p exp(-beta_D z).
        wk = np.asarray([np.sqrt(m.size) for m in members])
        qcs = [np.stack([np.percentile(rgb[m, c], _QUANTILES) for m in members])
               for c in range(3)]
        b_inf, beta_b, beta_d, status, found, keep_back = _fit_ladder(
            zk_a, qcs, wk, dark_a, config)
        checks += found
    if status == "attenuation-unidentified" and keep_back:
        # beta_D implausible, the joint fit's backscatter plausible: keep it, drop beta_D.
        beta_d[:] = 0.0
        checks.append("beta_D not used; the backscatter fitted with it kept")
    elif status == "attenuation-unidentified":
        # Fall back to the dark-pixel envelope for backscatter alone (an upper bound).
        beta_d[:] = 0.0
        for c in range(3):
            b_inf[c], beta_b[c] = backscatter_envelope(
                zk_a, dark_a[:, c], b_inf_max=LIMITS["B_inf"][1], steps=200)
        lo, hi = LIMITS["B_inf"]
        if not np.all((b_inf >= lo) & (b_inf <= hi)):
            checks.append(f"B_inf = {np.round(b_inf, 3).tolist()} outside [{lo}, {hi}]")
            status = "backscatter-unidentified"
    if status == "backscatter-unidentified":
        b_inf[:] = 0.0
        beta_b[:] = LIMITS["beta_B_per_m"][1]
        beta_d[:] = 0.0

    model = WaterModel(
        B_inf_rgb=_t3(b_inf), beta_B_per_m=_t3(beta_b), beta_D_per_m=_t3(beta_d),
        range_span_m=span, frames=n_frames, status=status, checks=tuple(checks),
    )
    j = _invert(rgb.astype(np.float32), z.astype(np.float32), model, config.max_restore_gain)
    gains, exposure = balance(j, config, beta_d if model.has_attenuation else None)
    for check in checks:
        _log.info("water model: %s", check)
    return WaterModel(
        B_inf_rgb=model.B_inf_rgb, beta_B_per_m=model.beta_B_per_m,
        beta_D_per_m=model.beta_D_per_m, wb_gains=_t3(gains), exposure_gain=exposure,
        range_span_m=span, frames=n_frames, status=status, checks=tuple(checks),
    )


def _water_config(config: SeathruConfig | None) -> SeathruConfig:
    """``config``, or the water model's defaults for None.

    Raises:
        EnhanceError: a config of another attenuation mode.
    """
    if config is None:
        return WaterFitConfig()
    if not config.water_model:
        raise EnhanceError(f"the water model needs attenuation 'water-model', got "
                           f"{config.attenuation!r}")
    return config


def _t3(v: Sequence[float] | F64) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


# ------------------------------------------------------------------------------ restore


def _invert(lin: F32, z: F32, model: WaterModel, max_gain: float) -> F32:
    """``J = (I - B_inf (1 - e^{-beta_B z})) e^{beta_D z}`` for ``lin`` ``(..., 3)`` and
    ``z`` ``(...)`` float32 (finite), the gain capped at ``max_gain``."""
    zz = z[..., None]
    out = lin
    if model.has_backscatter:
        b_inf = np.asarray(model.B_inf_rgb, np.float32)
        beta_b = np.asarray(model.beta_B_per_m, np.float32)
        out = np.maximum(out - b_inf * (np.float32(1.0) - np.exp(-beta_b * zz)), np.float32(0))
    if model.has_attenuation:
        beta_d = np.asarray(model.beta_D_per_m, np.float32)
        out = out * np.exp(np.minimum(beta_d * zz, np.float32(np.log(max_gain))))
    return np.asarray(out, dtype=np.float32)


def restore(
    image: np.ndarray,
    range_m: np.ndarray,
    water_model: WaterModel,
    config: SeathruConfig | None = None,
) -> RestoreResult:
    """Restore one image with a dive's water model and the image's own range.

    Args:
        image: ``(H, W, 3)`` sRGB ``uint8``/``uint16``/float ``[0, 1]``.
        range_m: ``(H, W)`` float range along the line of sight in the image's pixel grid,
            metres, NaN (or <= 0) where unknown.
        water_model: from :func:`fit_water_model`.
        config: how holes are treated and the gain cap (the fit's config).

    Returns:
        :class:`RestoreResult`. A result that would come out black, NaN or saturated on more
        than half of its pixels is refused: the status says so and the image is the model's
        white balance of the input instead (never passed on as ``ok``).

    Raises:
        EnhanceError: a one-channel image, or a range map of another size (another grid).
    """
    config = _water_config(config)
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        require_rgb(arr[..., 0] if arr.ndim == 3 else arr, "restore", "image")
    z = np.asarray(range_m, dtype=np.float32)
    require_range_grid(z, arr.shape, "the image")
    lin, dtype = decode(arr, config.encoding)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(z) & (z > 0)
    notes: list[str] = list(water_model.checks)
    status = water_model.status
    frac = float(valid.mean())
    scale = np.asarray(water_model.wb_gains, np.float32) * np.float32(water_model.exposure_gain)
    if frac < config.min_valid_fraction:
        notes.append(f"range valid on {100 * frac:.1f} % of the pixels: white balance only")
        res = _checked(lin, lin * scale, dtype, "no-range", notes, scale, config.encoding)
        return _with_masks(res, np.zeros_like(valid), valid)
    if config.holes == "inpaint" and not valid.all():
        z_use = fill_range(z, valid, config.work_max_side_px, min_cover=0.25)
        far = cv2.distanceTransform((~valid).astype(np.uint8), cv2.DIST_L2, 3)
        where = far <= config.max_fill_fraction * max(valid.shape)
        z_use = np.where(where, z_use, np.float32(0))
    else:
        z_use = np.where(valid, z, np.float32(0))
        where = valid
    if arr.dtype == np.uint8 and config.encoding == "srgb":
        from sea3d.enhance._water_kernel import invert_u8

        z_k = np.where(where, z_use, np.float32(np.nan)).astype(np.float32)
        z_max = float(np.nanmax(z_k)) if where.any() else 1.0
        gain_t, off_t = _range_tables(water_model, scale, z_max, config.max_restore_gain)
        out = invert_u8(np.ascontiguousarray(arr), z_k, DECODE_SRGB_U8, gain_t, off_t,
                        _Z_STEP_M, encode_srgb_table_u8(), scale.astype(np.float32))
        return _with_masks(_checked_u8(lin, out, status, notes, scale), where, valid)
    j = _invert(lin, z_use, water_model, config.max_restore_gain)
    if not where.all():
        j = np.where(where[..., None], j, lin)
    res = _checked(lin, j * scale, dtype, status, notes, scale, config.encoding)
    return _with_masks(res, where, valid)


def _with_masks(
    res: RestoreResult, where: NDArray[np.bool_], valid: NDArray[np.bool_]
) -> RestoreResult:
    """``res`` with the pixels restored (none when it was refused) and those whose range was
    filled."""
    restored = where if not res.status.startswith("refused") else np.zeros_like(where)
    return dataclasses.replace(res, restored=restored, range_filled=restored & ~valid)


def _checked_u8(
    lin: F32, out: NDArray[np.uint8], status: str, notes: list[str], scale: F32
) -> RestoreResult:
    """:func:`_checked` for an 8-bit result, on a subsample (every 4th row and column)."""
    sub_in = lin[::4, ::4]
    sub_out = DECODE_SRGB_U8[out[::4, ::4]]
    res = _checked(sub_in, sub_out, np.dtype(np.float32), status, notes, scale)
    if res.status != status:
        return _checked(lin, DECODE_SRGB_U8[out], np.dtype(np.uint8), status, notes[:-1], scale)
    return RestoreResult(image=out, status=status, notes=res.notes)


def _checked(
    lin: F32, out_lin: F32, dtype: np.dtype, status: str, notes: list[str], scale: F32,
    encoding: Encoding = "srgb",
) -> RestoreResult:
    """Refuse a result that is mostly black, NaN or clipped where the input was not; encode
    what is given back in ``encoding`` and ``dtype``."""
    y_in = lin.mean(axis=2)
    y_out = out_lin.mean(axis=2)
    finite = np.isfinite(y_out)
    black = float(np.mean(~finite | (y_out < 2e-3))) - float(np.mean(y_in < 2e-3))
    clipped_in = float(np.mean(np.max(lin, axis=2) >= 0.96))
    clipped = float(np.mean(~finite | (np.max(out_lin, axis=2) >= 1.0))) - clipped_in
    if clipped_in > 0.5:
        notes.append(f"{100 * clipped_in:.0f} % of the input is clipped: nothing to restore")
        return RestoreResult(image=encode(lin, dtype, encoding), status="refused-saturated-input",
                             notes=tuple(notes))
    if black > 0.5 or clipped > 0.5 or not finite.all():
        why = "black" if black > 0.5 else ("saturated" if clipped > 0.5 else "not finite")
        notes.append(f"restoration came out {why}; gave the white-balanced input instead")
        _log.warning("water restore: result %s; refused", why)
        fallback = lin * (scale / max(float(np.max(lin * scale)), 1.0))
        return RestoreResult(image=encode(fallback, dtype, encoding), status=f"refused-{why}",
                             notes=tuple(notes))
    return RestoreResult(image=encode(out_lin, dtype, encoding), status=status, notes=tuple(notes))
