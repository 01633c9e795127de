"""The colour stage of ``sea3d process``: opt-in, statuses instead of raising."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.enhance.stage import ColourRestoreConfig, restore_colours_with_range
from sea3d.errors import EnhanceError


def _img(rng: np.random.Generator) -> np.ndarray:
    return (rng.random((48, 64, 3)) * np.array([60, 200, 170])).astype(np.uint8)


def test_colour_restoration_is_opt_in_and_falls_back_with_a_status(
    rng: np.random.Generator,
) -> None:
    a = _img(rng)
    range_m = np.full(a.shape[:2], 2.0, dtype=np.float32)
    assert restore_colours_with_range(a, range_m, ColourRestoreConfig()).status == "disabled"
    on = ColourRestoreConfig(enabled=True, method="water-model")
    res = restore_colours_with_range(a, np.full_like(range_m, np.nan), on)
    assert res.status == "fallback-grey-world" and "cannot fit B_inf or beta_D" in res.notes[0]
    assert res.image.shape == a.shape and res.image.mean() > 0
    # One range only: backscatter cannot be told from albedo; the stated step, not "ok".
    flat = restore_colours_with_range(a, range_m, on)
    assert flat.status == "backscatter-unidentified" and flat.image.dtype == np.uint8
    assert "range bin" in flat.notes[0] and flat.image.mean() > 20
    with pytest.raises(EnhanceError, match=r"32x24"):
        restore_colours_with_range(a, range_m[::2, ::2], on)
    grey = restore_colours_with_range(a[..., 1], range_m, on)
    assert grey.status == "fallback-none"


def test_the_per_image_seathru_still_runs_with_a_status(rng: np.random.Generator) -> None:
    a = _img(rng)
    ramp = np.linspace(1.0, 4.0, a.shape[0], dtype=np.float32)[:, None] * np.ones((1, a.shape[1]))
    res = restore_colours_with_range(a, ramp.astype(np.float32), ColourRestoreConfig(enabled=True))
    # A range ramp of 1-4 m identifies the water: the image's own fit, not a fallback.
    assert res.status == "ok" and res.model is not None and res.notes == ()
    assert res.image.dtype == np.uint8 and res.image.mean() > 20
