"""Vector Snell's law (paper eq. 2.11)."""

import numpy as np
import pytest

from sea3d.errors import GeometryError
from sea3d.refraction import refract


def test_known_angle_air_to_water():
    theta = np.deg2rad(30.0)
    incident = np.array([[np.sin(theta), 0.0, np.cos(theta)]])
    out, ok = refract(incident, [0.0, 0.0, -1.0], 1.0, 1.333)
    assert ok.all()
    expected = np.arcsin(np.sin(theta) / 1.333)
    np.testing.assert_allclose(np.arcsin(out[0, 0]), expected, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)


def test_normal_incidence_passes_straight():
    out, ok = refract(np.array([[0.0, 0.0, 1.0]]), [0.0, 0.0, -1.0], 1.0, 1.492)
    assert ok.all()
    np.testing.assert_allclose(out, [[0.0, 0.0, 1.0]], atol=1e-15)


def test_total_internal_reflection_is_reported_not_hidden():
    theta = np.deg2rad(60.0)  # beyond the critical angle glass -> air (about 42 deg)
    incident = np.array([[np.sin(theta), 0.0, np.cos(theta)], [0.0, 0.0, 1.0]])
    out, ok = refract(incident, [0.0, 0.0, -1.0], 1.492, 1.0)
    assert ok.tolist() == [False, True]
    assert np.isnan(out[0]).all()


def test_refracting_back_returns_the_original_direction(rng):
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.5
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    fwd, ok = refract(d, [0.0, 0.0, -1.0], 1.0, 1.333)
    back, ok2 = refract(-fwd, [0.0, 0.0, 1.0], 1.333, 1.0)
    assert ok.all() and ok2.all()
    np.testing.assert_allclose(-back, d, atol=1e-12)


def test_bad_input():
    with pytest.raises(GeometryError):
        refract(np.zeros((3, 4)), [0, 0, 1], 1.0, 1.3)
    with pytest.raises(GeometryError, match="indices"):
        refract(np.zeros((3, 3)), [0, 0, 1], 0.0, 1.3)
