"""Image-quality figures: known values, the gain searches, and the no-reference scores'
properties (including that they reward over-saturation)."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.enhance import (
    ciede2000,
    ciede2000_after_diagonal_gain,
    ciede2000_after_gain,
    colour_cast,
    compare_to_reference,
    uciqe,
    uiqm,
)
from sea3d.enhance._image import linear_to_srgb, srgb_to_linear
from sea3d.enhance.metrics import PLIP_GAMMA, _alpha_trimmed_mean
from sea3d.errors import EnhanceError

EXACT = 1e-9
DE_AFTER_GAIN_TOL = 0.05  # CIEDE2000 units: the bounded 1-D search stops at 1e-3 in log2 g
GAIN_REL_TOL = 0.01
# CIELAB of sRGB red (1, 0, 0), D65: L* 53.2408, a* 80.0925, b* 67.2032 (CIE 15 formulas; the
# standard published value, e.g. Lindbloom's calculator).
RED_LAB = (53.2408, 80.0925, 67.2032)


def _random_rgb(rng: np.random.Generator, h: int = 64, w: int = 96) -> np.ndarray:
    return rng.uniform(0.1, 0.9, size=(h, w, 3)).astype(np.float32)


def test_identical_images_score_perfectly(rng: np.random.Generator) -> None:
    img = _random_rgb(rng)
    m = compare_to_reference(img, img)
    assert m.ssim == pytest.approx(1.0, abs=1e-6)
    assert m.ciede2000 == pytest.approx(0.0, abs=1e-6)
    assert m.ciede2000_gain == pytest.approx(0.0, abs=1e-4)  # float32 sRGB round trip
    assert m.gain == pytest.approx(1.0, rel=1e-3)
    assert np.isinf(m.psnr_db)


def test_psnr_of_a_constant_offset_is_known(rng: np.random.Generator) -> None:
    ref = _random_rgb(rng) * 0.8
    m = compare_to_reference(ref + 0.1, ref)
    assert m.psnr_db == pytest.approx(20.0, abs=1e-3)  # 20 log10(1 / 0.1)


def test_exposure_gain_is_found_and_forgiven(rng: np.random.Generator) -> None:
    ref = _random_rgb(rng)
    darker = linear_to_srgb(srgb_to_linear(ref) * np.float32(0.5))
    assert ciede2000(darker, ref) > 5.0
    de, gain = ciede2000_after_gain(darker, ref)
    assert de < DE_AFTER_GAIN_TOL and gain == pytest.approx(2.0, rel=GAIN_REL_TOL)


def test_diagonal_gain_forgives_a_white_balance_but_a_global_gain_does_not(
    rng: np.random.Generator,
) -> None:
    ref = _random_rgb(rng) * 0.7
    tinted = linear_to_srgb(srgb_to_linear(ref) * np.float32([0.5, 1.0, 1.3]))
    de_global, _ = ciede2000_after_gain(tinted, ref)
    de_diag, gains = ciede2000_after_diagonal_gain(tinted, ref)
    assert de_global > 5.0
    assert de_diag < 0.1
    np.testing.assert_allclose(gains, [2.0, 1.0, 1 / 1.3], rtol=0.02)


def test_masks_select_pixels_and_bad_shapes_are_refused(rng: np.random.Generator) -> None:
    ref = _random_rgb(rng)
    out = ref.copy()
    out[:, :10] = 0.0
    mask = np.zeros(ref.shape[:2], dtype=bool)
    mask[:, 20:] = True
    assert ciede2000(out, ref, mask) == pytest.approx(0.0, abs=1e-9)
    assert ciede2000(out, ref) > 1.0
    with pytest.raises(EnhanceError, match="differ"):
        compare_to_reference(ref[:10], ref)
    with pytest.raises(EnhanceError, match="mask"):
        ciede2000(out, ref, mask[:10])
    with pytest.raises(EnhanceError, match="no pixel"):
        ciede2000(out, ref, np.zeros_like(mask))


def test_uciqe_known_values() -> None:
    grey = np.full((32, 32, 3), 0.5, dtype=np.float32)
    assert uciqe(grey).uciqe == pytest.approx(0.0, abs=1e-4)  # grey has a*, b* of ~1e-5
    bw = np.zeros((32, 32, 3), dtype=np.float32)
    bw[:, 16:] = 1.0
    s = uciqe(bw)
    assert s.con_l == pytest.approx(1.0, abs=1e-4) and s.uciqe == pytest.approx(0.2745, abs=1e-4)
    red = np.zeros((8, 8, 3), dtype=np.float32)
    red[..., 0] = 1.0
    L, a, b = RED_LAB
    c = np.hypot(a, b)
    s = uciqe(red)
    assert s.mu_s == pytest.approx(c / np.hypot(c, L), abs=1e-4)
    assert s.uciqe == pytest.approx(0.2576 * c / np.hypot(c, L), abs=1e-4)


def test_alpha_trimmed_mean_drops_ceil_low_and_floor_high() -> None:
    assert _alpha_trimmed_mean(np.arange(1.0, 11.0)) == pytest.approx(5.5, abs=EXACT)
    x = np.concatenate([np.arange(1.0, 10.0), [1000.0]])
    assert _alpha_trimmed_mean(x) == pytest.approx(np.mean(np.arange(2.0, 10.0)), abs=EXACT)
    # K = 15, alpha 0.1: ceil(1.5) = 2 dropped below, floor(1.5) = 1 above.
    y = np.arange(15.0)
    assert _alpha_trimmed_mean(y) == pytest.approx(np.mean(np.arange(2.0, 14.0)), abs=EXACT)


def test_uiqm_known_values() -> None:
    grey = np.full((40, 40, 3), 128, dtype=np.uint8)
    s = uiqm(grey)
    assert (s.uicm, s.uism, s.uiconm, s.uiqm) == pytest.approx((0, 0, 0, 0), abs=EXACT)
    flat = np.zeros((40, 40, 3), dtype=np.uint8)
    flat[:] = (200, 100, 50)
    s = uiqm(flat)
    assert s.uicm == pytest.approx(-0.0268 * np.hypot(100.0, 100.0), abs=1e-6)
    assert s.uiqm == pytest.approx(0.0282 * s.uicm, abs=1e-9)


def test_uiconm_of_uniform_blocks_is_the_plip_entropy_of_one_block() -> None:
    # Every 8x8 block spans intensities 50..150: r = (150 (-) 50) / (150 (+) 50) in PLIP.
    img = np.full((32, 32, 3), 50, dtype=np.uint8)
    img[::8, ::8] = 150
    g = PLIP_GAMMA
    r = (g * (150 - 50) / (g - 50)) / (150 + 50 - 150 * 50 / g)
    assert uiqm(img, block_px=8).uiconm == pytest.approx(-r * np.log(r), abs=1e-6)  # float32 /255


def test_no_reference_scores_reward_over_saturation(rng: np.random.Generator) -> None:
    """Why UIQM and UCIQE are never used alone: pushing chroma far past any truth raises them."""
    base = np.clip(0.45 + 0.1 * (_random_rgb(rng) - 0.5), 0, 1)
    grey_part = base.mean(axis=2, keepdims=True)
    oversat = np.clip(grey_part + 4.0 * (base - grey_part), 0, 1).astype(np.float32)
    assert uciqe(oversat).uciqe > uciqe(base).uciqe
    assert uiqm(oversat).uicm > uiqm(base).uicm


def test_colour_cast_is_zero_for_grey_and_large_for_blue() -> None:
    grey = np.full((8, 8, 3), 0.4, dtype=np.float32)
    blue = np.zeros((8, 8, 3), dtype=np.float32)
    blue[..., 2] = 0.6
    blue[..., 1] = 0.3
    assert colour_cast(grey) == pytest.approx(0.0, abs=1e-2)  # D65 white point rounding
    assert colour_cast(blue) > 30.0


# Sharma, Wu and Dalal (Color Res. Appl. 30(1), 2005), test data pairs 25 and 31 (inside the
# sRGB gamut; pair 1 is not): CIEDE2000 1.2644 and 2.0373. The images below are the sRGB
# encodings of those colours (scikit-image lab2rgb), so the whole chain (sRGB -> D65 CIELAB ->
# CIEDE2000) must give the published values.
SHARMA_PAIRS = (
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
    ((22.7233, 20.0904, -46.6940), (23.0331, 14.9730, -42.5619), 2.0373),
)
SHARMA_FLOAT_TOL = 1e-3  # float64 sRGB in; the table has 4 decimals
SSIM_TOL = 1e-6


@pytest.mark.parametrize(("lab1", "lab2", "want"), SHARMA_PAIRS)
def test_ciede2000_of_sharmas_pairs_through_srgb(
    lab1: tuple[float, ...], lab2: tuple[float, ...], want: float
) -> None:
    from skimage.color import lab2rgb

    rgb1 = lab2rgb(np.array([[lab1]]))
    rgb2 = lab2rgb(np.array([[lab2]]))
    assert 0.0 < rgb1.min() and rgb1.max() < 1.0 and 0.0 < rgb2.min() and rgb2.max() < 1.0
    img1 = np.tile(rgb1, (4, 4, 1)).astype(np.float64)
    img2 = np.tile(rgb2, (4, 4, 1)).astype(np.float64)
    assert ciede2000(img1, img2) == pytest.approx(want, abs=SHARMA_FLOAT_TOL)
    # A channel-order mix-up in the chain moves it far away.
    assert abs(ciede2000(img1[..., ::-1], img2[..., ::-1]) - want) > 0.2


def test_ssim_uses_data_range_one_whatever_the_dtype(rng: np.random.Generator) -> None:
    from skimage.metrics import structural_similarity

    ref = (rng.random((48, 64, 3)) * 80 + 80).astype(np.uint8)  # low contrast: noise shows
    noisy = np.clip(ref.astype(int) + rng.normal(0, 20, ref.shape), 0, 255).astype(np.uint8)
    # Our SSIM is the mean of the whole SSIM map (so that a mask can select pixels);
    # scikit-image's scalar crops the 3-pixel border first.
    _, smap = structural_similarity(ref / 255.0, noisy / 255.0, data_range=1.0, channel_axis=2,
                                    full=True)
    want = float(np.mean(smap))
    assert 0.5 < want < 0.9  # the noise matters: a wrong data range (255) gives 0.9999
    got_u8 = compare_to_reference(noisy, ref).ssim
    got_f = compare_to_reference(noisy.astype(np.float32) / 255, ref.astype(np.float32) / 255)
    assert got_u8 == pytest.approx(want, abs=SSIM_TOL)
    assert got_f.ssim == pytest.approx(want, abs=1e-4)  # float32 input


def _uiqm_rederived(img_u8: np.ndarray, block: int = 8) -> tuple[float, float, float, float]:
    """UIQM written again from Panetta, Gao and Agaian, IEEE J. Oceanic Eng. 41(3), 2016
    (Eqs. 1-13), with plain loops and its constants typed here (not imported): an independent
    re-derivation, no published per-image value having been found. The choices of
    :mod:`sea3d.enhance.metrics` where the paper is open are followed (EME blocks with +1,
    PLIP block sum, ``-r log r``)."""
    x = img_u8.astype(np.float64)
    h, w = x.shape[:2]
    r, g, b = x[..., 0].ravel(), x[..., 1].ravel(), x[..., 2].ravel()

    def trimmed(v: np.ndarray) -> float:
        s = sorted(v.tolist())
        k = len(s)
        lo, hi = int(np.ceil(0.1 * k)), int(np.floor(0.1 * k))
        kept = s[lo : k - hi]
        return sum(kept) / len(kept)

    rg, yb = r - g, (r + g) / 2 - b
    m_rg, m_yb = trimmed(rg), trimmed(yb)
    s_rg = sum((v - m_rg) ** 2 for v in rg) / rg.size
    s_yb = sum((v - m_yb) ** 2 for v in yb) / yb.size
    uicm = -0.0268 * np.sqrt(m_rg**2 + m_yb**2) + 0.1586 * np.sqrt(s_rg + s_yb)

    def sobel_mag(ch: np.ndarray) -> np.ndarray:
        p = np.pad(ch, 1, mode="edge")
        gx = np.zeros_like(ch)
        gy = np.zeros_like(ch)
        kx = [[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]]
        for dy in range(3):
            for dx in range(3):
                win = p[dy : dy + h, dx : dx + w]
                gx += kx[dy][dx] * win
                gy += kx[dx][dy] * win
        return np.sqrt(gx**2 + gy**2)

    def eme(v: np.ndarray) -> float:
        k2, k1 = h // block, w // block
        tot = 0.0
        for i in range(k2):
            for j in range(k1):
                blk = v[i * block : (i + 1) * block, j * block : (j + 1) * block]
                tot += np.log((blk.max() + 1) / (blk.min() + 1))
        return 2.0 / (k1 * k2) * tot

    uism = sum(lam * eme(sobel_mag(x[..., c]) * x[..., c])
               for c, lam in enumerate((0.299, 0.587, 0.114)))
    gam = 1026.0
    inten = x.mean(axis=2)
    prod_log = 0.0
    n = 0
    for i in range(h // block):
        for j in range(w // block):
            blk = inten[i * block : (i + 1) * block, j * block : (j + 1) * block]
            mx, mn = blk.max(), blk.min()
            den = mx + mn - mx * mn / gam
            ratio = (gam * (mx - mn) / (gam - mn)) / den if den > 0 else 0.0
            e = -ratio * np.log(ratio) if ratio > 0 else 0.0
            prod_log += np.log(1 - e / gam)
            n += 1
    uiconm = gam - gam * np.exp(prod_log / n)
    return (0.0282 * uicm + 0.2953 * uism + 3.5753 * uiconm, uicm, uism, uiconm)


def test_uiqm_of_a_textured_image_matches_an_independent_rederivation(
    rng: np.random.Generator,
) -> None:
    # Texture, edges and contrast in every block: every term is far from zero, so a wrong
    # weight of any of the three shows.
    img = (rng.uniform(0, 1, (48, 64, 3)) ** 2 * np.array([255, 180, 120])).astype(np.uint8)
    img[:, ::7] = (240, 60, 20)
    want = _uiqm_rederived(img)
    s = uiqm(img)
    assert abs(want[1]) > 1 and want[2] > 1 and want[3] > 0.05
    np.testing.assert_allclose((s.uiqm, s.uicm, s.uism, s.uiconm), want, rtol=1e-6)
