"""``sea3d demo``: the end-to-end demo on the simulator's default scene."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sea3d.cli._args import add_output, config_default, config_option, image_size

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands


def register(sub: Subcommands) -> None:
    """Add ``sea3d demo``."""
    p = sub.add_parser(
        "demo",
        help="simulate a short dive, process it into a trajectory and a mesh, write a report",
        description="Simulate a lawnmower survey through the paper's dome-port rig, check one "
        "pair's refraction-corrected depth against ground truth, process the whole dive "
        "(depth, poses, TSDF fusion, mesh) and write OUT/report.html and OUT/summary.json.",
    )
    from sea3d.pipeline.demo import DemoConfig

    out = config_default(DemoConfig, "out_dir")
    add_output(p, type=Path, default=out, help=f"output folder (default {out})")
    C = DemoConfig
    config_option(p, C, "scene", help="lake, tank, reef or a scene YAML")
    config_option(p, C, "water", choices=["none", "clear", "coastal", "turbid"],
                  help="water type")
    config_option(p, C, "port", choices=["dome", "flat", "none"],
                  help="ports on the paper's rig")
    config_option(p, C, "engine", choices=["sea3d", "sea3d-gpu", "opencv"],
                  help="stereo matching engine")
    config_option(p, C, "size_px", "--size", dest="size", type=image_size, metavar="WxH",
                  shown="x".join(str(v) for v in C.size_px),
                  help="image size of the simulated survey")
    config_option(p, C, "frames", type=int, help="stereo frames, 10 per second")
    config_option(p, C, "max_disparity_px", "--max-disparity", dest="max_disparity", type=int,
                  help="disparities of the one-pair check at 1920 px width (scaled)")
    config_option(p, C, "voxel_m", type=float, help="TSDF voxel, metres")
    p.add_argument("--workers", type=int, help="worker processes (default one per core)")
    config_option(p, C, "seed", type=int, help="sensor-noise seed")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from sea3d.cli._progress import stage_bars
    from sea3d.pipeline.demo import DemoConfig, run_demo

    config = DemoConfig(
        out_dir=args.out,
        scene=args.scene,
        water=args.water,
        port=args.port,
        engine=args.engine,
        size_px=args.size,
        frames=args.frames,
        max_disparity_px=args.max_disparity,
        voxel_m=args.voxel_m,
        workers=args.workers,
        seed=args.seed,
    )
    quiet = args.json

    def progress(msg: str) -> None:
        if not quiet:
            print(f"[demo] {msg}", file=sys.stderr, flush=True)

    result = run_demo(config, progress, bars=stage_bars(not quiet))
    s = result.summary
    if args.json:
        json.dump(s, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
        return 0
    d = s["depth_check"]
    ours, base = d["refraction_corrected"], d["pinhole_in_water_baseline"]
    line = (
        f"one pair: median depth error {100 * ours['median_rel']:.2f} % refraction-corrected, "
        f"{100 * base['median_rel']:.2f} % pinhole-in-water baseline"
    )
    if d.get("ports_ignored_baseline") is not None:
        line += f", {100 * d['ports_ignored_baseline']['median_rel']:.2f} % with the ports ignored"
    print(line)
    p = s["process"]
    msg = (f"dive: {p['frames']} frames, {p['frames_lost']} lost, path {p['path_length_m']:.2f} m"
           f", poses from {s['poses']}")
    tv = p.get("trajectory_vs_gt")
    if isinstance(tv, dict) and "ate_m" in tv:
        msg += f"; ATE RMSE {1000 * tv['ate_m']['rmse']:.1f} mm"
    mv = p.get("mesh_vs_gt")
    if isinstance(mv, dict) and "accuracy_m" in mv:
        msg += (f"; mesh accuracy median {1000 * mv['accuracy_m']['median']:.1f} mm, 90th "
                f"percentile {1000 * mv['accuracy_m']['p90']:.1f} mm")
    print(msg)
    t = s["timings_s"]
    print(f"wall time {t['total_s']:.0f} s (dive {t['simulate_s']:.0f} s, processing "
          f"{t['process_s']:.0f} s, {t['compile_s']:.1f} s one-off kernel compilation)")
    files = s.get("files", {})
    results = [Path(f) for k, f in files.items() if not k.startswith("demo_")]
    where = results[0].parent if results else result.out_dir
    print(f"wrote {result.report_html} and {result.out_dir / 'summary.json'}; the dive's "
          f"results in {where}/: {', '.join(p.name for p in results)}")
    print(f"report: {result.report_html}")
    return 0
