"""White balance, CLAHE and UDCP: known answers and properties on small synthetic images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sea3d.enhance import (
    clahe,
    grey_world,
    red_compensation,
    shades_of_grey,
    udcp,
    white_balance_pair,
)
from sea3d.enhance._image import linear_to_srgb, srgb_to_linear
from sea3d.errors import EnhanceError

MEAN_TOL = 2e-3  # linear units: float32 sRGB round trip and gain arithmetic
SRGB_ROUNDTRIP_TOL = 1e-5  # IEC 61966-2-1 decode then encode
LSB_8BIT = 1  # one grey level


def _cast_image(rng: np.random.Generator, h: int = 60, w: int = 80) -> np.ndarray:
    """A float sRGB image: grey texture in linear light under a blue-green cast."""
    grey = rng.uniform(0.05, 0.6, size=(h, w, 1)).astype(np.float32)
    lin = grey * np.array([0.25, 0.8, 1.0], dtype=np.float32)
    return linear_to_srgb(lin)


def test_srgb_transfer_round_trips_and_matches_the_standard_break_points() -> None:
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=SRGB_ROUNDTRIP_TOL)
    # IEC 61966-2-1: 0.04045 encoded is 0.0031308 linear; 0.5 encoded is 0.21404 linear.
    np.testing.assert_allclose(srgb_to_linear(np.float32([0.04045, 0.5])), [0.0031308, 0.21404],
                               atol=1e-5)


def test_grey_world_equalises_the_linear_channel_means(rng: np.random.Generator) -> None:
    img = _cast_image(rng)
    out = grey_world(img)
    means = srgb_to_linear(out).reshape(-1, 3).mean(axis=0)
    assert means.max() - means.min() < MEAN_TOL
    # Brightness is kept: the mean of the three means does not move.
    before = srgb_to_linear(img).reshape(-1, 3).mean(axis=0)
    assert abs(means.mean() - before.mean()) < MEAN_TOL


def test_shades_of_grey_equalises_minkowski_norms(rng: np.random.Generator) -> None:
    img = _cast_image(rng)
    out = srgb_to_linear(shades_of_grey(img, p=6.0)).reshape(-1, 3).astype(np.float64)
    norms = np.mean(out**6, axis=0) ** (1 / 6)
    assert norms.max() - norms.min() < MEAN_TOL
    # p = 1 is grey world; on an image whose channels are not proportional, p = 6 differs.
    np.testing.assert_allclose(shades_of_grey(img, p=1.0), grey_world(img), atol=1e-6)
    varied = np.full((40, 50, 3), 0.3, dtype=np.float32)
    varied[..., 0] = np.where(rng.random((40, 50)) < 0.05, 0.9, 0.2)  # red: rare highlights
    assert np.abs(shades_of_grey(varied) - grey_world(varied)).mean() > 1e-2


def test_clipped_pixels_do_not_vote(rng: np.random.Generator) -> None:
    img = _cast_image(rng)
    img[:, :40] = 1.0  # a blown-out half carries no colour
    out = grey_world(img)
    means = srgb_to_linear(out[:, 40:]).reshape(-1, 3).mean(axis=0)
    assert means.max() - means.min() < MEAN_TOL


def test_red_compensation_restores_red_where_grey_world_cannot(rng: np.random.Generator) -> None:
    img = _cast_image(rng)
    img[..., 0] = 0.0  # red absorbed completely
    gw = grey_world(img)
    rc = red_compensation(img)
    assert np.all(gw[..., 0] == 0.0)  # a gain times zero stays zero
    assert rc[..., 0].mean() > 0.1
    np.testing.assert_allclose(red_compensation(img, alpha=0.0), gw, atol=1e-6)


def test_pair_shares_gains_so_left_and_right_keep_one_colour(rng: np.random.Generator) -> None:
    left = _cast_image(rng)
    right = linear_to_srgb(srgb_to_linear(left) * np.float32(0.5))  # darker copy
    lo, ro = white_balance_pair(left, right, "grey-world")
    def means(x: np.ndarray) -> np.ndarray:
        return srgb_to_linear(x).reshape(-1, 3).mean(0)

    gain_l = means(lo) / means(left)
    gain_r = means(ro) / means(right)
    np.testing.assert_allclose(gain_l, gain_r, rtol=1e-3)
    # Separate balancing would give the same gains here too; a pair whose halves differ in
    # colour shows the difference: joint gains are the pooled ones.
    blue = np.ones_like(left) * np.float32([0.2, 0.4, 0.9])
    lo2, _ = white_balance_pair(left, blue, "grey-world")
    assert not np.allclose(lo2, grey_world(left), atol=1e-2)


def test_dtypes_round_trip_and_a_grey_image_is_left_alone() -> None:
    grey = np.full((20, 30, 3), 120, dtype=np.uint8)
    assert np.abs(grey_world(grey).astype(int) - 120).max() <= LSB_8BIT
    g16 = np.full((20, 30, 3), 30000, dtype=np.uint16)
    out16 = shades_of_grey(g16)
    assert out16.dtype == np.uint16 and np.abs(out16.astype(int) - 30000).max() <= 2


def test_black_image_gives_black_not_nan() -> None:
    out = grey_world(np.zeros((10, 10, 3), dtype=np.float32))
    assert np.all(np.isfinite(out)) and np.all(out == 0)


@pytest.mark.parametrize("fn", [grey_world, shades_of_grey, red_compensation, udcp])
def test_colour_methods_refuse_one_channel_images(fn: object) -> None:
    with pytest.raises(EnhanceError, match="RGB"):
        fn(np.zeros((10, 10), dtype=np.uint8))  # type: ignore[operator]


def test_clahe_raises_local_contrast_and_keeps_chroma(rng: np.random.Generator) -> None:
    # A low-contrast textured image with a colour.
    tex = rng.uniform(0.45, 0.55, size=(120, 160)).astype(np.float32)
    tex = cv2.GaussianBlur(tex, (0, 0), 2.0)
    img = np.stack([tex * 0.6, tex, tex * 0.8], axis=2)
    out = clahe(img)
    lab_in = cv2.cvtColor(img, cv2.COLOR_RGB2Lab)
    lab_out = cv2.cvtColor(out, cv2.COLOR_RGB2Lab)
    assert lab_out[..., 0].std() > 2.0 * lab_in[..., 0].std()
    # a*, b* barely move where nothing clips (chroma is kept).
    assert np.median(np.abs(lab_out[..., 1:] - lab_in[..., 1:])) < 2.0
    grey = clahe((tex * 255).astype(np.uint8))
    assert grey.dtype == np.uint8 and grey.shape == tex.shape


def test_udcp_removes_synthetic_haze(rng: np.random.Generator) -> None:
    h, w = 90, 120
    J = rng.uniform(0.0, 0.8, size=(h, w, 3)).astype(np.float32)
    J[rng.random((h, w)) < 0.1] = 0.0  # dark pixels in every patch: the prior holds
    z = np.linspace(0.5, 3.0, w, dtype=np.float32)[None, :, None]
    t = np.exp(-0.6 * z)
    A = np.array([0.1, 0.6, 0.7], dtype=np.float32)
    hazy = J * t + A * (1 - t)
    out = udcp(hazy, patch_px=7, guided_radius_px=8)
    err_in = np.abs(hazy - J).mean()
    err_out = np.abs(out - J).mean()
    assert err_out < 0.6 * err_in
    with pytest.raises(EnhanceError, match="odd"):
        udcp(hazy, patch_px=8)


U8_PATH_TOL = 1  # codes, table path against float path rounded: measured 0 (grey world,
# shades of grey) and 1 (red compensation: its channel means are float32 on the float path)


@pytest.mark.parametrize("method", ["grey-world", "shades-of-grey", "red-comp"])
def test_the_8bit_table_path_gives_the_float_paths_result(
    rng: np.random.Generator, method: str
) -> None:
    a = (rng.random((60, 80, 3)) * np.array([90, 230, 255])).astype(np.uint8)
    b = (rng.random((60, 80, 3)) * np.array([60, 200, 255])).astype(np.uint8)
    a[:8] = 255  # clipped pixels must stay out of the statistics on both paths
    fa, fb = (x.astype(np.float32) / 255 for x in (a, b))
    fn = {"grey-world": grey_world, "shades-of-grey": shades_of_grey,
          "red-comp": red_compensation}[method]
    for fast, slow in ((fn(a), fn(fa)), *zip(white_balance_pair(a, b, method),
                                             white_balance_pair(fa, fb, method), strict=True)):
        assert fast.dtype == np.uint8
        want = (np.clip(slow, 0, 1) * 255 + 0.5).astype(np.uint8)
        assert np.abs(fast.astype(int) - want).max() <= U8_PATH_TOL
        assert not np.array_equal(fast, a)  # it did balance
    if method == "red-comp":  # blue compensated too (Eq. 5): a second joint table
        fast = red_compensation(a, blue_alpha=0.5)
        want = (np.clip(red_compensation(fa, blue_alpha=0.5), 0, 1) * 255 + 0.5).astype(np.uint8)
        assert np.abs(fast.astype(int) - want).max() <= U8_PATH_TOL
        assert not np.array_equal(fast, red_compensation(a))


@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
def test_grey_world_leaves_an_empty_channel_out_of_the_target(
    rng: np.random.Generator, dtype: type
) -> None:
    # Red and green carry texture, blue is empty (deep water): the gains equalise red and
    # green to their own mean; counting the empty channel would darken them by a third.
    lin = np.zeros((60, 80, 3), np.float32)
    lin[..., 0] = rng.uniform(0.02, 0.2, (60, 80))
    lin[..., 1] = rng.uniform(0.1, 0.6, (60, 80))
    img = linear_to_srgb(lin)
    if dtype == np.uint8:
        img = (img * 255 + 0.5).astype(np.uint8)
    out = grey_world(img)
    to_lin = srgb_to_linear(out.astype(np.float32) / 255 if dtype == np.uint8 else out)
    got = to_lin.reshape(-1, 3).mean(axis=0)
    before = srgb_to_linear(img.astype(np.float32) / 255 if dtype == np.uint8 else img)
    target = before.reshape(-1, 3).mean(axis=0)[:2].mean()
    tol = 5 * MEAN_TOL if dtype == np.uint8 else MEAN_TOL  # 8-bit quantisation
    np.testing.assert_allclose(got[:2], [target, target], atol=tol)
    assert got[2] == 0.0
