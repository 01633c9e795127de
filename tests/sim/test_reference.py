"""Clean references: the same view without water (or without water on the line of sight), the
same noise seed, and the water model's coefficients alongside."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from sea3d.geometry.se3 import look_at
from sea3d.refraction.presets import paper_rig
from sea3d.sim import Imaging, Renderer, builtin_scene
from sea3d.sim.reference import simulate_pair_with_reference

RADIANCE_REL_TOL = 1e-5  # float32 shading against the float64 formula
T_VIEW = look_at((0.35, -1.6, 0.9), (0.0, 0.0, 0.1))


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(builtin_scene("lake"), supersample=1)


def test_line_of_sight_water_is_exactly_the_formation_model(renderer: Renderer) -> None:
    """underwater = J exp(-beta_D z) + B_inf (1 - exp(-beta_B z)), pixel by pixel."""
    rig = paper_rig("none", size_px=(96, 54))
    im = dataclasses.replace(Imaging.underwater("coastal"), caustics=0.3).without_sensor_noise()
    under = renderer.render(rig.left, T_VIEW, im)
    j = renderer.render(rig.left, T_VIEW, im.without_line_of_sight_water())
    w = im.water
    assert w is not None
    z = under.gt.range_m.astype(np.float64)[..., None]  # pinhole: rays start at the centre
    hit = np.isfinite(z[..., 0])
    bD, bB, Binf = (np.asarray(v) for v in (w.beta_D_per_m, w.beta_B_per_m, w.B_inf_rgb))
    expect = j.radiance * np.exp(-bD * z) + Binf * (1 - np.exp(-bB * z))
    np.testing.assert_allclose(under.radiance[hit], expect[hit], rtol=RADIANCE_REL_TOL, atol=1e-7)
    # Rays that hit nothing see the veiling light under water and black without it.
    assert (~hit).any()
    np.testing.assert_allclose(under.radiance[~hit], np.broadcast_to(Binf, (int((~hit).sum()), 3)),
                               rtol=1e-6)
    assert np.all(j.radiance[~hit] == 0)
    # Without water the lights are not attenuated either: brighter than J everywhere.
    clean = renderer.render(rig.left, T_VIEW, im.without_water())
    assert np.all(clean.radiance[hit] >= j.radiance[hit] - 1e-7)


def test_reference_pair_shares_the_seed_and_is_not_clipped(renderer: Renderer) -> None:
    rig = paper_rig("none", size_px=(96, 54))
    p = simulate_pair_with_reference(rig, renderer.scene, T_VIEW, "clear", seed=3,
                                     renderer=renderer)
    assert p.left.shape == p.left_clean.shape == p.left_unattenuated.shape == (54, 96, 3)
    assert p.water["name"] == "clear" and p.water["beta_D_per_m"] == [0.40, 0.08, 0.05]
    # The references are exposed not to clip (the same exposure would blow out the sand).
    assert np.percentile(p.left_clean.max(axis=2), 99.5) <= 245
    assert p.exposure_clean < Imaging.underwater("clear").exposure
    # Same seed, same noise: rendering the clean view by hand gives the same bytes.
    im = Imaging.underwater("clear").without_water()
    v = renderer.render(rig.left, T_VIEW, im.without_sensor_noise())
    again = dataclasses.replace(im, exposure=p.exposure_clean).sensor(
        v.radiance, np.random.default_rng(3)
    )
    np.testing.assert_array_equal(again, p.left_clean)
    other = simulate_pair_with_reference(rig, renderer.scene, T_VIEW, "clear", seed=4,
                                         renderer=renderer)
    assert not np.array_equal(other.left_clean, p.left_clean)


def test_survey_writes_clean_references_and_the_water_model(tmp_path: Path) -> None:
    import json

    import cv2

    from sea3d.io.session import SessionWriter
    from sea3d.sim.survey import SurveyConfig, simulate_survey

    rig = paper_rig("none", size_px=(64, 36))
    cfg = SurveyConfig(frames=2, water="turbid", supersample=1, trajectory="orbit",
                       clean_reference=True)
    with SessionWriter(tmp_path / "s", format="folder") as w:
        res = simulate_survey(builtin_scene("lake"), rig, cfg, w, tmp_path / "gt")
    meta = json.loads((tmp_path / "gt" / "sim.json").read_text())
    assert meta["water_model"]["beta_D_per_m"] == [1.10, 0.75, 1.30]
    assert 0 < meta["clean_reference_exposure"] <= Imaging.underwater("turbid").exposure
    for t in res.frame_t_ns:
        for side in ("left", "right"):
            img = cv2.imread(str(tmp_path / "gt" / "clean" / side / f"{int(t)}.png"))
            assert img is not None and img.shape == (36, 64, 3)
