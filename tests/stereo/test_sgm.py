"""sea3d's SGM and the OpenCV reference on synthetic pairs with known disparity."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from _textures import coarse_noise, smooth_noise
from sea3d.errors import ConfigError, StereoError
from sea3d.stereo import OpenCVSgbmConfig, SgmConfig, make_config, match
from sea3d.stereo.sgm import choose_pyramid_levels

# Tolerances (units in names). The synthetic scenes are textured planes, so nearly every
# non-occluded pixel must be found to well under a pixel.
SUBPIXEL_MEDIAN_ERR_PX = 0.15
BAD_1PX_MAX_PERCENT = 3.0
MIN_DENSITY = 0.85


def _band_limited(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Band-limited random texture: fine grain over 8 px blobs, float32 0-255."""
    fine = smooth_noise(rng, (h, w), 1.2, scale=255)
    return (0.7 * fine + 0.3 * coarse_noise(rng, (h, w), 8, scale=255)).astype(np.float32)


def _slanted_pair(
    rng: np.random.Generator, h: int = 120, w: int = 200, d0: float = 12.0, slope: float = 0.04
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left/right views of a slanted textured plane, with a brightness and contrast change in
    the right view (haze/caustics); returns uint8 left, uint8 right and the true disparity.

    The right image is sampled from the texture at ``u - d(u)`` with ``d = d0 + slope * u``.
    """
    tex = _band_limited(rng, h, w + 64)
    u = np.arange(w, dtype=np.float32)
    d_true = np.tile(d0 + slope * u, (h, 1)).astype(np.float32)
    # left(u) = tex(u + 32); right(u_r) = left(u_r + d) -> sample tex at u_r + d + 32
    left = tex[:, 32 : 32 + w]
    # invert u_l - d(u_l) = u_r for the right view: u_l = (u_r + d0) / (1 - slope)
    u_r = np.arange(w, dtype=np.float32)
    u_l = (u_r + d0) / (1.0 - slope)
    map_x = np.tile(u_l + 32, (h, 1)).astype(np.float32)
    map_y = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    right = cv2.remap(tex, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    right = 0.75 * right + 30.0  # illumination change between the views
    return (
        np.clip(left, 0, 255).astype(np.uint8),
        np.clip(right, 0, 255).astype(np.uint8),
        d_true,
    )


def _errors(d: np.ndarray, d_true: np.ndarray, margin_px: int) -> tuple[np.ndarray, float]:
    inner = np.zeros_like(d_true, dtype=bool)
    inner[4:-4, margin_px:-4] = True
    valid = np.isfinite(d) & inner
    return np.abs(d[valid] - d_true[valid]), float(valid.sum() / inner.sum())


def test_sgm_recovers_slanted_plane_with_brightness_change_to_subpixel() -> None:
    rng = np.random.default_rng(0)
    left, right, d_true = _slanted_pair(rng)
    res = match(left, right, SgmConfig(max_disparity_px=31))
    assert res.disparity_px.dtype == np.float32
    assert res.disparity_px.shape == left.shape
    err, density = _errors(res.disparity_px, d_true, margin_px=24)
    assert density > MIN_DENSITY
    assert np.median(err) < SUBPIXEL_MEDIAN_ERR_PX
    assert 100 * np.mean(err > 1.0) < BAD_1PX_MAX_PERCENT
    assert res.timings_s["match_s"] > 0
    conf = res.confidence
    assert conf.shape == left.shape and np.all((conf >= 0) & (conf <= 1))
    assert np.all(conf[~res.valid] == 0)


@pytest.mark.parametrize("paths", [8, 16])
def test_sgm_coarse_to_fine_matches_full_search(paths: int) -> None:
    rng = np.random.default_rng(0)
    left, right, d_true = _slanted_pair(rng, h=160, w=320, d0=40.0, slope=0.05)
    full = match(left, right, SgmConfig(max_disparity_px=79, pyramid_levels=0, paths=paths))
    c2f = match(left, right, SgmConfig(max_disparity_px=79, pyramid_levels=2, paths=paths,
                                       band_paths=paths))
    assert c2f.timings_s["pyramid_levels"] == 2
    for res in (full, c2f):
        err, density = _errors(res.disparity_px, d_true, margin_px=64)
        assert density > MIN_DENSITY
        assert np.median(err) < SUBPIXEL_MEDIAN_ERR_PX
        assert 100 * np.mean(err > 1.0) < BAD_1PX_MAX_PERCENT


def test_sgm_accepts_rgb_uint16_and_float_inputs_alike() -> None:
    rng = np.random.default_rng(0)
    left, right, _ = _slanted_pair(rng, h=64, w=128)
    cfg = SgmConfig(max_disparity_px=31)
    ref = match(left, right, cfg).disparity_px
    rgb = match(np.dstack([left] * 3), np.dstack([right] * 3), cfg).disparity_px
    u16 = match(left.astype(np.uint16) * 257, right.astype(np.uint16) * 257, cfg).disparity_px
    np.testing.assert_array_equal(np.isfinite(ref), np.isfinite(rgb))
    np.testing.assert_allclose(ref, rgb, atol=1e-3, equal_nan=True)  # grey conversion rounding
    # uint16 is stretched to 0-255 by its maximum, so grey levels differ slightly from the uint8
    # input; the refinement's intensity weights see that (a few thousandths of a pixel)
    assert np.nanmedian(np.abs(ref - u16)) < 0.01


def test_opencv_engine_is_descaled_and_range_rounded_to_16() -> None:
    rng = np.random.default_rng(0)
    left, right, d_true = _slanted_pair(rng)
    cfg = OpenCVSgbmConfig(max_disparity_px=20, mode="hh")
    assert cfg.num_disparities == 32
    res = match(left, right, cfg)
    # Reference: raw OpenCV output / 16 on the same input
    w = cfg.block_size_px
    raw = cv2.StereoSGBM_create(0, 32, w, P1=8 * w * w, P2=32 * w * w, disp12MaxDiff=1,
                                preFilterCap=63, uniquenessRatio=10, speckleWindowSize=100,
                                speckleRange=2, mode=cv2.StereoSGBM_MODE_HH).compute(left, right)
    expected = np.where(raw >= 0, raw / 16.0, np.nan)
    np.testing.assert_allclose(res.disparity_px, expected, equal_nan=True)
    err, _ = _errors(res.disparity_px, d_true, margin_px=36)
    assert np.median(err) < 0.5  # descaled: a missed /16 would be ~190 px off


@pytest.mark.parametrize("mode", ["sgbm", "hh", "sgbm_3way", "hh4"])
def test_opencv_modes_all_run(mode: str) -> None:
    rng = np.random.default_rng(0)
    left, right, _ = _slanted_pair(rng, h=64, w=128)
    res = match(left, right, OpenCVSgbmConfig(max_disparity_px=31, mode=mode))  # type: ignore[arg-type]
    assert 0.5 < res.valid_fraction <= 1.0


def test_bad_input_raises_clear_errors() -> None:
    rng = np.random.default_rng(0)
    img = (rng.random((40, 60)) * 255).astype(np.uint8)
    cfg = SgmConfig(max_disparity_px=15)
    with pytest.raises(StereoError, match="differ in size"):
        match(img, img[:, :50], cfg)
    with pytest.raises(StereoError, match="as wide as the image"):
        match(img, img, SgmConfig(max_disparity_px=60))
    bad = img.astype(np.float32)
    bad[3, 4] = np.nan
    with pytest.raises(StereoError, match="non-finite"):
        match(bad, bad, cfg)
    with pytest.raises(StereoError, match="shape"):
        match(img[None], img[None], cfg)
    with pytest.raises(ConfigError):
        SgmConfig(max_disparity_px=0)
    with pytest.raises(ConfigError):
        SgmConfig(p1=50, p2=10)
    with pytest.raises(ConfigError):
        make_config("vpi", 15)


def test_pyramid_levels_auto_keeps_small_images_at_full_search() -> None:
    cfg = SgmConfig()
    assert choose_pyramid_levels(375, 450, 64, cfg) == 0
    assert choose_pyramid_levels(1080, 1920, 256, cfg) >= 2


def test_sgm_default_coarse_to_fine_with_four_band_paths() -> None:
    rng = np.random.default_rng(0)
    left, right, d_true = _slanted_pair(rng, h=160, w=320, d0=40.0, slope=0.05)
    res = match(left, right, SgmConfig(max_disparity_px=79, pyramid_levels=1))
    err, density = _errors(res.disparity_px, d_true, margin_px=64)
    assert density > MIN_DENSITY
    assert np.median(err) < SUBPIXEL_MEDIAN_ERR_PX


def test_left_border_pixels_whose_match_is_off_the_image_are_invalid_not_wrong() -> None:
    rng = np.random.default_rng(0)
    left, right, _ = _slanted_pair(rng, h=96, w=200, d0=20.0, slope=0.0)
    res = match(left, right, SgmConfig(max_disparity_px=47))
    d = res.disparity_px
    border = d[:, :18]  # x < d_true: the right image does not see these points
    matched = res.measured[:, :18]
    assert np.all(np.abs(border[matched] - 20.0) < 2.0)
    assert matched.mean() < 0.1
    # the default dense output fills them from their neighbour, marked with confidence 0
    assert np.isfinite(border).all()
    assert np.all(res.confidence[:, :18][~matched] == 0)
    sparse = match(left, right, SgmConfig(max_disparity_px=47, fill_max_px=0))
    np.testing.assert_array_equal(np.isfinite(sparse.disparity_px), res.measured)


@pytest.mark.parametrize(
    ("engine", "cv_mode"),
    [("opencv", cv2.StereoSGBM_MODE_SGBM), ("opencv-hh", cv2.StereoSGBM_MODE_HH),
     ("opencv-3way", cv2.StereoSGBM_MODE_SGBM_3WAY)],
)
def test_opencv_engine_names_select_their_modes(engine: str, cv_mode: int) -> None:
    # each name must run its own OpenCV mode (3WAY and HH differ on this pair): compare with
    # cv2.StereoSGBM in that mode directly
    rng = np.random.default_rng(1)
    left, right, _ = _slanted_pair(rng)
    cfg = make_config(engine, 31)
    ours = match(left, right, cfg).disparity_px
    w = cfg.block_size_px  # type: ignore[union-attr]
    raw = cv2.StereoSGBM_create(0, 32, w, P1=8 * w * w, P2=32 * w * w, disp12MaxDiff=1,
                                preFilterCap=63, uniquenessRatio=10, speckleWindowSize=100,
                                speckleRange=2, mode=cv_mode).compute(left, right)
    ref = np.where(raw < 0, np.nan, raw / 16.0)
    np.testing.assert_array_equal(np.isfinite(ours), np.isfinite(ref))
    np.testing.assert_allclose(ours, ref, equal_nan=True)
    others = {cv2.StereoSGBM_MODE_SGBM, cv2.StereoSGBM_MODE_HH, cv2.StereoSGBM_MODE_SGBM_3WAY}
    for other in others - {cv_mode}:
        alt = cv2.StereoSGBM_create(0, 32, w, P1=8 * w * w, P2=32 * w * w, disp12MaxDiff=1,
                                    preFilterCap=63, uniquenessRatio=10, speckleWindowSize=100,
                                    speckleRange=2, mode=other).compute(left, right)
        assert not np.array_equal(raw, alt)


def _stepped_pair(rng: np.random.Generator, h: int = 160, w: int = 320
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plane at 20 px with vertical bars at 60 px every 16 columns: a depth step in every
    coarse band window."""
    tex = _band_limited(rng, h, w + 128)
    d_true = np.full((h, w), 20.0, np.float32)
    bars = (np.arange(w) // 8) % 2 == 1
    d_true[:, bars] = 60.0
    xs = np.arange(w)
    left = np.empty((h, w), np.float32)
    right = np.zeros((h, w), np.float32)
    for x in xs:  # the left pixel x shows texture column x + d (so the right sees it at x)
        left[:, x] = tex[:, x + int(d_true[0, x]) + 32]
    # right view: background first, the bars painted over it (they occlude)
    for d, sel in ((20, ~bars), (60, bars)):
        for x in xs[sel]:
            xr = x - d
            if 0 <= xr < w:
                right[:, xr] = tex[:, x + d + 32]
    return left.astype(np.uint8), right.astype(np.uint8), d_true


def test_coarse_trial_keeps_the_band_on_smooth_depth_and_searches_in_full_at_steps() -> None:
    rng = np.random.default_rng(0)
    left, right, d_true = _slanted_pair(rng, h=160, w=320, d0=40.0, slope=0.05)
    cfg = SgmConfig(max_disparity_px=79)
    assert choose_pyramid_levels(160, 320, 80, cfg) == 0  # inside the full-search budget
    res = match(left, right, cfg)
    full = match(left, right, SgmConfig(max_disparity_px=79, pyramid_levels=0))
    # smooth: the trial's band is kept (two coarser levels: 20 disparities at a quarter size)
    assert res.timings_s["pyramid_levels"] == 2
    assert res.timings_s["trial_step_fraction"] < cfg.trial_step_fraction
    err, density = _errors(res.disparity_px, d_true, margin_px=64)
    err_full, _ = _errors(full.disparity_px, d_true, margin_px=64)
    assert density > MIN_DENSITY
    assert np.median(err) < SUBPIXEL_MEDIAN_ERR_PX
    assert 100 * np.mean(err > 1.0) <= 100 * np.mean(err_full > 1.0) + 0.5
    stepped, stepped_r, _ = _stepped_pair(rng)
    res = match(stepped, stepped_r, cfg)
    assert res.timings_s["trial_step_fraction"] >= cfg.trial_step_fraction
    assert res.timings_s["pyramid_levels"] == 0  # depth steps: searched in full after all
    off = match(left, right, SgmConfig(max_disparity_px=79, trial_step_fraction=0.0))
    assert off.timings_s["pyramid_levels"] == 0 and "trial_step_fraction" not in off.timings_s


def _census_reference(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census signatures the plain way: neighbours in row-major order (centre skipped), the
    first 32 shifted into the low word (the first one most significant), the rest into the
    high word; borders replicate."""
    h, w = img.shape
    pad = np.pad(img, ((half_h, half_h), (half_w, half_w)), mode="edge")
    lo = np.zeros((h, w), np.uint64)
    hi = np.zeros((h, w), np.uint64)
    n = 0
    for dy in range(2 * half_h + 1):
        for dx in range(2 * half_w + 1):
            if dy == half_h and dx == half_w:
                continue
            bit = (pad[dy:dy + h, dx:dx + w] < img).astype(np.uint64)
            if n < 32:
                lo = (lo << np.uint64(1)) | bit
            else:
                hi = (hi << np.uint64(1)) | bit
            n += 1
    return (hi << np.uint64(32)) | (lo & np.uint64(0xFFFFFFFF))


@pytest.mark.parametrize("shape", [(23, 11), (9, 37)])
@pytest.mark.parametrize(("half_h", "half_w"), [(3, 4), (1, 1), (2, 6)])
def test_census_transform_matches_the_plain_definition_bit_for_bit(
        half_h: int, half_w: int, shape: tuple[int, int]) -> None:
    from sea3d.stereo._sgm_kernels import census_transform

    rng = np.random.default_rng(3)
    # ties (quantised values); a narrow image, so the replicated borders meet, and one whose
    # rows end part-way through a block of 16 pixels
    img = np.round(rng.random(shape) * 8).astype(np.float32)
    got = census_transform(img, half_h, half_w)
    assert got.dtype == np.uint64
    np.testing.assert_array_equal(got, _census_reference(img, half_h, half_w))


def test_band_offsets_are_the_prefix_sums_of_the_band_widths() -> None:
    from sea3d.stereo._sgm_kernels import band_offsets

    rng = np.random.default_rng(4)
    for nch in (np.ones((5, 7), np.int32), np.full((3, 4), 3, np.int32),
                rng.integers(1, 4, (6, 9)).astype(np.int32)):
        want = np.concatenate([[0], np.cumsum(nch.ravel().astype(np.int64) * 16)])
        got = band_offsets(nch)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want)


def test_vertical_slope_is_the_least_squares_row_slope_of_the_valid_pixels() -> None:
    from sea3d.stereo.sgm import _vertical_slope

    h, w = 40, 30
    yy = np.arange(h, dtype=np.float32)[:, None] * np.ones((1, w), np.float32)
    disp = (10.0 + 0.25 * yy).astype(np.float32)  # 0.25 px per row
    disp[::4, ::3] = np.nan
    disp[10:30, 5:25] = np.nan  # a hole larger than the 13 x 9 window
    gy = _vertical_slope(disp, 6, 4)
    assert gy.dtype == np.float32 and gy.shape == (h, w)
    # away from the borders (the window zero-padded there is still exact for a plane)
    inner = gy[8:-8, 6:-6]
    ok = np.isfinite(inner)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(inner[ok], 0.25, atol=1e-3)
    # the middle of the hole sees no valid pixel at all
    assert np.isnan(gy[20, 15])
