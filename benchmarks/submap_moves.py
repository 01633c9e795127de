"""Every submap of a ``sea3d process`` run against the simulator's scene, before and after the
odometry moved it.

A submap's voxels are fused in a grid that is the world as the odometry held it when the
submap started; the final merge places it where it best fits its keyframes' final poses
(after every loop closure and smoother update: :func:`sea3d.recon.submaps.submap_placement`).
This script reads each stored submap (``OUT/submaps/``), extracts its surface points, and
measures their distance to the ground-truth scene both where
fusion put them (before) and where the merge puts them (after), in the frame that
``summary.json``'s ``T_gt_world`` aligns the final trajectory to the ground truth with. A move
that helped brings a submap closer to the scene; one that hurt takes it away::

    sea3d sim --scene lake --frames 600 --size 640x360 --water coastal \\
        --trajectory lawnmower --seed 7 -o survey.mcap
    sea3d process survey.mcap -o OUT --voxel-m 0.02
    python benchmarks/submap_moves.py OUT            # scene: survey_gt/scene.ply
    python benchmarks/submap_moves.py OUT --scene SCENE.ply --markdown

Prints one row per submap (anchor keyframe, frames, the move in mm and degrees, the median and
90th percentile of the surface's distance to the scene before and after) and a verdict: how
many moves made their submap worse by more than ``--worse-mm`` at the median. Exit status 0;
2 for unusable input (no submaps, no ground truth, no ``T_gt_world``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sea3d.errors import Sea3dError


@dataclass(frozen=True)
class SubmapMove:
    """One submap: how far the merge moved it and its surface's distance to the scene."""

    submap_id: int
    anchor_keyframe_id: int
    frames: int
    points: int
    move_mm: float
    move_deg: float
    median_before_mm: float
    median_after_mm: float
    p90_before_mm: float
    p90_after_mm: float


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def submap_moves(out: Path, scene_path: Path, *, max_points: int = 20000,
                 seed: int = 0) -> list[SubmapMove]:
    """Measure every submap of the run in ``out`` (see the module)."""
    from sea3d.eval.surface import point_to_mesh_distance
    from sea3d.io.mesh_files import read_mesh
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.pipeline.ordered import T_left_rect
    from sea3d.pipeline.submap_store import DiskSubmapStore
    from sea3d.recon.submaps import submap_placement
    from sea3d.recon.tsdf import TsdfConfig, TsdfVolume
    from sea3d.stereo.recipe import StereoDepth

    summary = json.loads((out / "summary.json").read_text())
    if summary.get("T_gt_world") is None:
        raise Sea3dError(f"{out / 'summary.json'}: no T_gt_world (was the run's ground truth "
                         "found?)")
    T_gt_world = np.asarray(summary["T_gt_world"], np.float64)
    session = open_session(summary["session"])
    try:
        rig = resolve_rig(None, session)
    finally:
        session.close()
    w, h = summary["image_size_px"]
    if (rig.width, rig.height) != (w, h):
        rig = rig.scaled(w, h)
    T_lr = T_left_rect(StereoDepth(rig).maps)
    traj = read_trajectory(out / "trajectory.tum")
    pose_at = {int(t): T for t, T in zip(traj.t_ns, traj.T_world_x, strict=True)}
    with open(out / "status.csv", newline="") as f:
        keyframe_poses = {int(r["keyframe_id"]): pose_at[int(r["t_ns"])] @ T_lr
                          for r in csv.DictReader(f) if r["keyframe_id"]}

    scene = read_mesh(scene_path)
    rng = np.random.default_rng(seed)

    store = DiskSubmapStore(out / "submaps")
    rows = []
    for sid in store.ids():
        sm = store.get(sid)
        if sm.anchor_keyframe_id not in keyframe_poses or not len(sm.blocks):
            continue
        vol = TsdfVolume.from_blocks(sm.blocks, TsdfConfig(
            voxel_m=sm.blocks.voxel_m, trunc_voxels=sm.blocks.trunc_voxels,
            block_resolution=sm.blocks.block_resolution or 8))
        p, _, _ = vol.extract_points()
        if len(p) == 0:
            continue
        if len(p) > max_points:
            p = p[rng.choice(len(p), max_points, replace=False)]
        T_after = submap_placement(sm, keyframe_poses)  # grid -> world; before: identity
        d = []
        for T in (np.eye(4), T_after):
            q = p @ (T_gt_world[:3, :3] @ T[:3, :3]).T + (T_gt_world[:3, :3] @ T[:3, 3]
                                                          + T_gt_world[:3, 3])
            d.append(point_to_mesh_distance(q, scene.vertices, scene.triangles) * 1e3)
        rows.append(SubmapMove(
            submap_id=int(sid), anchor_keyframe_id=int(sm.anchor_keyframe_id),
            frames=int(sm.frames), points=len(p),
            move_mm=float(np.linalg.norm(T_after[:3, 3])) * 1e3,
            move_deg=_angle_deg(T_after[:3, :3]),
            median_before_mm=float(np.median(d[0])), median_after_mm=float(np.median(d[1])),
            p90_before_mm=float(np.percentile(d[0], 90)),
            p90_after_mm=float(np.percentile(d[1], 90))))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="a `sea3d process` output folder")
    p.add_argument("--scene", type=Path, help="ground-truth scene mesh (default: the run's "
                   "ground truth folder's scene.ply)")
    p.add_argument("--worse-mm", type=float, default=1.0,
                   help="a move that raises its submap's median distance by more than this "
                   "made it worse (default 1 mm)")
    p.add_argument("--markdown", action="store_true", help="print a Markdown table")
    a = p.parse_args(argv)
    try:
        summary = json.loads((a.out / "summary.json").read_text())
        scene = a.scene
        if scene is None:
            if not summary.get("ground_truth"):
                raise Sea3dError(f"{a.out}: the run found no ground truth; give --scene")
            scene = Path(summary["ground_truth"]) / "scene.ply"
        rows = submap_moves(a.out, scene)
    except (Sea3dError, OSError, ValueError, KeyError) as err:
        print(f"submap_moves: {err}", file=sys.stderr)
        return 2
    if not rows:
        print(f"submap_moves: {a.out / 'submaps'} holds no submap with surface",
              file=sys.stderr)
        return 2
    head = ("submap", "anchor kf", "frames", "move mm", "move deg", "median before mm",
            "median after mm", "p90 before mm", "p90 after mm")
    if a.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
    else:
        print("  ".join(head))
    for r in rows:
        cells = (str(r.submap_id), str(r.anchor_keyframe_id), str(r.frames),
                 f"{r.move_mm:.1f}", f"{r.move_deg:.2f}", f"{r.median_before_mm:.1f}",
                 f"{r.median_after_mm:.1f}", f"{r.p90_before_mm:.1f}", f"{r.p90_after_mm:.1f}")
        print(("| " + " | ".join(cells) + " |") if a.markdown else "  ".join(cells))
    worse = [r for r in rows if r.median_after_mm > r.median_before_mm + a.worse_mm]
    better = [r for r in rows if r.median_after_mm < r.median_before_mm - a.worse_mm]
    print(f"{len(rows)} submaps: {len(better)} closer to the scene after their move, "
          f"{len(worse)} farther (by more than {a.worse_mm:g} mm at the median)"
          + (": " + ", ".join(str(r.submap_id) for r in worse) if worse else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
