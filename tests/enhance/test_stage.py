"""Stage functions for ``sea3d process``: defaults as measured, statuses instead of raising."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.enhance import clahe, white_balance_pair
from sea3d.enhance.stage import (
    ColourConfig,
    FeatureEnhanceConfig,
    MatchEnhanceConfig,
    enhance_for_features,
    enhance_for_matching,
    enhance_pair_for_matching,
    restore_colours,
)
from sea3d.errors import EnhanceError


def _img(rng: np.random.Generator) -> np.ndarray:
    return (rng.random((48, 64, 3)) * np.array([60, 200, 170])).astype(np.uint8)


def test_matching_gets_the_raw_images_by_default(rng: np.random.Generator) -> None:
    a, b = _img(rng), _img(rng)
    cfg = MatchEnhanceConfig()
    assert cfg.method == "none"
    assert enhance_for_matching(a, cfg) is a
    la, lb = enhance_pair_for_matching(a, b, cfg)
    assert la is a and lb is b
    la, lb = enhance_pair_for_matching(a, b, MatchEnhanceConfig(method="grey-world"))
    ea, eb = white_balance_pair(a, b, "grey-world")
    np.testing.assert_array_equal(la, ea)
    np.testing.assert_array_equal(lb, eb)
    with pytest.raises(EnhanceError):
        MatchEnhanceConfig(method="seathru")  # type: ignore[arg-type]


def test_features_get_clahe_by_default(rng: np.random.Generator) -> None:
    a = _img(rng)
    np.testing.assert_array_equal(enhance_for_features(a, FeatureEnhanceConfig()), clahe(a))
    grey = a[..., 1]
    assert enhance_for_features(grey, FeatureEnhanceConfig()).shape == grey.shape


def test_colour_restoration_is_opt_in_and_falls_back_with_a_status(
    rng: np.random.Generator,
) -> None:
    a = _img(rng)
    depth = np.full(a.shape[:2], 2.0, dtype=np.float32)
    assert restore_colours(a, depth, 50.0, 32.0, 24.0, ColourConfig()).status == "disabled"
    on = ColourConfig(enabled=True)
    res = restore_colours(a, np.full_like(depth, np.nan), 50.0, 32.0, 24.0, on)
    assert res.status == "fallback-grey-world" and "no valid pixel" in res.notes[0]
    assert res.image.shape == a.shape and res.image.mean() > 0
    ok = restore_colours(a, depth, 50.0, 32.0, 24.0, on)
    assert ok.status in ("ok", "fallback-grey-world") and ok.image.dtype == np.uint8
    with pytest.raises(EnhanceError, match=r"32x24"):
        restore_colours(a, depth[::2, ::2], 50.0, 32.0, 24.0, on)
