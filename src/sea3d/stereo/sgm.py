"""sea3d's own semi-global matcher, built for underwater images.

* Costs: Hamming distance of census signatures (default 9x7 window), which ignore the
  brightness and contrast changes that caustics and haze cause between the two views.
* Aggregation: Hirschmüller's semi-global recursion along 8 (or 16) paths, with P2 lowered
  across image edges (``P2 * tau / (tau + |dI|)``) so that disparity steps follow intensity steps.
* Selection: winner-take-all, subpixel parabola (or equiangular) fit, uniqueness test,
  left-right check against the right view's winners read off the same aggregated volume, and a
  confidence map ``1 - best / second best``.
* Coarse-to-fine: when the full volume ``H * W * D`` is large, the pair is matched on an image
  pyramid; each finer level searches only a narrow per-pixel band around the coarser answer
  (spanning the coarse neighbourhood, so both sides of a depth step are searched). At 1920x1080
  with 256 disparities the volumes are then ~50-100x smaller than a full one.
* Post-processing: NaN-aware median and speckle removal.
"""

from __future__ import annotations

import logging
import time

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from sea3d.stereo import _sgm_kernels as K
from sea3d.stereo._images import check_pair, to_grey_float
from sea3d.stereo._simd import LANES
from sea3d.stereo.filters import fill_holes, median_nan, remove_speckles
from sea3d.stereo.types import DisparityResult, SgmConfig

__all__ = ["choose_pyramid_levels", "match_sgm", "warm_up"]

log = logging.getLogger(__name__)

_SUBPIXEL = {"none": 0, "parabola": 1, "equiangular": 2}
# Each direction is walked forward and backward, so 4 directions make the 8 paths.
_DIRECTIONS_8 = ((0, 1), (1, 0), (1, 1), (1, -1))
_DIRECTIONS_16 = (*_DIRECTIONS_8, (1, 2), (1, -2), (2, 1), (2, -1))
# scanlines walked in lockstep by one thread: neighbouring rows for horizontal paths (few, so
# their cost rows stream from memory side by side), columns for the others: an eighth of the
# image width (measured at 1080p: 240 columns ran the vertical sweeps 1.4x faster than 64, the
# long inner loop amortising each step's set-up), but at least 64
_ROW_GROUP = 8
_COLUMN_GROUP_MIN = 64
_SLOPE_HALF_WIDTH_PX = 4  # columns either side in the refinement's vertical-slope fit


def choose_pyramid_levels(height: int, width: int, num_disparities: int, config: SgmConfig) -> int:
    """Number of pyramid levels above full resolution for an image and disparity range.

    ``config.pyramid_levels`` if set. Otherwise 0 (one full search) when the full volume
    ``H * W * D`` fits ``config.full_search_budget``; else the fewest levels at which the
    coarsest full volume (``H * W * D / 8**levels``) fits ``config.coarse_search_budget``,
    keeping at least 16 disparities and 32 pixels a side at the coarsest level.
    """
    if config.pyramid_levels is not None:
        return config.pyramid_levels
    h, w, d = height, width, num_disparities
    if h * w * d <= config.full_search_budget:
        return 0
    levels = 0
    while h * w * d > config.coarse_search_budget and d >= 32 and min(h, w) >= 64:
        h, w, d = (h + 1) // 2, (w + 1) // 2, (d + 1) // 2
        levels += 1
    return levels


def _level_search(
    gl: NDArray[np.float32],
    gr: NDArray[np.float32],
    num_disp: int,
    coarse: NDArray[np.float32] | None,
    config: SgmConfig,
    timings: dict[str, float],
    band: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    paths: int | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32], int]:
    h, w = gl.shape
    t0 = time.perf_counter()
    if coarse is None:
        chunks = -(-num_disp // LANES)
        lo = np.zeros((h, w), np.int32)
        nch = np.full((h, w), chunks, np.int32)
        none = np.zeros((h, w), np.bool_)
    else:
        lo, nch, none = band if band is not None else _band(coarse, h, w, num_disp, config)
    offs = K.band_offsets(nch)
    k_band = int(nch.max()) * LANES
    t1 = time.perf_counter()
    hh, hw = config.census_height_px // 2, config.census_width_px // 2
    if config.census_presmooth_px > 0:
        sigma = config.census_presmooth_px
        gl_c = np.asarray(cv2.GaussianBlur(gl, (0, 0), sigma), dtype=np.float32)
        gr_c = np.asarray(cv2.GaussianBlur(gr, (0, 0), sigma), dtype=np.float32)
    else:
        gl_c, gr_c = gl, gr
    cl = K.census_transform(gl_c, hh, hw)
    cr = K.census_transform(gr_c, hh, hw)
    cost = K.band_costs(cl, cr, lo, nch, offs, num_disp)
    t2 = time.perf_counter()
    total = np.empty(cost.shape[0], np.int16)
    if paths is None:
        paths = config.paths if coarse is None else config.band_paths
    dirs = {4: _DIRECTIONS_8[:2], 8: _DIRECTIONS_8, 16: _DIRECTIONS_16}[paths]
    guide = np.clip(gl + 0.5, 0, 255).astype(np.uint8).reshape(-1)
    lof = lo.reshape(-1)
    ncf = nch.reshape(-1)
    lut = K.p2_table(config.p1, config.p2, config.p2_edge_tau)
    first = True
    for dy, dx in dirs:
        for p0, so, si, n_outer, n_inner, s in K.path_sweeps(h, w, dy, dx):
            group = _ROW_GROUP if dy == 0 else max(_COLUMN_GROUP_MIN, -(-w // 8))
            K.sweep(cost, lof, ncf, offs, guide, total, config.p1, lut, p0, so, si, n_outer,
                    n_inner, s, group, not first)
            first = False
    del cost
    t3 = time.perf_counter()
    disp, conf = K.select_disparity(
        total, lo, nch, offs, none, num_disp, config.uniqueness, config.lr_max_diff_px,
        _SUBPIXEL[config.subpixel],
    )
    K.invalidate_left_border(disp, 16, 1.0)
    t4 = time.perf_counter()
    for key, val in (("band_s", t1 - t0), ("cost_s", t2 - t1), ("aggregate_s", t3 - t2),
                     ("select_s", t4 - t3)):
        timings[key] = timings.get(key, 0.0) + val
    return disp, conf, k_band


def _band(coarse: NDArray[np.float32], h: int, w: int, num_disp: int, config: SgmConfig
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    out: tuple[np.ndarray, np.ndarray, np.ndarray] = K.band_from_coarse(
        coarse, h, w, num_disp, config.band_max_px // LANES, config.band_margin_px,
        config.band_radius_px,
    )
    return out


def _trial_applies(h: int, w: int, num_disp: int, levels: int, config: SgmConfig) -> bool:
    """A full search that one coarser trial level might replace (see
    ``SgmConfig.trial_step_fraction``): more than two chunks of candidates (with two, a
    one-chunk band saves at most half of the full level's work, and the trial level costs some
    of that back: on venus, 32 disparities, it was no faster and 0.01 points of bad-2 worse)
    and an image large enough to halve."""
    return (levels == 0 and config.pyramid_levels is None and config.trial_step_fraction > 0
            and num_disp > 2 * LANES and min(h, w) >= 64)


def _trial_levels(h: int, w: int, num_disp: int) -> int:
    """Coarser levels of the trial: two where the range a quarter the size still spans a
    chunk of 16 and the image a quarter the size keeps 32 px a side (a full search at a
    quarter the size, then a one-chunk band at half the size, instead of a full search at
    half the size: at 640x360 with 80 disparities, six frames of the simulated dive, the
    aggregation took 24 ms of CPU a frame against 27 ms with one coarser level, for the same
    disparities to the bit), else one."""
    return 2 if -(-num_disp // 4) >= LANES and min(h, w) >= 128 else 1


def match_sgm(left: np.ndarray, right: np.ndarray, config: SgmConfig) -> DisparityResult:
    """Match a rectified pair with sea3d's semi-global matcher.

    Args:
        left, right: ``(H, W)`` or ``(H, W, 3)`` RGB, uint8, uint16 or float, same shape.
        config: matcher settings; the search range is ``0..config.max_disparity_px``.

    Returns:
        :class:`DisparityResult` with disparity (H, W) float32 px of the left view (NaN
        invalid), confidence in [0, 1], and per-stage timings (``match_s`` for the whole call).

    Raises:
        StereoError: mismatched sizes, bad dtype, non-finite values, or a disparity range as
            wide as the image.
    """
    check_pair(left, right, config.max_disparity_px)
    # Static scheduling: numba's dynamic chunks cost about 4 ms of CPU per chunk here
    # (measured: a 1080p sweep of 135 line groups took 39 ms static, 68 ms in chunks of 16,
    # 607 ms in chunks of 1), far more than the load balance they buy.
    previous_chunk = numba.set_parallel_chunksize(0)
    try:
        return _match_sgm(left, right, config)
    finally:
        numba.set_parallel_chunksize(previous_chunk)


def _vertical_slope(disp: NDArray[np.float32], half_h: int, half_w: int) -> NDArray[np.float32]:
    """Least-squares slope of the disparity along rows, px/px, over a ``(2 half_h + 1) x
    (2 half_w + 1)`` window of valid pixels (NaN where the window holds too few): the vertical
    tilt the alignment refinement lets its window follow. Measured steadier than central
    differences of a median-filtered map (fronto-parallel planes at 3-5 m: 0.39/0.61 %
    against 0.57/0.82 % depth error) at the same accuracy on receding sea floors."""
    v, d = K.valid_and_zeroed(disp)
    ramp = np.arange(-half_h, half_h + 1, dtype=np.float32)
    ones_y = np.ones(2 * half_h + 1, np.float32)
    ones_x = np.ones(2 * half_w + 1, np.float32)
    def f(img: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return np.asarray(cv2.sepFilter2D(img, cv2.CV_32F, ones_x, ky,
                                          borderType=cv2.BORDER_CONSTANT))
    s1, sj, sjj = f(v, ones_y), f(v, ramp), f(v, ramp * ramp)
    sd, sjd = f(d, ones_y), f(d, ramp)
    out: NDArray[np.float32] = K.slope_from_sums(s1, sj, sjj, sd, sjd)
    return out


def _match_sgm(left: np.ndarray, right: np.ndarray, config: SgmConfig) -> DisparityResult:
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    gl, gr = to_grey_float(left, right)
    h, w = gl.shape
    num_disp = config.max_disparity_px + 1
    levels = choose_pyramid_levels(h, w, num_disp, config)
    trial = _trial_applies(h, w, num_disp, levels, config)
    if trial:
        levels = _trial_levels(h, w, num_disp)
    pyramid = [(gl, gr)]
    for _ in range(levels):
        a, b = pyramid[-1]
        pyramid.append((np.asarray(cv2.pyrDown(a)), np.asarray(cv2.pyrDown(b))))
    timings["pyramid_s"] = time.perf_counter() - t_start
    coarse: NDArray[np.float32] | None = None
    conf: NDArray[np.float32] | None = None
    for lev in range(levels, -1, -1):
        a, b = pyramid[lev]
        nd = min(-(-num_disp // (1 << lev)), a.shape[1] - 1)
        band = None
        paths = None
        if trial and lev == 0:
            # the coarse trial: keep its band where the coarse map has few depth steps, else
            # search the full range after all
            assert coarse is not None
            band = _band(coarse, a.shape[0], a.shape[1], nd, config)
            frac = float(np.count_nonzero(band[1] > 1)) / band[1].size
            timings["trial_step_fraction"] = frac
            paths = config.paths
            if frac >= config.trial_step_fraction:
                coarse, band = None, None
                levels = 0
        disp, conf, k_band = _level_search(a, b, nd, coarse, config, timings, band, paths)
        log.debug("level %d: %dx%d, %d disparities, band %d", lev, a.shape[1], a.shape[0],
                  nd, k_band)
        t0 = time.perf_counter()
        if lev == 0 and config.refine_iterations > 0:
            r = config.refine_window_px // 2
            reach = (r // config.refine_row_step) * config.refine_row_step
            gy = _vertical_slope(disp, reach, _SLOPE_HALF_WIDTH_PX)
            c = config.refine_weight_cutoff
            inv_gamma = 1.0 / c if c > 0 else 0.0
            disp = K.refine_subpixel(a, b, disp, gy, r, r, config.refine_iterations, 0.5,
                                     inv_gamma, config.refine_row_step)
            timings["refine_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
        if config.median_px > 1:
            disp = median_nan(disp, config.median_px)
        if config.speckle_size_px > 0:
            disp = remove_speckles(
                disp, max(config.speckle_size_px >> (2 * lev), 4), config.speckle_range_px
            )
        timings["post_s"] = timings.get("post_s", 0.0) + time.perf_counter() - t0
        coarse = disp
    assert coarse is not None and conf is not None
    disp = coarse
    fill = w if config.fill_max_px is None else config.fill_max_px
    if fill > 0:
        t0 = time.perf_counter()
        conf = np.where(np.isfinite(disp), conf, np.float32(0.0)).astype(np.float32)
        disp = fill_holes(disp, fill)
        timings["post_s"] += time.perf_counter() - t0
    disp[disp > config.max_disparity_px] = config.max_disparity_px
    conf = np.where(np.isfinite(disp), conf, np.float32(0.0)).astype(np.float32)
    timings["match_s"] = time.perf_counter() - t_start
    timings["pyramid_levels"] = float(levels)
    return DisparityResult(disparity_px=disp, confidence=conf, timings_s=timings, engine="sea3d")


def warm_up() -> float:
    """Compile (or load from numba's cache) every kernel on a tiny pair; returns seconds."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    img = (rng.random((80, 112)) * 255).astype(np.uint8)
    left, right = img[:, :-16], img[:, 16:]  # true disparity 16 px
    for paths in (8,):
        match_sgm(left, right, SgmConfig(max_disparity_px=31, paths=paths, pyramid_levels=1))
    return time.perf_counter() - t0
