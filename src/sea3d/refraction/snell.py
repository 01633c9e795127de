"""Snell's law in vector form.

For a unit incident direction ``i``, a unit surface normal ``n`` that faces the incident side
(``n . i < 0``) and indices ``n_i`` (incident) and ``n_r`` (refracted), the refracted direction
is the paper's eq. 2.11::

    r = (n_i / n_r) i + ((n_i / n_r) cos(theta_i) - sqrt(1 - sin^2(theta_r))) n

with ``cos(theta_i) = -n . i`` and ``sin^2(theta_r) = (n_i / n_r)^2 (1 - cos^2(theta_i))``.
When ``sin^2(theta_r) > 1`` the light is totally internally reflected: there is no refracted
ray, and this module says so instead of returning a reflected or clipped one.
"""

from __future__ import annotations

import numpy as np

from sea3d._typing import BoolArray, FloatArray
from sea3d.errors import GeometryError

__all__ = ["refract"]


def refract(
    incident: object, normal: object, n_incident: float, n_refracted: float
) -> tuple[FloatArray, BoolArray]:
    """Refract unit directions at a surface (paper eq. 2.11).

    Args:
        incident: ``(N, D)`` unit incident directions (D = 2 or 3).
        normal: ``(N, D)`` or ``(D,)`` unit surface normals facing the incident side.
        n_incident: refractive index on the incident side (> 0).
        n_refracted: refractive index on the far side (> 0).

    Returns:
        ``directions`` ``(N, D)`` unit refracted directions and ``ok`` ``(N,)`` bool. Where
        ``ok`` is False (total internal reflection, or a normal on the wrong side) the row is
        NaN.

    Raises:
        GeometryError: shapes that do not match, or non-positive indices.
    """
    i = np.asarray(incident, dtype=np.float64)
    if i.ndim != 2 or i.shape[1] not in (2, 3):
        raise GeometryError(f"incident directions must be (N, 2) or (N, 3), got {i.shape}")
    try:
        n = np.broadcast_to(np.asarray(normal, dtype=np.float64), i.shape)
    except ValueError as err:
        raise GeometryError(
            f"normals of shape {np.asarray(normal).shape} do not match directions {i.shape}"
        ) from err
    if n_incident <= 0 or n_refracted <= 0:
        raise GeometryError(f"refractive indices must be > 0, got {n_incident}, {n_refracted}")
    eta = n_incident / n_refracted
    cos_i = -np.einsum("ij,ij->i", n, i)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    ok = (sin2_t <= 1.0) & (cos_i >= 0.0)
    with np.errstate(invalid="ignore"):
        coef = eta * cos_i - np.sqrt(1.0 - sin2_t)
    out = eta * i + coef[:, None] * n
    out[~ok] = np.nan
    return out, ok
