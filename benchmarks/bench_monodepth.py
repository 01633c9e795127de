"""Benchmark: monocular depth made metric by alignment to our stereo depth (sea3d.monodepth).

Simulated pairs of the lake scene (coastal water, the paper's dome rig): stereo depth with our
SGM (``sea3d.stereo.depth.compute_depth``), true depth in the rectified left view from the
simulator's ground truth. Three "networks": the real FastDepth (MIT, trained indoors on NYU
Depth v2, ``tests/data/models/fastdepth_224``; metric indoors, weak underwater: only its layout,
aligned in depth to stereo, is used), and two stand-ins of known error that bound what
alignment can reach: ``oracle`` (the true inverse depth under an unknown scale and shift) and
``perturbed`` (the same with a smooth 5 % relative error field and 1 % pixel noise).
For each: the median relative depth error after alignment at pixels where stereo has depth and
in stereo's holes (where the fused map takes the network), beside stereo's own error, and our
robust alignment (RANSAC + Huber in inverse depth) beside plain least squares in inverse depth
(the closed-form alignment of MiDaS-style evaluations) as the reference, in the same run.

    python benchmarks/bench_monodepth.py [--size 640x360] [--pairs 4]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from sea3d.geometry.se3 import look_at
from sea3d.monodepth import align_depth, fill_holes
from sea3d.rectify import rectify_rig
from sea3d.refraction.presets import paper_rig
from sea3d.stereo import make_config
from sea3d.stereo.depth import compute_depth, max_disparity_for_depth

ROOT = Path(__file__).resolve().parents[1]
POSES = [([0.6, -1.4, 1.3], [0.0, 0.0, 0.0]), ([-1.2, -0.8, 1.1], [0.2, 0.1, 0.0]),
         ([0.0, -1.8, 0.9], [0.0, 0.0, 0.1]), ([1.3, 0.4, 1.4], [0.0, 0.2, 0.0]),
         ([-0.5, 1.5, 1.2], [0.1, -0.1, 0.0]), ([0.9, -0.9, 0.7], [-0.2, 0.3, 0.0])]


def _pairs(cache: Path, size: tuple[int, int], n: int) -> list[dict[str, np.ndarray]]:
    from sea3d.sim import Renderer, builtin_scene, simulate_pair

    rig = paper_rig("dome", size_px=size)
    path = cache / f"monodepth_{size[0]}x{size[1]}_{n}.npz"
    if path.is_file():
        d = np.load(path)
        return [{k: d[f"{k}{i}"] for k in ("left", "right", "points")} for i in range(n)]
    cache.mkdir(parents=True, exist_ok=True)
    renderer = Renderer(builtin_scene("lake"))
    out, flat = [], {}
    for i, (eye, target) in enumerate(POSES[:n]):
        left, right, gt = simulate_pair(rig, "lake", look_at(eye, target), "coastal", seed=i,
                                        renderer=renderer)
        out.append({"left": left, "right": right, "points": gt.points_cam})
        for k, v in out[-1].items():
            flat[f"{k}{i}"] = v
    np.savez_compressed(path, **flat)
    return out


def _gt_rect(points_cam: np.ndarray, maps: object) -> np.ndarray:
    """True depth along the rectified left z axis at every rectified pixel (nearest raw pixel
    of the remap table, its true point rotated into the rectified frame)."""
    mx, my = maps.map_left_x, maps.map_left_y  # type: ignore[attr-defined]
    pts = np.stack([cv2.remap(points_cam[..., k].astype(np.float32), mx, my, cv2.INTER_NEAREST,
                              borderValue=np.nan) for k in range(3)], axis=-1)
    R = maps.R_rect_left_left  # type: ignore[attr-defined]
    return np.asarray(pts @ R[2], dtype=np.float64)


def _lstsq_inverse(pred: np.ndarray, sparse: np.ndarray) -> np.ndarray:
    ok = np.isfinite(sparse) & np.isfinite(pred)
    A = np.column_stack([pred[ok], np.ones(int(ok.sum()))])
    (s, t), *_ = np.linalg.lstsq(A, 1.0 / sparse[ok], rcond=None)
    inv = s * pred + t
    return np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.nan)


def _lstsq_depth(pred: np.ndarray, sparse: np.ndarray) -> np.ndarray:
    ok = np.isfinite(sparse) & np.isfinite(pred)
    A = np.column_stack([pred[ok], np.ones(int(ok.sum()))])
    (s, t), *_ = np.linalg.lstsq(A, sparse[ok], rcond=None)
    d = s * pred + t
    return np.where(d > 0, d, np.nan)


def _med_rel(est: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    m = mask & np.isfinite(est) & np.isfinite(gt)
    return float(np.median(np.abs(est[m] - gt[m]) / gt[m])) if m.any() else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / ".cache")
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    rig = paper_rig("dome", size_px=(w, h))
    maps = rectify_rig(rig, depth_range_m=(0.5, 10.0))
    config = make_config("sea3d", max_disparity_for_depth(maps, 0.5))
    pairs = _pairs(args.cache, (w, h), args.pairs)
    print(f"monodepth: {len(pairs)} simulated pairs, {w}x{h}, paper dome rig, coastal water; "
          "load average %.1f %.1f %.1f" % os.getloadavg())
    from sea3d.monodepth.model import MonoDepthConfig, OnnxDepthModel

    fastdepth = OnnxDepthModel(ROOT / "tests" / "data" / "models" / "fastdepth_224" /
                               "fastdepth_224.onnx",
                               MonoDepthConfig(output_kind="metric", normalize="unit"))
    rng = np.random.default_rng(0)
    rows: dict[str, list[float]] = {}
    t_ours, t_ref = [], []
    for pair in pairs:
        res = compute_depth(maps, pair["left"], pair["right"], config, max_depth_m=10.0)
        stereo = res.depth_m.astype(np.float64)
        gt = _gt_rect(pair["points"], maps)
        near = np.isfinite(gt) & (gt < 10.0)
        valid = np.isfinite(stereo) & near
        holes = ~np.isfinite(stereo) & near
        rows.setdefault("stereo valid fraction", []).append(float(valid.sum() / near.sum()))
        rows.setdefault("stereo at its pixels", []).append(_med_rel(stereo, gt, valid))
        inv = np.nan_to_num(1.0 / gt, nan=0.0)
        vv, uu = np.mgrid[0:h, 0:w] / max(w, h)
        smooth = 0.05 * np.sin(2 * np.pi * (1.3 * uu + 0.4)) * np.cos(2 * np.pi * (0.9 * vv))
        rect = cv2.remap(pair["left"], maps.map_left_x, maps.map_left_y, cv2.INTER_LINEAR)
        net_depth, _ = fastdepth.predict(rect)
        rows.setdefault("fastdepth: unscaled, all pixels", []).append(
            _med_rel(net_depth.astype(np.float64), gt, near))
        nets = {"fastdepth": (net_depth, "depth"),
                "oracle": (2.3 * inv + 0.1, "inverse"),
                "perturbed": ((2.3 * inv + 0.1) * (1 + smooth)
                              * (1 + 0.01 * rng.standard_normal(inv.shape)), "inverse")}
        for name, (pred, kind) in nets.items():
            t0 = time.perf_counter()
            aligned, _ = align_depth(pred, stereo, kind=kind)
            t_ours.append(time.perf_counter() - t0)
            fused, _ = fill_holes(stereo, aligned)
            t0 = time.perf_counter()
            ref = (_lstsq_inverse if kind == "inverse" else _lstsq_depth)(pred, stereo)
            t_ref.append(time.perf_counter() - t0)
            rows.setdefault(f"{name}: ours at stereo pixels", []).append(
                _med_rel(aligned, gt, valid))
            rows.setdefault(f"{name}: ours in stereo holes", []).append(
                _med_rel(fused, gt, holes))
            rows.setdefault(f"{name}: least squares in holes", []).append(
                _med_rel(ref, gt, holes))
    for k, v in rows.items():
        unit = "" if "fraction" in k else " (median relative error)"
        print(f"  {k:36s} {100 * statistics.median(v):7.2f} %{unit}   per pair: "
              + " ".join(f"{100 * x:.2f}" for x in v))
    print(f"  alignment time per frame: ours {1e3 * statistics.median(t_ours):.1f} ms, least "
          f"squares {1e3 * statistics.median(t_ref):.1f} ms (ratio "
          f"{statistics.median(t_ours) / statistics.median(t_ref):.1f})")


if __name__ == "__main__":
    main()
