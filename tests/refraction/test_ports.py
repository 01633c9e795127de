"""Dome- and flat-port cameras: reduction to the pinhole, round trips, independent 3D tracing."""

import numpy as np
import pytest

from sea3d.errors import RefractionError
from sea3d.geometry import PinholeCamera
from sea3d.refraction import DomePort, DomePortCamera, FlatPort, FlatPortCamera, refract
from tolerances import PINHOLE_REDUCTION_PX, REFRACTIVE_ROUNDTRIP_PX

R_IN = 0.03125  # the paper's acrylic dome (Table 2.5)
THICK = 0.0031
PAPER_CENTER = (-0.54e-3, 0.58e-3, 2.10e-3)  # Table 3.7


def _pinhole(dist=()):
    return PinholeCamera(1082.4, 1074.4, 949.5, 535.7, 1920, 1080, np.asarray(dist, float))


def _dome(center, dist=(), **kw):
    return DomePortCamera(
        _pinhole(dist),
        DomePort(center_m=np.asarray(center), inner_radius_m=R_IN, thickness_m=THICK, **kw),
    )


def test_centred_dome_reduces_to_pinhole_exactly(rng):
    cam = _dome((0.0, 0.0, 0.0), dist=(0.04, -0.01, 0.0, 0.0, 0.0))
    pts = np.c_[rng.uniform(-3, 3, (5000, 2)), rng.uniform(0.3, 20, 5000)]
    uv, valid = cam.project(pts)
    uv_pin, valid_pin = cam.pinhole.project(pts)
    np.testing.assert_array_equal(uv, uv_pin)
    np.testing.assert_array_equal(valid, valid_pin)
    grid = cam.pinhole.pixel_grid(step=13)
    rays = cam.unproject(grid)
    np.testing.assert_allclose(rays.directions, cam.pinhole.unproject(grid).directions, atol=1e-15)
    # The ray still starts on the outer surface, on the same line through the centre.
    np.testing.assert_allclose(np.linalg.norm(rays.origins, axis=1), R_IN + THICK, atol=1e-12)


def test_dome_with_equal_indices_reduces_to_pinhole(rng):
    cam = _dome((2e-3, -1e-3, 3e-3), n_air=1.333, n_glass=1.333, n_water=1.333)
    pts = np.c_[rng.uniform(-3, 3, (2000, 2)), rng.uniform(0.3, 20, 2000)]
    np.testing.assert_array_equal(cam.project(pts)[0], cam.pinhole.project(pts)[0])


@pytest.mark.parametrize(
    "center_mm",
    [
        PAPER_CENTER_MM := (-0.54, 0.58, 2.10),
        (5.0, 0.0, 0.0),
        (0.0, -5.0, 0.0),
        (0.0, 0.0, 5.0),
        (2.9, 2.9, -2.9),
    ],
)
def test_dome_round_trip_over_full_image_and_ranges(center_mm, rng):
    cam = _dome(np.asarray(center_mm) * 1e-3, dist=(0.04, -0.01, 0.001, -0.001, 0.0))
    step = 1 if center_mm == PAPER_CENTER_MM else 3
    uv = cam.pinhole.pixel_grid(step=step)
    rays = cam.unproject(uv)
    assert rays.valid.all()
    ranges = rng.uniform(0.3, 20.0, len(uv))
    back, valid = cam.project(rays.at(ranges))
    assert valid.all()
    assert np.abs(back - uv).max() < REFRACTIVE_ROUNDTRIP_PX
    # Origins lie on the outer sphere.
    np.testing.assert_allclose(
        np.linalg.norm(rays.origins - cam.port.center_m, axis=1), R_IN + THICK, atol=1e-12
    )


def _trace_dome_3d(cam: DomePortCamera, uv: np.ndarray):
    """Independent 3D implementation of the paper's eqs. 2.12-2.16 with vector Snell."""
    d = cam.pinhole.unproject(uv).directions
    c = cam.port.center_m
    r1, r2 = cam.port.inner_radius_m, cam.port.outer_radius_m

    def hit(o, d, r):
        oc = o - c
        b = np.einsum("ij,ij->i", d, oc)
        lam = -b + np.sqrt(b * b - (np.einsum("ij,ij->i", oc, oc) - r * r))
        return o + lam[:, None] * d

    p1 = hit(np.zeros_like(d), d, r1)
    g, _ = refract(d, -(p1 - c) / r1, cam.port.n_air, cam.port.n_glass)
    p2 = hit(p1, g, r2)
    w, _ = refract(g, -(p2 - c) / r2, cam.port.n_glass, cam.port.n_water)
    return p2, w


def test_dome_unproject_matches_independent_3d_trace():
    cam = _dome((1.5e-3, -2.0e-3, 3.0e-3))
    uv = cam.pinhole.pixel_grid(step=37)
    rays = cam.unproject(uv)
    origins, dirs = _trace_dome_3d(cam, uv)
    np.testing.assert_allclose(rays.origins, origins, atol=1e-12)
    np.testing.assert_allclose(rays.directions, dirs, atol=1e-12)


def test_dome_offset_moves_rays_by_the_expected_amount():
    # Known-answer check of the magnitude: a 2.1 mm axial offset of the paper's dome shifts the
    # image of a point 2 m away near the image corner by a few pixels, and by far less on axis.
    cam = _dome((0.0, 0.0, 2.10e-3))
    pts = np.array([[0.0, 0.0, 2.0], [1.5, 0.8, 2.0]])
    uv, _ = cam.project(pts)
    uv_pin, _ = cam.pinhole.project(pts)
    shift = np.linalg.norm(uv - uv_pin, axis=1)
    assert shift[0] < 1e-9
    assert 1.0 < shift[1] < 100.0


def _flat(normal=(0.0, 0.0, 1.0), **kw):
    return FlatPortCamera(
        _pinhole((0.03, -0.01, 0.0, 0.0, 0.0)),
        FlatPort(normal=np.asarray(normal), distance_m=0.01, thickness_m=0.008, **kw),
    )


@pytest.mark.parametrize("normal", [(0.0, 0.0, 1.0), (0.05, -0.03, 1.0)])
def test_flat_port_round_trip(normal, rng):
    cam = _flat(normal)
    uv = cam.pinhole.pixel_grid(step=4)
    rays = cam.unproject(uv)
    assert rays.valid.all()
    back, valid = cam.project(rays.at(rng.uniform(0.3, 20.0, len(uv))))
    assert valid.all()
    assert np.abs(back - uv).max() < REFRACTIVE_ROUNDTRIP_PX
    # Origins lie on the outer plane.
    np.testing.assert_allclose(rays.origins @ cam.port.normal, 0.018, atol=1e-12)


def test_flat_port_matches_independent_3d_trace():
    cam = _flat((0.05, -0.03, 1.0))
    n = cam.port.normal
    uv = cam.pinhole.pixel_grid(step=41)
    d = cam.pinhole.unproject(uv).directions
    p1 = d * (0.01 / (d @ n))[:, None]
    g, _ = refract(d, -n, cam.port.n_air, cam.port.n_glass)
    p2 = p1 + g * (0.008 / (g @ n))[:, None]
    w, _ = refract(g, -n, cam.port.n_glass, cam.port.n_water)
    rays = cam.unproject(uv)
    np.testing.assert_allclose(rays.origins, p2, atol=1e-12)
    np.testing.assert_allclose(rays.directions, w, atol=1e-12)


def test_flat_port_with_equal_indices_is_the_pinhole(rng):
    cam = _flat(n_air=1.2, n_glass=1.2, n_water=1.2)
    pts = np.c_[rng.uniform(-3, 3, (1000, 2)), rng.uniform(0.3, 20, 1000)]
    uv, valid = cam.project(pts)
    ref, vref = cam.pinhole.project(pts)
    np.testing.assert_array_equal(uv, ref)
    np.testing.assert_array_equal(valid, vref)
    assert np.abs(uv - ref).max() <= PINHOLE_REDUCTION_PX


def test_flat_port_magnifies_like_water():
    # Far from a thin window, refraction scales tan(angle) by about n_air / n_water.
    cam = _flat()
    pt = np.array([[1.0, 0.0, 20.0]])
    uv, _ = cam.project(pt)
    uv_pin, _ = cam.pinhole.project(pt)
    ratio = (uv[0, 0] - cam.pinhole.cx) / (uv_pin[0, 0] - cam.pinhole.cx)
    assert abs(ratio - 1.333 / 1.000292) < 0.01


def test_points_inside_the_port_or_behind_are_invalid():
    cam = _dome(PAPER_CENTER)
    uv, valid = cam.project(np.array([[0.0, 0.0, 0.01], [0.0, 0.0, -2.0], [0.0, 0.0, 2.0]]))
    assert valid.tolist() == [False, False, True]
    assert np.isnan(uv[:2]).all()


def test_bad_port_parameters_raise():
    with pytest.raises(RefractionError, match="outside the dome"):
        DomePort(center_m=np.array([0.0, 0.0, 0.04]), inner_radius_m=R_IN, thickness_m=THICK)
    with pytest.raises(RefractionError, match="inner_radius_m"):
        DomePort(center_m=np.zeros(3), inner_radius_m=-0.01, thickness_m=THICK)
    with pytest.raises(RefractionError, match="n_glass"):
        DomePort(center_m=np.zeros(3), inner_radius_m=R_IN, thickness_m=THICK, n_glass=0.5)
    with pytest.raises(RefractionError, match="forward"):
        FlatPort(normal=np.array([0.0, 0.0, -1.0]), distance_m=0.01, thickness_m=0.01)
    with pytest.raises(RefractionError, match="3 finite"):
        DomePort(center_m=np.zeros(2), inner_radius_m=R_IN, thickness_m=THICK)
