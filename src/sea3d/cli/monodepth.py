"""``sea3d mono-depth``: a user's ONNX monocular depth network, made metric.

``sea3d mono-depth IMAGE --model net.onnx -o depth.png --rig rig.yaml --right RIGHT`` runs the
network on the rectified left view, aligns it to our stereo depth of the pair and fills stereo's
holes; ``--align-depth METRIC`` aligns to a given depth map with holes, ``--align-sfm MODEL``
to the points of a COLMAP model. A SESSION is processed frame by frame (stereo from its rig).
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import add_depth_range, config_option

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands
    from sea3d.geometry.rig import StereoRig
    from sea3d.stereo.recipe import StereoDepth

__all__ = ["register"]

_FLOAT_SUFFIXES = (".npy", ".pfm", ".tif", ".tiff")


def register(sub: Subcommands) -> None:
    """Add ``mono-depth`` to the top-level parser."""
    p = sub.add_parser(
        "mono-depth",
        help="monocular depth from an ONNX network, aligned to metric stereo/sparse depth",
        description="Run a user-supplied ONNX depth network (onnxruntime; nothing is "
        "downloaded, see docs/monodepth.md to export Depth-Anything-V2-Small) and align its "
        "output robustly (scale and shift, in inverse depth by default) to sparse metric "
        "depth: our stereo depth of the same pair (then stereo's holes are filled), a depth "
        "map with holes, or SfM points.",
    )
    p.add_argument("input", metavar="IMAGE|SESSION", help="an image file or a session")
    p.add_argument("--model", required=True, metavar="MODEL.onnx", help="the ONNX network")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="image: output file (.png uint16 mm, .npy/.pfm/.tiff float32 m); "
                        "session: output folder (OUT/depth/<t_ns>.png)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--align-depth", metavar="METRIC",
                     help="metric depth map with holes (.png mm, .npy/.pfm/.tiff metres)")
    src.add_argument("--align-sfm", metavar="SPARSE_DIR",
                     help="COLMAP model (e.g. OUT/sparse of sea3d sfm) whose points align it")
    p.add_argument("--rig", metavar="RIG", help="rig file (stereo alignment; sessions: default "
                   "the session's rig)")
    p.add_argument("--right", metavar="RIGHT", help="the right image of the pair (with --rig)")
    from sea3d.monodepth.model import MonoDepthConfig

    opt = partial(config_option, p, MonoDepthConfig)
    opt("output_kind", choices=["inverse", "depth", "metric"])
    opt("normalize", choices=["imagenet", "unit"])
    opt("device", choices=["cpu", "cuda", "auto"])
    add_depth_range(p, near="stereo: nearest depth", far="stereo: farthest depth")
    from sea3d.stereo.recipe import DepthConfig

    config_option(p, DepthConfig, "engine", choices=["sea3d", "opencv", "sea3d-gpu"],
                  help="stereo matching engine")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_cmd_mono_depth)


def _read_rgb(path: Path) -> Any:
    from sea3d.errors import MonoDepthError
    from sea3d.io.image_files import read_image_rgb

    if not path.is_file():
        raise MonoDepthError(f"{path}: image not found")
    img = read_image_rgb(path)
    if img is None:
        raise MonoDepthError(f"{path}: cannot read the image")
    return img


def _stereo(rig: StereoRig, args: argparse.Namespace) -> StereoDepth:
    """The stereo depth of ``rig`` with the command's depth flags."""
    from sea3d.cli._args import depth_config
    from sea3d.errors import MonoDepthError
    from sea3d.stereo.recipe import StereoDepth

    lo, hi = args.min_depth, args.max_depth
    if lo is not None and hi is not None and not 0 < lo < hi:
        raise MonoDepthError(f"need 0 < --min-depth < --max-depth, got {lo} and {hi}")
    return StereoDepth(rig, depth_config(args))


def _relative_refused(path: Path) -> Any:
    from sea3d.errors import MonoDepthError

    return MonoDepthError(
        f"{path}: the network's output is relative (not metric) without alignment and "
        "cannot be stored as millimetres; align it (--rig/--right, --align-depth, "
        "--align-sfm) or write .npy/.pfm/.tiff"
    )


def _check_output(path: Path, args: argparse.Namespace) -> None:
    """Refuse an image's output that no writer takes, or a PNG of depth that stays relative."""
    from sea3d.cli._args import check_output_suffix
    from sea3d.io.depth_files import DEPTH_SUFFIXES

    check_output_suffix(path, "-o/--output", DEPTH_SUFFIXES, "depth")
    aligned = bool(args.right or args.rig or args.align_depth or args.align_sfm)
    if not aligned and args.output_kind != "metric" and \
            path.suffix.lower() not in _FLOAT_SUFFIXES:
        raise _relative_refused(path)


def _write(path: Path, depth: Any, metric: bool) -> None:
    from sea3d.io.depth_files import write_depth

    if not metric and path.suffix.lower() not in _FLOAT_SUFFIXES:
        raise _relative_refused(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_depth(path, depth)


def _cmd_mono_depth(args: argparse.Namespace) -> int:
    from sea3d.errors import MonoDepthError
    from sea3d.io.rig_file import load_rig
    from sea3d.io.session import is_session
    from sea3d.monodepth import MonoDepthConfig, OnnxDepthModel
    from sea3d.monodepth.metric import predict_metric
    from sea3d.pipeline.monodepth_session import sfm_sparse_depth, stereo_sparse_depth

    src = Path(args.input)
    out = Path(args.output)
    session = src.exists() and is_session(src)
    if not session:  # the output is checked before the network loads and runs
        _check_output(out, args)
    model = OnnxDepthModel(args.model, MonoDepthConfig(output_kind=args.output_kind,
                                                       normalize=args.normalize,
                                                       device=args.device))
    if session:
        return _session(args, model, src, out)
    left = _read_rgb(src)
    sparse, fill, frame = None, False, "left"
    view = left
    if args.right or (args.rig and not args.align_depth):
        if not (args.right and args.rig):
            raise MonoDepthError("stereo alignment needs both --rig and --right")
        if args.align_depth or args.align_sfm:
            raise MonoDepthError("give one alignment source: --rig/--right, --align-depth or "
                                 "--align-sfm")
        sparse, view = stereo_sparse_depth(_stereo(load_rig(args.rig), args), left,
                                           _read_rgb(Path(args.right)), str(src))
        fill, frame = True, "rect_left"
    elif args.align_depth:
        from sea3d.monodepth.align import read_alignment_depth

        # its grid sidecar decides: rectified depth is resampled with --rig or refused
        sparse = read_alignment_depth(Path(args.align_depth), left.shape[1], left.shape[0],
                                      rig=load_rig(args.rig) if args.rig else None)
        fill = True
    elif args.align_sfm:
        sparse = sfm_sparse_depth(Path(args.align_sfm), src.name, left.shape[1], left.shape[0])
    got = predict_metric(model, view, sparse, kind=args.output_kind, fill=fill)
    depth, info = got.depth, got.info
    if info.get("alignment") and info["alignment"]["status"] != "ok":
        raise MonoDepthError(f"{src}: {info['alignment']['message']}")
    metric = sparse is not None or args.output_kind == "metric"
    _write(out, depth, metric)
    summary = {"input": str(src), "model": str(args.model), "output": str(out),
               "output_kind": args.output_kind, "metric": metric, "frame": frame,
               "providers": model.providers, **info}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        al = info.get("alignment")
        print(f"{out}: {'metric' if metric else 'relative'} depth in the {frame} view"
              + (f"; {al['message']}" if al else ""))
    return 0


def _session(args: argparse.Namespace, model: Any, src: Path, out: Path) -> int:
    from sea3d.cli._progress import bar
    from sea3d.errors import MonoDepthError
    from sea3d.io.depth_files import write_depth_png_mm
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.io.sfm_files import write_summary
    from sea3d.pipeline.monodepth_session import monodepth_session, sfm_sparse_depth

    if args.align_depth or args.right:
        raise MonoDepthError(f"{src}: for a session give no --align-depth/--right: its right "
                             "camera (stereo) or --align-sfm aligns each frame")
    with open_session(src) as reader:
        stereo = None
        if not args.align_sfm:
            if args.rig is None and not reader.rig_yaml:
                raise MonoDepthError(f"{src}: the session stores no rig; pass --rig or "
                                     "--align-sfm")
            if reader.stamps("right").size == 0:
                raise MonoDepthError(f"{src}: the session has no right camera images for "
                                     "stereo alignment; pass --align-sfm")
            stereo = _stereo(resolve_rig(args.rig, reader), args)
        (out / "depth").mkdir(parents=True, exist_ok=True)
        result = monodepth_session(
            reader, model, kind=args.output_kind, stereo=stereo,
            sfm_sparse=None if stereo is not None else partial(sfm_sparse_depth,
                                                               Path(args.align_sfm)),
            on_frame=lambda t_ns, depth: write_depth_png_mm(out / "depth" / f"{t_ns}.png",
                                                            depth),
            progress=lambda stage, total: bar(total, stage, enabled=not args.json),
            name=str(src))
    frames = result.frames
    summary = {
        "input": str(src), "model": str(args.model), "output": str(out),
        "output_kind": args.output_kind, "frames": len(frames), "aligned": result.aligned,
        "frame": result.frame, "median_rel_error": result.median_rel_error,
        "providers": model.providers, "per_frame": frames,
    }
    write_summary(out / "summary.json", summary)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{result.aligned}/{len(frames)} frames aligned -> {out}/depth/<t_ns>.png "
              f"(uint16 mm, 0 invalid), {out}/summary.json")
    return 0
