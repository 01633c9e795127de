"""numba kernels for the renderer's per-sample work (one pass instead of many NumPy temporaries)."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from sea3d.sim.noise import fbm1

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


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
    light_pos: F64,
    light_axis: F64,
    light_intensity: float,
    cone_rad: float,
) -> F32:
    """Radiance at the camera of each hit: albedo x (sun + lamp) through the water model.

    See :meth:`sea3d.sim.optics.Imaging.shade` for the model; ``caustic_mod`` multiplies the
    direct sunlight (ones when caustics are off).
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
        z = path[i]
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
