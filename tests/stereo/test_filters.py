"""Post-filters: NaN-awareness, known answers, the chain and its parser."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.errors import ConfigError, StereoError
from sea3d.stereo.filters import (
    BilateralFilter,
    ConfidenceThreshold,
    Decimate,
    FillHoles,
    FilterChain,
    JointBilateralFilter,
    MedianFilter,
    SpeckleFilter,
    TemporalFilter,
    WlsFilter,
    decimate_nan,
    fill_holes,
    median_nan,
    parse_filter_chain,
    remove_speckles,
)

SMOOTH_TOL_PX = 1e-3  # smoothing a constant map must give the constant back


def _plane(rng: np.random.Generator) -> np.ndarray:
    d = np.full((40, 50), 12.0, np.float32)
    d[:, 25:] = 30.0  # a depth step
    holes = rng.random(d.shape) < 0.1
    d[holes] = np.nan
    return d


def test_median_removes_outlier_and_keeps_nan() -> None:
    rng = np.random.default_rng(0)
    d = _plane(rng)
    d[10, 10] = 99.0
    out = median_nan(d, 3)
    assert out[10, 10] == pytest.approx(12.0)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(d))
    # the step stays sharp
    assert np.nanmax(np.abs(out[:, :24] - 12.0)) == 0
    assert np.nanmax(np.abs(out[:, 26:] - 30.0)) == 0


def test_speckles_removed_and_large_regions_kept() -> None:
    d = np.full((30, 30), 10.0, np.float32)
    d[5:8, 5:8] = 25.0  # a 9-pixel island
    out = remove_speckles(d, size_px=20, range_px=1.0)
    assert np.isnan(out[5:8, 5:8]).all()
    assert np.isfinite(out[15:, 15:]).all()


def test_fill_holes_takes_background_neighbour() -> None:
    d = np.array([[5.0, np.nan, np.nan, 9.0, np.nan, np.nan, np.nan, np.nan, 7.0]], np.float32)
    out = fill_holes(d, 2)
    np.testing.assert_array_equal(out[0, :4], [5.0, 5.0, 5.0, 9.0])
    assert np.isnan(out[0, 4:8]).all()  # run of 4 > 2 stays


def test_decimate_halves_size_and_disparity() -> None:
    d = np.full((8, 10), 6.0, np.float32)
    d[0, 0] = np.nan
    out = decimate_nan(d, 2)
    assert out.shape == (4, 5)
    np.testing.assert_allclose(out, 3.0)


@pytest.mark.parametrize(
    "step",
    [
        BilateralFilter(),
        JointBilateralFilter(),
        WlsFilter(),
        MedianFilter(size_px=5),
    ],
)
def test_smoothing_filters_keep_constant_map_and_invalid_pixels(step: object) -> None:
    rng = np.random.default_rng(0)
    d = np.full((48, 64), 17.25, np.float32)
    d[rng.random(d.shape) < 0.05] = np.nan
    image = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
    out = FilterChain([step]).apply(d, image=image)  # type: ignore[list-item]
    np.testing.assert_array_equal(np.isnan(out), np.isnan(d))
    assert np.nanmax(np.abs(out - 17.25)) < SMOOTH_TOL_PX


def test_joint_bilateral_reduces_noise_on_plane() -> None:
    rng = np.random.default_rng(0)
    d = (20.0 + rng.normal(0, 0.5, (60, 80))).astype(np.float32)
    image = np.full((60, 80), 128, np.uint8)
    out = FilterChain([JointBilateralFilter()]).apply(d, image=image)
    assert np.std(out - 20.0) < 0.5 * np.std(d - 20.0)


def test_temporal_filter_averages_static_frames_and_resets() -> None:
    rng = np.random.default_rng(0)
    chain = FilterChain([TemporalFilter(alpha=0.5, max_step_px=2.0)])
    truth = np.full((10, 10), 8.0, np.float32)
    outs = [chain.apply(truth + rng.normal(0, 0.3, truth.shape).astype(np.float32))
            for _ in range(10)]
    assert np.std(outs[-1] - truth) < 0.7 * 0.3
    chain.reset()
    first = truth + 1.0
    np.testing.assert_array_equal(chain.apply(first), first)


def test_confidence_threshold_and_chain_parser() -> None:
    d = np.full((4, 4), 3.0, np.float32)
    conf = np.linspace(0, 1, 16, dtype=np.float32).reshape(4, 4)
    out = FilterChain([ConfidenceThreshold(min_confidence=0.5)]).apply(d, confidence=conf)
    np.testing.assert_array_equal(np.isnan(out), conf < 0.5)
    steps = parse_filter_chain("median:size_px=5,speckle:size_px=50:range_px=1.5,wls,fill,decimate")
    assert steps == (MedianFilter(size_px=5), SpeckleFilter(size_px=50, range_px=1.5),
                     WlsFilter(), FillHoles(), Decimate())
    with pytest.raises(ConfigError, match="unknown filter"):
        parse_filter_chain("blur")
    with pytest.raises(ConfigError, match="no parameter"):
        parse_filter_chain("median:radius=2")
    with pytest.raises(StereoError, match="guide"):
        FilterChain([WlsFilter()]).apply(d)


def test_median_matches_numpy_nanmedian_reference() -> None:
    rng = np.random.default_rng(0)
    d = rng.random((40, 50)).astype(np.float32) * 30
    d[rng.random(d.shape) < 0.05] = np.nan
    out = median_nan(d, 3)
    ref = np.full_like(d, np.nan)
    for y in range(d.shape[0]):
        for x in range(d.shape[1]):
            if np.isfinite(d[y, x]):
                ref[y, x] = np.nanmedian(d[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2])
    np.testing.assert_array_equal(out, ref)


def _noisy_step(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A disparity step (12 | 30 px) with 0.5 px noise, its truth, and a left image whose
    intensity edge lies on the step."""
    truth = np.full((60, 80), 12.0, np.float32)
    truth[:, 40:] = 30.0
    noisy = (truth + rng.normal(0, 0.5, truth.shape)).astype(np.float32)
    image = np.where(truth > 20, 200, 60).astype(np.uint8)
    return noisy, truth, image


@pytest.mark.parametrize("step", [BilateralFilter(), WlsFilter(), JointBilateralFilter()])
def test_edge_preserving_filters_smooth_noise_and_keep_the_step(step: object) -> None:
    # a filter replaced by a no-op keeps the noise; one that ignores edges blurs the step
    rng = np.random.default_rng(0)
    noisy, truth, image = _noisy_step(rng)
    out = FilterChain([step]).apply(noisy, image=image)  # type: ignore[list-item]
    inner = np.ones_like(truth, dtype=bool)
    inner[:, 36:44] = False  # away from the step
    assert np.std((out - truth)[inner]) < 0.5 * np.std((noisy - truth)[inner])
    # the step stays a step: pixels two columns from it keep their side's value
    assert np.abs(out[:, 38] - 12.0).max() < 2.0
    assert np.abs(out[:, 41] - 30.0).max() < 2.0
