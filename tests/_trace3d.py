"""An independent 3D ray tracer for tests of rendering and depth.

Written from the physics, sharing no code with ``sea3d.refraction`` or ``sea3d.geometry``: the
pinhole part is OpenCV's (``undistortPointsIter`` / ``projectPoints``, the reference tool), the
ports are sphere and plane intersections with the vector form of Snell's law written out here.
Depth checks that pass through it cannot agree with sea3d's camera models merely because both
sides share a bug.
"""

from __future__ import annotations

import cv2
import numpy as np

from sea3d.refraction import DomePortCamera, FlatPortCamera


def _snell(d: np.ndarray, n: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Refract unit directions ``d`` at unit normals ``n`` (pointing back into medium 1)."""
    cos_i = -np.einsum("ij,ij->i", n, d)
    eta = n1 / n2
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    t = eta * d + (eta * cos_i - np.sqrt(k))[:, None] * n
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def pinhole_directions(pinhole: object, uv: np.ndarray) -> np.ndarray:
    """Unit ray directions of raw pixels through a pinhole with OpenCV distortion."""
    K = np.asarray(pinhole.K, dtype=np.float64)  # type: ignore[attr-defined]
    dist = np.asarray(pinhole.dist, dtype=np.float64)  # type: ignore[attr-defined]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = cv2.undistortPointsIter(np.asarray(uv, np.float64).reshape(-1, 1, 2), K, dist, None,
                                 None, crit).reshape(-1, 2)
    d = np.c_[xy, np.ones(len(xy))]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def trace(camera: object, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions, in the camera frame, of the rays that leave raw pixels
    ``uv`` (N, 2) into the scene (water for port cameras)."""
    pin = getattr(camera, "pinhole", camera)
    d = pinhole_directions(pin, uv)
    o = np.zeros_like(d)
    if isinstance(camera, DomePortCamera):
        port = camera.port
        c = np.asarray(port.center_m, dtype=np.float64)
        for radius, n1, n2 in ((port.inner_radius_m, port.n_air, port.n_glass),
                               (port.inner_radius_m + port.thickness_m, port.n_glass,
                                port.n_water)):
            oc = o - c
            b = np.einsum("ij,ij->i", d, oc)
            lam = -b + np.sqrt(b * b - (np.einsum("ij,ij->i", oc, oc) - radius * radius))
            o = o + lam[:, None] * d
            normal = -(o - c) / radius  # back towards the camera (medium 1)
            d = _snell(d, normal, n1, n2)
    elif isinstance(camera, FlatPortCamera):
        port = camera.port
        nrm = np.asarray(port.normal, dtype=np.float64)
        nrm = nrm / np.linalg.norm(nrm)
        for dist_m, n1, n2 in ((port.distance_m, port.n_air, port.n_glass),
                               (port.distance_m + port.thickness_m, port.n_glass, port.n_water)):
            lam = (dist_m - o @ nrm) / (d @ nrm)
            o = o + lam[:, None] * d
            d = _snell(d, np.tile(-nrm, (len(d), 1)), n1, n2)
    return o, d


def project(camera: object, points: np.ndarray, iterations: int = 8) -> np.ndarray:
    """Raw pixels whose traced rays pass through ``points`` (N, 3, camera frame), found by
    Gauss-Newton on the pixel from the plain pinhole projection."""
    pin = getattr(camera, "pinhole", camera)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    K = np.asarray(pin.K, dtype=np.float64)
    dist = np.asarray(pin.dist, dtype=np.float64)
    uv = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                           dist)[0].reshape(-1, 2)
    if not isinstance(camera, DomePortCamera | FlatPortCamera):
        return uv

    def miss(q: np.ndarray) -> np.ndarray:
        o, d = trace(camera, q)
        v = pts - o
        off = v - np.einsum("ij,ij->i", v, d)[:, None] * d  # offset of the point off the ray
        return off[:, :2] / np.maximum(pts[:, 2:3], 1e-9)

    h = 1e-3
    for _ in range(iterations):
        r = miss(uv)
        jx = (miss(uv + [h, 0.0]) - r) / h
        jy = (miss(uv + [0.0, h]) - r) / h
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        du = (jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1]) / det
        dv = (jx[:, 0] * r[:, 1] - jx[:, 1] * r[:, 0]) / det
        uv = uv - np.c_[du, dv]
    return uv
