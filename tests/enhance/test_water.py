"""One water model per dive (:mod:`sea3d.enhance.water`): the fitted coefficients against the
simulator's known ones, restoration in every fallback step, and bad input.

Frames are textured albedo on tilted planes (1-6 m) rendered through the simulator's own
formation function (:meth:`sea3d.sim.Imaging.through_water`, coastal preset) and encoded to
8-bit sRGB: the coefficients that made them are known exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.enhance import SeathruConfig, ciede2000_after_gain, seathru
from sea3d.enhance._image import srgb_to_linear
from sea3d.enhance.water import (
    LIMITS,
    WaterFitConfig,
    WaterModel,
    fit_water_model,
    restore,
)
from sea3d.errors import EnhanceError
from sea3d.sim import Imaging
from sea3d.sim.optics import WATER_PRESETS, encode_srgb

H, W = 90, 120
# Fitted beta_D within 0.06 1/m of the preset per channel (measured 0.00-0.03): the coastal
# preset's channels differ by 0.10-0.38 1/m, so any swap of channels fails.
BETA_D_TOL_PER_M = 0.06
# Backscatter B(z) within 0.02 (linear) of the preset's at 1.5-5 m (B_inf and beta_B alone
# trade against each other over a finite span; their curve is what the images determine).
BACKSCATTER_TOL = 0.02
# Restored frames against the albedo, CIEDE2000 after one exposure gain: measured 1-2 with
# the fitted model; the raw frames are at 15-25.
RESTORED_DE_MAX = 4.0


def _frames(rng: np.random.Generator, n: int = 6, near_m: float = 1.0, far_m: float = 6.0,
            water: str = "coastal") -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    imaging = Imaging.underwater(water)
    frames, clean = [], []
    for k in range(n):
        # Albedo independent of range: grey-ish texture with coloured patches.
        base = rng.uniform(0.05, 0.6, (H // 3, W // 3, 3))
        albedo = np.kron(base, np.ones((3, 3, 1))) * rng.uniform(0.85, 1.0, (H, W, 1))
        t = k / max(n - 1, 1)
        z0 = near_m + 0.5 * t * (far_m - near_m)
        ramp = np.linspace(0.0, 1.0, H)[:, None] * np.ones((1, W))
        range_m = (z0 + ramp * (far_m - near_m) * 0.5).astype(np.float32)
        lin = imaging.through_water(albedo.reshape(-1, 3), range_m.ravel()).reshape(H, W, 3)
        frames.append((encode_srgb(lin), range_m))
        clean.append(encode_srgb(albedo.astype(np.float32)))
    return frames, clean


@pytest.fixture(scope="module")
def coastal() -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel]:
    frames, clean = _frames(np.random.default_rng(0))
    return frames, clean, fit_water_model(frames)


def test_fitted_attenuation_matches_the_simulators_coefficients_channel_by_channel(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    model = coastal[2]
    want = WATER_PRESETS["coastal"]
    assert model.status == "ok" and model.checks == ()
    got = np.asarray(model.beta_D_per_m)
    np.testing.assert_allclose(got, want.beta_D_per_m, atol=BETA_D_TOL_PER_M)
    # Channel order matters: the reversed order is far outside the tolerance.
    assert np.max(np.abs(got[::-1] - np.asarray(want.beta_D_per_m))) > 2 * BETA_D_TOL_PER_M
    z = np.array([1.5, 3.0, 5.0])[:, None]

    def curve(b_inf: tuple[float, ...], beta_b: tuple[float, ...]) -> np.ndarray:
        return np.asarray(b_inf) * (1.0 - np.exp(-np.asarray(beta_b) * z))

    np.testing.assert_allclose(curve(model.B_inf_rgb, model.beta_B_per_m),
                               curve(want.B_inf_rgb, want.beta_B_per_m), atol=BACKSCATTER_TOL)


def test_restoration_with_the_fitted_model_recovers_the_albedo(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    frames, clean, model = coastal
    for (img, z), ref in zip(frames, clean, strict=True):
        res = restore(img, z, model)
        assert res.status == "ok" and res.image.dtype == np.uint8
        raw_de = ciede2000_after_gain(img, ref)[0]
        de = ciede2000_after_gain(res.image, ref)[0]
        assert de < RESTORED_DE_MAX < raw_de, (de, raw_de)


def test_a_reversed_channel_order_restores_worse(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    frames, clean, model = coastal
    rev = WaterModel(B_inf_rgb=model.B_inf_rgb, beta_B_per_m=model.beta_B_per_m,
                     beta_D_per_m=model.beta_D_per_m[::-1])
    img, z = frames[-1]
    assert ciede2000_after_gain(restore(img, z, rev).image, clean[-1])[0] > 2 * RESTORED_DE_MAX


def test_a_narrow_range_span_falls_back_to_backscatter_and_white_balance() -> None:
    frames, _clean = _frames(np.random.default_rng(1), n=3, near_m=3.0, far_m=3.3)
    model = fit_water_model(frames)
    assert model.status == "attenuation-unidentified"
    assert any(c.startswith("beta_D") for c in model.checks)
    assert model.beta_D_per_m == (0.0, 0.0, 0.0)
    res = restore(*frames[0], model)
    assert res.status == "attenuation-unidentified"
    out = res.image.astype(np.float64)
    # White-balanced: the channel means are within 15 % of each other, not black.
    m = out.reshape(-1, 3).mean(axis=0)
    assert m.min() > 40 and m.max() / m.min() < 1.15


def test_holes_in_range_are_filled_and_all_holes_give_a_white_balance_with_a_status(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    frames, clean, model = coastal
    img, z = frames[2]
    holey = z.copy()
    holey[20:50, 30:80] = np.nan
    res = restore(img, holey, model)
    assert res.status == "ok"
    assert ciede2000_after_gain(res.image, clean[2])[0] < RESTORED_DE_MAX
    none = restore(img, np.full_like(z, np.nan), model)
    assert none.status == "no-range" and none.image.mean() > 20
    assert np.all(np.isfinite(none.image))


def test_a_water_model_that_cannot_be_fitted_names_the_parameter_and_why() -> None:
    frames, _ = _frames(np.random.default_rng(2), n=2)
    with pytest.raises(EnhanceError, match=r"cannot fit B_inf or beta_D: none of the 2 frames"):
        fit_water_model([(img, np.full_like(z, np.nan)) for img, z in frames])
    with pytest.raises(EnhanceError, match=r"cannot fit B_inf or beta_D"):
        fit_water_model([(np.full_like(img, 255), z) for img, z in frames])
    with pytest.raises(EnhanceError, match="at least one"):
        fit_water_model([])


def test_a_range_map_from_another_grid_is_refused(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    frames, _clean, model = coastal
    img, z = frames[0]
    with pytest.raises(EnhanceError, match="pixel grid"):
        restore(img, z[:, :-8], model)
    with pytest.raises(EnhanceError, match="pixel grid"):
        fit_water_model([(img, z.T)])


def test_grey_and_saturated_images_never_come_back_black_nan_or_clipped_as_ok(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    model = coastal[2]
    z = np.full((H, W), 3.0, np.float32)
    grey = np.full((H, W, 3), 128, np.uint8)
    res = restore(grey, z, model)
    assert res.image.mean() > 20 and np.all(np.isfinite(res.image))
    # Restoring a mid-grey wall at 3 m with the coastal model clips it: refused, and the
    # white-balanced input comes back instead, unclipped.
    assert res.status == "refused-saturated"
    assert float(np.mean(res.image.max(axis=2) == 255)) < 0.5
    sat = np.full((H, W, 3), 255, np.uint8)
    out = restore(sat, z, model)
    assert out.status.startswith("refused")
    # A model whose backscatter swallows the image gives it back white-balanced, not black.
    greedy = WaterModel(B_inf_rgb=(0.9, 0.9, 0.9), beta_B_per_m=(5.0, 5.0, 5.0),
                        beta_D_per_m=(0.1, 0.1, 0.1))
    blk = restore(grey, z, greedy)
    assert blk.status == "refused-black" and blk.image.mean() > 20


def test_plausibility_limits_are_physical() -> None:
    assert LIMITS["beta_D_per_m"][0] == 0.0 and LIMITS["beta_D_per_m"][1] <= 5.0
    with pytest.raises(EnhanceError):
        WaterFitConfig(range_bins=2)
    with pytest.raises(EnhanceError):
        WaterFitConfig(white_balance="max-rgb")  # type: ignore[arg-type]


def test_one_channel_images_are_refused_in_one_line(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    frames, _clean, model = coastal
    img, z = frames[0]
    with pytest.raises(EnhanceError, match="RGB"):
        restore(img[..., 1], z, model)
    with pytest.raises(EnhanceError, match="RGB"):
        fit_water_model([(img[..., 1], z)])


# The per-image Sea-thru in every attenuation mode must leave less than this share of the raw
# frame's CIEDE2000 (after one gain) against the albedo: measured 0.73 (fit, illuminant),
# 0.74 (none), 0.79 (fit-scaled) of the raw 22.8; an attenuation stage that did nothing, or
# a restoration that returned its input, stays at 1.
SEATHRU_KEPT_MAX = 0.85


@pytest.fixture(scope="module")
def one_frame() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    frames, clean = _frames(np.random.default_rng(0), n=4)
    img, z = frames[-1]
    return img, z, clean[-1]


@pytest.mark.parametrize("mode", ["fit", "fit-scaled", "illuminant", "none"])
def test_seathru_restores_in_every_attenuation_mode(
    mode: str, one_frame: tuple[np.ndarray, np.ndarray, np.ndarray]
) -> None:
    img, z, ref = one_frame
    res = seathru(img, z, SeathruConfig(attenuation=mode))  # type: ignore[arg-type]
    assert res.status == "ok" and res.model.attenuation_kind != "" and res.image.mean() > 20
    raw = ciede2000_after_gain(img, ref)[0]
    got = ciede2000_after_gain(res.image, ref)[0]
    assert got < SEATHRU_KEPT_MAX * raw, (mode, got, raw)


def test_fitted_attenuation_keeps_the_channel_order_of_the_water(
    one_frame: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> None:
    img, z, _ref = one_frame
    model = seathru(img, z, SeathruConfig(attenuation="fit")).model
    beta = model.beta_d_per_m(np.array([3.0]))[0]
    want = np.asarray(WATER_PRESETS["coastal"].beta_D_per_m)  # R 0.60 > B 0.32 > G 0.22
    assert list(np.argsort(beta)) == list(np.argsort(want)), beta


# ----------------------------------------------------------------- plausibility, fallbacks


def _frames_in(water: object, rng: np.random.Generator, n: int = 6
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """As :func:`_frames`, through a planted water (a :class:`sea3d.sim.optics.Water`)."""
    import dataclasses

    imaging = dataclasses.replace(Imaging.underwater("coastal"), water=water)
    frames = []
    for k in range(n):
        base = rng.uniform(0.05, 0.6, (H // 3, W // 3, 3))
        albedo = np.kron(base, np.ones((3, 3, 1))) * rng.uniform(0.85, 1.0, (H, W, 1))
        z0 = 1.0 + 2.5 * k / max(n - 1, 1)
        ramp = np.linspace(0.0, 1.0, H)[:, None] * np.ones((1, W))
        range_m = (z0 + ramp * 2.5).astype(np.float32)
        lin = imaging.through_water(albedo.reshape(-1, 3), range_m.ravel()).reshape(H, W, 3)
        frames.append((encode_srgb(lin), range_m))
    return frames


def _not_empty(img: np.ndarray) -> None:
    """Never a black, NaN or saturated image passed on as a result."""
    y = img.astype(np.float64).mean(axis=2)
    assert np.isfinite(y).all()
    assert np.mean(y < 1) < 0.5 and np.mean(img.max(axis=2) >= 255) < 0.5


def test_a_beta_d_below_any_natural_water_is_named_and_raised_to_the_floor() -> None:
    from sea3d.enhance.water import PURE_WATER_KD_PER_M
    from sea3d.sim.optics import Water

    # Red attenuated at 0.05 1/m: less than pure water absorbs at 600 nm (0.244): no water
    # does that, so a fit that finds it (here: the truth, planted) must not pass as ok.
    truth = (0.05, 0.20, 0.29)
    planted = Water(name="planted", beta_D_per_m=truth,
                    beta_B_per_m=(0.45, 0.25, 0.30), B_inf_rgb=(0.04, 0.20, 0.17))
    frames = _frames_in(planted, np.random.default_rng(3))
    floor_cfg = WaterFitConfig(below_floor="floor")
    model = fit_water_model(frames, floor_cfg)
    assert model.status == "attenuation-floor" and model.has_attenuation
    floor = 0.5 * PURE_WATER_KD_PER_M[0]
    named = [c for c in model.checks if c.startswith("beta_D_per_m[R]")]
    assert named and "pure water" in named[0] and f"{floor:.3f}" in named[0], model.checks
    # The red channel raised to the floor; green and blue, plausible, kept as fitted.
    assert model.beta_D_per_m[0] == pytest.approx(floor)
    np.testing.assert_allclose(model.beta_D_per_m[1:], truth[1:], atol=BETA_D_TOL_PER_M)
    for img, z in frames:
        res = restore(img, z, model, floor_cfg)
        assert res.status == "attenuation-floor"
        _not_empty(res.image)
    # Range in other units: no floor in 1/m applies; the same fit is ok there.
    assert fit_water_model(frames, WaterFitConfig(metric_range=False)).status == "ok"


def test_by_default_a_beta_d_below_any_natural_water_inverts_nothing_and_only_balances() -> None:
    from sea3d.enhance.water import PURE_WATER_KD_PER_M
    from sea3d.sim.optics import Water

    # The same planted red 0.05 1/m: by default the fit is taken as unable to tell the
    # direct signal from the backscatter, so neither is used: the frame is white-balanced.
    planted = Water(name="planted", beta_D_per_m=(0.05, 0.20, 0.29),
                    beta_B_per_m=(0.45, 0.25, 0.30), B_inf_rgb=(0.04, 0.20, 0.17))
    frames = _frames_in(planted, np.random.default_rng(3))
    model = fit_water_model(frames)
    assert model.status == "backscatter-unidentified"
    assert not model.has_attenuation and not model.has_backscatter
    assert model.beta_D_per_m == (0.0, 0.0, 0.0) and model.B_inf_rgb == (0.0, 0.0, 0.0)
    floor = 0.5 * PURE_WATER_KD_PER_M[0]
    named = [c for c in model.checks if c.startswith("beta_D_per_m[R]")]
    assert named and f"{floor:.3f}" in named[0], model.checks
    assert any("not inverted" in c for c in model.checks), model.checks
    img, z = frames[0]
    res = restore(img, z, model)
    assert res.status == "backscatter-unidentified"
    _not_empty(res.image)
    # White balance only: every pixel is the input times the same three gains (to 8-bit
    # rounding), whatever its range; an inversion would scale near and far pixels apart.
    lin_in = srgb_to_linear(img.astype(np.float32) / 255.0)
    lin_out = srgb_to_linear(res.image.astype(np.float32) / 255.0)
    ok = (lin_in > 0.05) & (lin_out < 0.95)
    scale = np.asarray(model.wb_gains) * model.exposure_gain
    np.testing.assert_allclose(lin_out[ok], (lin_in * scale)[ok], rtol=0.03, atol=2e-3)


def test_a_beta_d_at_its_upper_limit_drops_the_attenuation_and_keeps_the_backscatter(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sea3d.enhance import water

    # Planted: the blue channel's fit runs into beta_D's upper limit (5 1/m). Not a floor to
    # raise to, so attenuation is not used; the backscatter fitted with it is kept.
    real = water._fit_channel
    calls = []

    def blue_at_limit(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(1)
        b_inf, beta_b, beta_d, rms = real(*args, **kwargs)
        return (b_inf, beta_b, 5.0, rms) if len(calls) % 3 == 0 else (b_inf, beta_b, beta_d, rms)

    monkeypatch.setattr(water, "_fit_channel", blue_at_limit)
    frames = coastal[0]
    model = fit_water_model(frames)
    assert model.status == "attenuation-unidentified" and model.beta_D_per_m == (0, 0, 0)
    assert any(c.startswith("beta_D_per_m[B]") and "upper limit" in c for c in model.checks)
    assert "the backscatter fitted with it kept" in model.checks[-1]
    assert model.has_backscatter and model.B_inf_rgb == pytest.approx(coastal[2].B_inf_rgb)
    for img, z in frames[:2]:
        res = restore(img, z, model)
        assert res.status == "attenuation-unidentified"
        _not_empty(res.image)


def test_a_veiling_light_at_its_limit_is_reported_by_name() -> None:
    from sea3d.sim.optics import Water

    # B_inf 1.2 in green: above the 0.95 limit, so the fit runs into the bound. That is
    # reported by name; the curve B(z) over the fitted span is still what the frames give,
    # so the attenuation stays fitted (within the tolerance of the coastal test).
    truth = (0.60, 0.22, 0.32)
    planted = Water(name="bright", beta_D_per_m=truth, beta_B_per_m=(0.45, 0.25, 0.30),
                    B_inf_rgb=(0.04, 1.2, 0.17))
    frames = _frames_in(planted, np.random.default_rng(4))
    model = fit_water_model(frames)
    assert any(c.startswith("B_inf[G]") and "upper limit" in c for c in model.checks)
    assert model.status == "ok"
    np.testing.assert_allclose(model.beta_D_per_m, truth, atol=BETA_D_TOL_PER_M)
    for img, z in frames[:2]:
        res = restore(img, z, model)
        assert any(c.startswith("B_inf[G]") for c in res.notes)
        _not_empty(res.image)


def test_the_plausible_coastal_fit_trips_no_check(
    coastal: tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray], WaterModel],
) -> None:
    # The checks are not so tight that the simulator's own coastal water fails them.
    assert coastal[2].status == "ok" and coastal[2].checks == ()
    # Range in other units (a board's squares): only the unit-free limits apply.
    frames = [(img, z * 4.0) for img, z in coastal[0]]
    assert fit_water_model(frames, WaterFitConfig(metric_range=False)).status == "ok"
