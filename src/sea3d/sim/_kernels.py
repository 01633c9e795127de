"""numba kernels for the renderer's per-sample work (one pass instead of many NumPy temporaries)."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, F64
from sea3d.sim.noise import CACHE_COLS, fbm1, fbm1_cached


@numba.njit(cache=True, parallel=True)
def hit_points(o: F64, d: F64, t: F64, idx: NDArray[np.int64]) -> F64:
    """``o[idx] + t[idx] * d[idx]`` as ``(len(idx), 3)`` float64."""
    n = idx.shape[0]
    out = np.empty((n, 3), dtype=np.float64)
    for k in numba.prange(n):
        i = idx[k]
        for c in range(3):
            out[k, c] = o[i, c] + t[i] * d[i, c]
    return out


@numba.njit(cache=True, parallel=True)
def postprocess_hits(
    t_hit: F32,
    gid: NDArray[np.uint32],
    normals: F32,
    dirs: F32,
    lut: NDArray[np.int32],
    bad: NDArray[np.bool_],
) -> tuple[F64, NDArray[np.int32], F32]:
    """Open3D's cast results to (t (inf = miss), object id (-1 = miss), normals facing the ray)."""
    n = t_hit.shape[0]
    t = np.empty(n, dtype=np.float64)
    obj = np.empty(n, dtype=np.int32)
    nout = np.empty((n, 3), dtype=np.float32)
    nl = lut.shape[0]
    for i in numba.prange(n):
        g = gid[i]
        if bad[i] or not np.isfinite(t_hit[i]) or g == np.uint32(4294967295) or g >= nl:
            t[i] = np.inf
            obj[i] = -1
            nout[i, 0] = np.nan
            nout[i, 1] = np.nan
            nout[i, 2] = np.nan
            continue
        t[i] = t_hit[i]
        obj[i] = lut[g]
        dot = normals[i, 0] * dirs[i, 0] + normals[i, 1] * dirs[i, 1] + normals[i, 2] * dirs[i, 2]
        s = np.float32(-1.0) if dot > 0 else np.float32(1.0)
        nout[i, 0] = s * normals[i, 0]
        nout[i, 1] = s * normals[i, 1]
        nout[i, 2] = s * normals[i, 2]
    return t, obj, nout


@numba.njit(cache=True, parallel=True)
def light_and_water(
    albedo: F32,
    p: F64,
    n: F32,
    path: F64,
    caustic_mod: F32,
    sun_dir: F64,
    sun_irradiance: float,
    ambient: float,
    surface_z: float,
    beta_d: F64,
    beta_b: F64,
    b_inf: F64,
    water: bool,
    view_water: bool,
    light_pos: F64,
    light_axis: F64,
    light_intensity: float,
    cone_rad: float,
) -> F32:
    """Radiance at the camera of each hit: albedo x (sun + lamp) through the water model.

    See :meth:`sea3d.sim.optics.Imaging.shade` for the model; ``caustic_mod`` multiplies the
    direct sunlight (ones when caustics are off). ``view_water`` False removes the water between
    the camera and the hit (no attenuation along the view ray, no backscatter) while the lights
    still reach the hit through water.
    """
    m = albedo.shape[0]
    out = np.empty((m, 3), dtype=np.float32)
    for i in numba.prange(m):
        nx, ny, nz = n[i, 0], n[i, 1], n[i, 2]
        lam = nx * sun_dir[0] + ny * sun_dir[1] + nz * sun_dir[2]
        if lam < 0.0:
            lam = 0.0
        sun = sun_irradiance * (ambient + (1.0 - ambient) * lam * caustic_mod[i])
        depth_below = surface_z - p[i, 2]
        if depth_below < 0.0:
            depth_below = 0.0
        e_lamp = 0.0
        dl = 0.0
        if light_intensity > 0.0:
            lx = light_pos[0] - p[i, 0]
            ly = light_pos[1] - p[i, 1]
            lz = light_pos[2] - p[i, 2]
            dl = np.sqrt(lx * lx + ly * ly + lz * lz)
            inv = 1.0 / max(dl, 1e-9)
            lx *= inv
            ly *= inv
            lz *= inv
            cs = nx * lx + ny * ly + nz * lz
            if cs > 0.0:
                ca = -(lx * light_axis[0] + ly * light_axis[1] + lz * light_axis[2])
                # exp(-(angle / cone)^2) with angle^2 ~ 2 (1 - cos angle): no arccos needed.
                spot = np.exp(-2.0 * (1.0 - ca) / (cone_rad * cone_rad))
                e_lamp = light_intensity * spot * cs / max(dl, 0.05) ** 2
        z = path[i] if view_water else 0.0
        for c in range(3):
            if water:
                # Sun over depth_below then the view path z; lamp over dl then z.
                irr = sun * np.exp(-beta_d[c] * (depth_below + z)) + e_lamp * np.exp(
                    -beta_d[c] * (dl + z)
                )
                out[i, c] = albedo[i, c] * irr + b_inf[c] * (1.0 - np.exp(-beta_b[c] * z))
            else:
                out[i, c] = albedo[i, c] * (sun + e_lamp)
    return out


@numba.njit(cache=True, parallel=True)
def camera_ground_truth(o: F64, d: F64, t: F64, n_world: F32, R: F64) -> tuple[F32, F32, F32, F32]:
    """Per pixel: points (camera frame), depth (z), range, normals (camera frame); NaN on miss."""
    m = o.shape[0]
    pts = np.empty((m, 3), dtype=np.float32)
    nrm = np.empty((m, 3), dtype=np.float32)
    depth = np.empty(m, dtype=np.float32)
    rng = np.empty(m, dtype=np.float32)
    for i in numba.prange(m):
        if not np.isfinite(t[i]):
            for c in range(3):
                pts[i, c] = np.nan
                nrm[i, c] = np.nan
            depth[i] = np.nan
            rng[i] = np.nan
            continue
        x = o[i, 0] + t[i] * d[i, 0]
        y = o[i, 1] + t[i] * d[i, 1]
        zz = o[i, 2] + t[i] * d[i, 2]
        pts[i, 0] = x
        pts[i, 1] = y
        pts[i, 2] = zz
        depth[i] = zz
        rng[i] = np.sqrt(x * x + y * y + zz * zz)
        for c in range(3):  # R^T n: world normal into the camera frame
            nrm[i, c] = R[0, c] * n_world[i, 0] + R[1, c] * n_world[i, 1] + R[2, c] * n_world[i, 2]
    return pts, depth, rng, nrm


@numba.njit(cache=True, parallel=True)
def sand_albedo(
    p: F64,
    fp: F64,
    colour: F64,
    grain_freq: float,
    contrast: float,
    ripple_wavelength: float,
    seed: int,
) -> F32:
    """:class:`~sea3d.sim.materials.SandMaterial` in one pass (same noise fields and weights)."""
    n = p.shape[0]
    out = np.empty((n, 3), dtype=np.float32)
    s0 = np.uint64(seed & 0xFFFFFFFF)
    s1 = np.uint64((seed + 1) & 0xFFFFFFFF)
    s2 = np.uint64((seed + 2) & 0xFFFFFFFF)
    s3 = np.uint64((seed + 3) & 0xFFFFFFFF)
    for i in numba.prange(n):
        x, y, z, f = p[i, 0], p[i, 1], p[i, 2], fp[i]
        patches = fbm1(x, y, z, 0.0, 1.5, 2, 0.5, s0)
        mid = fbm1(x, y, z, f, 12.0, 3, 0.6, s3)
        grain = fbm1(x, y, z, f, grain_freq, 4, 0.8, s1)
        shade = 1.0 + 0.7 * (patches - 0.5) + 1.0 * (mid - 0.5) + contrast * 2.0 * (grain - 0.5)
        if ripple_wavelength > 0.0:
            warp = fbm1(x, y, z, 0.0, 1.5, 1, 0.5, s2)
            phase = (x * 0.8 + y * 0.6) / ripple_wavelength
            shade += 0.12 * np.sin(2.0 * np.pi * (phase + 3.0 * warp))
        for c in range(3):
            out[i, c] = min(1.0, max(0.0, colour[c] * shade))
    return out


@numba.njit(cache=True, parallel=True)
def caustic_raw(p: F64, scale_m: float, t_lattice: float) -> F32:
    """Unnormalised caustic brightness: ridges of two noise fields of (x, y) / scale and time."""
    n = p.shape[0]
    out = np.empty(n, dtype=np.float32)
    s77 = np.uint64(77)
    s78 = np.uint64(78)
    for i in numba.prange(n):
        x = p[i, 0] / scale_m
        y = p[i, 1] / scale_m
        a = fbm1(x, y, t_lattice, 0.0, 1.0, 2, 0.4, s77)
        b = fbm1(x * 1.37 + 11.0, y * 1.37 + 11.0, t_lattice * 1.37 + 11.0, 0.0, 1.0, 2, 0.4, s78)
        ra = 1.0 - abs(2.0 * a - 1.0)
        rb = 1.0 - abs(2.0 * b - 1.0)
        ra2 = ra * ra
        rb2 = rb * rb
        ra8 = ra2 * ra2 * ra2 * ra2
        rb8 = rb2 * rb2 * rb2 * rb2
        out[i] = ra8 * ra2 + rb8 * rb2
    return out


# ---------------------------------------------------------------------------------------------
# Fused per-pixel passes of Renderer.render: world rays for Open3D, hits plus ground truth, and
# one shading pass (sand texture, caustics, sun, lamp, water) over image rows.

N_SAND_PARAMS = 7  # colour r, g, b, grain frequency (1/m), contrast, ripple wavelength (m), seed
_N_SLOTS = 14  # noise cache slots: patches 2, mid 3, grain 4, warp 1, caustics 2 + 2


@numba.njit(cache=True, parallel=True)
def world_rays(o_cam: F32, d_cam: F32, R: F64, t: F64) -> tuple[F32, NDArray[np.bool_]]:
    """Camera-frame rays to Open3D's ``(N, 6)`` float32 world rays (transform in float64).

    Non-finite rays are flagged in ``bad`` and replaced by a harmless ray (0, 0, 0) -> +z.
    """
    n = o_cam.shape[0]
    rays = np.empty((n, 6), dtype=np.float32)
    bad = np.zeros(n, dtype=np.bool_)
    for i in numba.prange(n):
        x, y, z = o_cam[i, 0], o_cam[i, 1], o_cam[i, 2]
        dx, dy, dz = d_cam[i, 0], d_cam[i, 1], d_cam[i, 2]
        ok = True
        for r in range(3):
            a = np.float32(R[r, 0] * x + R[r, 1] * y + R[r, 2] * z + t[r])
            b = np.float32(R[r, 0] * dx + R[r, 1] * dy + R[r, 2] * dz + 0.0)
            rays[i, r] = a
            rays[i, 3 + r] = b
            if not (np.isfinite(a) and np.isfinite(b)):
                ok = False
        if not ok:
            bad[i] = True
            for r in range(6):
                rays[i, r] = 0.0
            rays[i, 5] = 1.0
    return rays, bad


@numba.njit(cache=True, parallel=True)
def hits_and_truth(
    t_hit: F32,
    gid: NDArray[np.uint32],
    normals: F32,
    rays: F32,
    lut: NDArray[np.int32],
    bad: NDArray[np.bool_],
    o_cam: F32,
    d_cam: F32,
    R: F64,
    t_out: F64,
    obj_out: NDArray[np.int32],
    n_world_out: F32,
    pts_out: F32,
    depth_out: F32,
    range_out: F32,
    n_cam_out: F32,
) -> None:
    """:func:`postprocess_hits` and :func:`camera_ground_truth` in one pass, into given arrays."""
    n = t_hit.shape[0]
    nl = lut.shape[0]
    nan32 = np.float32(np.nan)
    for i in numba.prange(n):
        g = gid[i]
        if bad[i] or not np.isfinite(t_hit[i]) or g == np.uint32(4294967295) or g >= nl:
            t_out[i] = np.inf
            obj_out[i] = -1
            for c in range(3):
                n_world_out[i, c] = nan32
                pts_out[i, c] = nan32
                n_cam_out[i, c] = nan32
            depth_out[i] = nan32
            range_out[i] = nan32
            continue
        ti = np.float64(t_hit[i])
        t_out[i] = ti
        obj_out[i] = lut[g]
        dot = normals[i, 0] * rays[i, 3] + normals[i, 1] * rays[i, 4] + normals[i, 2] * rays[i, 5]
        s = np.float32(-1.0) if dot > 0 else np.float32(1.0)
        n0 = s * normals[i, 0]
        n1 = s * normals[i, 1]
        n2 = s * normals[i, 2]
        n_world_out[i, 0] = n0
        n_world_out[i, 1] = n1
        n_world_out[i, 2] = n2
        x = o_cam[i, 0] + ti * d_cam[i, 0]
        y = o_cam[i, 1] + ti * d_cam[i, 1]
        zz = o_cam[i, 2] + ti * d_cam[i, 2]
        pts_out[i, 0] = x
        pts_out[i, 1] = y
        pts_out[i, 2] = zz
        depth_out[i] = zz
        range_out[i] = np.sqrt(x * x + y * y + zz * zz)
        for c in range(3):  # R^T n: world normal into the camera frame
            n_cam_out[i, c] = R[0, c] * n0 + R[1, c] * n1 + R[2, c] * n2


@numba.njit(cache=True, parallel=True)
def world_hit_points(
    o_cam: F32, d_cam: F32, R: F64, tv: F64, t: F64, idx: NDArray[np.int64]
) -> F64:
    """World hit points ``(len(idx), 3)`` float64 of camera-frame rays ``idx`` at ``t``."""
    m = idx.shape[0]
    out = np.empty((m, 3), dtype=np.float64)
    for k in numba.prange(m):
        i = idx[k]
        x, y, z = o_cam[i, 0], o_cam[i, 1], o_cam[i, 2]
        dx, dy, dz = d_cam[i, 0], d_cam[i, 1], d_cam[i, 2]
        for r in range(3):
            ow = R[r, 0] * x + R[r, 1] * y + R[r, 2] * z + tv[r]
            dw = R[r, 0] * dx + R[r, 1] * dy + R[r, 2] * dz + 0.0
            out[k, r] = ow + t[i] * dw
    return out


@numba.njit(cache=True)
def _sand_shade(
    x: float,
    y: float,
    z: float,
    f: float,
    grain_freq: float,
    contrast: float,
    ripple_wavelength: float,
    seed: np.int64,
    cache: NDArray[np.float64],
) -> float:
    """The brightness factor of :func:`sand_albedo` at one point (albedo = colour x this)."""
    s0 = np.uint64(seed & 0xFFFFFFFF)
    s1 = np.uint64((seed + 1) & 0xFFFFFFFF)
    s2 = np.uint64((seed + 2) & 0xFFFFFFFF)
    s3 = np.uint64((seed + 3) & 0xFFFFFFFF)
    patches = fbm1_cached(x, y, z, 0.0, 1.5, 2, 0.5, s0, cache, 0)
    mid = fbm1_cached(x, y, z, f, 12.0, 3, 0.6, s3, cache, 2)
    grain = fbm1_cached(x, y, z, f, grain_freq, 4, 0.8, s1, cache, 5)
    shade = 1.0 + 0.7 * (patches - 0.5) + 1.0 * (mid - 0.5) + contrast * 2.0 * (grain - 0.5)
    if ripple_wavelength > 0.0:
        warp = fbm1_cached(x, y, z, 0.0, 1.5, 1, 0.5, s2, cache, 9)
        phase = (x * 0.8 + y * 0.6) / ripple_wavelength
        shade += 0.12 * np.sin(2.0 * np.pi * (phase + 3.0 * warp))
    return shade


@numba.njit(cache=True, inline="always")
def _object_point(
    T_inv: F64, k: int, px: float, py: float, pz: float
) -> tuple[float, float, float]:
    """World point ``(px, py, pz)`` in object ``k``'s frame: ``T_inv[k] @ p``, metres."""
    qx = T_inv[k, 0, 0] * px + T_inv[k, 0, 1] * py + T_inv[k, 0, 2] * pz + T_inv[k, 0, 3]
    qy = T_inv[k, 1, 0] * px + T_inv[k, 1, 1] * py + T_inv[k, 1, 2] * pz + T_inv[k, 1, 3]
    qz = T_inv[k, 2, 0] * px + T_inv[k, 2, 1] * py + T_inv[k, 2, 2] * pz + T_inv[k, 2, 3]
    return qx, qy, qz


@numba.njit(cache=True, inline="always")
def _caustic_raw_at(
    px: float,
    py: float,
    t_lattice: float,
    caustic_scale: float,
    s77: np.uint64,
    s78: np.uint64,
    cache: NDArray[np.float64],
) -> np.float32:
    """:func:`caustic_raw`'s value at one world point (two ridged noise layers), float32."""
    cx = px / caustic_scale
    cy = py / caustic_scale
    a = fbm1_cached(cx, cy, t_lattice, 0.0, 1.0, 2, 0.4, s77, cache, 10)
    b = fbm1_cached(
        cx * 1.37 + 11.0, cy * 1.37 + 11.0, t_lattice * 1.37 + 11.0, 0.0, 1.0, 2, 0.4, s78,
        cache, 12,
    )  # fmt: skip
    ra = 1.0 - abs(2.0 * a - 1.0)
    rb = 1.0 - abs(2.0 * b - 1.0)
    ra2 = ra * ra
    rb2 = rb * rb
    ra8 = ra2 * ra2 * ra2 * ra2
    rb8 = rb2 * rb2 * rb2 * rb2
    return np.float32(ra8 * ra2 + rb8 * rb2)


@numba.njit(cache=True, parallel=True)
def shade_fused(
    o_cam: F32,
    d_cam: F32,
    R: F64,
    tv: F64,
    t: F64,
    obj: NDArray[np.int32],
    n_w: F32,
    pixel_angle: float,
    albedo_pre: F32,
    sand: NDArray[np.bool_],
    sand_par: F64,
    has_T: NDArray[np.bool_],
    T_inv: F64,
    sun_dir: F64,
    sun_irradiance: float,
    ambient: float,
    surface_z: float,
    beta_d: F64,
    beta_b: F64,
    b_inf: F64,
    water: bool,
    view_water: bool,
    light_pos: F64,
    light_axis: F64,
    light_intensity: float,
    cone_rad: float,
    caustics: float,
    caustic_scale: float,
    t_lattice: float,
    caustic_fade_depth: float,
    caustic_mean: float,
    row_len: int,
    out: F32,
) -> None:
    """Radiance of every ray into ``out`` (N, 3): the sand texture (other materials' albedo comes
    in ``albedo_pre``), caustics, sun, lamp and water in one pass, the same numbers as
    :func:`sand_albedo`, :func:`caustic_raw` and :func:`light_and_water` in turn.

    Rays are processed in rows of ``row_len`` consecutive rays (image rows), in parallel over
    rows; within a row the noise lattice values of the previous ray are reused.
    """
    n = t.shape[0]
    n_rows = (n + row_len - 1) // row_len
    sun32 = sun_dir.astype(np.float32)
    s77 = np.uint64(77)
    s78 = np.uint64(78)
    for row in numba.prange(n_rows):
        cache = np.full((_N_SLOTS, CACHE_COLS), np.nan)
        alb = np.empty(3, dtype=np.float32)
        i1 = min(n, (row + 1) * row_len)
        for i in range(row * row_len, i1):
            k = obj[i]
            if k < 0:
                for c in range(3):
                    out[i, c] = np.float32(b_inf[c]) if water and view_water else np.float32(0.0)
                continue
            ti = t[i]
            x, y, z = o_cam[i, 0], o_cam[i, 1], o_cam[i, 2]
            dx, dy, dz = d_cam[i, 0], d_cam[i, 1], d_cam[i, 2]
            px = (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + tv[0]) + ti * (
                R[0, 0] * dx + R[0, 1] * dy + R[0, 2] * dz + 0.0
            )
            py = (R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + tv[1]) + ti * (
                R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz + 0.0
            )
            pz = (R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + tv[2]) + ti * (
                R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz + 0.0
            )
            if sand[k]:
                qx, qy, qz = px, py, pz
                if has_T[k]:
                    qx, qy, qz = _object_point(T_inv, k, px, py, pz)
                shade = _sand_shade(
                    qx,
                    qy,
                    qz,
                    ti * pixel_angle,
                    sand_par[k, 3],
                    sand_par[k, 4],
                    sand_par[k, 5],
                    np.int64(sand_par[k, 6]),
                    cache,
                )
                for c in range(3):
                    alb[c] = np.float32(min(1.0, max(0.0, sand_par[k, c] * shade)))
            else:
                for c in range(3):
                    alb[c] = albedo_pre[i, c]
            nx, ny, nz = n_w[i, 0], n_w[i, 1], n_w[i, 2]
            depth_below = surface_z - pz
            if depth_below < 0.0:
                depth_below = 0.0
            mod = np.float32(1.0)
            if caustics > 0.0:
                fade = np.exp(-depth_below / caustic_fade_depth)
                if (nx * sun32[0] + ny * sun32[1] + nz * sun32[2] > 0) and fade > 0.02:
                    raw = _caustic_raw_at(px, py, t_lattice, caustic_scale, s77, s78, cache)
                    cval = np.float64(raw) / caustic_mean
                    mod = np.float32(1.0 + caustics * fade * (cval - 1.0))
            lam = nx * sun_dir[0] + ny * sun_dir[1] + nz * sun_dir[2]
            if lam < 0.0:
                lam = 0.0
            sun = sun_irradiance * (ambient + (1.0 - ambient) * lam * mod)
            e_lamp = 0.0
            dl = 0.0
            if light_intensity > 0.0:
                lx = light_pos[0] - px
                ly = light_pos[1] - py
                lz = light_pos[2] - pz
                dl = np.sqrt(lx * lx + ly * ly + lz * lz)
                inv = 1.0 / max(dl, 1e-9)
                lx *= inv
                ly *= inv
                lz *= inv
                cs = nx * lx + ny * ly + nz * lz
                if cs > 0.0:
                    ca = -(lx * light_axis[0] + ly * light_axis[1] + lz * light_axis[2])
                    spot = np.exp(-2.0 * (1.0 - ca) / (cone_rad * cone_rad))
                    e_lamp = light_intensity * spot * cs / max(dl, 0.05) ** 2
            tw = ti if view_water else 0.0
            for c in range(3):
                if water:
                    irr = sun * np.exp(-beta_d[c] * (depth_below + tw)) + e_lamp * np.exp(
                        -beta_d[c] * (dl + tw)
                    )
                    out[i, c] = alb[c] * irr + b_inf[c] * (1.0 - np.exp(-beta_b[c] * tw))
                else:
                    out[i, c] = alb[c] * (sun + e_lamp)


@numba.njit(cache=True, parallel=True)
def edge_pixels(
    obj_id: NDArray[np.int32], depth: F32, radiance: F32, hard_lut: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """See ``Renderer._edge_pixels``: object boundary, 2 % depth step, or (hard-edged textures)
    luminance step over 0.02 in the 3x3 neighbourhood (edge pixels repeat at the border)."""
    h, w = obj_id.shape
    edge = np.zeros((h, w), dtype=np.bool_)
    big = np.float32(1e6)
    for v in numba.prange(h):
        for u in range(w):
            k = obj_id[v, u]
            z = depth[v, u]
            if not np.isfinite(z):
                z = big
            lum = (
                np.float32(0.2126) * radiance[v, u, 0]
                + np.float32(0.7152) * radiance[v, u, 1]
                + np.float32(0.0722) * radiance[v, u, 2]
            )
            hard = hard_lut[k + 1]
            e = False
            for dv in (-1, 0, 1):
                vv = min(h - 1, max(0, v + dv))
                for du in (-1, 0, 1):
                    if dv == 0 and du == 0:
                        continue
                    uu = min(w - 1, max(0, u + du))
                    if obj_id[vv, uu] != k:
                        e = True
                        break
                    nz = depth[vv, uu]
                    if not np.isfinite(nz):
                        nz = big
                    if abs(nz - z) > np.float32(0.02) * min(nz, z):
                        e = True
                        break
                    if hard:
                        nl = (
                            np.float32(0.2126) * radiance[vv, uu, 0]
                            + np.float32(0.7152) * radiance[vv, uu, 1]
                            + np.float32(0.0722) * radiance[vv, uu, 2]
                        )
                        if abs(nl - lum) > np.float32(0.02):
                            e = True
                            break
                if e:
                    break
            edge[v, u] = e
    return edge


@numba.njit(cache=True, parallel=True)
def expose(radiance: F32, exposure: float, vignette: F32, out: F32) -> None:
    """``out = radiance * exposure * vignette`` (vignette ``(H, W)``, or ``(0, 0)`` for none)."""
    h, w = radiance.shape[0], radiance.shape[1]
    e = np.float32(exposure)
    vig = vignette.shape[0] > 0
    for v in numba.prange(h):
        for u in range(w):
            g = vignette[v, u] if vig else np.float32(1.0)
            for c in range(3):
                out[v, u, c] = (radiance[v, u, c] * e) * g


@numba.njit(cache=True, parallel=True)
def noise_and_encode(
    img: F32, normals: F32, full_well: float, read_noise: float, lut: NDArray[np.uint8]
) -> NDArray[np.uint8]:
    """Shot and read noise (``normals``: standard normal draws, or ``(0, 0, 0)`` for no noise)
    then clipping and 8-bit sRGB through the 16-bit ``lut``."""
    h, w = img.shape[0], img.shape[1]
    out = np.empty((h, w, 3), dtype=np.uint8)
    noisy = normals.shape[0] > 0
    fw = np.float32(full_well)
    rn2 = np.float32(read_noise) * np.float32(read_noise)
    for v in numba.prange(h):
        for u in range(w):
            for c in range(3):
                x = img[v, u, c]
                if noisy:
                    sg = np.float32(0.0)
                    if full_well > 0:
                        sg = np.float32(np.sqrt(min(max(x, np.float32(0.0)), np.float32(1.5)) / fw))
                    x = x + np.float32(np.sqrt(sg * sg + rn2)) * normals[v, u, c]
                x = min(max(x, np.float32(0.0)), np.float32(1.0))
                out[v, u, c] = lut[np.uint16(x * np.float32(65535.0) + np.float32(0.5))]
    return out
