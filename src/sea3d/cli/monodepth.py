"""``sea3d mono-depth``: a user's ONNX monocular depth network, made metric.

``sea3d mono-depth IMAGE --model net.onnx -o depth.png --rig rig.yaml --right RIGHT`` runs the
network on the rectified left view, aligns it to our stereo depth of the pair and fills stereo's
holes; ``--align-depth METRIC`` aligns to a given depth map with holes, ``--align-sfm MODEL``
to the points of a COLMAP model. A SESSION is processed frame by frame (stereo from its rig).
"""

from __future__ import annotations

import argparse
import json
import time
from functools import partial
from pathlib import Path
from typing import Any

from sea3d.cli._args import add_depth_range, config_option

__all__ = ["register"]

_FLOAT_SUFFIXES = (".npy", ".pfm", ".tif", ".tiff")


def register(sub: Any) -> None:
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
    p.add_argument("--engine", default="sea3d", choices=["sea3d", "opencv", "sea3d-gpu"],
                   help="stereo matching engine")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(handler=_cmd_mono_depth)


def _read_rgb(path: Path) -> Any:
    import cv2

    from sea3d.errors import MonoDepthError

    if not path.is_file():
        raise MonoDepthError(f"{path}: image not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise MonoDepthError(f"{path}: cannot read the image")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img.ndim == 3 else img


def _read_metric(path: Path) -> Any:
    from sea3d.errors import MonoDepthError
    from sea3d.io.depth_files import read_depth_png_mm, read_disparity

    if not path.is_file():
        raise MonoDepthError(f"{path}: depth file not found")
    if path.suffix.lower() == ".png":
        return read_depth_png_mm(path)
    return read_disparity(path)  # float metres: non-positive and non-finite are holes


class _Stereo:
    """Stereo depth of pairs with one rig (rectification maps and matcher built once)."""

    def __init__(self, rig: Any, args: argparse.Namespace) -> None:
        from sea3d.cli._args import depth_config
        from sea3d.errors import MonoDepthError
        from sea3d.stereo.recipe import StereoDepth

        lo, hi = args.min_depth, args.max_depth
        if lo is not None and hi is not None and not 0 < lo < hi:
            raise MonoDepthError(f"need 0 < --min-depth < --max-depth, got {lo} and {hi}")
        self.rig = rig
        self.stereo = StereoDepth(rig, depth_config(args))

    def depth(self, left: Any, right: Any, where: str) -> tuple[Any, Any]:
        from sea3d.errors import MonoDepthError

        for name, img in (("left", left), ("right", right)):
            if img.shape[:2] != (self.rig.height, self.rig.width):
                raise MonoDepthError(f"{where}: {name} image is {img.shape[1]}x{img.shape[0]} "
                                     f"but the rig is {self.rig.width}x{self.rig.height}")
        res = self.stereo.compute(left, right)
        return res.depth_m, res.rect_left


def _sfm_sparse(model_dir: Path, image_name: str, width: int, height: int) -> Any:
    """Sparse depth of a COLMAP model's points in one of its images (matched by name)."""
    import numpy as np

    from sea3d.errors import MonoDepthError
    from sea3d.io.sfm_files import read_colmap_model
    from sea3d.monodepth import sparse_depth_from_points

    rec = read_colmap_model(model_dir)
    names = {im.name: im for im in rec.images.values()}
    stem = Path(image_name).stem
    cands = [image_name, Path(image_name).name, f"left/{stem}.png", f"{stem}.png"]
    im = next((names[c] for c in cands if c in names), None)
    if im is None:
        im = next((v for k, v in names.items() if Path(k).stem == stem), None)
    if im is None or not im.has_pose:
        raise MonoDepthError(f"{model_dir}: no registered image named like {image_name!r}")
    cam = rec.cameras[im.camera_id]
    if (cam.width, cam.height) != (width, height):
        raise MonoDepthError(f"{model_dir}: image {im.name} is {cam.width}x{cam.height} in the "
                             f"model but the input is {width}x{height}")
    T = np.eye(4)
    T[:3, :4] = np.asarray(im.cam_from_world().matrix())
    pts = np.array([rec.points3D[p.point3D_id].xyz for p in im.points2D if p.has_point3D()])
    if len(pts) == 0:
        raise MonoDepthError(f"{model_dir}: image {im.name} sees no 3D points")
    pc = pts @ T[:3, :3].T + T[:3, 3]
    uv = np.asarray(cam.img_from_cam(pc), dtype=np.float64) - 0.5  # COLMAP -> our pixels
    # nearest point per pixel, with the camera's own (possibly distorted) projection
    K = np.eye(3)
    pix = np.column_stack([uv, np.ones(len(uv))]) * pc[:, 2:3]
    return sparse_depth_from_points(pix, K, width, height)


def _one(model: Any, view: Any, sparse: Any, kind: str, fill: bool) -> tuple[Any, dict[str, Any]]:
    import numpy as np

    from sea3d.monodepth import align_depth, fill_holes

    pred, timings = model.predict(view)
    info: dict[str, Any] = {"timings_s": timings}
    if sparse is None:
        info["alignment"] = None
        return pred, info
    if sparse.shape != pred.shape:
        from sea3d.errors import MonoDepthError

        raise MonoDepthError(f"the sparse depth is {sparse.shape[1]}x{sparse.shape[0]} but the "
                             f"image is {pred.shape[1]}x{pred.shape[0]}")
    t0 = time.perf_counter()
    aligned, al = align_depth(pred, sparse, kind=kind)
    info["alignment"] = {"status": al.status, "message": al.message, "scale": al.scale,
                         "shift": al.shift, "samples": al.samples, "inliers": al.inliers,
                         "median_rel_error": al.median_rel_error}
    out = aligned
    valid_sparse = float(np.mean(np.isfinite(sparse)))
    if fill and al.status == "ok":
        out, filled = fill_holes(sparse, aligned)
        info["filled_fraction"] = float(filled.mean())
    info["sparse_fraction"] = valid_sparse
    info["valid_fraction"] = float(np.mean(np.isfinite(out)))
    timings["align_s"] = time.perf_counter() - t0
    return out, info


def _write(path: Path, depth: Any, metric: bool) -> None:
    from sea3d.errors import MonoDepthError
    from sea3d.io.depth_files import write_depth

    if not metric and path.suffix.lower() not in _FLOAT_SUFFIXES:
        raise MonoDepthError(
            f"{path}: the network's output is relative (not metric) without alignment and "
            "cannot be stored as millimetres; align it (--rig/--right, --align-depth, "
            "--align-sfm) or write .npy/.pfm/.tiff"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    write_depth(path, depth)


def _cmd_mono_depth(args: argparse.Namespace) -> int:
    from sea3d.errors import MonoDepthError
    from sea3d.io.rig_file import load_rig
    from sea3d.monodepth import MonoDepthConfig, OnnxDepthModel

    model = OnnxDepthModel(args.model, MonoDepthConfig(output_kind=args.output_kind,
                                                       normalize=args.normalize,
                                                       device=args.device))
    src = Path(args.input)
    out = Path(args.output)
    from sea3d.cli.sfm import _is_session

    if src.exists() and _is_session(src):
        return _session(args, model, src, out)
    left = _read_rgb(src)
    sparse, fill, frame = None, False, "left"
    view = left
    if args.right or args.rig:
        if not (args.right and args.rig):
            raise MonoDepthError("stereo alignment needs both --rig and --right")
        if args.align_depth or args.align_sfm:
            raise MonoDepthError("give one alignment source: --rig/--right, --align-depth or "
                                 "--align-sfm")
        stereo = _Stereo(load_rig(args.rig), args)
        sparse, view = stereo.depth(left, _read_rgb(Path(args.right)), str(src))
        fill, frame = True, "rect_left"
    elif args.align_depth:
        sparse = _read_metric(Path(args.align_depth))
        if sparse.shape != left.shape[:2]:
            raise MonoDepthError(f"{args.align_depth}: depth map is {sparse.shape[1]}x"
                                 f"{sparse.shape[0]} but {src} is {left.shape[1]}x"
                                 f"{left.shape[0]}")
        fill = True
    elif args.align_sfm:
        sparse = _sfm_sparse(Path(args.align_sfm), src.name, left.shape[1], left.shape[0])
    depth, info = _one(model, view, sparse, args.output_kind, fill)
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
    import numpy as np

    from sea3d.cli._progress import bar
    from sea3d.errors import MonoDepthError
    from sea3d.io.depth_files import write_depth_png_mm
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.io.sfm_files import write_summary

    if args.align_depth or args.right:
        raise MonoDepthError(f"{src}: for a session give no --align-depth/--right: its right "
                             "camera (stereo) or --align-sfm aligns each frame")
    frames: list[dict[str, Any]] = []
    with open_session(src) as reader:
        stereo = None
        if not args.align_sfm:
            if args.rig is None and not reader.rig_yaml:
                raise MonoDepthError(f"{src}: the session stores no rig; pass --rig or "
                                     "--align-sfm")
            if reader.stamps("right").size == 0:
                raise MonoDepthError(f"{src}: the session has no right camera images for "
                                     "stereo alignment; pass --align-sfm")
            stereo = _Stereo(resolve_rig(args.rig, reader), args)
        (out / "depth").mkdir(parents=True, exist_ok=True)
        match = reader.match_pairs() if stereo is not None else None
        stamps = reader.stamps("left")
        todo = (list(zip(match.left_index, match.right_index, strict=True)) if match is not None
                else [(i, None) for i in range(stamps.size)])
        for li, ri in bar(len(todo), "mono-depth", enabled=not args.json, iterable=todo):
            t_ns = int(stamps[li])
            left = reader.image("left", int(li), by="index")
            where = f"{src} t_ns={t_ns}"
            if stereo is not None:
                sparse, view = stereo.depth(left, reader.image("right", int(ri), by="index"),
                                            where)
            else:
                sparse = _sfm_sparse(Path(args.align_sfm), f"left/{t_ns}.png", left.shape[1],
                                     left.shape[0])
                view = left
            depth, info = _one(model, view, sparse, args.output_kind, stereo is not None)
            al = info["alignment"]
            if al["status"] == "ok":
                write_depth_png_mm(out / "depth" / f"{t_ns}.png", depth)
            frames.append({"t_ns": t_ns, **info})
    ok = [f for f in frames if f["alignment"]["status"] == "ok"]
    summary = {
        "input": str(src), "model": str(args.model), "output": str(out),
        "output_kind": args.output_kind, "frames": len(frames), "aligned": len(ok),
        "frame": "rect_left" if stereo is not None else "left",
        "median_rel_error": float(np.median([f["alignment"]["median_rel_error"] for f in ok]))
        if ok else None, "providers": model.providers, "per_frame": frames,
    }
    write_summary(out / "summary.json", summary)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{len(ok)}/{len(frames)} frames aligned -> {out}/depth/<t_ns>.png (uint16 mm, 0 "
              f"invalid), {out}/summary.json")
    return 0
