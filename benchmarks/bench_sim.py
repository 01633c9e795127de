"""Benchmark: render one 1920x1080 stereo pair of the lake scene through the paper's dome-port rig
with every water effect on (coastal water, lamp, caustics, vignetting, blur, noise).

Prints, as medians over several pairs, the wall time and the process CPU time (all threads) per
pair, and the breakdown: ray generation (through the dome model, once per camera, cached across
frames), ray transform, casting (Open3D), shading (ground truth, textures, caustics, light,
water, adaptive supersampling) and the sensor model. The machine may be shared with other jobs:
CPU time is the steadier figure; on an idle 2-core machine the wall time lies between CPU/2 and
CPU.

The same pair is rendered by the reference path (``Renderer(fused=False)``: the per-material,
row-chunked renderer the fused one replaced) in the same process, and the images are compared
(they must be identical). As a floor, Open3D's own ``cast_rays`` is timed alone on the pair's
centre rays.

    python benchmarks/bench_sim.py [--size 1920x1080] [--supersample 2] [--runs 5]
        [--water coastal] [--reference-runs 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numba
import numpy as np
import open3d as o3d

from sea3d.refraction.presets import paper_rig
from sea3d.sim.motion import Mount
from sea3d.sim.optics import Imaging
from sea3d.sim.render import RenderedView, Renderer
from sea3d.sim.scene import builtin_scene

STAGES = ("transform", "casting", "shading", "sensor")


def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _pair(
    renderer: Renderer, rig, T_wl: np.ndarray, imaging: Imaging, seed: int
) -> tuple[float, float, RenderedView, RenderedView]:
    """Render one pair; return (wall s, CPU s, left, right)."""
    rng = np.random.default_rng(seed)
    w0, c0 = _clock()
    left = renderer.render(rig.left, T_wl, imaging, rng=rng, time_s=0.5)
    right = renderer.render(rig.right, T_wl @ rig.T_left_right, imaging, rng=rng, time_s=0.5)
    w1, c1 = _clock()
    return w1 - w0, c1 - c0, left, right


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--supersample", type=int, default=2)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--water", default="coastal")
    ap.add_argument("--reference-runs", type=int, default=1, help="0 skips the reference path")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    rig = paper_rig("dome", size_px=(w, h))
    scene = builtin_scene("lake")
    imaging = Imaging.underwater(args.water)
    T_wb = np.eye(4)
    T_wb[:3, 3] = (-1.2, -0.2, 1.3)
    T_wl = T_wb @ Mount.default(camera_tilt_deg=35.0).T_body_left

    renderer = Renderer(scene, supersample=args.supersample)
    w0, c0 = _clock()
    renderer.camera_rays(rig.left)
    renderer.camera_rays(rig.right)
    w1, c1 = _clock()
    ray_gen_wall, ray_gen_cpu = w1 - w0, c1 - c0
    _pair(renderer, rig, T_wl, imaging, 0)  # warm-up: numba compilation or cache load
    walls, cpus, parts_wall, parts_cpu = [], [], [], []
    for _ in range(args.runs):
        renderer.timings_s.clear()
        renderer.cpu_timings_s.clear()
        wall, cpu, left, right = _pair(renderer, rig, T_wl, imaging, 0)
        walls.append(wall)
        cpus.append(cpu)
        parts_wall.append(dict(renderer.timings_s))
        parts_cpu.append(dict(renderer.cpu_timings_s))

    # Open3D alone on the same centre rays of both cameras (the casting floor).
    cast_walls, cast_cpus = [], []
    ray_sets = []
    for cam, T in ((rig.left, T_wl), (rig.right, T_wl @ rig.T_left_right)):
        cr = renderer.camera_rays(cam)
        o = cr.origins[0].reshape(-1, 3).astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        d = cr.dirs[0].reshape(-1, 3).astype(np.float64) @ T[:3, :3].T
        ray_sets.append(o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32)))
    for _ in range(args.runs):
        w0, c0 = _clock()
        for rays in ray_sets:
            renderer._rc.cast_rays(rays, nthreads=0)
        w1, c1 = _clock()
        cast_walls.append(w1 - w0)
        cast_cpus.append(c1 - c0)

    med = statistics.median
    print(
        f"sea3d sim: {w}x{h} stereo pair, lake scene, dome ports, water={args.water}, "
        f"supersample={args.supersample} (adaptive: "
        f"{100 * renderer.last_supersampled_fraction:.1f} % of pixels supersampled); "
        f"{numba.get_num_threads()} numba threads, load average {os.getloadavg()[0]:.1f} "
        f"on {os.cpu_count()} cores"
    )
    print(
        f"  ray generation through the dome (once per camera, cached): "
        f"{ray_gen_cpu:.2f} s CPU, {ray_gen_wall:.2f} s wall for both cameras"
    )
    print(
        f"  per pair, median of {args.runs}: {med(cpus):.2f} s CPU, {med(walls):.2f} s wall "
        f"(min {min(walls):.2f} s)   [aim: < 2 s wall on 2 cores]"
    )
    print(f"    {'stage':<10} {'CPU s':>6} {'wall s':>7}")
    for key in STAGES:
        print(
            f"    {key:<10} {med(p.get(key, 0.0) for p in parts_cpu):6.2f} "
            f"{med(p.get(key, 0.0) for p in parts_wall):7.2f}"
        )
    print(
        f"  Open3D cast_rays alone on the pair's centre rays: {med(cast_cpus):.2f} s CPU, "
        f"{med(cast_walls):.2f} s wall"
    )
    if args.reference_runs > 0:
        ref = Renderer(scene, supersample=args.supersample, fused=False)
        ref.camera_rays(rig.left)
        ref.camera_rays(rig.right)
        ref_walls, ref_cpus = [], []
        for _ in range(args.reference_runs):
            wall, cpu, ref_left, ref_right = _pair(ref, rig, T_wl, imaging, 0)
            ref_walls.append(wall)
            ref_cpus.append(cpu)
        same = np.array_equal(ref_left.image, left.image) and np.array_equal(
            ref_right.image, right.image
        )
        print(
            f"  reference path (fused=False), median of {args.reference_runs}: "
            f"{med(ref_cpus):.2f} s CPU, {med(ref_walls):.2f} s wall; fused is "
            f"{med(ref_cpus) / med(cpus):.1f}x less CPU, {med(ref_walls) / med(walls):.1f}x "
            f"less wall; images identical: {'yes' if same else 'NO'}"
        )


if __name__ == "__main__":
    main()
