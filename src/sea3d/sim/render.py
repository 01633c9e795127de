"""Ray-traced rendering of a scene through any sea3d camera model, with ground truth.

Each pixel's rays come from the camera model's own ``unproject`` (pinhole, dome port or flat
port), so refraction at the port is exact rather than approximated: a port camera's rays start on
the outer port surface and point into the water, and Open3D's
:class:`open3d.t.geometry.RaycastingScene` casts them from there. Colour is the mean of
``supersample x supersample`` stratified rays per pixel (anti-aliasing), by default only where
the centre rays show an edge (adaptive supersampling); ground truth comes from the ray through
the exact pixel centre, so it is sharp and matches the camera model's ``project`` to float
precision.

Ground truth per pixel (camera frame, OpenCV axes):

- ``depth_m``: z of the hit point in the camera frame (for port cameras too), float32 metres;
- ``range_m``: distance from the camera centre to the hit point, float32 metres;
- ``points_cam``: the hit point, float32 metres; ``normals_cam``: the surface normal facing the
  camera; ``object_id``: int32 index into :attr:`Scene.objects`.

Where nothing is hit, float fields are NaN and ``object_id`` is -1.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from sea3d._typing import F32, FloatArray
from sea3d.errors import SimulationError
from sea3d.geometry.camera import CameraModel
from sea3d.sim._kernels import (
    N_SAND_PARAMS,
    camera_ground_truth,
    edge_pixels,
    hit_points,
    hits_and_truth,
    postprocess_hits,
    shade_fused,
    world_hit_points,
    world_rays,
)
from sea3d.sim.materials import SandMaterial
from sea3d.sim.noise import rigid_transform
from sea3d.sim.optics import Imaging, caustic_mean
from sea3d.sim.scene import Scene

__all__ = ["Hits", "RenderedView", "Renderer", "ViewTruth"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True, eq=False)
class ViewTruth:
    """Per-pixel ground truth of one rendered view (see the module docstring).

    Attributes:
        depth_m: ``(H, W)`` float32, z in the camera frame, metres, NaN where nothing is hit.
        range_m: ``(H, W)`` float32, distance from the camera centre, metres, NaN where no hit.
        points_cam: ``(H, W, 3)`` float32 hit points in the camera frame, metres.
        normals_cam: ``(H, W, 3)`` float32 unit normals in the camera frame, facing the camera.
        object_id: ``(H, W)`` int32 object index, -1 where nothing is hit.
    """

    depth_m: F32
    range_m: F32
    points_cam: F32
    normals_cam: F32
    object_id: NDArray[np.int32]


@dataclass(frozen=True, kw_only=True, eq=False)
class RenderedView:
    """One rendered image and its ground truth.

    Attributes:
        image: ``(H, W, 3)`` uint8 sRGB image (RGB order).
        radiance: ``(H, W, 3)`` float32 linear radiance before the sensor model.
        gt: :class:`ViewTruth`.
    """

    image: NDArray[np.uint8]
    radiance: F32
    gt: ViewTruth


@dataclass(frozen=True, kw_only=True, eq=False)
class Hits:
    """Result of casting N rays.

    Attributes:
        t_m: ``(N,)`` float64 distance along the ray (ray directions are unit), inf for no hit.
        object_id: ``(N,)`` int32, -1 for no hit.
        normals_world: ``(N, 3)`` float32 unit normals, world frame, facing the incoming ray.
    """

    t_m: FloatArray
    object_id: NDArray[np.int32]
    normals_world: F32


@dataclass(frozen=True, eq=False)
class _CameraRays:
    origins: F32  # (S, H, W, 3) camera frame; S = 1 (centre only) when supersampling adaptively
    dirs: F32  # (S, H, W, 3)
    pixel_angle_rad: float
    colour_samples: tuple[int, ...]  # which of the offsets are averaged for colour
    offsets: tuple[tuple[float, float], ...]  # (du, dv) of every sample, centre first


def _clock() -> tuple[float, float]:
    """(wall, process CPU) seconds now; CPU time counts every thread of the process."""
    return time.perf_counter(), time.process_time()


def _sample_offsets(supersample: int) -> tuple[list[tuple[float, float]], tuple[int, ...]]:
    """Pixel offsets: the centre first (ground truth), then the stratified colour samples."""
    n = supersample
    grid = [((i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5) for j in range(n) for i in range(n)]
    if n % 2 == 1:
        centre = grid.index((0.0, 0.0))
        rest = [g for k, g in enumerate(grid) if k != centre]
        return [(0.0, 0.0), *rest], tuple(range(len(grid)))
    return [(0.0, 0.0), *grid], tuple(range(1, len(grid) + 1))


class Renderer:
    """Renders views of one scene.

    Args:
        scene: the :class:`~sea3d.sim.scene.Scene`.
        supersample: rays per pixel along each axis for colour (1 = one ray per pixel).
        adaptive: supersample only pixels at object boundaries, depth steps and edges of
            hard-edged textures (boards, markers); elsewhere the band-limited procedural textures
            need no more than the centre ray. False supersamples every pixel.
        chunk_rows: image rows processed at once by the reference path (bounds memory).
        nthreads: Open3D ray-casting threads (0 = all cores).
        fused: shade in fused numba passes over the whole image (the default). False runs the
            original per-material path in row chunks; it gives the same images and is kept as
            the reference the tests compare against.

    Raises:
        SimulationError: for an empty scene or ``supersample < 1``.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        supersample: int = 2,
        adaptive: bool = True,
        chunk_rows: int = 128,
        nthreads: int = 0,
        fused: bool = True,
    ) -> None:
        if supersample < 1:
            raise SimulationError(f"supersample must be >= 1, got {supersample}")
        if not scene.objects:
            raise SimulationError(f"scene {scene.name!r} has no objects to render")
        self.scene = scene
        self.supersample = int(supersample)
        self.adaptive = bool(adaptive)
        self.last_supersampled_fraction = 0.0
        self.chunk_rows = int(chunk_rows)
        self.nthreads = int(nthreads)
        self._rc = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        geom_to_obj: dict[int, int] = {}
        for k, obj in enumerate(scene.objects):
            tmesh = o3d.t.geometry.TriangleMesh.from_legacy(obj.mesh)
            gid = self._rc.add_triangles(tmesh)
            geom_to_obj[int(gid)] = k
        lut = np.full(max(geom_to_obj) + 2, -1, dtype=np.int32)
        for gid, k in geom_to_obj.items():
            lut[gid] = k
        self._geom_lut = lut
        # Index object_id + 1 (so -1, nothing hit, is index 0): does the material have hard edges?
        self._hard_lut = np.array(
            [False] + [o.material.hard_edges for o in scene.objects]
        )
        # Per-object tables for the fused shading kernel: which objects are sand (their texture
        # is evaluated inside the kernel), the sand parameters and world-to-object transforms.
        self.fused = bool(fused)
        n_obj = len(scene.objects)
        self._sand = np.zeros(n_obj, dtype=bool)
        self._sand_par = np.zeros((n_obj, N_SAND_PARAMS), dtype=np.float64)
        self._has_T = np.zeros(n_obj, dtype=bool)
        self._T_inv = np.zeros((n_obj, 3, 4), dtype=np.float64)
        for k, obj in enumerate(scene.objects):
            Tw = np.asarray(obj.T_world_object, dtype=np.float64)
            if not np.array_equal(Tw, np.eye(4)):
                self._has_T[k] = True
                self._T_inv[k, :, :3] = Tw[:3, :3].T
                self._T_inv[k, :, 3] = -Tw[:3, :3].T @ Tw[:3, 3]
            m = obj.material
            if type(m) is SandMaterial:
                self._sand[k] = True
                self._sand_par[k] = (
                    *m.colour_rgb,
                    1.0 / (16.0 * m.grain_m),
                    m.contrast,
                    m.ripple_wavelength_m,
                    m.seed,
                )
        self._other_lut = np.concatenate([[False], ~self._sand])  # index object_id + 1
        self._ray_cache: dict[tuple[int, int], tuple[Any, _CameraRays]] = {}
        # Seconds spent per stage, summed over calls (clear them to start over): wall time, and
        # process CPU time (all threads; the fused path and ray generation only).
        self.timings_s: dict[str, float] = defaultdict(float)
        self.cpu_timings_s: dict[str, float] = defaultdict(float)

    # ------------------------------------------------------------------------------------------

    def cast(self, origins_world: FloatArray, dirs_world: FloatArray) -> Hits:
        """Cast rays into the scene.

        Args:
            origins_world: ``(N, 3)`` float64 ray origins, world frame, metres.
            dirs_world: ``(N, 3)`` float64 unit directions, world frame. NaN rows never hit.

        Returns:
            :class:`Hits`.
        """
        n = origins_world.shape[0]
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = origins_world
        rays[:, 3:] = dirs_world
        bad = ~np.isfinite(rays.sum(axis=1))
        if bad.any():
            rays[bad] = np.array([0, 0, 0, 0, 0, 1], dtype=np.float32)
        ans = self._rc.cast_rays(o3d.core.Tensor(rays), nthreads=self.nthreads)  # type: ignore[call-overload]
        t, obj, normals = postprocess_hits(
            ans["t_hit"].numpy(),
            ans["geometry_ids"].numpy(),
            ans["primitive_normals"].numpy(),
            rays[:, 3:],
            self._geom_lut,
            bad,
        )
        return Hits(t_m=t, object_id=obj, normals_world=normals)

    def camera_rays(self, camera: CameraModel) -> _CameraRays:
        """Every sample ray of ``camera`` in its own frame, computed once per camera object."""
        key = (id(camera), self.supersample)
        cached = self._ray_cache.get(key)
        if cached is not None and cached[0] is camera:
            return cached[1]
        c0 = _clock()
        w, h = int(camera.width), int(camera.height)
        offsets, colour = _sample_offsets(self.supersample)
        # Adaptive supersampling needs the extra rays for a few pixels only: made on demand.
        n_cached = 1 if self.adaptive else len(offsets)
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        origins = np.empty((n_cached, h, w, 3), dtype=np.float32)
        dirs = np.empty((n_cached, h, w, 3), dtype=np.float32)
        for s, (du, dv) in enumerate(offsets[:n_cached]):
            uv = np.stack([(uu + du).ravel(), (vv + dv).ravel()], axis=1)
            rays = camera.unproject(uv)
            d = rays.directions / np.linalg.norm(rays.directions, axis=1, keepdims=True)
            origins[s] = rays.origins.reshape(h, w, 3)
            dirs[s] = d.reshape(h, w, 3)
        c = np.array([[(w - 1) / 2, (h - 1) / 2], [(w - 1) / 2 + 1, (h - 1) / 2]])
        r = camera.unproject(c).directions
        cosang = float(np.dot(r[0], r[1]) / (np.linalg.norm(r[0]) * np.linalg.norm(r[1])))
        ang = float(np.arccos(np.clip(cosang, -1.0, 1.0)))
        cam_rays = _CameraRays(
            origins=origins,
            dirs=dirs,
            pixel_angle_rad=ang,
            colour_samples=colour,
            offsets=tuple(offsets),
        )
        self._ray_cache[key] = (camera, cam_rays)
        self._lap("ray_generation", c0)
        return cam_rays

    def _lap(self, key: str, start: tuple[float, float]) -> tuple[float, float]:
        """Add the wall and CPU time since ``start`` (from :func:`_clock`) to stage ``key``."""
        now = _clock()
        self.timings_s[key] += now[0] - start[0]
        self.cpu_timings_s[key] += now[1] - start[1]
        return now

    def render(
        self,
        camera: CameraModel,
        T_world_cam: FloatArray,
        imaging: Imaging | None = None,
        *,
        time_s: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> RenderedView:
        """Render one view.

        Args:
            camera: any :class:`~sea3d.geometry.camera.CameraModel`.
            T_world_cam: ``(4, 4)`` float64 camera pose (maps camera-frame points to world).
            imaging: water, light and sensor effects; None = :meth:`Imaging.clean`.
            time_s: scene time (caustic animation), seconds.
            rng: generator for sensor noise (required when noise is on).

        Returns:
            :class:`RenderedView` with the image and ground truth.

        Raises:
            SimulationError: for a malformed pose.
        """
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise SimulationError(f"T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
        imaging = imaging or Imaging.clean()
        if self.fused:
            return self._render_fused(camera, T, imaging, time_s, rng)
        cam_rays = self.camera_rays(camera)
        _, h, w, _ = cam_rays.origins.shape
        S = len(cam_rays.offsets)
        R, tvec = T[:3, :3], T[:3, 3]
        light_pos = R @ np.asarray(imaging.vehicle_light_offset_m, dtype=np.float64) + tvec
        light_axis = R[:, 2]
        radiance = np.empty((h, w, 3), dtype=np.float32)
        depth = np.full((h, w), np.nan, dtype=np.float32)
        rng_m = np.full((h, w), np.nan, dtype=np.float32)
        points = np.full((h, w, 3), np.nan, dtype=np.float32)
        normals = np.full((h, w, 3), np.nan, dtype=np.float32)
        obj_id = np.full((h, w), -1, dtype=np.int32)
        colour_idx = np.asarray(cam_rays.colour_samples)
        # Pass 1: every pixel's centre ray (index 0): ground truth, and the colour of pixels that
        # need no more samples.
        for r0 in range(0, h, self.chunk_rows):
            r1 = min(h, r0 + self.chunk_rows)
            t0 = time.perf_counter()
            o_cam = cam_rays.origins[0, r0:r1].reshape(-1, 3).astype(np.float64)
            d_cam = cam_rays.dirs[0, r0:r1].reshape(-1, 3).astype(np.float64)
            o_w = rigid_transform(R, tvec, o_cam)
            d_w = rigid_transform(R, np.zeros(3), d_cam)
            t1 = time.perf_counter()
            hits = self.cast(o_w, d_w)
            t2 = time.perf_counter()
            rad = self._shade(
                hits, o_w, d_w, cam_rays.pixel_angle_rad, imaging, light_pos, light_axis, time_s
            )
            radiance[r0:r1] = rad.reshape(r1 - r0, w, 3)
            p_cam, z_cam, r_cam, n_cam = camera_ground_truth(
                o_cam, d_cam, hits.t_m, hits.normals_world, R
            )
            points[r0:r1] = p_cam.reshape(r1 - r0, w, 3)
            normals[r0:r1] = n_cam.reshape(r1 - r0, w, 3)
            depth[r0:r1] = z_cam.reshape(r1 - r0, w)
            rng_m[r0:r1] = r_cam.reshape(r1 - r0, w)
            obj_id[r0:r1] = hits.object_id.reshape(r1 - r0, w)
            t3 = time.perf_counter()
            self.timings_s["transform"] += t1 - t0
            self.timings_s["casting"] += t2 - t1
            self.timings_s["shading"] += t3 - t2
        # Pass 2: the stratified colour samples, for every pixel or (adaptive) only where the
        # centre rays show an edge the band-limited textures cannot smooth.
        if S > 1:
            if self.adaptive:
                vv, uu = np.nonzero(self._edge_pixels(obj_id, depth, radiance))
            else:
                vv, uu = np.nonzero(np.ones((h, w), dtype=bool))
            n_sub = len(colour_idx)
            batch = max(1, (self.chunk_rows * w) // n_sub)
            for b0 in range(0, vv.size, batch):
                bv, bu = vv[b0 : b0 + batch], uu[b0 : b0 + batch]
                t0 = time.perf_counter()
                if cam_rays.origins.shape[0] > 1:
                    o_sub = cam_rays.origins[colour_idx[:, None], bv[None, :], bu[None, :]]
                    d_sub = cam_rays.dirs[colour_idx[:, None], bv[None, :], bu[None, :]]
                else:
                    o_sub, d_sub = self._sample_rays(camera, cam_rays, colour_idx, bu, bv)
                    self.timings_s["ray_generation"] += time.perf_counter() - t0
                    t0 = time.perf_counter()
                o_w = rigid_transform(R, tvec, o_sub.reshape(-1, 3))
                d_w = rigid_transform(R, np.zeros(3), d_sub.reshape(-1, 3))
                t1 = time.perf_counter()
                hits = self.cast(o_w, d_w)
                t2 = time.perf_counter()
                rad = self._shade(
                    hits,
                    o_w,
                    d_w,
                    cam_rays.pixel_angle_rad,
                    imaging,
                    light_pos,
                    light_axis,
                    time_s,
                )
                radiance[bv, bu] = rad.reshape(n_sub, bv.size, 3).mean(axis=0)
                t3 = time.perf_counter()
                self.timings_s["transform"] += t1 - t0
                self.timings_s["casting"] += t2 - t1
                self.timings_s["shading"] += t3 - t2
            self.last_supersampled_fraction = float(vv.size) / float(h * w)
        t4 = time.perf_counter()
        image = imaging.sensor(radiance, rng)
        self.timings_s["sensor"] += time.perf_counter() - t4
        gt = ViewTruth(
            depth_m=depth, range_m=rng_m, points_cam=points, normals_cam=normals, object_id=obj_id
        )
        return RenderedView(image=image, radiance=radiance, gt=gt)

    def _render_fused(
        self,
        camera: CameraModel,
        T: FloatArray,
        imaging: Imaging,
        time_s: float,
        rng: np.random.Generator | None,
    ) -> RenderedView:
        """:meth:`render` in whole-image numba passes: the same numbers as the reference path."""
        cam_rays = self.camera_rays(camera)
        _, h, w, _ = cam_rays.origins.shape
        n = h * w
        R = np.ascontiguousarray(T[:3, :3])
        tvec = np.ascontiguousarray(T[:3, 3])
        radiance = np.empty((h, w, 3), dtype=np.float32)
        depth = np.empty((h, w), dtype=np.float32)
        rng_m = np.empty((h, w), dtype=np.float32)
        points = np.empty((h, w, 3), dtype=np.float32)
        normals = np.empty((h, w, 3), dtype=np.float32)
        obj_id = np.empty((h, w), dtype=np.int32)
        # Pass 1: every pixel's centre ray: ground truth, and the colour of most pixels.
        o_cam = cam_rays.origins[0].reshape(n, 3)
        d_cam = cam_rays.dirs[0].reshape(n, 3)
        t_m, n_w = self._trace(
            o_cam,
            d_cam,
            R,
            tvec,
            obj_id.reshape(n),
            (points.reshape(n, 3), depth.reshape(n), rng_m.reshape(n), normals.reshape(n, 3)),
        )
        c0 = _clock()
        self._shade_rays(
            o_cam,
            d_cam,
            R,
            tvec,
            t_m,
            obj_id.reshape(n),
            n_w,
            cam_rays.pixel_angle_rad,
            imaging,
            time_s,
            w,
            radiance.reshape(n, 3),
        )
        del t_m, n_w
        self._lap("shading", c0)
        # Pass 2: the stratified colour samples where the centre rays show an edge (adaptive),
        # or everywhere.
        if len(cam_rays.offsets) > 1:
            c0 = _clock()
            if self.adaptive:
                vv, uu = np.nonzero(edge_pixels(obj_id, depth, radiance, self._hard_lut))
            else:
                vv, uu = np.nonzero(np.ones((h, w), dtype=bool))
            self._lap("shading", c0)
            colour_idx = np.asarray(cam_rays.colour_samples)
            n_sub = len(colour_idx)
            batch = max(1, (self.chunk_rows * w) // n_sub)
            for b0 in range(0, vv.size, batch):
                bv, bu = vv[b0 : b0 + batch], uu[b0 : b0 + batch]
                c0 = _clock()
                if cam_rays.origins.shape[0] > 1:
                    o_sub = cam_rays.origins[colour_idx[:, None], bv[None, :], bu[None, :]]
                    d_sub = cam_rays.dirs[colour_idx[:, None], bv[None, :], bu[None, :]]
                else:
                    o_sub, d_sub = self._sample_rays(camera, cam_rays, colour_idx, bu, bv)
                self._lap("ray_generation", c0)
                m = n_sub * bv.size
                o_s = np.ascontiguousarray(o_sub.reshape(m, 3))
                d_s = np.ascontiguousarray(d_sub.reshape(m, 3))
                obj_s = np.empty(m, dtype=np.int32)
                gt_s = (
                    np.empty((m, 3), dtype=np.float32),
                    np.empty(m, dtype=np.float32),
                    np.empty(m, dtype=np.float32),
                    np.empty((m, 3), dtype=np.float32),
                )
                t_s, n_s = self._trace(o_s, d_s, R, tvec, obj_s, gt_s)
                c0 = _clock()
                rad = np.empty((m, 3), dtype=np.float32)
                self._shade_rays(
                    o_s,
                    d_s,
                    R,
                    tvec,
                    t_s,
                    obj_s,
                    n_s,
                    cam_rays.pixel_angle_rad,
                    imaging,
                    time_s,
                    256,
                    rad,
                )
                radiance[bv, bu] = rad.reshape(n_sub, bv.size, 3).mean(axis=0)
                self._lap("shading", c0)
            self.last_supersampled_fraction = float(vv.size) / float(n)
        c0 = _clock()
        image = imaging.sensor(radiance, rng)
        self._lap("sensor", c0)
        gt = ViewTruth(
            depth_m=depth, range_m=rng_m, points_cam=points, normals_cam=normals, object_id=obj_id
        )
        return RenderedView(image=image, radiance=radiance, gt=gt)

    def _trace(
        self,
        o_cam: NDArray[np.floating[Any]],
        d_cam: NDArray[np.floating[Any]],
        R: FloatArray,
        tvec: FloatArray,
        obj_out: NDArray[np.int32],
        gt_out: tuple[F32, F32, F32, F32],
    ) -> tuple[FloatArray, F32]:
        """Cast camera-frame rays posed by ``(R, tvec)``; fill object ids and ground truth
        (points, depth, range, normals in the camera frame); return ``t`` and world normals."""
        c0 = _clock()
        rays, bad = world_rays(o_cam, d_cam, R, tvec)
        c0 = self._lap("transform", c0)
        ans = self._rc.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self.nthreads)
        c0 = self._lap("casting", c0)
        n = rays.shape[0]
        t_m = np.empty(n, dtype=np.float64)
        n_w = np.empty((n, 3), dtype=np.float32)
        hits_and_truth(
            ans["t_hit"].numpy(),
            ans["geometry_ids"].numpy(),
            ans["primitive_normals"].numpy(),
            rays,
            self._geom_lut,
            bad,
            o_cam,
            d_cam,
            R,
            t_m,
            obj_out,
            n_w,
            *gt_out,
        )
        self._lap("shading", c0)
        return t_m, n_w

    def _shade_rays(
        self,
        o_cam: NDArray[np.floating[Any]],
        d_cam: NDArray[np.floating[Any]],
        R: FloatArray,
        tvec: FloatArray,
        t_m: FloatArray,
        obj: NDArray[np.int32],
        n_w: F32,
        pixel_angle_rad: float,
        imaging: Imaging,
        time_s: float,
        row_len: int,
        out: F32,
    ) -> None:
        """Radiance of each ray into ``out`` ``(N, 3)``: sand inside the fused kernel, the other
        materials' albedo first through their own ``albedo`` on their hits."""
        n = t_m.shape[0]
        albedo_pre = np.empty((n, 3), dtype=np.float32)  # rows written only for other materials
        idx = np.flatnonzero(self._other_lut[obj + 1])
        if idx.size:
            p_w = world_hit_points(o_cam, d_cam, R, tvec, t_m, idx)
            fp = t_m[idx] * pixel_angle_rad
            ids = obj[idx]
            for k in np.unique(ids):
                sel = ids == k
                p_k = p_w[sel]
                if self._has_T[k]:
                    Ti = self._T_inv[k]
                    p_k = rigid_transform(Ti[:, :3], Ti[:, 3], p_k)
                albedo_pre[idx[sel]] = self.scene.objects[int(k)].material.albedo(p_k, fp[sel])
        w = imaging.water
        zeros = np.zeros(3)
        sun_dir = -np.asarray(imaging.sun_direction_world, dtype=np.float64)
        sun_dir /= np.linalg.norm(sun_dir)
        light_pos = R @ np.asarray(imaging.vehicle_light_offset_m, dtype=np.float64) + tvec
        shade_fused(
            o_cam,
            d_cam,
            R,
            tvec,
            t_m,
            obj,
            n_w,
            float(pixel_angle_rad),
            albedo_pre,
            self._sand,
            self._sand_par,
            self._has_T,
            self._T_inv,
            sun_dir,
            float(imaging.sun_irradiance),
            float(imaging.ambient),
            float(self.scene.surface_z_m),
            np.asarray(w.beta_D_per_m, dtype=np.float64) if w else zeros,
            np.asarray(w.beta_B_per_m, dtype=np.float64) if w else zeros,
            np.asarray(w.B_inf_rgb, dtype=np.float64) if w else zeros,
            w is not None,
            bool(imaging.line_of_sight_water),
            light_pos,
            np.ascontiguousarray(R[:, 2]),
            float(imaging.vehicle_light),
            float(np.deg2rad(imaging.vehicle_light_cone_deg)),
            float(imaging.caustics),
            float(imaging.caustic_scale_m),
            float(time_s * imaging.caustic_speed_per_s),
            float(imaging.caustic_fade_depth_m),
            caustic_mean() if imaging.caustics > 0 else 1.0,
            int(row_len),
            out,
        )

    @staticmethod
    def _sample_rays(
        camera: CameraModel,
        cam_rays: _CameraRays,
        colour_idx: NDArray[np.int64],
        bu: NDArray[np.int64],
        bv: NDArray[np.int64],
    ) -> tuple[FloatArray, FloatArray]:
        """Camera-frame rays of the colour samples of pixels ``(bu, bv)``: ``(K, N, 3)`` each."""
        offs = np.asarray([cam_rays.offsets[k] for k in colour_idx])  # (K, 2)
        uv = np.stack([bu[None, :] + offs[:, 0:1], bv[None, :] + offs[:, 1:2]], axis=-1).reshape(
            -1, 2
        )
        rays = camera.unproject(uv.astype(np.float64))
        d = rays.directions / np.linalg.norm(rays.directions, axis=1, keepdims=True)
        k = len(colour_idx)
        return rays.origins.reshape(k, -1, 3), d.reshape(k, -1, 3)

    def _edge_pixels(
        self, obj_id: NDArray[np.int32], depth: F32, radiance: F32
    ) -> NDArray[np.bool_]:
        """Pixels whose 3x3 neighbourhood crosses an object boundary, a depth step of more than
        2 %, or (on hard-edged textures: boards, markers) a luminance step of more than 0.02."""
        h, w = obj_id.shape
        pad_id = np.pad(obj_id, 1, mode="edge")
        z = np.where(np.isfinite(depth), depth, np.float32(1e6))
        pad_z = np.pad(z, 1, mode="edge")
        lum = radiance @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        pad_l = np.pad(lum, 1, mode="edge")
        hard = self._hard_lut[obj_id + 1]
        edge = np.zeros((h, w), dtype=bool)
        for dv in (0, 1, 2):
            for du in (0, 1, 2):
                if dv == 1 and du == 1:
                    continue
                nid = pad_id[dv : dv + h, du : du + w]
                nz = pad_z[dv : dv + h, du : du + w]
                nl = pad_l[dv : dv + h, du : du + w]
                edge |= nid != obj_id
                edge |= np.abs(nz - z) > 0.02 * np.minimum(nz, z)
                edge |= hard & (np.abs(nl - lum) > 0.02)
        return edge

    def _shade(
        self,
        hits: Hits,
        o_w: FloatArray,
        d_w: FloatArray,
        pixel_angle_rad: float,
        imaging: Imaging,
        light_pos: FloatArray,
        light_axis: FloatArray,
        time_s: float,
    ) -> F32:
        n = hits.t_m.shape[0]
        out = imaging.background(n)
        hit = hits.object_id >= 0
        if not hit.any():
            return out
        idx = np.flatnonzero(hit)
        t = hits.t_m[idx]
        p_w = hit_points(o_w, d_w, hits.t_m, idx)
        footprint = t * pixel_angle_rad
        albedo = np.empty((idx.size, 3), dtype=np.float32)
        ids = hits.object_id[idx]
        present = np.flatnonzero(np.bincount(ids, minlength=len(self.scene.objects)))
        for k in present:
            obj = self.scene.objects[int(k)]
            Tw = obj.T_world_object
            if len(present) == 1:
                p_k, fp_k = p_w, footprint
            else:
                sel = ids == k
                p_k, fp_k = p_w[sel], footprint[sel]
            if not np.array_equal(Tw, np.eye(4)):
                p_k = rigid_transform(Tw[:3, :3].T, -Tw[:3, :3].T @ Tw[:3, 3], p_k)
            if len(present) == 1:
                albedo[:] = obj.material.albedo(p_k, fp_k)
            else:
                albedo[sel] = obj.material.albedo(p_k, fp_k)
        out[idx] = imaging.shade(
            albedo,
            p_w,
            hits.normals_world[idx],
            t,
            surface_z_m=self.scene.surface_z_m,
            light_pos_world=light_pos,
            light_axis_world=light_axis,
            time_s=time_s,
        )
        return out
