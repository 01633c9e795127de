"""``sea3d stereo``, ``sea3d eval disparity`` and ``sea3d depth``.

``stereo`` matches an already rectified pair; ``eval disparity`` scores a disparity map against
Middlebury-style ground truth; ``depth`` rectifies a raw pair with a rig file and writes metric
depth (and optionally a point cloud).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import (
    add_depth_range,
    check_output_suffix,
    config_option,
    depth_config,
    plural,
    positive_float,
)

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register"]

_ENGINES = ("sea3d", "sea3d-gpu", "opencv", "opencv-hh", "opencv-3way")


def _positive_int(text: str) -> int:
    """argparse type: an integer > 0 (so bad values fail before any work)."""
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from err
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {value}")
    return value


def _check_range(max_disparity: int, width: int, engine: str, what: str) -> None:
    """Refuse a ``--max-disparity`` the engine cannot search in an image ``width`` wide."""
    from sea3d.errors import StereoError

    opencv = engine.startswith("opencv")
    n = max_disparity + 1
    if opencv:
        n = -(-n // 16) * 16  # OpenCV searches whole multiples of 16
    if n >= width if opencv else n > width:
        top = (width - 1) // 16 * 16 - 1 if opencv else width - 1
        note = f"; OpenCV rounds the range up to {n} disparities" if opencv else ""
        raise StereoError(
            f"--max-disparity {max_disparity} is too wide for {what} ({width} px wide{note}): "
            f"use at most {top}"
        )


def _read_image(path: str) -> Any:
    from sea3d.errors import SessionError, StereoError
    from sea3d.io.session.common import read_image_file

    p = Path(path)
    if not p.is_file():
        raise StereoError(f"image not found: {p}")
    try:  # refuses cut files (cv2.imread returns a cut JPEG half grey)
        return read_image_file(p)
    except SessionError as err:
        raise StereoError(str(err)) from err


def _engine_config(args: argparse.Namespace) -> Any:
    from sea3d.stereo import make_config

    overrides: dict[str, Any] = {}
    if args.engine == "sea3d" and getattr(args, "paths", None):
        overrides["paths"] = args.paths
    if args.engine == "sea3d" and getattr(args, "no_fill", False):
        overrides["fill_max_px"] = 0
    return make_config(args.engine, args.max_disparity, **overrides)


def _warm_up(engine: str) -> float:
    if engine == "sea3d":
        from sea3d.stereo.sgm import warm_up

        return warm_up()
    return 0.0


def _check_depth_range(args: argparse.Namespace) -> None:
    from sea3d.errors import StereoError

    if args.min_depth is not None and args.max_depth is not None and \
            not args.min_depth < args.max_depth:
        raise StereoError(
            f"need 0 < --min-depth < --max-depth, got {args.min_depth} and {args.max_depth}"
        )


def _cmd_stereo(args: argparse.Namespace) -> int:
    from sea3d.io.depth_files import DISPARITY_SUFFIXES, write_disparity
    from sea3d.stereo import match
    from sea3d.stereo.filters import FilterChain, parse_filter_chain

    check_output_suffix(args.output, "-o/--output", DISPARITY_SUFFIXES, "disparity")
    if args.confidence:
        check_output_suffix(args.confidence, "--confidence", DISPARITY_SUFFIXES, "confidence")
    config = _engine_config(args)
    chain = FilterChain(parse_filter_chain(args.filters)) if args.filters else None
    left = _read_image(args.left)
    right = _read_image(args.right)
    _check_range(args.max_disparity, int(left.shape[1]), args.engine, args.left)
    compile_s = _warm_up(args.engine)
    result = match(left, right, config)
    disp = result.disparity_px
    filter_s = 0.0
    if chain is not None:
        t0 = time.perf_counter()
        disp = chain.apply(disp, image=left, confidence=result.confidence)
        filter_s = time.perf_counter() - t0
    write_disparity(args.output, disp)
    import numpy as np

    if args.confidence:
        conf = np.where(np.isfinite(disp), result.confidence, np.float32(0.0))
        write_disparity(args.confidence, conf.astype(np.float32))
    valid_fraction = float(np.isfinite(disp).mean())
    measured_fraction = float(result.measured.mean())
    if args.json:
        out = {
            "engine": result.engine,
            "match_s": result.timings_s["match_s"],
            "filter_s": filter_s,
            "compile_s": compile_s,
            "valid_fraction": valid_fraction,
            "measured_fraction": measured_fraction,
            "confidence": str(args.confidence) if args.confidence else None,
            "width": int(disp.shape[1]),
            "height": int(disp.shape[0]),
            "max_disparity_px": args.max_disparity,
            "timings_s": result.timings_s,
            "output": str(args.output),
        }
        print(json.dumps(out, indent=2))
    else:
        print(
            f"{args.output}: {disp.shape[1]}x{disp.shape[0]}, {100 * valid_fraction:.1f} % valid "
            f"({100 * measured_fraction:.1f} % matched, the rest filled), "
            f"matched in {result.timings_s['match_s']:.3f} s ({result.engine})"
        )
    return 0


def _cmd_eval_disparity(args: argparse.Namespace) -> int:
    from sea3d.errors import StereoError
    from sea3d.eval import disparity_metrics
    from sea3d.io.depth_files import read_disparity

    est = read_disparity(args.estimate, scale=args.est_scale)
    gt = read_disparity(args.ground_truth, scale=args.scale)
    if est.shape != gt.shape:
        raise StereoError(
            f"{args.estimate} is {est.shape[1]}x{est.shape[0]} but {args.ground_truth} is "
            f"{gt.shape[1]}x{gt.shape[0]}"
        )
    m = disparity_metrics(est, gt)
    if args.json:
        print(json.dumps(m.as_dict(), indent=2))
    else:
        print(
            f"bad-0.5 {m.bad_0_5:6.2f} %  bad-1 {m.bad_1:6.2f} %  bad-2 {m.bad_2:6.2f} %  "
            f"bad-4 {m.bad_4:6.2f} %  EPE {m.epe_px:.3f} px  density {m.density:6.2f} %"
        )
    return 0


def _cmd_depth_session(args: argparse.Namespace) -> int:
    """Depth for every stereo pair of a session, with a progress bar."""
    from pathlib import Path

    from sea3d.cli._progress import bar as progress_bar
    from sea3d.io.depth_files import write_depth_grid, write_depth_png_mm, write_ply
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.pipeline.depth_pair import rectified_grid
    from sea3d.pipeline.depth_session import depth_session
    from sea3d.stereo.recipe import StereoDepth

    _check_depth_range(args)
    config = depth_config(args)
    out = Path(args.output)
    with open_session(args.session) as session:
        rig = resolve_rig(args.rig, session)
        if len(session.match_pairs().left_index) == 0:
            from sea3d.errors import StereoError

            raise StereoError(f"{args.session}: no stereo pairs to process")
        if args.max_disparity is not None:
            _check_range(args.max_disparity, rig.width, args.engine, "the rig's images")
        stereo = StereoDepth(rig, config)
        (out / "depth").mkdir(parents=True, exist_ok=True)
        grid = rectified_grid(stereo.maps, rig)
        if args.points:
            (out / "cloud").mkdir(parents=True, exist_ok=True)

        def save(t_ns: int, res: Any) -> None:
            write_depth_png_mm(out / "depth" / f"{t_ns}.png", res.depth_m)
            write_depth_grid(out / "depth" / f"{t_ns}.png", grid)
            if args.points:
                write_ply(out / "cloud" / f"{t_ns}.ply", res.points_left, res.colors_rgb)

        result = depth_session(
            session, stereo, on_pair=save, name=str(args.session),
            progress=lambda stage, total: progress_bar(total, stage, unit="pair",
                                                       enabled=not args.json))
    done = result.pairs
    summary = {
        "session": str(args.session),
        "output": str(out),
        "pairs": done,
        "unpaired_left": result.unpaired_left,
        "unpaired_right": result.unpaired_right,
        "mean_valid_fraction": result.mean_valid_fraction,
        "refractive": result.refractive,
        "max_disparity_px": result.max_disparity_px,
        "depth_range_m": list(result.depth_range_m),
        "engine": args.engine,
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{plural(done, 'pair')} -> {out}/depth/<t_ns>.png (uint16 mm, 0 invalid)"
            + (f" and {out}/cloud/<t_ns>.ply" if args.points else "")
            + f"; {result.unpaired_left} left and "
            f"{plural(result.unpaired_right, 'right frame')} "
            "unpaired"
        )
    return 0


def _cmd_depth(args: argparse.Namespace) -> int:

    if args.session is not None:
        if args.left or args.right:
            from sea3d.errors import StereoError

            raise StereoError("give either --session or --left/--right, not both")
        return _cmd_depth_session(args)
    if not (args.left and args.right and args.rig):
        from sea3d.errors import StereoError

        raise StereoError("sea3d depth needs --rig with --left and --right, or --session")
    if args.points is True:
        from sea3d.errors import StereoError

        raise StereoError("--points needs a file name (cloud.ply) for a single pair")

    from sea3d.io.depth_files import DEPTH_SUFFIXES, write_depth, write_ply

    check_output_suffix(args.output, "-o/--output", DEPTH_SUFFIXES, "depth")
    if args.points:
        check_output_suffix(args.points, "--points", (".ply",), "a point cloud")
    from sea3d.io.rig_file import load_rig
    from sea3d.pipeline.depth_pair import depth_pair

    _check_depth_range(args)
    config = depth_config(args)
    rig = load_rig(args.rig)
    if args.max_disparity is not None:
        _check_range(args.max_disparity, rig.width, args.engine, f"the rig {args.rig}")
    left = _read_image(args.left)
    right = _read_image(args.right)
    pair = depth_pair(rig, left, right, config, grid=args.grid,
                      names=(args.left, args.right, args.rig))
    res = pair.result
    write_depth(args.output, pair.depth_m, pair.grid)
    if args.points:
        write_ply(args.points, res.points_left, res.colors_rgb)
    summary = {"output": str(args.output), "points": str(args.points) if args.points else None,
               **pair.summary, "engine": args.engine}
    valid_fraction = summary["valid_fraction"]
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{args.output}: {100 * valid_fraction:.1f} % valid, median depth "
            f"{summary['median_depth_m'] or float('nan'):.3f} m"
            + (f", {plural(len(res.points_left), 'point')} -> {args.points}"
               if args.points else "")
            + (" (refraction-corrected)" if summary["refractive"] else "")
        )
    return 0


def register(sub: Subcommands) -> None:
    """Add ``stereo`` and ``depth`` to the top-level parser."""
    p = sub.add_parser(
        "stereo",
        help="match a rectified stereo pair into a disparity map",
        description="Match a rectified pair (u_right = u_left - d) into float32 disparity "
        "in pixels, NaN invalid.",
    )
    p.add_argument("left", help="left image (rectified)")
    p.add_argument("right", help="right image (rectified)")
    p.add_argument(
        "--max-disparity",
        type=_positive_int,
        required=True,
        metavar="N",
        help="largest disparity searched, pixels (range 0..N)",
    )
    p.add_argument("-o", "--output", required=True, help="output disparity: .pfm, .npy or .tiff")
    from sea3d.stereo.recipe import DepthConfig

    config_option(p, DepthConfig, "engine", choices=_ENGINES, help="matching engine")
    p.add_argument("--paths", type=int, choices=(8, 16), help="sea3d engine: aggregation paths")
    p.add_argument(
        "--filters", default="", help='post-filter chain, e.g. "median:size_px=3,speckle,wls"'
    )
    p.add_argument(
        "--confidence",
        metavar="PATH",
        help="also write the confidence map (.pfm, .npy or .tiff; 0 = filled or invalid)",
    )
    p.add_argument(
        "--no-fill",
        action="store_true",
        help="sea3d engine: leave unmatched pixels NaN (default: dense, filled from the "
        "background neighbour, with confidence 0)",
    )
    p.add_argument("--json", action="store_true", help="print timings and figures as JSON")
    p.set_defaults(handler=_cmd_stereo)


    d = sub.add_parser(
        "depth",
        help="metric depth (and a point cloud) from a raw pair and a rig file",
        description="Rectify a raw pair with rig.yaml, match, and write float32 depth in metres "
        "(.tiff/.npy/.pfm) or a 16-bit millimetre PNG (0 invalid).",
    )
    d.add_argument("--rig", help="rig.yaml (with --session: default the session's stored rig)")
    d.add_argument("--left", help="raw left image")
    d.add_argument("--right", help="raw right image")
    d.add_argument(
        "--session",
        help="a recorded session (MCAP or folder): depth for every pair into -o FOLDER/depth/, "
        "with --points also FOLDER/cloud/",
    )
    d.add_argument(
        "-o",
        "--output",
        required=True,
        help="depth output: .png (uint16 mm, 0 invalid), .tiff, .npy or .pfm (m); with "
        "--session an output folder",
    )
    d.add_argument(
        "--points",
        nargs="?",
        const=True,
        help="also write a coloured point cloud (.ply), left camera frame (with --session: a "
        "flag, one PLY per pair)",
    )
    from sea3d.stereo.recipe import DepthConfig

    config_option(d, DepthConfig, "engine", choices=_ENGINES, help="matching engine")
    d.add_argument(
        "--grid", choices=("rectified", "raw"), default="rectified",
        help="pixel grid of the depth file (one pair): rectified left view (default, as "
        "matched) or raw left view (the camera's own pixels, e.g. for enhance --depth); a "
        "FILE.grid.json sidecar says which",
    )
    d.add_argument(
        "--max-disparity",
        type=_positive_int,
        default=None,
        metavar="N",
        help="largest disparity searched (default: from --min-depth, else an eighth of the "
        "image width)",
    )
    add_depth_range(d, far="farthest depth kept (refractive rectification range too)")
    config_option(d, DepthConfig, "min_confidence", type=float, metavar="C",
                  help="drop matches below this confidence (0..1) from depth and points "
                  "(the default drops only the filled, unmatched pixels)")
    d.add_argument("--json", action="store_true", help="print timings and figures as JSON")
    d.set_defaults(handler=_cmd_depth)


def register_eval(esub: Subcommands) -> None:
    """Add ``eval disparity`` to the ``eval`` command's subparsers."""
    ed = esub.add_parser(
        "disparity",
        help="bad-pixel rates, EPE and density against ground-truth disparity",
        description="Compare EST with GT (PFM, NPY, TIFF, or scaled PNG/PGM; 0 or NaN unknown).",
    )
    ed.add_argument("estimate", metavar="EST", help="estimated disparity (.pfm .npy .tiff .png)")
    ed.add_argument("ground_truth", metavar="GT", help="ground-truth disparity")
    ed.add_argument(
        "--scale",
        type=positive_float,
        default=None,
        help="GT integer images store d * scale (Middlebury: 16, 8 or 4)",
    )
    ed.add_argument(
        "--est-scale",
        type=positive_float,
        default=None,
        help="the same for an integer estimate image",
    )
    ed.add_argument("--json", action="store_true", help="print the figures as JSON")
    ed.set_defaults(handler=_cmd_eval_disparity)
