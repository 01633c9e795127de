"""One config for every Sea-thru (:class:`sea3d.enhance.config.SeathruConfig`): the water model
and the per-image stages read the same object, each mode with its own measured defaults, and
settings that a mode cannot honour are refused when the config is made."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.enhance import SeathruConfig, WaterFitConfig, enhance_image, fit_water_model, restore
from sea3d.errors import EnhanceError


def _frame(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    h, w = 60, 80
    z = np.linspace(1.0, 5.0, h, dtype=np.float32)[:, None] * np.ones((1, w), np.float32)
    albedo = np.kron(rng.uniform(0.1, 0.7, (h // 4, w // 4, 3)), np.ones((4, 4, 1)))
    lin = albedo * np.exp(-np.array([0.5, 0.15, 0.1]) * z[..., None]) + np.array(
        [0.05, 0.2, 0.25]) * (1.0 - np.exp(-0.4 * z[..., None]))
    img = (np.clip(lin, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    z[:6, :10] = np.nan
    return img, z


def test_each_attenuation_mode_gets_its_own_defaults_unless_given() -> None:
    water = SeathruConfig(attenuation="water-model")
    per_image = SeathruConfig(attenuation="illuminant")
    assert (water.range_bins, water.work_max_side_px, water.max_restore_gain) == (12, 240, 20.0)
    assert (per_image.range_bins, per_image.work_max_side_px,
            per_image.max_restore_gain) == (10, 400, 30.0)
    assert SeathruConfig(attenuation="water-model", range_bins=7).range_bins == 7
    assert WaterFitConfig() == water


def test_settings_a_mode_cannot_honour_are_refused() -> None:
    with pytest.raises(EnhanceError, match="always fits backscatter"):
        SeathruConfig(attenuation="water-model", backscatter=False)
    with pytest.raises(EnhanceError, match="needs attenuation 'water-model'"):
        SeathruConfig(attenuation="illuminant", white_balance="locus")
    with pytest.raises(EnhanceError, match="range_bins must be >= 3"):
        SeathruConfig(attenuation="water-model", range_bins=2)
    with pytest.raises(EnhanceError, match="needs attenuation 'water-model'"):
        fit_water_model([_frame(np.random.default_rng(0))], SeathruConfig())


def test_the_water_model_config_given_to_enhance_image_is_the_one_that_fits_and_restores() -> None:
    img, z = _frame(np.random.default_rng(0))
    cfg = SeathruConfig(attenuation="water-model", holes="mask", white_balance="none")
    out = enhance_image(img, "seathru", range_m=z, seathru_config=cfg)
    model = fit_water_model([(img, z)], cfg)
    assert out.water_model == model
    np.testing.assert_array_equal(out.images[0], restore(img, z, model, cfg).image)
    default = enhance_image(img, "seathru", range_m=z)
    assert default.water_model != model  # the config changed the fit (no white balance)
