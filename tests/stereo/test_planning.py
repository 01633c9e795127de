"""Rig planner: depth error, nearest range, overlap and the refraction's effect.

Expected values: the stereo formulas ``sigma_z = z^2 S / (f B)`` and ``z_min = f B / N``
(standard rectified-stereo geometry, e.g. Hartley & Zisserman ch. 9), the overlap of two
parallel pinholes ``1 - f B / (z W)`` for a centred principal point, and Snell's law for a
flat port (magnification n_water / n_air at the image centre).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from sea3d.errors import ConfigError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction.ports import N_AIR, N_WATER
from sea3d.refraction.presets import paper_rig, with_ports
from sea3d.stereo.planning import PlanConfig, override_rig, plan_rig

W, H = 320, 180
FORMULA_REL = 1e-9  # the table is the formula itself for an ideal pinhole rig
OVERLAP_ABS = 2.5 / W  # the grid's columns are 2 px apart; half a column at each edge
FLAT_MAGNIFICATION_REL = 0.02  # fitted virtual pinhole against the paraxial n_w / n_a


def _ideal_rig(fx: float = 400.0, baseline_m: float = 0.1) -> StereoRig:
    pin = PinholeCamera(fx=fx, fy=fx, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)
    T = np.eye(4)
    T[0, 3] = baseline_m
    return StereoRig(left=pin, right=pin, T_left_right=T)


@pytest.fixture(scope="module")
def ideal_plan():
    return plan_rig(_ideal_rig(), PlanConfig(max_disparity_px=40, disparity_noise_px=0.5))


def test_ideal_pinhole_rig_follows_the_stereo_formulas(ideal_plan):
    f, B, S, N = 400.0, 0.1, 0.5, 40
    assert ideal_plan.min_range_m == pytest.approx(f * B / N, rel=FORMULA_REL)
    assert ideal_plan.focal_rectified_px == pytest.approx(f, rel=FORMULA_REL)
    assert len(ideal_plan.rows) == 8
    assert ideal_plan.rows[0].range_m == pytest.approx(1.0)
    assert ideal_plan.rows[-1].range_m == pytest.approx(10.0)
    for row in ideal_plan.rows:
        z = row.range_m
        assert row.depth_error_m == pytest.approx(z * z * S / (f * B), rel=FORMULA_REL)
        assert row.disparity_px == pytest.approx(f * B / z, rel=FORMULA_REL)
        assert row.overlap_fraction == pytest.approx(1 - f * B / (z * W), abs=OVERLAP_ABS)
        assert row.refraction_bias_m is None
        assert row.in_range
    assert not ideal_plan.refractive
    assert ideal_plan.hfov_deg == pytest.approx(np.degrees(2 * np.arctan(W / 2 / f)), abs=1e-6)


def test_error_grows_with_range_and_overlap_with_range(ideal_plan):
    err = [r.depth_error_m for r in ideal_plan.rows]
    ov = [r.overlap_fraction for r in ideal_plan.rows]
    assert all(b > a for a, b in itertools.pairwise(err))
    assert all(b >= a for a, b in itertools.pairwise(ov))


def test_range_option_sets_the_rows_and_marks_what_is_too_near():
    plan = plan_rig(_ideal_rig(), PlanConfig(max_disparity_px=40, range_m=(0.5, 3.0), rows=6))
    assert [round(r.range_m, 6) for r in plan.rows] == pytest.approx(np.linspace(0.5, 3.0, 6))
    assert not plan.rows[0].in_range  # 0.5 m needs 80 px of disparity
    assert plan.rows[-1].in_range


def test_centred_dome_changes_nothing():
    rig = with_ports(
        _ideal_rig(), "dome", dome_center_left_m=(0, 0, 0), dome_center_right_m=(0, 0, 0)
    )
    plan = plan_rig(rig, PlanConfig(max_disparity_px=40))
    assert plan.refractive
    assert plan.focal_water_px == pytest.approx(400.0, rel=1e-4)
    for row in plan.rows:
        assert abs(row.refraction_bias_m) < 1e-6 * row.range_m


def test_flat_port_magnifies_by_the_water_index_and_ignoring_it_shortens_depth():
    air = plan_rig(_ideal_rig(), PlanConfig(max_disparity_px=40))
    flat = plan_rig(with_ports(_ideal_rig(), "flat"), PlanConfig(max_disparity_px=40))
    assert flat.focal_water_px / air.focal_px == pytest.approx(
        N_WATER / N_AIR, rel=FLAT_MAGNIFICATION_REL
    )
    assert flat.hfov_deg < air.hfov_deg
    # nearest range grows with the effective focal length
    assert flat.min_range_m > 1.25 * air.min_range_m
    # in-air triangulation of in-water pixels: depth about 1/1.33 of the truth, or shorter
    for row in flat.rows:
        assert row.refraction_bias_m < -0.2 * row.range_m
    assert flat.virtual_pinhole_rms_px is not None and flat.virtual_pinhole_rms_px > 0.1


def test_paper_dome_bias_is_a_few_percent():
    """The paper's off-centre domes: ignoring them costs percent-level depth (docs/depth.md,
    ``bench_stereo.py --refraction``: 2.1-2.2 % median error with the dome ports ignored)."""
    plan = plan_rig(paper_rig("dome", size_px=(W, H)), PlanConfig(range_m=(1.0, 5.0), rows=5))
    for row in plan.rows:
        assert 0.005 < abs(row.refraction_bias_m) / row.range_m < 0.06


def test_override_rig_replaces_values_and_keeps_ports():
    rig = paper_rig("dome", size_px=(W, H))
    new = override_rig(rig, fx_px=300.0, baseline_m=0.2, size_px=(640, 360))
    assert new.width == 640 and new.height == 360
    assert new.left.pinhole.fx == pytest.approx(300.0)  # type: ignore[attr-defined]
    assert new.baseline_m == pytest.approx(0.2)
    assert type(new.left) is type(rig.left)
    assert new.left.port is rig.left.port  # type: ignore[attr-defined]
    scaled = override_rig(rig, size_px=(2 * W, 2 * H))
    assert scaled.left.pinhole.fx == pytest.approx(2 * rig.left.pinhole.fx)  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "kwargs",
    [{"rows": 4}, {"max_disparity_px": 0}, {"disparity_noise_px": -1.0}, {"range_m": (2.0, 1.0)}],
)
def test_bad_config_is_refused(kwargs):
    with pytest.raises(ConfigError):
        PlanConfig(**kwargs)


def test_bad_override_is_refused():
    with pytest.raises(ConfigError, match="baseline"):
        override_rig(_ideal_rig(), baseline_m=0.0)
