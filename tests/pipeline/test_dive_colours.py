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
from sea3d.enhance.water import WaterFitConfig
from sea3d.errors import ConfigError
from sea3d.pipeline import colour_stage
from sea3d.pipeline.colour_stage import DiveColourConfig, DiveColours, frame_range_m
from sea3d.pipeline.frame_stage import FrameResult

H, W = 72, 96
MAPS = SimpleNamespace(focal_px=80.0, cx_px=(W - 1) / 2, cy_px=(H - 1) / 2, baseline_m=0.1)
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
# These frames are lit white (no water above the scene), so the inversion's J is the albedo:
# the colour tests keep J (no white balance after it); the default pools grey world.
KEEP_J = WaterFitConfig(white_balance="none")


def _encode(lin: np.ndarray) -> np.ndarray:
    x = np.clip(lin, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return (s * 255 + 0.5).astype(np.uint8)


def _frame(k: int, rng: np.random.Generator, *, status: str = "ok",
           right_only: np.ndarray | None = None) -> tuple[FrameResult, np.ndarray]:
    """A frame of the same water: a textured albedo (drawn from one distribution) at ranges
    1.0-3.0 m (plus 0.1 m per frame), and its albedo in linear RGB. The right view sees the
    same surface shifted by the disparity ``f B / depth``, through its own range;
    ``right_only`` (a linear colour) paints the right view's left quarter with an object
    the left view does not see."""
    albedo = np.clip(rng.uniform(0.1, 0.7, (H, W, 1)) * np.array([0.8, 0.7, 0.55])
                     + rng.normal(0, 0.03, (H, W, 3)), 0.02, 1.0)
    z = (np.linspace(1.0, 3.0, H)[:, None] * np.ones((1, W)) + 0.1 * k).astype(np.float32)
    lin = albedo * np.exp(-BETA_D * z[..., None]) + B_INF * (1 - np.exp(-BETA_B * z[..., None]))
    x = (np.arange(W) - MAPS.cx_px) / MAPS.focal_px
    y = (np.arange(H) - MAPS.cy_px) / MAPS.focal_px
    depth = (z / np.sqrt(1 + x[None, :] ** 2 + y[:, None] ** 2)).astype(np.float32)
    # right pixel u_r sees the left pixel u = u_r + f B / depth (depth of pixel u_r: smooth)
    src = np.clip(np.rint(np.arange(W)[None, :] + MAPS.focal_px * MAPS.baseline_m / depth),
                  0, W - 1).astype(int)
    rows = np.arange(H)[:, None]
    alb_r = albedo[rows, src]
    d_r = depth[rows, src].astype(np.float64)
    x_r = (np.arange(W)[None, :] - MAPS.cx_px) / MAPS.focal_px
    z_r = d_r * np.sqrt(1 + x_r ** 2 + y[:, None] ** 2)
    if right_only is not None:
        alb_r[:, : W // 4] = right_only
    lin_r = alb_r * np.exp(-BETA_D * z_r[..., None]) + B_INF * (
        1 - np.exp(-BETA_B * z_r[..., None]))
    if status != "ok":
        depth[:] = np.nan
    img = _encode(lin)
    res = FrameResult(t_ns=1000 * (k + 1), status=status, rect_left=img,  # type: ignore[arg-type]
                      rect_right=_encode(lin_r), depth_m=depth, fusion_depth_m=depth,
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
    assert calls == [6] and dive.fits == 1  # 3 pairs, both views of each
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
    dive = DiveColours(MAPS, DiveColourConfig(fit_frames=4, fit_stride=2, water=KEEP_J))
    out = [r for f, _ in frames for r in dive.push(f)] + dive.flush()
    err = np.stack([_chroma(r.color_left) for r in out]) - want
    assert np.std(err, axis=0).max() < STABLE_LOG_CHROMA_SD
    assert np.abs(err.mean(axis=0)).max() < RESTORED_LOG_CHROMA_TOL
    raw_err = np.stack([_chroma(f.rect_left) for f, _ in frames]) - want
    assert np.abs(raw_err.mean(axis=0)).max() > 3 * RESTORED_LOG_CHROMA_TOL
    # The same frames, each with a model of its own: the colour moves from frame to frame.
    alone = []
    for f, _a in frames:
        (r,) = DiveColours(MAPS, DiveColourConfig(fit_frames=1, more_frames=0,
                                                 water=KEEP_J)).push(f)
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
    sat = dataclasses.replace(sat, rect_left=np.full_like(sat.rect_left, 255),
                              rect_right=np.full_like(sat.rect_right, 255))
    d2 = DiveColours(MAPS, DiveColourConfig(fit_frames=1))
    (r,) = d2.push(sat)
    assert r.colour_status == "fallback-grey-world" and "cannot fit" in d2.summary()["fit_error"]


def test_dive_colour_config_is_checked() -> None:
    with pytest.raises(ConfigError, match="fit_frames"):
        DiveColourConfig(fit_frames=0)
    with pytest.raises(ConfigError, match="fit_stride"):
        DiveColourConfig(fit_stride=0)


# The pair's restored colours (log R/G, log B/G of the mean over the pixels both views see):
# 0.0003 apart with the pair's one balance (measured); with a balance of each view's own
# (the right view's fit sees an object the left does not) 0.051 apart (measured).
PAIR_LOG_CHROMA_TOL = 0.01


def test_both_views_of_a_pair_get_one_balance_and_agree(rng: np.random.Generator) -> None:
    red = np.array([0.7, 0.08, 0.05])  # an object only the right view sees
    frames = [_frame(k, rng, right_only=red)[0] for k in range(4)]
    seen = np.zeros((H, W), bool)
    seen[:, W // 4 + 2: W - 12] = True  # both views see these right pixels

    def pair_gap(dive: DiveColours) -> float:
        gaps = []
        for f in frames:
            (r,) = dive.push(f) if dive.fitted else [*dive.push(f), *dive.flush()][-1:]
            left = r.color_left
            right = dive.restore_right(f)
            src = np.clip(np.rint(np.arange(W)[None, :] + MAPS.focal_px * MAPS.baseline_m
                                  / f.depth_m), 0, W - 1).astype(int)
            left_at_right = left[np.arange(H)[:, None], src]
            gaps.append(np.abs(_chroma(right[seen][None]) - _chroma(left_at_right[seen][None])))
        return float(np.max(gaps))

    pooled = DiveColours(MAPS, DiveColourConfig(fit_frames=1))
    got = pair_gap(pooled)
    assert pooled.model is not None and pooled.model.status == "ok"
    assert got < PAIR_LOG_CHROMA_TOL
    # Each view balanced on its own statistics (the right's include the red object): apart.
    right_alone = DiveColours(MAPS, DiveColourConfig(fit_frames=1, pool_pair=False))
    right_alone.model = colour_stage.fit_water_model(
        [(frames[0].rect_right, colour_stage.right_range_m(frames[0], MAPS))])
    right_alone.fits = 1
    left_alone = DiveColours(MAPS, DiveColourConfig(fit_frames=1, pool_pair=False))
    (rl,) = [*left_alone.push(frames[0]), *left_alone.flush()][:1]
    right = right_alone.restore_right(frames[0])
    src = np.clip(np.rint(np.arange(W)[None, :] + MAPS.focal_px * MAPS.baseline_m
                          / frames[0].depth_m), 0, W - 1).astype(int)
    left_at_right = rl.color_left[np.arange(H)[:, None], src]
    apart = float(np.max(np.abs(_chroma(right[seen][None]) - _chroma(left_at_right[seen][None]))))
    assert apart > 3 * PAIR_LOG_CHROMA_TOL


def test_the_right_range_is_the_left_surface_seen_from_the_right_centre(
    rng: np.random.Generator,
) -> None:
    res, _ = _frame(0, rng)
    got = colour_stage.right_range_m(res, MAPS)
    # the left points, moved into the right camera (centre B along x), by their range there
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = res.depth_m.astype(np.float64)
    p = np.stack([(u - MAPS.cx_px) / MAPS.focal_px * z - MAPS.baseline_m,
                  (v - MAPS.cy_px) / MAPS.focal_px * z, z], axis=-1)
    ur = np.rint(u - MAPS.focal_px * MAPS.baseline_m / z).astype(int)
    want = np.full((H, W), np.nan)
    ok = (ur >= 0) & (ur < W)
    want[v[ok].astype(int), ur[ok]] = np.linalg.norm(p[ok], axis=1)
    have = np.isfinite(got) & np.isfinite(want)
    assert have.mean() > 0.8
    # the right pixel's own ray (its rounded column) against the exact point: < 0.5 px off
    np.testing.assert_allclose(got[have], want[have], rtol=3e-3)


def test_a_first_fit_that_is_not_ok_gathers_more_frames_and_fits_again(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The first fallback step: the model from the first fit frames fails a check (planted:
    # the first fit says so), so more frames are held and the dive is fitted once more over
    # all of them; every frame is restored with that second model, none leaves early.
    from sea3d.enhance.water import WaterModel

    calls: list[int] = []
    real_fit = colour_stage.fit_water_model

    def first_fails(frames, config=None):  # type: ignore[no-untyped-def]
        calls.append(len(frames))
        got = real_fit(frames, config)
        if len(calls) == 1:
            return WaterModel(B_inf_rgb=got.B_inf_rgb, beta_B_per_m=got.beta_B_per_m,
                              beta_D_per_m=(0.0, 0.0, 0.0), status="attenuation-unidentified",
                              checks=("beta_D_per_m[R] = 0.010 below 0.122 (planted)",))
        return got

    monkeypatch.setattr(colour_stage, "fit_water_model", first_fails)
    dive = DiveColours(MAPS, DiveColourConfig(fit_frames=2, fit_stride=1, more_frames=2))
    frames = [_frame(k, rng)[0] for k in range(6)]
    got_at = [len(dive.push(f)) for f in frames]
    out_n = sum(got_at) + len(dive.flush())
    assert got_at == [0, 0, 0, 4, 1, 1]  # held until the 4th fit frame, then one by one
    assert calls == [4, 8] and dive.fits == 1  # both views: 2 pairs, then 4
    assert out_n == 6 and dive.model is not None and dive.model.status == "ok"
    info = dive.summary()
    assert info["first_fit_status"] == "attenuation-unidentified"
    assert len(info["fit_frames_t_ns"]) == 4
    # With more_frames 0 the first model restores (no second fit).
    calls.clear()
    dive0 = DiveColours(MAPS, DiveColourConfig(fit_frames=2, fit_stride=1, more_frames=0))
    assert [len(dive0.push(f)) for f in frames[:2]] == [0, 2]
    assert calls == [4] and dive0.model is not None
    assert dive0.model.status == "attenuation-unidentified"
