"""How far pinhole TSDF input lands from the true surface, with and without resampling.

For the paper's rig behind dome and flat ports, every rectified pixel's *exact* point is made
by casting the pixel's true refracted ray (through the rectification table and the port) into
the simulator's lake scene: what a perfect matcher and exact triangulation would give. The
depth image of those points is then handed to a pinhole TSDF (back-projected through the
rectified view's virtual pinhole K) as it is (``none``), z-buffered to the nearest pixel
(``raster``), or resampled (``resample``, sea3d's default, :mod:`sea3d.recon.depth_resample`).
Printed: the distance of the back-projected points to the scene mesh, in millimetres, and the
share of pixels kept.

``--stereo`` adds the share of real (simulated coastal) stereo depth pixels that resampling
keeps.

    python benchmarks/bench_fusion_refraction.py [--size 640x360] [--stereo]
"""

from __future__ import annotations

import argparse

import numpy as np
import open3d as o3d

from sea3d.geometry.se3 import look_at, transform_points
from sea3d.recon.depth_resample import virtual_pinhole_depth
from sea3d.rectify import rectify_rig
from sea3d.refraction.presets import paper_rig
from sea3d.sim import builtin_scene


def exact_frame(port: str, size: tuple[int, int], scene: o3d.t.geometry.RaycastingScene,
                T: np.ndarray) -> tuple:
    rig = paper_rig(port, size_px=size)
    maps = rectify_rig(rig, depth_range_m=(0.5, 8.0))
    h, w = maps.height, maps.width
    v, u = np.mgrid[0:h, 0:w]
    raw = np.stack([maps.map_left_x[v, u], maps.map_left_y[v, u]], -1).reshape(-1, 2)
    rays = rig.left.unproject(raw.astype(np.float64))
    o = transform_points(T, np.nan_to_num(rays.origins))
    d = np.nan_to_num(rays.directions) @ T[:3, :3].T
    hit = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], 1).astype(np.float32)))
    t = hit["t_hit"].numpy().astype(np.float64)
    good = rays.valid & np.isfinite(t)
    t = np.where(good, t, 0.0)
    X_rect = transform_points(np.linalg.inv(T), o + d * t[:, None]) @ maps.R_rect_left_left.T
    depth = np.full(h * w, np.nan, np.float32)
    depth[good] = X_rect[good, 2]
    return maps, depth.reshape(h, w), X_rect[good]


def surface_error_mm(maps, scene, T, depth) -> np.ndarray:
    vv, uu = np.nonzero(np.isfinite(depth))
    z = depth[vv, uu].astype(np.float64)
    K = maps.P_left[:3, :3]
    B = np.stack([(uu - K[0, 2]) / K[0, 0] * z, (vv - K[1, 2]) / K[1, 1] * z, z], axis=1)
    Bw = transform_points(T, B @ maps.R_rect_left_left)
    return 1000.0 * scene.compute_distance(o3d.core.Tensor(Bw.astype(np.float32))).numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--stereo", action="store_true",
                    help="also: the share of real stereo depth that resampling keeps")
    args = ap.parse_args()
    size = tuple(int(x) for x in args.size.split("x"))
    if args.stereo:
        stereo_kept(size)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(
        builtin_scene("lake").combined_mesh()))
    T = look_at((0.35, -1.6, 0.9), (0.0, 0.0, 0.1))
    print(f"exact points of the lake scene at {size[0]}x{size[1]}, distance of the pinhole "
          "TSDF input to the scene surface (mm)")
    print(f"{'port':6} {'method':9} {'kept':>7} {'median':>8} {'p90':>8} {'p99':>8}  "
          f"virtual pinhole residual RMS / max")
    for port in ("dome", "flat"):
        maps, depth, pts = exact_frame(port, size, scene, T)
        n = np.isfinite(depth).sum()
        fb = maps.focal_px * maps.baseline_m
        for method in ("none", "raster", "resample"):
            fd = virtual_pinhole_depth(depth, pts, maps.P_left[:3, :3], method=method,
                                       focal_baseline_px_m=fb)
            e = surface_error_mm(maps, scene, T, fd)
            print(f"{port:6} {method:9} {100 * np.isfinite(fd).sum() / n:6.1f}% "
                  f"{np.median(e):8.3f} {np.percentile(e, 90):8.3f} {np.percentile(e, 99):8.3f}"
                  f"  {maps.report_left.rms_px:.3f} / {maps.report_left.max_px:.3f} px")


def stereo_kept(size: tuple[int, int]) -> None:
    """Share of real stereo depth pixels that resampling keeps (simulated coastal pairs)."""
    from sea3d.sim import simulate_pair
    from sea3d.stereo import make_config
    from sea3d.stereo.depth import compute_depth, max_disparity_for_depth

    rig = paper_rig("dome", size_px=size)
    maps = rectify_rig(rig, depth_range_m=(0.5, 4.0))
    cfg = make_config("sea3d", max_disparity_for_depth(maps, 0.5))
    kept, total = 0, 0
    for k, (eye, target) in enumerate((((0.35, -1.6, 0.9), (0.0, 0.0, 0.1)),
                                       ((-0.5, -1.2, 1.1), (0.2, 0.3, 0.0)))):
        left, right, _ = simulate_pair(rig, "lake", look_at(eye, target), "coastal", seed=k)
        res = compute_depth(maps, left, right, cfg, max_depth_m=4.0)
        pts = res.points_left @ maps.R_rect_left_left.T
        fd = virtual_pinhole_depth(res.depth_m, pts, maps.P_left[:3, :3],
                                   focal_baseline_px_m=maps.focal_px * maps.baseline_m)
        kept += int(np.isfinite(fd).sum())
        total += int(np.isfinite(res.depth_m).sum())
    print(f"stereo depth of 2 simulated coastal pairs at {size[0]}x{size[1]} (dome): resampling "
          f"keeps {100 * kept / total:.2f} % of {total} valid pixels")


if __name__ == "__main__":
    main()
