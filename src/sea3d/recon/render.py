"""Pictures without a display: point clouds (a z-buffered splat renderer in numpy) and meshes
(CPU ray casting with Open3D, shaded)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.geometry.se3 import invert_T, look_at, transform_points

__all__ = ["render_mesh", "render_points", "view_from_above"]


def render_points(
    points: NDArray[np.float64],
    colors_rgb: NDArray[np.uint8],
    T_world_view: NDArray[np.float64],
    *,
    size_px: tuple[int, int] = (960, 540),
    fov_deg: float = 60.0,
    splat_px: int = 2,
    background_rgb: tuple[int, int, int] = (24, 24, 28),
) -> NDArray[np.uint8]:
    """Render coloured points from a virtual pinhole camera (OpenCV axes) with a z-buffer.

    Args:
        points: ``(N, 3)`` points in the world frame, metres.
        colors_rgb: ``(N, 3)`` uint8 colours.
        T_world_view: 4x4 pose of the virtual camera.
        size_px: ``(width, height)`` of the picture.
        fov_deg: horizontal field of view.
        splat_px: side of the square each point covers, pixels.
        background_rgb: colour where no point lands.

    Returns:
        ``(H, W, 3)`` uint8 RGB picture; nearer points hide farther ones.

    Raises:
        ReconError: mismatched points and colours.
    """
    if points.ndim != 2 or points.shape[1] != 3 or colors_rgb.shape != points.shape:
        raise ReconError(
            f"render_points needs points (N, 3) and colours (N, 3); got {points.shape}, "
            f"{colors_rgb.shape}"
        )
    w, h = size_px
    f = 0.5 * w / np.tan(np.deg2rad(fov_deg) / 2)
    p = transform_points(invert_T(T_world_view), points)
    front = p[:, 2] > 1e-3
    p, c = p[front], colors_rgb[front]
    u = np.rint(f * p[:, 0] / p[:, 2] + (w - 1) / 2).astype(np.int64)
    v = np.rint(f * p[:, 1] / p[:, 2] + (h - 1) / 2).astype(np.int64)
    offsets = [(du, dv) for dv in range(splat_px) for du in range(splat_px)]
    uu = np.concatenate([u + du for du, _ in offsets])
    vv = np.concatenate([v + dv for _, dv in offsets])
    zz = np.tile(p[:, 2], len(offsets))
    cc = np.tile(c, (len(offsets), 1))
    ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
    uu, vv, zz, cc = uu[ok], vv[ok], zz[ok], cc[ok]
    # z-buffer: for each pixel keep the nearest point (sort by pixel, then depth).
    pix = vv * w + uu
    order = np.lexsort((zz, pix))
    first = np.unique(pix[order], return_index=True)[1]
    keep = order[first]
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background_rgb
    img[vv[keep], uu[keep]] = cc[keep]
    return img


def render_mesh(
    mesh: Mesh,
    T_world_view: NDArray[np.float64],
    *,
    size_px: tuple[int, int] = (960, 540),
    fov_deg: float = 50.0,
    light_dir_view: tuple[float, float, float] = (0.3, -0.5, 1.0),
    ambient: float = 0.35,
    background_rgb: tuple[int, int, int] = (24, 24, 28),
) -> NDArray[np.uint8]:
    """A shaded picture of a mesh, ray cast on the CPU (Open3D ``RaycastingScene``; no display
    or OpenGL needed).

    Each pixel's colour is the hit triangle's vertex colours interpolated at the hit, times
    ``ambient + (1 - ambient) * |n . l|`` with the face normal ``n`` and a light from
    ``light_dir_view`` (view frame, OpenCV axes); grey where the mesh has no colours.

    Args:
        mesh: the mesh (world frame).
        T_world_view: 4x4 pose of the virtual camera (OpenCV axes: z forward, y down).
        size_px: ``(width, height)``.
        fov_deg: horizontal field of view.

    Returns:
        ``(H, W, 3)`` uint8 RGB.
    """
    import open3d as o3d

    _Tensor: Any = o3d.core.Tensor

    w, h = size_px
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background_rgb
    if mesh.empty:
        return img
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        _Tensor(np.ascontiguousarray(mesh.vertices, np.float32)),
        _Tensor(np.ascontiguousarray(mesh.triangles, np.uint32)),
    )
    f = 0.5 * w / np.tan(np.deg2rad(fov_deg) / 2)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d_view = np.stack([(u - (w - 1) / 2) / f, (v - (h - 1) / 2) / f, np.ones_like(u)], -1)
    d_view /= np.linalg.norm(d_view, axis=-1, keepdims=True)
    R, t = T_world_view[:3, :3], T_world_view[:3, 3]
    d = d_view.reshape(-1, 3) @ R.T
    rays = np.concatenate([np.broadcast_to(t, d.shape), d], axis=1).astype(np.float32)
    hit = scene.cast_rays(_Tensor(rays))
    tri = hit["primitive_ids"].numpy().astype(np.int64)
    ok = tri != np.iinfo(np.uint32).max
    if not ok.any():
        return img
    uvb = hit["primitive_uvs"].numpy()[ok].astype(np.float64)
    nrm = hit["primitive_normals"].numpy()[ok].astype(np.float64)
    light = np.asarray(light_dir_view, np.float64) @ R.T
    light /= np.linalg.norm(light)
    shade = ambient + (1.0 - ambient) * np.abs(nrm @ light)
    if mesh.colors_rgb is not None:
        corners = mesh.colors_rgb[mesh.triangles[tri[ok]]].astype(np.float64)
        b1, b2 = uvb[:, 0], uvb[:, 1]
        col = (corners[:, 0] * (1 - b1 - b2)[:, None] + corners[:, 1] * b1[:, None]
               + corners[:, 2] * b2[:, None])
    else:
        col = np.full((int(ok.sum()), 3), 200.0)
    out = img.reshape(-1, 3)
    out[ok] = np.clip(col * shade[:, None], 0, 255).astype(np.uint8)
    return img


def view_from_above(
    points: NDArray[np.float64], *, tilt_deg: float = 35.0, fov_deg: float = 50.0,
    aspect: float = 16 / 9, up_world: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> NDArray[np.float64]:
    """``T_world_view`` of a camera that frames ``points`` from above (``up_world``), tilted
    ``tilt_deg`` from looking straight down, far enough back for the whole extent."""
    lo = np.percentile(points, 1, axis=0)
    hi = np.percentile(points, 99, axis=0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    up = np.asarray(up_world, np.float64)
    up /= np.linalg.norm(up)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    tilt = np.deg2rad(tilt_deg)
    back = np.cross(side, up)
    direction = -np.cos(tilt) * up + np.sin(tilt) * back  # from the eye to the centre
    fov_v = 2 * np.arctan(np.tan(np.deg2rad(fov_deg) / 2) / aspect)
    dist = 0.9 * radius / np.tan(min(np.deg2rad(fov_deg), fov_v) / 2)
    eye = centre - dist * direction
    screen_up = up - direction * float(up @ direction)
    return look_at(eye, centre, up=screen_up)
