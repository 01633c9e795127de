"""``sea3d demo``: the end-to-end demo on the simulator's default scene."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sea3d.cli._args import image_size


def register(sub: Any) -> None:
    """Add ``sea3d demo``."""
    p = sub.add_parser(
        "demo",
        help="simulate an underwater pair, compute refraction-corrected depth, write a report",
    )
    p.add_argument(
        "--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)"
    )
    p.add_argument(
        "--scene", default="lake", help="lake, tank, reef or a scene YAML file (default lake)"
    )
    p.add_argument(
        "--water",
        default="coastal",
        choices=["none", "clear", "coastal", "turbid"],
        help="water between the cameras and the scene; none = clean images (default coastal)",
    )
    p.add_argument(
        "--port",
        default="dome",
        choices=["dome", "flat", "none"],
        help="camera housings of the paper's rig: dome or flat ports, or none (default dome)",
    )
    p.add_argument(
        "--engine",
        default="sea3d",
        choices=["sea3d", "sea3d-gpu", "opencv"],
        help="stereo matcher: sea3d's own (CPU), its GPU version, or OpenCV's SGBM "
        "(default sea3d)",
    )
    p.add_argument(
        "--size",
        type=image_size,
        default=(1920, 1080),
        metavar="WxH",
        help="image size to simulate and process (default 1920x1080; 960x540 is quicker)",
    )
    p.add_argument(
        "--max-disparity",
        type=int,
        default=256,
        metavar="PX",
        help="disparity search range in pixels at 1920 px width, scaled with --size "
        "(default 256)",
    )
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from sea3d.pipeline.demo import DemoConfig, run_demo

    config = DemoConfig(
        out_dir=args.out,
        scene=args.scene,
        water=args.water,
        port=args.port,
        engine=args.engine,
        size_px=args.size,
        max_disparity_px=args.max_disparity,
        seed=args.seed,
    )
    quiet = args.json

    def progress(msg: str) -> None:
        if not quiet:
            print(f"[demo] {msg}", file=sys.stderr, flush=True)

    result = run_demo(config, progress)
    s = result.summary
    if args.json:
        json.dump(s, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    ours, base = s["refraction_corrected"], s["pinhole_in_water_baseline"]
    print(f"valid depth on {100 * s['valid_fraction']:.1f} % of pixels, {s['points']} points")
    line = (
        f"median depth error: {100 * ours['median_rel']:.2f} % refraction-corrected, "
        f"{100 * base['median_rel']:.2f} % pinhole-in-water baseline"
    )
    ignored = s.get("ports_ignored_baseline")
    if ignored is not None:
        line += f", {100 * ignored['median_rel']:.2f} % with the ports ignored"
    print(line)
    print(f"report: {result.report_html}")
    return 0
