"""One water model per dive in ``sea3d process --restore-colours water-model``
(:mod:`sea3d.pipeline.colour_stage`), on synthetic frames made with the revised formation
model (Akkaynak and Treibitz 2018, Eq. 1) from known water and a known albedo.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from sea3d.enhance._image import srgb_to_linear
from sea3d.errors import ConfigError
from sea3d.pipeline import colour_stage
from sea3d.pipeline.colour_stage import DiveColourConfig, DiveColours, frame_range_m
from sea3d.pipeline.frame_stage import FrameResult

H, W = 72, 96
MAPS = SimpleNamespace(focal_px=80.0, cx_px=(W - 1) / 2, cy_px=(H - 1) / 2)
BETA_D = np.array([0.6, 0.15, 0.1])
BETA_B = np.array([0.8, 0.8, 0.8])
B_INF = np.array([0.04, 0.22, 0.28])
# Frame-to-frame stability of the restored colour (log R/G, log B/G of the mean over the
# pixels, minus the albedo's): with the dive's one model, its standard deviation over 10
# frames that see the same water at other ranges (1.0-3.0 m shifted by up to 0.9 m) is 0.0016
# (measured); a model fitted to each frame alone gives 0.11 (measured), as the per-frame fit
# moves by 0.08 in tests/enhance/test_process_colours.py on the simulator.
STABLE_LOG_CHROMA_SD = 0.01
# The restored colour against the albedo's (the same log chromaticity, mean over the frames):
# 0.044 (measured); the raw frames are several times farther.
RESTORED_LOG_CHROMA_TOL = 0.1


def _encode(lin: np.ndarray) -> np.ndarray:
    x = np.clip(lin, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return (s * 255 + 0.5).astype(np.uint8)


def _frame(k: int, rng: np.random.Generator, *, status: str = "ok") -> tuple[FrameResult,
                                                                              np.ndarray]:
    """A frame of the same water: a textured albedo (drawn from one distribution) at ranges
    1.0-3.0 m (plus 0.1 m per frame), and its albedo in linear RGB."""
    albedo = np.clip(rng.uniform(0.1, 0.7, (H, W, 1)) * np.array([0.8, 0.7, 0.55])
                     + rng.normal(0, 0.03, (H, W, 3)), 0.02, 1.0)
    z = (np.linspace(1.0, 3.0, H)[:, None] * np.ones((1, W)) + 0.1 * k).astype(np.float32)
    lin = albedo * np.exp(-BETA_D * z[..., None]) + B_INF * (1 - np.exp(-BETA_B * z[..., None]))
    x = (np.arange(W) - MAPS.cx_px) / MAPS.focal_px
    y = (np.arange(H) - MAPS.cy_px) / MAPS.focal_px
    depth = (z / np.sqrt(1 + x[None, :] ** 2 + y[:, None] ** 2)).astype(np.float32)
    if status != "ok":
        depth[:] = np.nan
    img = _encode(lin)
    res = FrameResult(t_ns=1000 * (k + 1), status=status, rect_left=img,  # type: ignore[arg-type]
                      rect_right=img.copy(), depth_m=depth, fusion_depth_m=depth,
                      valid_fraction=float(np.isfinite(depth).mean()),
                      timings_s={"match_s": 0.01})
    return res, albedo


def _chroma(img: np.ndarray) -> np.ndarray:
    m = srgb_to_linear(img.astype(np.float64) / 255).reshape(-1, 3).mean(axis=0)
    return np.log(np.array([m[0] / m[1], m[2] / m[1]]))


def test_the_range_of_a_frame_is_its_depth_along_the_pinhole_rays(
    rng: np.random.Generator,
) -> None:
    res, _ = _frame(0, rng)
    want = np.linspace(1.0, 3.0, H)[:, None] * np.ones((1, W))
    np.testing.assert_allclose(frame_range_m(res, MAPS), want, rtol=1e-5)


def test_the_dive_is_fitted_once_from_frames_spread_over_its_start_and_none_leaves_early(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls = []
    real_fit = colour_stage.fit_water_model

    def counting_fit(frames, config=None):  # type: ignore[no-untyped-def]
        calls.append(len(frames))
        return real_fit(frames, config)

    monkeypatch.setattr(colour_stage, "fit_water_model", counting_fit)
    dive = DiveColours(MAPS, DiveColourConfig(fit_frames=3, fit_stride=2))
    out: list[FrameResult] = []
    frames = [_frame(k, rng)[0] for k in range(10)]
    for k, f in enumerate(frames):
        got = dive.push(f)
        # Held until the 3rd fit frame (frame 4: frames 0, 2, 4 are fitted) is in.
        assert (got == []) == (k < 4), k
        out += got
    out += dive.flush()
    assert calls == [3] and dive.fits == 1
    assert dive.fit_stamps == [frames[0].t_ns, frames[2].t_ns, frames[4].t_ns]
    assert [r.t_ns for r in out] == [f.t_ns for f in frames]  # every frame, in time order
    assert dive.model is not None and dive.model.status == "ok"
    assert {r.colour_status for r in out} == {"ok"}
    for r, f in zip(out, frames, strict=True):
        assert r.color_left.shape == (H, W, 3) and r.color_left.dtype == np.uint8
        assert "restore_colours_s" in r.timings_s and r.timings_s["match_s"] == 0.01
        # What the odometry gets is untouched; the colours are restored (not a copy).
        assert r.rect_left is f.rect_left and r.depth_m is f.depth_m
        assert np.abs(r.color_left.astype(int) - f.rect_left).mean() > 10
    info = dive.summary()
    assert info["fits"] == 1 and info["water_model"]["status"] == "ok"
    # The known water: the red attenuation is found (within 0.15 1/m of 0.6).
    assert abs(info["water_model"]["beta_D_per_m"][0] - BETA_D[0]) < 0.15


def _albedo_chroma(albedo: np.ndarray) -> np.ndarray:
    m = albedo.reshape(-1, 3).mean(axis=0)
    return np.log(np.array([m[0] / m[1], m[2] / m[1]]))


def test_one_model_per_dive_keeps_the_colour_stable_from_frame_to_frame(
    rng: np.random.Generator,
) -> None:
    frames = [_frame(k, rng) for k in range(10)]
    want = np.stack([_albedo_chroma(a) for _f, a in frames])
    dive = DiveColours(MAPS, DiveColourConfig(fit_frames=4, fit_stride=2))
    out = [r for f, _ in frames for r in dive.push(f)] + dive.flush()
    err = np.stack([_chroma(r.color_left) for r in out]) - want
    assert np.std(err, axis=0).max() < STABLE_LOG_CHROMA_SD
    assert np.abs(err.mean(axis=0)).max() < RESTORED_LOG_CHROMA_TOL
    raw_err = np.stack([_chroma(f.rect_left) for f, _ in frames]) - want
    assert np.abs(raw_err.mean(axis=0)).max() > 3 * RESTORED_LOG_CHROMA_TOL
    # The same frames, each with a model of its own: the colour moves from frame to frame.
    alone = []
    for f, _a in frames:
        (r,) = DiveColours(MAPS, DiveColourConfig(fit_frames=1)).push(f)
        alone.append(_chroma(r.color_left))
    assert np.std(np.stack(alone) - want, axis=0).max() > 3 * STABLE_LOG_CHROMA_SD


def test_a_dive_whose_water_cannot_be_fitted_gets_grey_world_with_a_stated_status(
    rng: np.random.Generator,
) -> None:
    dive = DiveColours(MAPS, DiveColourConfig(fit_frames=2))
    frames = [_frame(k, rng, status="no_depth")[0] for k in range(3)]
    failed = dataclasses.replace(frames[0], t_ns=99_999, status="failed")
    out = [r for f in [*frames, failed] for r in dive.push(f)] + dive.flush()
    assert [r.t_ns for r in out] == [1000, 2000, 3000, 99_999]
    assert [r.colour_status for r in out[:3]] == ["fallback-grey-world"] * 3
    assert out[3] is failed  # a failed frame passes through untouched
    for r in out[:3]:
        img = r.color_left.astype(np.float64)
        assert np.isfinite(img).all() and 10 < img.mean() < 245
    info = dive.summary()
    assert info["water_model"] is None and "no frame with depth" in info["fit_error"]
    # Held frames are bounded: without depth, the fit is tried after 2 x 2 x 1 frames.
    d1 = DiveColours(MAPS, DiveColourConfig(fit_frames=2, fit_stride=1))
    got = [len(d1.push(_frame(k, rng, status="no_depth")[0])) for k in range(6)]
    assert got == [0, 0, 0, 4, 1, 1] and d1.fits == 1
    # Frames with depth but a saturated view: the fit raises, every frame says so.
    sat, _ = _frame(0, rng)
    sat = dataclasses.replace(sat, rect_left=np.full_like(sat.rect_left, 255))
    d2 = DiveColours(MAPS, DiveColourConfig(fit_frames=1))
    (r,) = d2.push(sat)
    assert r.colour_status == "fallback-grey-world" and "cannot fit" in d2.summary()["fit_error"]


def test_dive_colour_config_is_checked() -> None:
    with pytest.raises(ConfigError, match="fit_frames"):
        DiveColourConfig(fit_frames=0)
    with pytest.raises(ConfigError, match="fit_stride"):
        DiveColourConfig(fit_stride=0)
