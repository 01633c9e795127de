"""``sea3d process``, ``sea3d fuse``, ``sea3d eval trajectory`` and ``sea3d eval surface``.

``process`` turns a recorded session into a trajectory, a mesh, a point cloud and a report;
``fuse`` integrates RGB-D frames with known poses into a mesh; the ``eval`` commands measure
trajectories (ATE, RPE) and surfaces (accuracy, completeness).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sea3d._text import loop_checks_text
from sea3d.cli import error_line
from sea3d.cli._args import (
    add_depth_range,
    add_loop_closure_flag,
    config_option,
    image_size,
    odometry_config,
    param_option,
    plural,
)

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register", "register_eval"]




# ------------------------------------------------------------------------------------ process


def _cmd_process(args: argparse.Namespace) -> int:
    from sea3d.cli._args import depth_config
    from sea3d.enhance.registry import process_enhance_hook
    from sea3d.pipeline.process import (
        ColourConfig,
        ExecutorConfig,
        MapConfig,
        PoseConfig,
        ProcessConfig,
        run_process,
    )

    config = ProcessConfig(
        out_dir=args.output,
        rig_path=args.rig,
        size_px=args.size,
        depth=depth_config(args),
        map=MapConfig(voxel_m=args.voxel_m, integrate=args.integrate,
                      min_observations=args.min_observations,
                      min_piece_triangles=args.min_piece_triangles,
                      hole_margin_px=args.hole_margin_px,
                      carve_free_space=args.carve_free_space,
                      min_confidence=args.fusion_min_confidence,
                      confidence_full=args.fusion_confidence_full),
        poses=PoseConfig(use_imu=not args.no_imu, poses_path=args.poses,
                         odometry_config=odometry_config(args)),
        colours=ColourConfig(
            enhance=process_enhance_hook(args.enhance) if args.enhance else None,
            restore_colours=args.restore_colours),
        executor=ExecutorConfig(workers=args.workers, scheduler=args.scheduler),
        fresh=args.fresh,
        rebuild_cache_config=args.rebuild_cache_config,
        report=not args.no_report,
        max_frames=args.max_frames,
        depth_rate=args.depth_rate,
    )
    from sea3d.cli._progress import stage_bars

    result = run_process(args.session, config, progress=stage_bars(not args.json))
    s = result.summary
    if args.json:
        json.dump(s, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
        return 0
    print(
        f"{plural(s['frames'], 'frame')}: {plural(s['keyframes'], 'keyframe')}, "
        f"{s['frames_lost']} lost, {plural(s['loop_closures'], 'loop closure')}"
        f" ({plural(s.get('relinks', 0), 're-link')} across lost frames apart)"
        f"{loop_checks_text(s.get('loop_checks', {}))}, path "
        f"{s['path_length_m']:.2f} m; poses from {s['odometry']}"
    )
    fps = s.get("frames_per_second")
    print(f"{s['frames_fused']} frames fused into {plural(s['submaps'], 'submap')}; "
          f"{s['mesh']['triangles']} triangles, {s['cloud']['points']} cloud points"
          + (f"; {fps:.2f} frames/s" if fps else "")
          + (f" ({s['frames_from_cache']} from the cache)" if s["frames_from_cache"] else ""))
    tv = s.get("trajectory_vs_gt")
    if isinstance(tv, dict) and "ate_m" in tv:
        print(f"against ground truth: ATE RMSE {1000 * tv['ate_m']['rmse']:.1f} mm "
              f"({tv['ate_rmse_pct_of_path'] or 0:.3f} % of the path)", end="")
        mv = s.get("mesh_vs_gt")
        if isinstance(mv, dict) and "accuracy_m" in mv:
            print(f"; mesh accuracy median {1000 * mv['accuracy_m']['median']:.1f} mm, 90th "
                  f"percentile {1000 * mv['accuracy_m']['p90']:.1f} mm", end="")
        print()
    print(f"wrote {result.out_dir}/: {_written(result.files)}")
    if "mesh_gt_frame" in result.files:
        print("trajectory.tum, mesh.ply, cloud.ply and results.mcap are in the odometry's world "
              "(the first left camera); mesh_gt_frame.ply and trajectory_gt_frame.tum in the "
              "ground truth's (for 'sea3d eval surface')")
    return 0


def _written(files: dict[str, Path]) -> str:
    """The names of the files a run wrote, in its order, for the closing "wrote" line."""
    return ", ".join(Path(p).name for p in files.values() if Path(p).exists())


# --------------------------------------------------------------------------------------- fuse


def _glob(pattern: str, what: str) -> list[Path]:
    from sea3d.errors import ReconError
    from sea3d.io.image_files import image_paths

    paths = image_paths(pattern)
    if not paths:
        raise ReconError(f"no {what} files match {pattern!r}")
    return paths


def _cmd_fuse(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.cli import _progress
    from sea3d.cli._args import check_output_suffix
    from sea3d.io.mesh_files import CLOUD_SUFFIXES, MESH_SUFFIXES, write_mesh, write_point_cloud
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.pipeline.fuse import fuse_rgbd
    from sea3d.recon.cloud import CloudConfig, clean_point_cloud
    from sea3d.recon.tsdf import TsdfConfig

    check_output_suffix(args.output, "-o/--output", MESH_SUFFIXES, "a mesh")
    if args.cloud:
        check_output_suffix(args.cloud, "--cloud", CLOUD_SUFFIXES, "a point cloud")
    colors = _glob(args.color, "colour")
    depths = _glob(args.depth, "depth")
    poses = read_trajectory(args.poses)
    fx, fy, cx, cy = args.intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    config = TsdfConfig(voxel_m=args.voxel_m, trunc_voxels=args.trunc_voxels,
                        min_depth_m=args.min_depth, max_depth_m=args.max_depth)
    with _progress.bar(len(colors), "fuse", enabled=not args.json, leave=True) as bar:
        res = fuse_rgbd(colors, depths, poses, K, config, depth_scale=args.depth_scale,
                        progress=bar.update)
    write_mesh(args.output, res.mesh)
    n_cloud = None
    if args.cloud:
        p, c, n = res.volume.extract_points()
        cl = clean_point_cloud(p, c, n, CloudConfig(voxel_m=args.voxel_m / 2))
        write_point_cloud(args.cloud, cl.points, cl.colors, cl.normals)
        n_cloud = len(cl.points)
    ms = np.asarray(res.integrate_ms)
    out = {
        "frames": res.frames,
        "skipped_without_pose": res.skipped,
        "vertices": len(res.mesh.vertices),
        "triangles": len(res.mesh.triangles),
        "tsdf_ms_per_frame_median": float(np.median(ms)),
        "tsdf_ms_per_frame_mean": float(np.mean(ms)),
        "blocks": res.volume.block_count,
        "memory_mb": res.volume.memory_bytes / 2**20,
        "mesh": str(args.output),
        "cloud": str(args.cloud) if args.cloud else None,
        "cloud_points": n_cloud,
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{plural(res.frames, 'frame')} fused ({res.skipped} without a pose), "
              f"{out['tsdf_ms_per_frame_median']:.1f} ms per frame; "
              f"{out['triangles']} triangles -> {args.output}"
              + (f"; {n_cloud} points -> {args.cloud}" if args.cloud else ""))
    return 0


# --------------------------------------------------------------------------------------- eval


def _cmd_eval_trajectory(args: argparse.Namespace) -> int:
    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.io.trajectory_files import read_trajectory

    # repeated stamps are kept and paired as evo pairs them (evo's figure on such files).
    # The reader's own warnings are held back: its notes say the same, printed once below.
    reader_log = logging.getLogger("sea3d.io.trajectory_files")
    level = reader_log.level
    reader_log.setLevel(logging.ERROR)
    try:
        est = read_trajectory(args.estimate, args.est_format, kitti_times=args.est_times,
                              duplicates="keep")
        ref = read_trajectory(args.ground_truth, args.gt_format, kitti_times=args.gt_times,
                              duplicates="keep")
    finally:
        reader_log.setLevel(level)
    for note in est.notes + ref.notes:
        print(f"sea3d: warning: {note}", file=sys.stderr)
    by_index = not (est.timed and ref.timed)
    m = evaluate_trajectory(est.t_ns, est.T_world_x, ref.t_ns, ref.T_world_x, align=args.align,
                            max_diff_s=args.max_diff_s, by_index=by_index,
                            rpe_deltas_m=args.rpe_delta_m, rpe_along=args.rpe_along)
    if args.json:
        d = m.as_dict()
        d["paired_by"] = "index" if by_index else "time"
        d["duplicates_kept"] = {"estimate": est.duplicates_kept,
                                "reference": ref.duplicates_kept}
        print(json.dumps(d, indent=2))
        for w in m.warnings:
            print(f"sea3d: warning: {error_line(w)}", file=sys.stderr)
        return 0
    a = m.ate_m
    print(f"{m.matched} of {m.estimate_poses} poses paired by {'index' if by_index else 'time'}"
          f", aligned {m.align}" + (f" (scale {m.scale:.4f})" if m.align == "sim3" else "")
          + f"; path {m.path_length_m:.2f} m")
    print(f"ATE: rmse {a.rmse:.4f} m, mean {a.mean:.4f}, median {a.median:.4f}, std {a.std:.4f},"
          f" min {a.min:.4f}, max {a.max:.4f} m; rotation rmse {m.ate_rotation_deg.rmse:.3f} deg"
          + ("" if m.rotation_meaningful else " (meaningless: see the warning)"))
    for r in m.rpe:
        t = r.translation_m
        print(f"RPE {r.delta_m:g} m ({t.count} pairs): rmse {t.rmse:.4f} m ({r.drift_pct:.2f} %),"
              f" mean {t.mean:.4f}, median {t.median:.4f}, max {t.max:.4f} m; rotation rmse "
              f"{r.rotation_deg.rmse:.3f} deg"
              + (" (meaningless: see the warning)"
                 if any(w.startswith(f"RPE over {r.delta_m:g} m") for w in m.warnings) else ""))
    for w in m.warnings:
        print(f"sea3d: warning: {error_line(w)}", file=sys.stderr)
    return 0


# Above this share of the reference outside the mesh's box, completeness says little about the
# mesh (a quarter: a survey that saw most of its reference stays well below it).
OUTSIDE_NOTE_FRACTION = 0.25


def _cmd_eval_surface(args: argparse.Namespace) -> int:
    from sea3d.pipeline.surface_eval import evaluate_surface

    res = evaluate_surface(
        args.mesh, args.reference, align=args.align,
        trajectories=None if args.trajectories is None else tuple(args.trajectories),
        max_diff_s=args.max_diff_s, icp_max_distance_m=args.icp_max_distance_m,
        samples=args.samples, thresholds_m=tuple(t / 1000.0 for t in args.thresholds_mm),
        crop_margin_m=args.crop_margin_m)
    m, align, how = res.metrics, res.alignment, error_line(res.how)
    if args.json:
        d = m.as_dict()
        d["alignment"] = {**align.as_dict(), "how": how}
        print(json.dumps(d, indent=2))
        return 0
    a, c = m.accuracy_m, m.completeness_m
    print(how)
    print(f"accuracy (estimate to reference): median {1000 * a.median:.1f} mm, mean "
          f"{1000 * a.mean:.1f} mm, 90th percentile {1000 * a.p90:.1f} mm")
    print(f"completeness (reference to estimate): median {1000 * c.median:.1f} mm, mean "
          f"{1000 * c.mean:.1f} mm, 90th percentile {1000 * c.p90:.1f} mm")
    if m.reference_outside > OUTSIDE_NOTE_FRACTION:
        print(f"note: {100 * m.reference_outside:.0f} % of the reference surface lies outside the "
              "mesh's bounding box, so completeness mostly measures what the survey never saw; "
              "--crop-margin-m M keeps only the reference within M of that box", file=sys.stderr)
    for t, p, r, f in zip(m.thresholds_m, m.precision, m.recall, m.fscore, strict=True):
        print(f"within {1000 * t:g} mm: precision {100 * p:.1f} %, recall {100 * r:.1f} %, "
              f"F-score {100 * f:.1f} %")
    return 0


# ----------------------------------------------------------------------------------- register


def register(sub: Subcommands) -> None:
    """Add ``process`` and ``fuse``."""
    p = sub.add_parser(
        "process",
        help="a whole session into a trajectory, a coloured mesh, a point cloud and a report",
        description="Rectify, match and triangulate every stereo pair (in worker processes or "
        "on a Dask cluster), run the odometry and fuse depth into keyframe-anchored TSDF "
        "submaps, in time order. Writes OUT/trajectory.tum, mesh.ply, cloud.ply, status.csv, "
        "summary.json and report.html; per-frame results are cached in OUT/cache so a rerun "
        "resumes where a run stopped.",
    )
    p.add_argument("session", type=Path, help="an MCAP file or a session folder")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="output folder")
    p.add_argument("--rig", type=Path, help="rig file (default: the rig stored with the session)")
    p.add_argument("--size", type=image_size, metavar="WxH",
                   help="process at this size (images resized, intrinsics scaled)")
    from sea3d.pipeline.config import RESTORE_COLOURS, ColourConfig, MapConfig
    from sea3d.stereo.recipe import DepthConfig

    config_option(p, MapConfig, "voxel_m", type=float, metavar="V",
                  help="TSDF voxel edge in metres")
    p.add_argument("--no-imu", action="store_true", help="visual odometry only")
    add_loop_closure_flag(p)
    ex = p.add_mutually_exclusive_group()
    ex.add_argument("--workers", type=int, metavar="N",
                    help="local worker processes for the per-frame stage (default: one per "
                    "core; 0 runs it in this process)")
    ex.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                    help="run the per-frame stage on this Dask scheduler's workers")
    p.add_argument("--poses", type=Path, metavar="TRAJ",
                   help="known T_world_left poses (TUM, KITTI or EuRoC CSV) instead of odometry")
    config_option(p, DepthConfig, "engine",
                  choices=["sea3d", "sea3d-gpu", "opencv", "opencv-hh", "opencv-3way"],
                  help="stereo matching engine")
    add_depth_range(p, near="nearest depth resolved", far="farthest depth fused")
    config_option(p, MapConfig, "integrate", choices=["trusted", "keyframes"],
                  help="fuse every frame with a trusted pose or keyframes only")
    config_option(p, MapConfig, "min_observations", type=int, metavar="N",
                  help="mesh and cloud keep the voxels fused from at least N depth frames "
                  "(1: every voxel seen; 2 drops the surfaces one frame's wrong depth leaves)")
    config_option(p, MapConfig, "min_piece_triangles", type=int, metavar="N",
                  help="drop mesh pieces of fewer than N triangles not connected to the rest, "
                  "and the cloud's points on them (specks in open water; 0 keeps all)")
    config_option(p, MapConfig, "hole_margin_px", type=int, metavar="N",
                  help="do not fuse depth pixels within N px of a pixel without depth "
                  "(fewer floaters, less surface beside wide holes; 0 fuses every pixel)")
    config_option(p, MapConfig, "carve_free_space", action="store_true", shown="off",
                  help="each frame takes an observation from the voxels of its submap that "
                  "it sees through (free-space carving; costs about 20 ms a frame)")
    config_option(p, MapConfig, "min_confidence", "--fusion-min-confidence",
                  dest="fusion_min_confidence", type=float, metavar="C",
                  help="do not fuse depth pixels of matching confidence below C (0..1; the "
                  "odometry still gets them)")
    config_option(p, MapConfig, "confidence_full", "--fusion-confidence-full",
                  dest="fusion_confidence_full", type=float, metavar="C",
                  help="weight each depth pixel's observation by min(1, confidence / C) "
                  "(default: every observation weighs 1)")
    p.add_argument("--fresh", action="store_true",
                   help="discard cached per-frame results in OUT instead of resuming")
    p.add_argument("--rebuild-cache-config", action="store_true",
                   help="OUT/cache/config.json is damaged: write it again for this run and "
                   "keep the cached frames (each still checked as it is read); only for a "
                   "rerun of the options and session that made them")
    p.add_argument("--enhance-method", "--enhance", dest="enhance", metavar="METHOD",
                   help="enhance each raw image before matching, as 'sea3d enhance --method': "
                        "none (default: measured best for stereo), grey-world, shades-of-grey, "
                        "red-comp, clahe, udcp, or a package.module:function (docs/enhance.md)"
                        "; --enhance is a deprecated alias, kept for one release")
    config_option(p, ColourConfig, "restore_colours", "--restore-colors", "--restore-colours",
                  choices=list(RESTORE_COLOURS),
                  help="colours of mesh and cloud, restored after depth with the stereo "
                  "range: seathru (one water model fitted to the dive's first 8 frames, "
                  "every frame inverted with it; water-model is its older name) or "
                  "seathru-per-image (Sea-thru fitted to each image alone, seconds per "
                  "frame); --restore-colours is a deprecated alias, kept for one release")
    from sea3d.pipeline.process import ProcessConfig

    config_option(p, ProcessConfig, "depth_rate", metavar="all|auto|N",
                  help="which frames get stereo depth: all, auto (when the motion "
                        "since the last depth frame needs it), or every N-th; odometry sees "
                        "every frame, fusion the depth frames")
    p.add_argument("--max-frames", type=int, metavar="N", help="only the first N pairs")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--json", action="store_true", help="print summary.json (no progress bars)")
    p.set_defaults(handler=_cmd_process)

    f = sub.add_parser(
        "fuse",
        help="fuse RGB-D frames with known poses into a coloured TSDF mesh",
        description="Integrate colour + depth images with known camera poses (T_world_cam) "
        "into a TSDF (Open3D's VoxelBlockGrid) and write its mesh. Integer depth images hold "
        "metres x --depth-scale (0 invalid); float images hold metres.",
    )
    f.add_argument("--color", required=True, metavar="GLOB", help="colour images, e.g. 'rgb/*.png'")
    f.add_argument("--depth", required=True, metavar="GLOB", help="depth images")
    f.add_argument("--poses", type=Path, required=True, metavar="TRAJ",
                   help="T_world_cam per frame (TUM, KITTI or EuRoC CSV): in frame order when "
                   "the counts agree, else by the nanosecond stamps in the file names")
    f.add_argument("--intrinsics", type=float, nargs=4, required=True,
                   metavar=("FX", "FY", "CX", "CY"), help="depth camera intrinsics, pixels")
    from sea3d.pipeline.fuse import fuse_rgbd
    from sea3d.recon.tsdf import TsdfConfig

    param_option(f, fuse_rgbd, "depth_scale", type=float, metavar="S",
                 shown="1000: millimetres", help="integer depth = metres x S")
    f.add_argument("--voxel-m", type=float, required=True, metavar="V", help="voxel edge, metres")
    config_option(f, TsdfConfig, "trunc_voxels", type=float, metavar="N",
                  help="truncation distance in voxels")
    config_option(f, TsdfConfig, "min_depth_m", "--min-depth", dest="min_depth", type=float,
                  metavar="M", help="nearest depth used, metres")
    config_option(f, TsdfConfig, "max_depth_m", "--max-depth", dest="max_depth", type=float,
                  metavar="M", help="farthest depth used, metres")
    f.add_argument("-o", "--output", type=Path, required=True, metavar="MESH",
                   help="output mesh (.ply)")
    f.add_argument("--cloud", type=Path, metavar="CLOUD",
                   help="also write a cleaned point cloud (.ply)")
    f.add_argument("--json", action="store_true", help="print the figures as JSON")
    f.set_defaults(handler=_cmd_fuse)


def register_eval(esub: Subcommands) -> None:
    """Add ``eval trajectory`` and ``eval surface``."""
    t = esub.add_parser(
        "trajectory",
        help="ATE and RPE of an estimated trajectory against ground truth",
        description="Read TUM, KITTI or EuRoC CSV trajectories, pair poses by time (KITTI "
        "without times: by index), align (Umeyama) and report the absolute trajectory error "
        "and the relative pose error per travelled distance, as evo defines them.",
    )
    t.add_argument("estimate", metavar="EST", help="estimated trajectory")
    t.add_argument("ground_truth", metavar="GT", help="reference trajectory")
    from sea3d.eval.surface import DEFAULT_THRESHOLDS_M, align_by_trajectories, surface_metrics
    from sea3d.eval.trajectory import evaluate_trajectory

    param_option(t, evaluate_trajectory, "align", choices=["se3", "sim3", "none"],
                 help="alignment of the estimate")
    param_option(t, evaluate_trajectory, "max_diff_s", type=float, metavar="S",
                 help="largest stamp difference of a pair, seconds")
    t.add_argument("--rpe-delta-m", type=float, nargs="+", metavar="D",
                   help="RPE distances, metres (default 1, 10, 100 m where the path allows)")
    param_option(t, evaluate_trajectory, "rpe_along", choices=["estimate", "reference"],
                 shown="estimate, as evo", help="whose path picks the RPE pairs")
    t.add_argument("--est-format", choices=["tum", "kitti", "euroc"], help="default: guessed")
    t.add_argument("--gt-format", choices=["tum", "kitti", "euroc"], help="default: guessed")
    t.add_argument("--est-times", type=Path, metavar="TIMES", help="KITTI times.txt of EST")
    t.add_argument("--gt-times", type=Path, metavar="TIMES", help="KITTI times.txt of GT")
    t.add_argument("--json", action="store_true", help="print the figures as JSON")
    t.set_defaults(handler=_cmd_eval_trajectory)

    s = esub.add_parser(
        "surface",
        help="accuracy and completeness of a mesh against a reference mesh, in metres",
        description="Sample both surfaces by area; accuracy is the distance of the mesh's "
        "samples to the reference, completeness that of the reference's samples to the mesh "
        "(exact point-to-triangle distances); precision, recall and F-score at thresholds. "
        "Both must be in one frame: --trajectories aligns the mesh by Umeyama on the paired "
        "poses of its trajectory and the reference's, --align icp refines (or finds) it by "
        "ICP; each states its residual. By default a mesh of 'sea3d process' is aligned with "
        "the trajectory.tum beside it and the ground truth its summary.json names.",
    )
    s.add_argument("mesh", metavar="MESH", help="reconstructed mesh (or point cloud)")
    s.add_argument("reference", metavar="REF_MESH", help="reference mesh (or point cloud)")
    param_option(s, surface_metrics, "samples", type=int, help="samples per surface")
    mm = [round(t * 1e3, 6) for t in DEFAULT_THRESHOLDS_M]
    shown = " ".join(f"{t:g}" for t in mm)
    s.add_argument("--thresholds-mm", type=float, nargs="+", default=mm, metavar="T",
                   help=f"precision/recall thresholds, mm (default {shown})")
    s.add_argument("--trajectories", type=Path, nargs=2, metavar=("EST", "GT"),
                   help="align by these trajectories: EST in the mesh's world, GT in the "
                   "reference's (TUM, KITTI or EuRoC CSV)")
    s.add_argument("--align", choices=["auto", "none", "se3", "sim3", "icp"], default="auto",
                   help="auto (default): SE(3) from the trajectories when known, else none with "
                   "a warning; sim3 also fits scale; icp refines after the trajectories (or "
                   "alone)")
    param_option(s, align_by_trajectories, "max_diff_s", type=float, metavar="S",
                 help="largest stamp difference of a pose pair, seconds")
    s.add_argument("--icp-max-distance-m", type=float, metavar="D",
                   help="ICP's largest correspondence distance (default 2 %% of the "
                   "reference's bounding-box diagonal)")
    s.add_argument("--crop-margin-m", type=float, metavar="M",
                   help="only reference surface within the mesh's bounding box grown by M")
    s.add_argument("--json", action="store_true", help="print the figures as JSON")
    s.set_defaults(handler=_cmd_eval_surface)
