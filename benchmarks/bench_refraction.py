"""Benchmark: dome-port unproject of a whole 1920x1080 image and projection of 1M points.

The reference is OpenCV doing the pinhole part alone on the same input (cv2.undistortPoints for
the rays, cv2.projectPoints for the points): the refractive model does that work *and* traces
two refractions per ray (and solves for the path when projecting). Medians of several runs.

    python benchmarks/bench_refraction.py [--repeats 5] [--worked-example]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from sea3d.refraction.presets import paper_rig


def _median_s(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up: numba compilation and caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def worked_example() -> None:
    """The table in docs/conventions.md: pixel shift against the in-air pinhole."""
    for port in ("dome", "flat"):
        cam = paper_rig(port).left  # type: ignore[arg-type]
        uv = np.array([[949.5, 535.7], [1440.0, 810.0], [1919.0, 1079.0]])
        rays = cam.unproject(uv)
        for z in (0.5, 2.0, 10.0):
            s = (z - rays.origins[:, 2]) / rays.directions[:, 2]
            uv_air, _ = cam.pinhole.project(rays.at(s))  # type: ignore[attr-defined]
            shift = np.linalg.norm(uv_air - uv, axis=1)
            print(f"{port:4s} z={z:5.1f} m  shift px: " + "  ".join(f"{v:7.2f}" for v in shift))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--worked-example", action="store_true")
    args = parser.parse_args()
    if args.worked_example:
        worked_example()
        return
    rig = paper_rig("dome")
    cam = rig.left
    pin = cam.pinhole  # type: ignore[attr-defined]
    pin = pin.with_dist([0.04, -0.01, 0.001, -0.001, 0.002])  # realistic lens distortion
    from sea3d.refraction import DomePortCamera

    cam = DomePortCamera(pin, cam.port)  # type: ignore[attr-defined]
    uv = pin.pixel_grid()
    rng = np.random.default_rng(0)
    pts = cam.unproject(uv[:1_000_000]).at(rng.uniform(0.3, 20.0, 1_000_000))
    K, dist = pin.K, pin.dist

    t_unproj = _median_s(lambda: cam.unproject(uv), args.repeats)
    t_cv_undist = _median_s(
        lambda: cv2.undistortPoints(uv.reshape(-1, 1, 2), K, dist), args.repeats
    )
    t_proj = _median_s(lambda: cam.project(pts), args.repeats)
    t_cv_proj = _median_s(
        lambda: cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist), args.repeats
    )
    n_pix = len(uv)
    print(f"unproject {n_pix} px (1920x1080) through the paper's dome, median of {args.repeats}:")
    print(f"  sea3d dome unproject   {t_unproj:7.3f} s  {n_pix / t_unproj / 1e6:6.2f} M rays/s")
    print(
        f"  cv2.undistortPoints    {t_cv_undist:7.3f} s  {n_pix / t_cv_undist / 1e6:6.2f} M rays/s"
        "  (pinhole only, 5 fixed-point steps)"
    )
    print(f"  ratio sea3d / OpenCV   {t_unproj / t_cv_undist:7.2f}   (aim: whole image < 0.5 s)")
    print(f"project {len(pts)} points (0.3-20 m) through the dome:")
    print(f"  sea3d dome project     {t_proj:7.3f} s  {len(pts) / t_proj / 1e6:6.2f} M points/s")
    print(
        f"  cv2.projectPoints      {t_cv_proj:7.3f} s  {len(pts) / t_cv_proj / 1e6:6.2f} M points/s"
        "  (pinhole only)"
    )
    print(f"  ratio sea3d / OpenCV   {t_proj / t_cv_proj:7.2f}   (aim: 1M points < 2 s)")


if __name__ == "__main__":
    main()
