"""``sea3d calibrate``: printable boards, stereo calibration (in air or in water), and refractive
port calibration."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d.cli import error_line
from sea3d.cli._args import add_port_options, config_option, param_option
from sea3d.errors import CalibrationError, ConfigError

if TYPE_CHECKING:
    from sea3d.calib.port import PortRigCalibration
    from sea3d.calib.stereo import StereoCalibration
    from sea3d.cli._args import Subcommands

log = logging.getLogger(__name__)


def register(sub: Subcommands) -> None:
    """Add ``sea3d calibrate ...``."""
    cal = sub.add_parser("calibrate", help="calibration boards, stereo and port calibration")
    csub = cal.add_subparsers(dest="calibrate_command", metavar="ACTION", required=True)

    board = csub.add_parser("board", help="write a printable board (PDF at true scale, or PNG)")
    board.add_argument("board", metavar="BOARD",
                       help="e.g. checkerboard:9x6:95mm, charuco:5x7:40mm:30mm:DICT_6X6_250, "
                            "apriltag:7x5:91.4mm:114.3mm, or a board YAML file")
    from sea3d.calib.printable import board_pdf

    param_option(board, board_pdf, "paper", help="A0-A5, letter, legal, tabloid or WxHmm")
    board.add_argument("--dpi", type=float, default=300.0, help="PNG output: dots per inch")
    board.add_argument("-o", "--output", required=True, metavar="FILE", help=".pdf or .png")
    board.set_defaults(handler=_board)

    stereo = csub.add_parser("stereo", help="calibrate a stereo pair from board images "
                                            "(in air, or in water with refraction absorbed)")
    _add_pair_inputs(stereo)
    stereo.add_argument("-o", "--output", required=True, metavar="RIG", help="rig file to write")
    stereo.add_argument("--json", action="store_true", help="print the result as JSON")
    stereo.add_argument("--report", metavar="HTML", help="write an HTML report")
    from sea3d.calib.stereo import StereoCalibConfig

    config_option(stereo, StereoCalibConfig, "distortion",
                  choices=["standard", "simple", "rational"],
                  help="standard: k1 k2 p1 p2 k3; simple: k3 = 0; rational: 8 "
                       "coefficients (wide lenses, in water)")
    config_option(stereo, StereoCalibConfig, "min_views", type=int, help="fewest usable pairs")
    stereo.add_argument("--no-reject", action="store_true", help="keep every detected pair")
    stereo.add_argument("--no-holdout", action="store_true",
                        help="skip the leave-one-pair-out error (faster)")
    stereo.add_argument("--opencv-start", action="store_true",
                        help="also start the refinement from OpenCV's stereoCalibrate")
    stereo.set_defaults(handler=_stereo)

    from sea3d.cli.odometry import register_calibrate_imu

    register_calibrate_imu(csub)  # sea3d calibrate imu: camera-IMU rotation and time offset

    port = csub.add_parser("port", help="refractive dome/flat-port calibration from in-water "
                                        "board images and an in-air rig")
    port.add_argument("--rig", required=True, metavar="RIG", help="in-air rig (pinhole)")
    port.add_argument("--port", choices=["dome", "flat"], required=True,
                      help="the housings' ports: dome (fits each dome's centre) or flat (fits "
                           "each port's normal and distance)")
    add_port_options(port, flat_help="flat port: starting distance camera centre to inner glass")
    port.add_argument("--refine-focal", action="store_true",
                      help="also estimate the focal length (one scale on fx and fy)")
    _add_pair_inputs(port)
    port.add_argument("-o", "--output", required=True, metavar="RIG", help="rig file to write")
    port.add_argument("--json", action="store_true", help="print the result as JSON")
    port.add_argument("--report", metavar="HTML", help="write an HTML report: verdict and "
                      "guidance, the ports with their uncertainty, per-view errors, residuals "
                      "through the port models, rejected views")
    port.set_defaults(handler=_port)


def _add_pair_inputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--left", required=True, metavar="GLOB", help="left images, e.g. 'd/left*.png'")
    p.add_argument("--right", required=True, metavar="GLOB", help="right images")
    p.add_argument("--board", required=True, metavar="BOARD",
                   help="board spec (checkerboard:9x6:25mm ...) or board file")
    p.add_argument("--detector", choices=["auto", "sector+subpix", "sector", "classic",
                                           "accurate", "fast"], default="auto",
                   help="checkerboards: auto (default) = run every detector and keep the one "
                        "whose calibration has the lowest holdout error (calibrate port: "
                        "sector); sector = OpenCV's sector-based detector (about 0.3 s "
                        "per 640x480 image, 1.5 s at 1920x1080; alias accurate); sector+subpix "
                        "= its corners refined by cornerSubPix; classic = findChessboardCorners "
                        "+ cornerSubPix (10 ms; alias fast)")


# ---------------------------------------------------------------------- helpers
def _expand(pattern: str, side: str) -> list[Path]:
    from sea3d.io.image_files import image_paths

    paths = image_paths(pattern)
    if not paths:
        raise CalibrationError(f"--{side} {pattern!r} matches no files")
    return paths


def _load_image(path: Path) -> Any:
    from sea3d.io.image_files import read_image_rgb

    return read_image_rgb(path)


def _detect_all(paths: list[Path], board: Any, quiet: bool, detector: str = "auto"
                ) -> dict[str, list[Any]]:
    """Detections of every image (:func:`sea3d.calib.targets.detect_images`), with a bar."""
    from sea3d.calib.targets import detect_images
    from sea3d.cli._progress import bar

    return detect_images(((p.name, _load_image(p)) for p in bar(
        len(paths), "detecting", unit="img", enabled=not quiet, iterable=paths)), board, detector)


def _pair_paths(left: list[Path], right: list[Path]) -> None:
    if len(left) == len(right):
        return

    def key(p: Path) -> str:
        return "".join(re.findall(r"\d+", p.stem))

    kl, kr = {key(p) for p in left}, {key(p) for p in right}
    only_l = [p.name for p in left if key(p) not in kr][:5]
    only_r = [p.name for p in right if key(p) not in kl][:5]
    raise CalibrationError(
        f"{len(left)} left and {len(right)} right images; they must pair up one to one "
        f"(left only: {', '.join(only_l) or '-'}; right only: {', '.join(only_r) or '-'})")


def _size_hint(paths: list[Path], dets: list[Any], board: Any, max_images: int = 8) -> str:
    """``; N of M images hold a checkerboard of CxR inner corners -- did you mean ...?``

    One image can mislead (a partly hidden or steeply seen board gives a smaller count), so up
    to ``max_images`` of the images without a detection each name the size they hold, and the
    size most of them name wins (the larger board on a tie).
    """
    from collections import Counter

    from sea3d.calib.targets import diagnose_checkerboard_size

    if board.kind != "checkerboard":
        return ""
    votes: Counter[tuple[int, int]] = Counter()
    asked = 0
    for path, det in zip(paths, dets, strict=True):
        if det.ok or asked >= max_images:
            continue
        img = _load_image(path)
        if img is None:
            continue
        asked += 1
        found = diagnose_checkerboard_size(img, board)
        if found is not None:
            votes[found] += 1
    if not votes:
        return ""
    (c, r), n = max(votes.items(), key=lambda kv: (kv[1], kv[0][0] * kv[0][1]))
    return (f"; {n} of {asked} images without the board hold a checkerboard of {c}x{r} inner "
            f"corners -- did you mean --board checkerboard:{c}x{r}:{board.square_m * 1e3:g}mm?")


# ---------------------------------------------------------------------- handlers
def _board(args: argparse.Namespace) -> int:
    from sea3d.calib.printable import board_pdf
    from sea3d.calib.targets import parse_board, render_board
    from sea3d.io.documents import write_document
    from sea3d.io.image_files import write_image_rgb

    board = parse_board(args.board)
    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix == ".pdf":
        write_document(out, board_pdf(board, args.paper))
    elif suffix in (".png", ".tif", ".tiff"):
        if args.dpi <= 0:
            raise ConfigError(f"--dpi must be positive; got {args.dpi}")
        img = render_board(board, px_per_m=args.dpi / 0.0254, margin_m=0.01)
        write_image_rgb(out, img, ConfigError)
    else:
        raise ConfigError(f"-o {out}: use a .pdf (true scale) or .png file")
    w, h = board.size_m
    print(f"wrote {out}: {board.name}, {w * 1e3:.1f} x {h * 1e3:.1f} mm; print at 100 %")
    return 0


def _stereo(args: argparse.Namespace) -> int:
    from sea3d.calib.stereo import StereoCalibConfig, calibrate_stereo, calibrate_stereo_best
    from sea3d.calib.targets import parse_board
    from sea3d.io.rig_file import save_rig

    board = parse_board(args.board)
    left_paths, right_paths = _expand(args.left, "left"), _expand(args.right, "right")
    _pair_paths(left_paths, right_paths)
    quiet = bool(args.json)
    from sea3d.calib.targets import DETECTOR_ALIASES

    detector = DETECTOR_ALIASES.get(args.detector, args.detector)
    reason = f"{detector}, named with --detector {args.detector}"
    if detector == "auto" and args.no_holdout:
        detector = "sector+subpix"
        reason = ("sector+subpix, the default: with --no-holdout there is no holdout error to "
                  "choose a detector by")
    left = _detect_all(left_paths, board, quiet, detector)
    right = _detect_all(right_paths, board, quiet, detector)
    cfg = StereoCalibConfig(distortion=args.distortion, min_views=args.min_views,
                            reject_outliers=not args.no_reject, holdout=not args.no_holdout,
                            opencv_start=args.opencv_start)
    first = next(iter(left))
    try:
        if len(left) > 1:
            result = calibrate_stereo_best({n: (left[n], right[n]) for n in left}, cfg)
        else:
            result = calibrate_stereo(left[first], right[first], cfg)
            if board.kind == "checkerboard":
                result = dataclasses.replace(result, detector=detector, detector_reason=reason)
    except CalibrationError as err:
        raise CalibrationError(f"{err}{_size_hint(left_paths, left[first], board)}") from err
    if args.report:
        from sea3d.calib.report import render_report
        from sea3d.io.documents import write_document

        sample = None
        if result.left is not None and result.views:
            names = {p.name: p for p in left_paths + right_paths}
            li, ri = _load_image(names[result.views[0].left]), _load_image(
                names[result.views[0].right])
            if li is not None and ri is not None:
                sample = (li, ri)
        write_document(args.report, render_report(result, sample_pair=sample))
    if result.ok:
        save_rig(result.to_rig(), args.output)
    if args.json:
        json.dump(result.to_dict(), sys.stdout, indent=2)
        print()
    else:
        _print_stereo(result, args)
    return 0 if result.ok else 1


def _print_stereo(result: StereoCalibration, args: argparse.Namespace) -> None:
    if not result.ok:
        print(f"calibration failed: {result.message}")
        if args.report:
            print(f"  report: {args.report}")
        return
    assert result.left is not None and result.right is not None  # an ok result has both
    print(f"{result.message}; wrote {args.output}")
    if result.detector:
        print(f"  detector: {result.detector_reason}")
    print(f"  RMS {result.rms_px:.3f} px (left {result.left.rms_px:.3f}, right "
          f"{result.right.rms_px:.3f}), holdout {result.holdout_px:.3f} px")
    print(f"  baseline {result.baseline_m * 1e3:.2f} mm; coverage left "
          f"{result.left.coverage:.0%}, right {result.right.coverage:.0%}")
    for r in result.views_rejected:
        print(f"  rejected {r.left} / {r.right}: {r.reason}")
    print(f"  verdict: {error_line(result.verdict)}")
    for g in result.guidance[1:]:
        print(f"  - {error_line(g)}")
    if args.report:
        print(f"  report: {args.report}")


def _port(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.calib.port import PortCalibConfig, calibrate_port_rig
    from sea3d.calib.targets import parse_board
    from sea3d.io.rig_file import load_rig, save_rig
    from sea3d.refraction import DomePort, FlatPort

    air = load_rig(args.rig)
    board = parse_board(args.board)
    left_paths, right_paths = _expand(args.left, "left"), _expand(args.right, "right")
    _pair_paths(left_paths, right_paths)
    quiet = bool(args.json)
    # No holdout error for port fits to choose by: 'auto' means the sector-based corners,
    # which recover the simulator's domes best (benchmarks/bench_port_sim.py: refining them
    # by cornerSubPix moved the axial dome offsets by 0.3-0.4 mm).
    detector = "sector" if args.detector == "auto" else args.detector
    left = next(iter(_detect_all(left_paths, board, quiet, detector).values()))
    right = next(iter(_detect_all(right_paths, board, quiet, detector).values()))
    ports: list[DomePort | FlatPort] = []
    for _ in range(2):
        if args.port == "dome":
            ports.append(DomePort(center_m=np.zeros(3), inner_radius_m=args.inner_radius_mm * 1e-3,
                                  thickness_m=(args.thickness_mm or 3.1) * 1e-3,
                                  n_air=args.n_air, n_glass=args.n_glass, n_water=args.n_water))
        else:
            ports.append(FlatPort(normal=np.array([0.0, 0.0, 1.0]),
                                  distance_m=args.flat_distance_mm * 1e-3,
                                  thickness_m=(args.thickness_mm or 10.0) * 1e-3,
                                  n_air=args.n_air, n_glass=args.n_glass, n_water=args.n_water))
    cfg = PortCalibConfig(refine_focal=args.refine_focal)
    result = calibrate_port_rig(air, ports[0], ports[1], left, right, cfg)
    if result.ok:
        save_rig(result.rig, args.output)
    if args.report:
        from sea3d.calib.report import render_port_report
        from sea3d.io.documents import write_document

        write_document(args.report, render_port_report(result))
    if args.json:
        json.dump(result.to_dict(), sys.stdout, indent=2)
        print()
    else:
        _print_port(result, args)
    return 0 if result.ok else 1


def _print_port(result: PortRigCalibration, args: argparse.Namespace) -> None:
    import numpy as np

    from sea3d.calib.port import assess_port

    if not result.ok:
        print(f"port calibration failed: {result.message}")
    else:
        print(f"{result.message}; wrote {args.output}")
        for side, r in (("left", result.left), ("right", result.right)):
            if args.port == "dome":
                c, s = r.dome_center_m * 1e3, r.dome_center_std_m * 1e3
                print(f"  {side}: dome centre ({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) mm "
                      f"+- ({s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f}) mm, RMS {r.rms_px:.3f} px")
            else:
                print(f"  {side}: normal {np.round(r.normal, 5).tolist()}, distance "
                      f"{r.distance_m * 1e3:.3f} mm, RMS {r.rms_px:.3f} px")
            if args.refine_focal and r.camera is not None:
                print(f"    fx {r.camera.pinhole.fx:.2f} px (scale {r.focal_scale:.5f} +- "
                      f"{r.focal_scale_std:.5f})")
    for a, b, why in result.views_rejected:
        print(f"  rejected {a} / {b}: {why}")
    if result.ok:
        verdict, guidance = assess_port(result)
        print(f"  verdict: {error_line(verdict)}")
        for g in guidance[1:]:
            print(f"  - {error_line(g)}")
    if args.report:
        print(f"  report: {args.report}")
