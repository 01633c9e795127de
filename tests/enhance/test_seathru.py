"""Sea-thru: recovery of known water on synthetic images that obey the formation model, hole
handling, bad input, and the range helpers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sea3d.enhance import (
    SeathruConfig,
    apply_seathru,
    ciede2000_after_diagonal_gain,
    depth_to_range,
    fit_seathru,
    range_from_points,
    seathru,
)
from sea3d.enhance._image import linear_to_srgb
from sea3d.errors import EnhanceError
from sea3d.geometry.pinhole import PinholeCamera

BETA_D = np.array([0.55, 0.20, 0.30])  # 1/m, coastal-like
BETA_B = np.array([0.45, 0.25, 0.30])
B_INF = np.array([0.05, 0.30, 0.25])
BACKSCATTER_TOL = 0.02  # linear units, at every range of the scene
RANGE_REL_TOL = 1e-6


def _scene(rng: np.random.Generator, h: int = 120, w: int = 160) -> tuple[np.ndarray, ...]:
    """Linear J (mean albedo 0.5, with black pixels at every range: the dark-pixel prior holds),
    a floor-like range map from 1 m (bottom) to 6 m (top), and the underwater image."""
    J = rng.uniform(0.1, 0.9, size=(h, w, 3)).astype(np.float32)
    J *= np.float32([1.0, 0.9, 0.8])  # coloured albedo: grey world is not right here
    J[rng.random((h, w)) < 0.03] = 0.0
    z = np.linspace(6.0, 1.0, h, dtype=np.float32)[:, None].repeat(w, axis=1)
    zz = z[..., None].astype(np.float64)
    I = J * np.exp(-BETA_D * zz) + B_INF * (1 - np.exp(-BETA_B * zz))
    return J, z, I.astype(np.float32)


def _linear(**kw: object) -> SeathruConfig:
    """Linear images; no denoising (the synthetic albedo is per-pixel noise by design)."""
    return SeathruConfig(encoding="linear", **{"denoise": False, **kw})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def scene() -> tuple[np.ndarray, ...]:
    return _scene(np.random.default_rng(0))


@pytest.mark.parametrize("fit", ["eq10", "envelope"])
def test_backscatter_of_known_water_is_recovered(scene: tuple[np.ndarray, ...], fit: str) -> None:
    _J, z, I = scene
    model = fit_seathru([(I, z)], _linear(backscatter_fit=fit, attenuation="none"))
    zs = np.linspace(1.0, 6.0, 11)
    truth = B_INF * (1 - np.exp(-BETA_B * zs[:, None]))
    assert np.abs(model.backscatter_rgb(zs) - truth).max() < BACKSCATTER_TOL


def test_restoration_removes_the_water(scene: tuple[np.ndarray, ...]) -> None:
    J, z, I = scene
    ref = linear_to_srgb(J)
    res = seathru(I, z, _linear(white_balance="none", exposure="none"))
    out = linear_to_srgb(res.image)
    before, _ = ciede2000_after_diagonal_gain(linear_to_srgb(I), ref)
    after, _ = ciede2000_after_diagonal_gain(out, ref)
    assert res.status == "ok"
    assert after < 0.35 * before
    # Each stage matters: without the attenuation stage far pixels stay dark and blue.
    no_att = seathru(I, z, _linear(white_balance="none", exposure="none", attenuation="none"))
    partial, _ = ciede2000_after_diagonal_gain(linear_to_srgb(no_att.image), ref)
    assert after < 0.7 * partial


@pytest.mark.parametrize("attenuation", ["fit", "illuminant"])
def test_a_model_fitted_on_one_image_restores_another(
    scene: tuple[np.ndarray, ...], attenuation: str
) -> None:
    _J, z, I = scene
    cfg = _linear(attenuation=attenuation)
    model = fit_seathru([(I, z)], cfg)
    a = apply_seathru(I, z, model, cfg).image
    np.testing.assert_allclose(a, seathru(I, z, cfg).image, atol=1e-6)
    shifted = apply_seathru(I[:, 5:], z[:, 5:], model, cfg).image  # "the right image"
    if attenuation == "fit":  # a function of range only: the same pixels exactly
        np.testing.assert_allclose(shifted, a[:, 5:], atol=1e-6)
    else:  # the illuminant map is the image's own: close, not equal
        assert np.median(np.abs(shifted - a[:, 5:])) < 0.01


def test_holes_are_inpainted_not_treated_as_far(scene: tuple[np.ndarray, ...]) -> None:
    _J, z, I = scene
    cfg = _linear()
    full = seathru(I, z, cfg)
    holed = z.copy()
    holed[40:70, 50:90] = np.nan
    res = seathru(I, holed, cfg)
    hole = np.isnan(holed)
    assert res.range_filled[hole].all() and not res.range_filled[~hole].any()
    assert np.all(np.isfinite(res.image))
    err_inpaint = np.abs(res.image[hole] - full.image[hole]).mean()
    # The failure the issue warns about: holes read as "far" (here 30 m) wreck those pixels.
    far = np.where(hole, np.float32(30.0), z)
    err_far = np.abs(apply_seathru(I, far, full.model, cfg).image[hole] - full.image[hole]).mean()
    assert err_inpaint < 0.2 * err_far
    masked = seathru(I, holed, dataclasses.replace(cfg, holes="mask"))
    assert not masked.restored[hole].any()
    gains = np.asarray(masked.model.wb_gains) * masked.model.exposure_gain
    np.testing.assert_allclose(masked.image[hole], np.clip(I[hole] * gains, 0, 1), atol=1e-5)


def test_srgb_uint8_input_comes_back_uint8(scene: tuple[np.ndarray, ...]) -> None:
    _J, z, I = scene
    img8 = (linear_to_srgb(I) * 255 + 0.5).astype(np.uint8)
    out = seathru(img8, z)
    assert out.image.dtype == np.uint8 and out.image.shape == img8.shape
    assert out.image.mean() > 20  # not black


def test_bad_input_is_refused_with_a_clear_message(scene: tuple[np.ndarray, ...]) -> None:
    _J, z, I = scene
    with pytest.raises(EnhanceError, match="160x120 but image is 80x60"):
        seathru(I[::2, ::2], z)
    with pytest.raises(EnhanceError, match="no valid pixel"):
        seathru(I, np.full_like(z, np.nan))
    with pytest.raises(EnhanceError, match="only"):
        sparse = np.full_like(z, np.nan)
        sparse[0, :5] = 2.0
        seathru(I, sparse)
    with pytest.raises(EnhanceError, match="RGB"):
        seathru(I[..., 0], z)
    with pytest.raises(EnhanceError, match="saturated"):
        seathru(np.full_like(I, 1.0), z)


def test_a_flat_grey_view_does_not_come_out_black(scene: tuple[np.ndarray, ...]) -> None:
    _J, z, _I = scene
    flat = np.full((*z.shape, 3), 0.3, dtype=np.float32)
    res = seathru(flat, z, _linear())
    assert np.all(np.isfinite(res.image))
    assert res.image.mean() > 0.05
    # Nothing to restore in a flat view: the result says it fell back, and why.
    assert res.status == "fallback-grey-world"
    assert res.notes == ("restoration came out empty; fell back to grey world",)


def test_depth_to_range_and_back_from_points() -> None:
    z = np.full((5, 7), 2.0, dtype=np.float32)
    z[0, 0] = np.nan
    r = depth_to_range(z, 10.0, 10.0, 3.0, 2.0)
    assert np.isnan(r[0, 0])
    assert r[4, 6] == pytest.approx(2.0 * np.sqrt(1 + 0.3**2 + 0.2**2), rel=RANGE_REL_TOL)
    assert r[2, 3] == pytest.approx(2.0, rel=RANGE_REL_TOL)
    cam = PinholeCamera(fx=10.0, fy=10.0, cx=3.0, cy=2.0, width=7, height=5)
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.3, 0.2, 1.0]])
    rm = range_from_points(pts, cam)
    assert rm[2, 3] == pytest.approx(2.0)  # the nearer of two points on one pixel wins
    assert rm[4, 6] == pytest.approx(np.linalg.norm(pts[2]))
    assert np.isnan(rm).sum() == 5 * 7 - 2


def test_denoising_removes_amplified_noise_and_keeps_the_colour(
    scene: tuple[np.ndarray, ...],
) -> None:
    _J, z, _I = scene
    rng = np.random.default_rng(5)
    h, w = z.shape
    flat = np.full((h, w, 3), 0.5, dtype=np.float32)
    flat[::7, ::7] = 0.0  # a few dark pixels at every range for the backscatter
    zz = z[..., None].astype(np.float64)
    clean = flat * np.exp(-BETA_D * zz) + B_INF * (1 - np.exp(-BETA_B * zz))
    noisy = np.clip(clean + rng.normal(0, 0.004, clean.shape), 0, 1).astype(np.float32)
    far = z > 4.0
    off = seathru(noisy, z, _linear(denoise=False)).image
    on = seathru(noisy, z, _linear(denoise=True)).image
    # Far pixels were amplified most: their spread drops, their mean colour stays.
    assert on[far].std(axis=0).mean() < 0.7 * off[far].std(axis=0).mean()
    np.testing.assert_allclose(on[far].mean(axis=0), off[far].mean(axis=0), atol=0.02)


@pytest.mark.parametrize("attenuation", ["illuminant", "water-model"])
def test_one_frame_and_the_same_frame_twice_are_the_same_fit(
    scene: tuple[np.ndarray, ...], attenuation: str
) -> None:
    # Every stage pools the frames' samples: the same frame twice holds the same water (the
    # water model subsamples each frame at random, so its parameters agree to 0.01, not
    # exactly).
    _J, z, I = scene
    cfg = SeathruConfig(attenuation=attenuation, encoding="linear")  # type: ignore[arg-type]
    once = fit_seathru([(I, z)], cfg)
    twice = fit_seathru([(I, z), (I, z)], cfg)
    np.testing.assert_allclose(twice.wb_gains, once.wb_gains, atol=0.01)
    assert twice.exposure_gain == pytest.approx(once.exposure_gain, abs=0.01)
    a = apply_seathru(I, z, once, cfg).image
    b = apply_seathru(I, z, twice, cfg).image
    assert float(np.median(np.abs(a - b))) < 0.01


def test_a_fit_needs_a_frame_and_refuses_a_model_of_the_other_kind(
    scene: tuple[np.ndarray, ...],
) -> None:
    _J, z, I = scene
    with pytest.raises(EnhanceError, match="at least one"):
        fit_seathru([], SeathruConfig())
    per_image = fit_seathru([(I, z)], _linear())
    with pytest.raises(EnhanceError, match="per-image attenuation"):
        apply_seathru(I, z, per_image, SeathruConfig(attenuation="water-model"))
