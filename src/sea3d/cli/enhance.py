"""``sea3d enhance`` (one image, or a whole session) and ``sea3d eval enhance``.

    sea3d enhance dive.png -o dive_restored.png --method seathru --depth depth.tiff --rig rig.yaml
    sea3d enhance dive.png -o dive_grey.png --method grey-world
    sea3d enhance --session dive.mcap -o dive_seathru.mcap --method seathru
    sea3d eval enhance restored.png reference.png --json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sea3d.cli._args import add_depth_range, config_option, param_option
from sea3d.enhance.registry import METHODS

__all__ = ["register", "register_eval"]



def _read_image(path: str | Path) -> Any:
    from sea3d.errors import EnhanceError
    from sea3d.io.image_files import read_image_rgb

    p = Path(path)
    if not p.is_file():
        raise EnhanceError(f"image not found: {p}")
    img = read_image_rgb(p)
    if img is None:
        raise EnhanceError(f"cannot read image {p}")
    return img


def _write_image(path: str | Path, img: Any) -> None:
    from sea3d.errors import EnhanceError
    from sea3d.io.image_files import write_image_rgb

    write_image_rgb(path, img, EnhanceError)


def _seathru_config(args: argparse.Namespace) -> Any:
    """The Sea-thru settings of the flags (the water model by default)."""
    from sea3d.enhance.config import SeathruConfig

    return SeathruConfig(
        holes=args.holes,
        backscatter=not args.no_backscatter,
        attenuation=args.attenuation,
        white_balance="none" if args.no_white_balance else "grey-world",
    )


def _cmd_enhance(args: argparse.Namespace) -> int:
    from sea3d.errors import EnhanceError

    if args.session is not None:
        if args.input is not None:
            raise EnhanceError("give either an input image or --session, not both")
        return _cmd_enhance_session(args)
    if args.input is None:
        raise EnhanceError("sea3d enhance needs an input image (or --session SESSION)")
    from sea3d.cli._args import check_output_suffix
    from sea3d.enhance.api import enhance_image
    from sea3d.io.image_files import IMAGE_SUFFIXES

    check_output_suffix(args.output, "-o/--output", IMAGE_SUFFIXES, "an image")
    params: dict[str, Any] = {}
    if args.method == "clahe":
        params["clip_limit"] = _clip_limit(args)

    image = _read_image(args.input)
    range_m = None
    if args.method == "seathru":
        from sea3d.pipeline.enhance_image import range_for_image

        if args.depth is None:
            raise EnhanceError(
                "--method seathru needs --depth DEPTH (float32 m .npy/.tiff or 16-bit mm PNG)"
            )
        range_m = range_for_image(args.depth, image.shape[:2], image_name=str(args.input),
                                  rig_path=args.rig, is_range=args.range,
                                  focal_px=args.focal_px,
                                  depth_range_m=(args.min_depth, args.max_depth))
    out = enhance_image(
        image,
        args.method,
        range_m=range_m,
        seathru_config=_seathru_config(args) if args.method == "seathru" else None,
        **params,
    )
    _write_image(args.output, out.images[0])
    summary: dict[str, Any] = {
        "input": str(args.input),
        "output": str(args.output),
        "method": args.method,
        "status": out.status,
        "notes": list(out.notes),
    }
    if out.model is not None:
        summary["seathru_model"] = out.model.as_dict()
    if out.water_model is not None:
        summary["water_model"] = out.water_model.as_dict()
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        extra = f" ({out.status}: {'; '.join(out.notes)})" if out.status != "ok" else ""
        print(f"{args.output}: {args.method}{extra}")
    return 0


def _clip_limit(args: argparse.Namespace) -> float:
    """``--clip-limit``, refused unless > 0 (every image would be kept unchanged)."""
    from sea3d.errors import EnhanceError

    if not args.clip_limit > 0 or args.clip_limit == float("inf"):
        raise EnhanceError(f"--clip-limit must be > 0 and finite, got {args.clip_limit:g}")
    return float(args.clip_limit)


def _cmd_enhance_session(args: argparse.Namespace) -> int:
    from sea3d.cli._args import check_session_output, depth_config
    from sea3d.cli._progress import bar as progress_bar
    from sea3d.cli._progress import once_per_message
    from sea3d.errors import EnhanceError
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import SessionWriter, layout_of, open_session
    from sea3d.pipeline.enhance_session import SessionEnhancement
    from sea3d.stereo.recipe import StereoDepth

    out_path = Path(args.output)
    # before the session is opened and the method set up (Sea-thru builds its stereo depth)
    check_session_output(out_path, "-o/--output", args.format)
    params: dict[str, Any] = {}
    if args.method == "clahe":
        params["clip_limit"] = _clip_limit(args)
    with open_session(args.session) as session:
        stereo = cfg = None
        if args.method == "seathru":
            if args.rig is None and not session.rig_yaml:
                raise EnhanceError(
                    f"{args.session} stores no rig; Sea-thru needs stereo depth: pass --rig"
                )
            stereo = StereoDepth(resolve_rig(args.rig, session), depth_config(args))
            cfg = _seathru_config(args)
        job = SessionEnhancement(session, args.method, stereo=stereo, seathru_config=cfg,
                                 params=params, name=str(args.session))
        imu = session.imu()
        sonar = session.sonar()
        with SessionWriter(
            out_path, format=args.format or layout_of(out_path), rig_yaml=session.rig_yaml
        ) as writer, once_per_message("sea3d.enhance", "pair"):
            for k in range(len(imu)):
                writer.write_imu(int(imu.t_ns[k]), imu.accel_mps2[k], imu.gyro_radps[k])
            for k in range(len(sonar)):
                writer.write_sonar(int(sonar.t_ns[k]), float(sonar.range_m[k]),
                                   float(sonar.confidence[k]))

            def save(pair: Any, left: Any, right: Any, status: str) -> None:
                writer.write_image("left", pair.t_ns, left)
                writer.write_image("right", pair.right_t_ns or pair.t_ns, right)

            result = job.run(save, progress=lambda stage, total: progress_bar(
                total, stage, unit="pair", enabled=not args.json))
    statuses = result.status_counts
    summary = {
        "session": str(args.session),
        "output": str(out_path),
        "method": args.method,
        "pairs": sum(statuses.values()),
        "status_counts": statuses,
        "imu": len(imu),
        "sonar": len(sonar),
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{summary['pairs']} pairs -> {out_path} ({args.method}; "
            + ", ".join(f"{k}: {v}" for k, v in sorted(statuses.items()))
            + f"); IMU {len(imu)} and echosounder {len(sonar)} samples copied"
        )
    return 0


def register(sub: Any) -> None:
    """Add ``enhance`` to the top-level parser."""
    p = sub.add_parser(
        "enhance",
        help="underwater colour restoration, white balance, CLAHE, dehazing",
        description="Enhance one image (IN -o OUT) or every stereo pair of a session "
        "(--session SESSION -o OUT_SESSION, a new session with the same rig, IMU and "
        "echosounder). Sea-thru uses metric depth: --depth for one image (float32 m "
        ".npy/.tiff with NaN invalid, or a 16-bit millimetre PNG, in the image's pixel grid), "
        "our stereo depth for a session.",
    )
    p.add_argument("input", nargs="?", help="input image")
    p.add_argument("-o", "--output", required=True, help="output image, or output session")
    p.add_argument("--method", choices=METHODS, default="seathru", help="method (default seathru)")
    p.add_argument("--depth", help="depth map of the input image (seathru)")
    p.add_argument(
        "--range", action="store_true", help="--depth already holds range along the line of sight"
    )
    p.add_argument(
        "--rig", type=Path, help="rig file: intrinsics for depth -> range (and a session's rig)"
    )
    p.add_argument(
        "--focal-px", type=float, help="pinhole focal length for depth -> range (centred)"
    )
    from sea3d.enhance.config import ATTENUATIONS, SeathruConfig
    from sea3d.stereo.recipe import DepthConfig

    config_option(p, SeathruConfig, "holes", choices=("inpaint", "mask"),
                  help="pixels without depth: restore with inpainted range, or only "
                  "white-balance them")
    p.add_argument(
        "--attenuation", choices=ATTENUATIONS,
        default="water-model",
        help="Sea-thru: water-model (default: one water model fitted to the image, or once to "
        "a session's pairs, then inverted) or a per-image Sea-thru attenuation stage (fit: "
        "the paper's beta_D(z))",
    )
    p.add_argument("--no-backscatter", action="store_true", help="Sea-thru: skip backscatter")
    p.add_argument(
        "--no-white-balance", action="store_true", help="Sea-thru: skip the final grey world"
    )
    from sea3d.enhance.contrast import clahe

    param_option(p, clahe, "clip_limit", type=float, help="CLAHE clip limit")
    p.add_argument("--session", help="enhance every stereo pair of this session (MCAP or folder)")
    p.add_argument("--format", choices=("mcap", "folder"), help="output session layout")
    config_option(p, DepthConfig, "engine", choices=("sea3d", "opencv"),
                  help="session + seathru: stereo engine for the depth")
    add_depth_range(p, near="session + seathru: nearest depth",
                    far="session + seathru: farthest depth")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(handler=_cmd_enhance)


def _cmd_eval_enhance(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.enhance.metrics import colour_cast, compare_to_reference, uciqe, uiqm
    from sea3d.errors import EnhanceError

    img = _read_image(args.output_image)
    out: dict[str, Any] = {"image": str(args.output_image)}
    if args.reference is not None:
        ref = _read_image(args.reference)
        if ref.shape != img.shape:
            raise EnhanceError(
                f"{args.output_image} is {img.shape[1]}x{img.shape[0]} but {args.reference} is "
                f"{ref.shape[1]}x{ref.shape[0]} (or channels differ)"
            )
        mask = None
        if args.mask is not None:
            m = _read_image(args.mask)
            mask = (m if m.ndim == 2 else m[..., 0]) > 0
            if mask.shape != img.shape[:2]:
                raise EnhanceError(f"mask {args.mask} is not {img.shape[1]}x{img.shape[0]}")
        out["reference"] = str(args.reference)
        out.update(compare_to_reference(img, ref, mask).as_dict())
    if np.asarray(img).ndim == 3:
        out["uiqm"] = uiqm(img).as_dict()
        out["uciqe"] = uciqe(img).as_dict()
        out["colour_cast"] = colour_cast(img)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        if "psnr_db" in out:
            print(
                f"PSNR {out['psnr_db']:.2f} dB  SSIM {out['ssim']:.4f}  CIEDE2000 "
                f"{out['ciede2000']:.2f}  after gain {out['ciede2000_gain']:.2f} "
                f"(x{out['gain']:.3f})  after per-channel gains {out['ciede2000_diag']:.2f}"
            )
        if "uiqm" in out:
            print(
                f"UIQM {out['uiqm']['uiqm']:.3f}  UCIQE {out['uciqe']['uciqe']:.4f}  "
                f"colour cast {out['colour_cast']:.2f}"
            )
    return 0


def register_eval(esub: Any) -> None:
    """Add ``eval enhance`` to the ``eval`` command's subparsers."""
    e = esub.add_parser(
        "enhance",
        help="PSNR, SSIM, CIEDE2000 (also after an exposure gain), UIQM, UCIQE of an image",
        description="Compare an enhanced image with a reference (PSNR, SSIM with data range 1, "
        "mean CIEDE2000, CIEDE2000 after the best global exposure gain and after the best "
        "per-channel gains) and give its no-reference scores (UIQM, UCIQE, colour cast).",
    )
    e.add_argument("output_image", metavar="OUT", help="enhanced image")
    e.add_argument("reference", metavar="REFERENCE", nargs="?", help="reference image")
    e.add_argument("--mask", help="image whose non-zero pixels are the ones evaluated")
    e.add_argument("--json", action="store_true", help="print the figures as JSON")
    e.set_defaults(handler=_cmd_eval_enhance)
