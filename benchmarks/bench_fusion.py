"""TSDF fusion speed and agreement: ``sea3d fuse`` against Open3D's VoxelBlockGrid called
directly, on the same 7-Scenes chess frames, in the same process.

Both integrate the 60 colour + depth frames of ``../shared/data/rgbd/7scenes_chess`` (depth in
millimetres, poses camera-to-world, fx = fy = 585, cx 320, cy 240) into 1 cm voxels with a
4-voxel truncation and 4 m range, from the same preloaded arrays: sea3d's
:class:`~sea3d.recon.tsdf.TsdfVolume` (the integration loop of ``sea3d fuse``) and the minimal
direct Open3D loop (``compute_unique_block_coordinates`` + ``integrate``), alternating runs.
``sea3d fuse``'s whole run (:func:`sea3d.pipeline.fuse.fuse_rgbd`, files read) is timed once.
Printed: median milliseconds per frame (wall and CPU, several runs), their ratio, and the two
meshes against each other (``sea3d eval surface`` in both directions). Open3D is run twice:
with sea3d's half-pixel principal-point convention (the meshes must agree to float rounding)
and with K as it is (what a user of Open3D gets: Open3D truncates a voxel's projection to find
its pixel); first, the same effect on an analytic floor seen at 45 degrees.

Then floaters on the same real frames (``heldout``): every fifth frame is held out and the
others are fused by Open3D's plain loop and by sea3d: as it was, with free-space carving
(:attr:`~sea3d.recon.tsdf.TsdfConfig.carve_free_space`, Kinect depth noise ``1.6e-3 z^2`` m
after Khoshelham and Elberink 2012, Sensors 12:1437, "about 4 cm at 5 m"), with the pixels
within 2 px of a hole left out (:attr:`~sea3d.recon.tsdf.TsdfConfig.hole_margin_px`) and
with both; each with meshes of the voxels seen once (``weight_threshold`` 0.5) and twice
(1.5, ``sea3d process``'s ``MapConfig.min_observations = 2``).
There is no ground-truth mesh: each mesh is rendered (Open3D ray casting) at the held-out
poses and compared with the held-out Kinect depth, pixels where both have depth: the depth
difference (median, p90, p99), the pixels where the mesh stands more than 5 cm in front of
what the held-out frame saw (a surface where the camera sees free space: floaters), the
held-out pixels the mesh explains within 2 cm (completeness), and the mesh vertices that lie
more than 5 cm in front of a held-out frame's depth (its 3x3 minimum) where they project
(margins widen to 3 and 2 standard errors of the depth where those are larger; held-out
depth beyond the fused range is left out).

Then the same on real stereo (``kitti``): a KITTI odometry excerpt (``$SEA3D_REAL_DATA/
kitti_seq1``, 51 rectified 1241x376 pairs, ground-truth poses), sea3d's SGM depth of every
pair (matched pixels, disparity >= 4 px) fused into 5 cm voxels up to 20 m with the
ground-truth poses, the held-out frames compared with OpenCV SGBM's depth of the same pair
(an independent matcher), depth noise ``0.25 px / f B``.
CPU milliseconds per frame of each integration loop are printed beside them.

Last (``--survey FRAMES``, alone): a simulated lake survey (640x360, coastal water, dome
ports; kept in ``out/bench_fusion/``), sea3d's depth of every frame cached in the virtual
pinhole as ``sea3d process`` fuses it, fused with all pixels, with carving, with a confidence
gate, with hole margins of 1 and 2 px; meshes of the voxels seen once and twice; every
vertex's exact distance to the scene (median, p90, p99, max, count beyond 10 cm) and the
completeness of the scene samples within 3 cm of the fused depth.

    python benchmarks/bench_fusion.py [--repeats 3] [--voxel-m 0.01] [--skip-speed]
    python benchmarks/bench_fusion.py --survey 300 [--survey-poses T_world_cam.npy]

With ``--confidence`` the floater rows are the plain ones, the 2 px hole margin and the
matcher's confidence as a gate (``TsdfConfig.min_confidence`` 0.2) and as weights
(``confidence_full`` 0.5 and 1); with ``--skip-speed --confidence``, KITTI alone (Kinect
depth has no matcher confidence). The survey prints Open3D's plain loop on the same depth
first.

    python benchmarks/bench_fusion.py --survey 150 --confidence
    python benchmarks/bench_fusion.py --skip-speed --confidence
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.core as o3c

from sea3d.eval.surface import surface_metrics
from sea3d.io.depth_files import read_depth
from sea3d.io.rgbd_files import read_color
from sea3d.io.trajectory_files import TrajectoryFile
from sea3d.pipeline.fuse import fuse_rgbd
from sea3d.recon.tsdf import TsdfConfig, TsdfVolume

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "rgbd" / "7scenes_chess"
K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])


def frames(root: Path) -> tuple[list[Path], list[Path], np.ndarray]:
    colors = sorted(root.glob("frame-*.color.jpg"))
    depths = sorted(root.glob("frame-*.depth.png"))
    poses = np.stack([np.loadtxt(p) for p in sorted(root.glob("frame-*.pose.txt"))])
    # The stored rotations are orthonormal to 1e-4 only; both runs get the nearest rotations
    # (as a TUM file's quaternions would give), so that rigid inverses are exact.
    U, _, Vt = np.linalg.svd(poses[:, :3, :3])
    poses[:, :3, :3] = U @ Vt
    return colors, depths, poses


def sea3d_direct(images: list[tuple[np.ndarray, np.ndarray]], poses: np.ndarray,
                 cfg: TsdfConfig) -> tuple[list[float], list[float]]:
    """The integration loop of ``sea3d fuse`` on preloaded frames (what fuse_rgbd times)."""
    vol = TsdfVolume(cfg)
    wall, cpu = [], []
    for (depth, color), T in zip(images, poses, strict=True):
        t0, c0 = time.perf_counter(), time.process_time()
        vol.integrate(depth, color, K, T)
        wall.append(1000 * (time.perf_counter() - t0))
        cpu.append(1000 * (time.process_time() - c0))
    return wall, cpu


def open3d_direct(images: list[tuple[np.ndarray, np.ndarray]], poses: np.ndarray,
                  K_o3d: np.ndarray, voxel_m: float, max_depth_m: float,
                  block_count: int = 4096) -> tuple[np.ndarray, list[float], list[float]]:
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel_m, block_resolution=8,
        block_count=block_count, device=o3c.Device("CPU:0"))
    Kt = o3c.Tensor(K_o3d)
    wall, cpu = [], []
    for (depth, color), T in zip(images, poses, strict=True):
        t0, c0 = time.perf_counter(), time.process_time()
        d = o3d.t.geometry.Image(o3c.Tensor(np.nan_to_num(depth, nan=0.0)))
        c = o3d.t.geometry.Image(o3c.Tensor(color.astype(np.float32) / 255.0))
        E = o3c.Tensor(np.linalg.inv(T))
        blocks = vbg.compute_unique_block_coordinates(d, Kt, E, 1.0, max_depth_m, 4.0)
        vbg.integrate(blocks, d, c, Kt, Kt, E, 1.0, max_depth_m, 4.0)
        wall.append(1000 * (time.perf_counter() - t0))
        cpu.append(1000 * (time.process_time() - c0))
    mesh = vbg.extract_triangle_mesh(0.5)
    return (mesh.vertex.positions.numpy().astype(np.float64),
            mesh.triangle.indices.numpy().astype(np.int64)), wall, cpu


def half_pixel_floor() -> None:
    """The floor seen at about 45 degrees from 1.3 m (analytic depth, 160x120, f 130 px):
    where one TSDF integration puts it with and without sea3d's half-pixel convention."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from sea3d.geometry.se3 import look_at
    from synthetic_views import K as K_syn
    from synthetic_views import render

    T = look_at((0.3, -0.9, 1.0), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, c = render(T, box=False)
    vol = TsdfVolume(TsdfConfig(voxel_m=0.02))
    vol.integrate(d, c, K_syn, T)
    ours = 1000 * np.median(vol.extract_mesh().vertices[:, 2])
    (naive_v, _), _, _ = open3d_direct([(d, c)], T[None], K_syn, 0.02, 5.0)
    print(f"floor at z = 0 seen at 45 deg, 2 cm voxels: mesh median z {ours:+.2f} mm (sea3d), "
          f"{1000 * np.median(naive_v[:, 2]):+.2f} mm (Open3D with K as it is)")


KINECT_NOISE_PER_M = 1.6e-3
"""Kinect v1 depth's standard error at 1 m (m), growing with depth squared (Khoshelham and
Elberink 2012: about 4 cm at 5 m)."""


def render_depth(vertices: np.ndarray, triangles: np.ndarray, T_world_cam: np.ndarray,
                 shape: tuple[int, int], K: np.ndarray = K) -> np.ndarray:
    """Depth (H, W) float32 m of a mesh seen by the pinhole ``K`` at ``T_world_cam`` (pixel
    centres at integer coordinates), NaN where no triangle is hit."""
    h, w = shape
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3c.Tensor(vertices.astype(np.float32)),
                        o3c.Tensor(triangles.astype(np.uint32)))
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    dirs_cam = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1],
                         np.ones_like(uu)], axis=-1).reshape(-1, 3)
    dirs = dirs_cam @ T_world_cam[:3, :3].T  # camera z = 1: the ray parameter is the depth
    rays = np.concatenate([np.broadcast_to(T_world_cam[:3, 3], dirs.shape), dirs], axis=1)
    t = scene.cast_rays(o3c.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    out = np.where(np.isfinite(t), t, np.nan).reshape(h, w).astype(np.float32)
    return out


def heldout_figures(mesh: tuple[np.ndarray, np.ndarray], held: list[tuple[np.ndarray,
                    np.ndarray]], poses: np.ndarray, K: np.ndarray = K,
                    noise_per_m: float = 0.0) -> dict[str, float]:
    """Depth-reprojection consistency of a mesh with held-out frames (module docstring):
    "in front" and "seen through" mean nearer than the held-out depth by more than
    ``max(5 cm, 3 sigma_z)``, "explained" within ``max(2 cm, 2 sigma_z)``, with ``sigma_z =
    noise_per_m z^2`` of the held-out depth ``z``."""
    import cv2

    v, f = mesh
    errs, front, explained, valid = [], 0, 0, 0
    seen_through = np.zeros(len(v), bool)
    for (depth, _), T in zip(held, poses, strict=True):
        r = render_depth(v, f, T, depth.shape, K)
        both = np.isfinite(r) & np.isfinite(depth)
        e = r[both] - depth[both]
        sig = noise_per_m * depth[both] ** 2
        errs.append(np.abs(e))
        front += int((e < -np.maximum(0.05, 3 * sig)).sum())
        valid += int(np.isfinite(depth).sum())
        explained += int((np.abs(e) < np.maximum(0.02, 2 * sig)).sum())
        d_min = cv2.erode(np.nan_to_num(depth, nan=0.0), np.ones((3, 3), np.uint8))
        pc = (v - T[:3, 3]) @ T[:3, :3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2])
            vv = np.rint(K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2])
        ok = (pc[:, 2] > 0) & (u >= 0) & (u < depth.shape[1]) & (vv >= 0) & (vv < depth.shape[0])
        dm = np.zeros(len(v), np.float32)
        dm[ok] = d_min[vv[ok].astype(int), u[ok].astype(int)]
        seen_through |= ok & (dm > 0) & (dm - pc[:, 2] > np.maximum(0.05, 3 * noise_per_m
                                                                    * dm**2))
    a = np.concatenate(errs)
    return {"median_mm": 1000 * float(np.median(a)), "p90_mm": 1000 * float(np.quantile(a, 0.9)),
            "p99_mm": 1000 * float(np.quantile(a, 0.99)),
            "in_front_pct": 100 * front / max(len(a), 1),
            "explained_pct": 100 * explained / max(valid, 1),
            "vertices": float(len(v)), "seen_through": float(seen_through.sum())}


def heldout(images: list[tuple[np.ndarray, np.ndarray]], poses: np.ndarray, voxel_m: float,
            every: int = 5, *, K: np.ndarray = K, max_depth_m: float = 4.0,
            noise_per_m: float = KINECT_NOISE_PER_M,
            reference: list[tuple[np.ndarray, np.ndarray]] | None = None,
            title: str = "7-Scenes chess, Kinect depth",
            confidences: list[np.ndarray] | None = None, only_confidence: bool = False) -> None:
    """Floaters on real frames: the module docstring's held-out comparison (``reference``:
    the held-out frames' depth to compare with, default their own in ``images``;
    ``confidences``: the matcher's confidence of each frame's depth, for the
    confidence-gated and -weighted rows; ``only_confidence``: those rows and the plain ones
    only)."""
    held_idx = np.arange(0, len(images), every)
    fuse_idx = np.setdiff1d(np.arange(len(images)), held_idx)
    fused = [images[i] for i in fuse_idx]
    # the reference within the fused depth range only: beyond it the mesh has nothing to say
    held = [(np.where((d > 0) & (d <= max_depth_m), d, np.nan).astype(np.float32), c)
            for d, c in ((reference or images)[i] for i in held_idx)]
    K_half = K.copy()
    K_half[:2, 2] += 0.5
    base = TsdfConfig(voxel_m=voxel_m, min_depth_m=0.0, max_depth_m=max_depth_m,
                      initial_blocks=16384)
    carve = replace(base, carve_free_space=True, depth_noise_per_m=noise_per_m)
    meshes: dict[str, tuple[tuple[np.ndarray, np.ndarray], float]] = {}
    ref, _, cpu = open3d_direct(fused, poses[fuse_idx], K_half, voxel_m, max_depth_m)
    meshes["Open3D VoxelBlockGrid"] = (ref, statistics.median(cpu))
    variants = [("sea3d, seen once", base)]
    if not only_confidence:
        variants += [("carving", carve),
                     ("hole margin 1 px", replace(base, hole_margin_px=1)),
                     ("hole margin 2 px", replace(base, hole_margin_px=2)),
                     ("hole margin 2 px + carving", replace(carve, hole_margin_px=2))]
    if confidences is not None:
        variants += [("confidence >= 0.2", replace(base, min_confidence=0.2)),
                     ("weighted, full at 0.5", replace(base, confidence_full=0.5)),
                     ("weighted, full at 1", replace(base, confidence_full=1.0))]
    variants += [(f"{n}, seen twice" if n != "sea3d, seen once" else "sea3d, seen twice",
                  replace(c, weight_threshold=1.5)) for n, c in variants]
    for name, cfg in variants:
        vol = TsdfVolume(cfg)
        cpu = []
        for i, ((depth, color), T) in enumerate(zip(fused, poses[fuse_idx], strict=True)):
            conf = None if confidences is None else confidences[fuse_idx[i]]
            c0 = time.process_time()
            vol.integrate(depth, color, K, T, confidence=conf)
            cpu.append(1000 * (time.process_time() - c0))
        m = vol.extract_mesh()
        meshes[name] = ((m.vertices, m.triangles), statistics.median(cpu[1:]))
    print(f"\n{title}: held-out depth check, {len(fuse_idx)} frames fused, {len(held_idx)} "
          f"held out (every {every}th), {1000 * voxel_m:.0f} mm voxels")
    print(f"{'mesh':40} {'CPU ms/fr':>9} {'|dz| med':>8} {'p90':>6} {'p99':>6} "
          f"{'in front %':>10} {'explained %':>11} {'vertices':>9} {'seen through':>12}")
    for name, (mesh, ms) in meshes.items():
        r = heldout_figures(mesh, held, poses[held_idx], K, noise_per_m)
        print(f"{name:40} {ms:9.1f} {r['median_mm']:8.2f} {r['p90_mm']:6.1f} "
              f"{r['p99_mm']:6.1f} {r['in_front_pct']:10.3f} {r['explained_pct']:11.2f} "
              f"{r['vertices']:9.0f} {r['seen_through']:12.0f}")


KITTI = Path(os.environ.get("SEA3D_REAL_DATA", "/work/realdata")) / "kitti_seq1"
SGM_SIGMA_PX = 0.25
"""Sub-pixel SGM's disparity noise (docs/depth.md, the planner's figure)."""


def kitti_frames(root: Path) -> tuple[list[tuple[np.ndarray, np.ndarray]],
                                      list[tuple[np.ndarray, np.ndarray]], np.ndarray,
                                      np.ndarray, float, list[np.ndarray]]:
    """KITTI odometry excerpt: sea3d SGM depth (matched pixels only, as ``sea3d process``
    fuses) and OpenCV SGBM depth (the independent reference for held-out frames) of every
    rectified pair, poses ``T_world_left``, K, ``f B`` (px m) and SGM's confidence of each
    pair."""
    import cv2

    from sea3d.stereo.sgm import match_sgm
    from sea3d.stereo.types import SgmConfig

    rows = [np.asarray(ln.split(":")[-1].split(), np.float64).reshape(3, 4)
            for ln in (root / "calib.txt").read_text().splitlines() if ln.strip()]
    P0, P1 = rows[0], rows[1]
    Kk = P0[:3, :3].copy()
    fB = float(-P1[0, 3])
    poses = np.loadtxt(root / "poses.txt").reshape(-1, 3, 4)
    T = np.tile(np.eye(4), (len(poses), 1, 1))
    T[:, :3, :] = poses
    ours, ref, confs = [], [], []
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    lefts = sorted((root / "image_0").glob("*.png"))
    rights = sorted((root / "image_1").glob("*.png"))
    for lp, rp in zip(lefts, rights, strict=True):
        left = cv2.imread(str(lp), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(rp), cv2.IMREAD_GRAYSCALE)
        res = match_sgm(left, right, SgmConfig(max_disparity_px=127))
        d = np.where(res.confidence > 0, res.disparity_px, np.nan)
        confs.append(res.confidence.astype(np.float32))
        col = np.repeat(left[..., None], 3, axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            ours.append((np.where(d >= 4, fB / d, np.nan).astype(np.float32), col))
            dr = sgbm.compute(left, right).astype(np.float32) / 16.0
            ref.append((np.where(dr >= 4, fB / dr, np.nan).astype(np.float32), col))
    return ours, ref, T[: len(ours)], Kk, fB, confs


def kitti(root: Path, voxel_m: float = 0.05, max_depth_m: float = 20.0,
          only_confidence: bool = False) -> None:
    """The held-out check on real stereo: KITTI's rectified pairs, sea3d's SGM depth fused
    with the ground-truth poses, held-out frames compared with OpenCV SGBM's depth."""
    if not (root / "calib.txt").is_file():
        print(f"\nno KITTI excerpt at {root}: real-stereo check skipped")
        return
    ours, ref, T, Kk, fB, confs = kitti_frames(root)
    heldout(ours, T, voxel_m, K=Kk, max_depth_m=max_depth_m, noise_per_m=SGM_SIGMA_PX / fB,
            reference=ref, confidences=confs, only_confidence=only_confidence,
            title=f"KITTI {root.name}, sea3d SGM depth (f B {fB:.0f} px m), "
            "held-out frames' OpenCV SGBM depth")

def survey_depth(session: Path, cache: Path) -> None:
    """Every frame's fusion depth and confidence in the virtual pinhole (as the per-frame
    stage of ``sea3d process`` makes it, 0.5-4 m), colours and ground-truth
    ``T_world_cam``, cached as ``cache/fNNNNN.npz``."""
    import cv2

    from sea3d.io.rig_file import rig_from_yaml
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.recon.depth_resample import pinhole_offsets, virtual_pinhole_depth
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    if (cache / "T_world_cam.npy").is_file():
        return
    cache.mkdir(parents=True, exist_ok=True)
    with open_session(session) as s:
        stereo = StereoDepth(rig_from_yaml(s.rig_yaml, "the session's rig"),
                             DepthConfig(min_depth_m=0.5, max_depth_m=4.0))
        maps = stereo.maps
        Ks = maps.P_left[:3, :3].copy()
        match, stamps = s.match_pairs(), s.stamps("left")
        gt = read_trajectory(session / "gt" / "poses_left.tum")
        R4 = np.eye(4)
        R4[:3, :3] = maps.R_rect_left_left.T
        poses = []
        for i in range(len(match)):
            res = stereo.compute(s.image("left", int(match.left_index[i]), by="index"),
                                 s.image("right", int(match.right_index[i]), by="index"))
            pts = np.einsum("ij,kj->ik", res.points_left, maps.R_rect_left_left)
            depth = virtual_pinhole_depth(res.depth_m, pts, Ks, method="resample",
                                          focal_baseline_px_m=maps.focal_px * maps.baseline_m)
            du, dv = pinhole_offsets(res.depth_m, pts, Ks)
            vv, uu = np.mgrid[0:depth.shape[0], 0:depth.shape[1]].astype(np.float32)
            mx = np.where(np.isfinite(du), uu - du, -10).astype(np.float32)
            my = np.where(np.isfinite(dv), vv - dv, -10).astype(np.float32)
            assert res.confidence is not None
            conf = cv2.remap(res.confidence.astype(np.float32), mx, my, cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            rl = res.rect_left
            col = rl if rl.ndim == 3 else np.repeat(rl[..., None], 3, 2)
            t = int(stamps[match.left_index[i]])
            poses.append(gt.T_world_x[int(np.argmin(np.abs(gt.t_ns - t)))] @ R4)
            np.savez(cache / f"f{i:05d}.npz", depth=depth, conf=conf, color=col, t=t)
    np.save(cache / "K.npy", Ks)
    np.save(cache / "fB.npy", np.array([maps.focal_px * maps.baseline_m]))
    np.save(cache / "T_world_cam.npy", np.stack(poses))


def survey(frames_n: int, poses_path: Path | None, only_confidence: bool = False) -> None:
    """Floaters on the simulated lake survey: the variants of benchmarks/results/fusion.md
    (Floaters) fused from the same cached depth, every vertex's distance to the scene."""
    from scipy.spatial import cKDTree

    from sea3d.cli import main as cli
    from sea3d.eval.surface import sample_surface
    from sea3d.io.mesh_files import read_mesh

    base_dir = Path(__file__).resolve().parents[1] / "out" / "bench_fusion"
    session = base_dir / f"lake_640x360_{frames_n}"
    if not (session / "session.json").is_file():
        cli(["-q", "sim", "--scene", "lake", "--frames", str(frames_n), "--size", "640x360",
             "--water", "coastal", "--format", "folder", "--out", str(session)])
    cache = base_dir / f"depth_{frames_n}"
    survey_depth(session, cache)
    files = sorted(cache.glob("f*.npz"))
    Ks, fB = np.load(cache / "K.npy"), float(np.load(cache / "fB.npy")[0])
    T = np.load(poses_path) if poses_path else np.load(cache / "T_world_cam.npy")
    scene = read_mesh(session / "gt" / "scene.ply")
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3c.Tensor(scene.vertices.astype(np.float32)),
                     o3c.Tensor(scene.triangles.astype(np.uint32)))
    data = [np.load(f) for f in files]
    pts = []
    for fr, Tw in zip(data[::3], T[::3], strict=False):
        z = fr["depth"][::4, ::4]
        vv, uu = np.mgrid[0:fr["depth"].shape[0]:4, 0:fr["depth"].shape[1]:4]
        ok = np.isfinite(z)
        pc = np.stack([(uu[ok] - Ks[0, 2]) / Ks[0, 0] * z[ok],
                       (vv[ok] - Ks[1, 2]) / Ks[1, 1] * z[ok], z[ok]], 1)
        pts.append(pc @ Tw[:3, :3].T + Tw[:3, 3])
    ref = sample_surface(scene.vertices, scene.triangles, 400_000, np.random.default_rng(0))
    dd, _ = cKDTree(np.concatenate(pts)).query(ref, k=1, distance_upper_bound=0.03)
    observed = ref[np.isfinite(dd)]
    base = TsdfConfig(voxel_m=0.02, min_depth_m=0.5, max_depth_m=4.0, initial_blocks=50_000)
    carve = replace(base, carve_free_space=True, depth_noise_per_m=SGM_SIGMA_PX / fB)
    variants = [("all pixels", base, 0.0)]
    if not only_confidence:
        variants += [("carving", carve, 0.0),
                     ("hole margin 1 px", replace(base, hole_margin_px=1), 0.0)]
    variants += [("hole margin 2 px", replace(base, hole_margin_px=2), 0.0),
                 ("confidence >= 0.2", replace(base, min_confidence=0.2), 0.0),
                 ("weighted, full at 0.5", replace(base, confidence_full=0.5), 0.0),
                 ("weighted, full at 1", replace(base, confidence_full=1.0), 0.0),
                 ("weighted 0.5 + margin 2", replace(base, confidence_full=0.5,
                                                     hole_margin_px=2), 0.0)]
    print(f"\nlake survey, {len(files)} frames 640x360, 2 cm voxels, "
          f"{'given' if poses_path else 'ground-truth'} poses; {len(observed)} observed "
          "scene samples")
    print(f"{'fused':20} {'kept':>5} {'vertices':>9} {'med mm':>7} {'p90':>6} {'p99':>6} "
          f"{'max':>6} {'>10cm':>6} {'compl med/p90':>14} {'rec 2cm':>7} {'CPU ms/fr':>9}")
    K_half = Ks.copy()
    K_half[:2, 2] += 0.5
    o3d_in = [(np.where((fr["depth"] >= 0.5) & (fr["depth"] <= 4.0), fr["depth"], np.nan)
               .astype(np.float32), fr["color"]) for fr in data]
    ref_mesh, _, ref_cpu = open3d_direct(o3d_in, T[: len(o3d_in)], K_half, 0.02, 4.0,
                                         block_count=50_000)
    dv = rc.compute_distance(o3c.Tensor(ref_mesh[0].astype(np.float32))).numpy()
    q = 1000 * np.quantile(dv, [0.5, 0.9, 0.99])
    print(f"{'Open3D VoxelBlockGrid':20} {'once':>5} {len(dv):9d} {q[0]:7.2f} {q[1]:6.1f} "
          f"{q[2]:6.1f} {1000 * dv.max():6.0f} {int((dv > 0.1).sum()):6d} {'':>14} {'':>7} "
          f"{statistics.median(ref_cpu):9.1f}")
    for name, cfg, cmin in variants:
        vol = TsdfVolume(cfg)
        cpu = []
        for fr, Tw in zip(data, T, strict=False):
            z = np.where(fr["conf"] >= cmin, fr["depth"], np.nan) if cmin else fr["depth"]
            c0 = time.process_time()
            vol.integrate(z, fr["color"], Ks, Tw, confidence=fr["conf"])
            cpu.append(1000 * (time.process_time() - c0))
        for kept, wt in (("once", 0.5), ("twice", 1.5)):
            m = vol.extract_mesh(wt)
            dv = rc.compute_distance(o3c.Tensor(m.vertices.astype(np.float32))).numpy()
            sm = surface_metrics(m.vertices, m.triangles, scene.vertices, scene.triangles,
                                 samples=200_000, reference_points=observed)
            rec = dict(zip(sm.thresholds_m, sm.recall, strict=True)).get(0.02, float("nan"))
            q = 1000 * np.quantile(dv, [0.5, 0.9, 0.99])
            print(f"{name:20} {kept:>5} {len(dv):9d} {q[0]:7.2f} {q[1]:6.1f} {q[2]:6.1f} "
                  f"{1000 * dv.max():6.0f} {int((dv > 0.1).sum()):6d} "
                  f"{1000 * sm.completeness_m.median:6.2f} / {1000 * sm.completeness_m.p90:5.2f}"
                  f" {100 * rec:7.1f} {statistics.median(cpu):9.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--voxel-m", type=float, default=0.01)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--kitti", type=Path, default=KITTI,
                    help="a KITTI odometry excerpt (image_0, image_1, calib.txt, poses.txt)")
    ap.add_argument("--survey", type=int, default=0, metavar="FRAMES",
                    help="only the floaters on a simulated lake survey of FRAMES frames")
    ap.add_argument("--survey-poses", type=Path, default=None,
                    help="(N, 4, 4) .npy of T_world_cam for --survey instead of the truth")
    ap.add_argument("--skip-speed", action="store_true",
                    help="only the held-out floater check")
    ap.add_argument("--confidence", action="store_true",
                    help="floater rows: the plain ones and the confidence-gated and -weighted "
                    "ones only (with --skip-speed: KITTI alone, 7-Scenes has no confidence)")
    args = ap.parse_args()
    if args.survey:
        survey(args.survey, args.survey_poses, args.confidence)
        return
    if args.skip_speed and args.confidence:
        kitti(args.kitti, only_confidence=True)
        return
    colors, depths, poses = frames(args.data)
    if args.skip_speed:
        images = [(read_depth(d, 1000.0), read_color(c))
                  for c, d in zip(colors, depths, strict=True)]
        heldout(images, poses, args.voxel_m)
        kitti(args.kitti)
        return
    half_pixel_floor()
    traj = TrajectoryFile(t_ns=np.arange(len(poses), dtype=np.int64), T_world_x=poses,
                          format="tum", timed=False, path=args.data)
    images = [(read_depth(d, 1000.0), read_color(c)) for c, d in zip(colors, depths, strict=True)]
    cfg = TsdfConfig(voxel_m=args.voxel_m, min_depth_m=0.0, max_depth_m=4.0)
    K_half = K.copy()
    K_half[:2, 2] += 0.5
    ours_ms, ours_cpu, ref_ms, ref_cpu, e2e = [], [], [], [], []
    ours = ref = naive = None
    for _ in range(args.repeats):
        wall, cpu = sea3d_direct(images, poses, cfg)
        ours_ms.append(statistics.median(wall))
        ours_cpu.append(statistics.median(cpu))
        ref, wall, cpu = open3d_direct(images, poses, K_half, args.voxel_m, 4.0)
        ref_ms.append(statistics.median(wall))
        ref_cpu.append(statistics.median(cpu))
    t0 = time.perf_counter()
    res = fuse_rgbd(colors, depths, traj, K, cfg, depth_scale=1000.0)
    e2e.append(1000 * (time.perf_counter() - t0) / res.frames)
    ours = res.mesh
    naive, _, _ = open3d_direct(images, poses, K, args.voxel_m, 4.0)
    assert ours is not None and ref is not None and naive is not None
    n = len(colors)
    print(f"7-Scenes chess, {n} frames 640x480, {1000 * args.voxel_m:.0f} mm voxels, "
          f"median of {args.repeats} runs")
    a, b = statistics.median(ours_ms), statistics.median(ref_ms)
    print(f"TSDF ms per frame (wall): sea3d fuse {a:.1f}, Open3D VoxelBlockGrid direct {b:.1f},"
          f" ratio {a / b:.2f}")
    c, d = statistics.median(ours_cpu), statistics.median(ref_cpu)
    print(f"TSDF CPU ms per frame: sea3d fuse {c:.1f}, Open3D direct {d:.1f}, ratio {c / d:.2f}")
    print(f"sea3d fuse end to end (reading JPEG + PNG, integrating): {e2e[0]:.1f} ms per frame, "
          f"one run")
    print(f"meshes: sea3d {len(ours.vertices)} vertices, Open3D {len(ref[0])} (same K "
          f"convention), {len(naive[0])} (K as it is)")
    for name, other in (("Open3D, same convention", ref), ("Open3D, K as it is", naive)):
        m = surface_metrics(ours.vertices, ours.triangles, other[0], other[1], samples=200_000)
        print(f"sea3d mesh against {name}: accuracy median {1000 * m.accuracy_m.median:.3f} mm, "
              f"p90 {1000 * m.accuracy_m.p90:.3f} mm; completeness median "
              f"{1000 * m.completeness_m.median:.3f} mm, p90 {1000 * m.completeness_m.p90:.3f} mm")
    heldout(images, poses, args.voxel_m)
    kitti(args.kitti)


if __name__ == "__main__":
    main()
