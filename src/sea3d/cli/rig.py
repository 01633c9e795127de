"""``sea3d rig``: create, show, convert rigs, and project / unproject through their cameras."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import add_port_options, image_size
from sea3d.errors import ConfigError

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands
    from sea3d.geometry.rig import StereoRig


def register(sub: Subcommands) -> None:
    """Add ``sea3d rig ...``."""
    rig = sub.add_parser("rig", help="create, inspect and convert stereo rig files")
    rsub = rig.add_subparsers(dest="rig_command", metavar="ACTION", required=True)

    create = rsub.add_parser(
        "create", help="write a rig.yaml from a preset or an existing calibration"
    )
    src = create.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", choices=["sea3d-paper"], help="a built-in rig")
    src.add_argument(
        "--from",
        dest="from_file",
        metavar="FILE",
        help="an existing calibration: rig.yaml, OpenCV/MATLAB FileStorage stereo YAML, or a "
        "Kalibr camchain(-imucam).yaml",
    )
    create.add_argument("--extrinsics", metavar="FILE", help="OpenCV stereo_calib extrinsics.yml")
    create.add_argument("-o", "--output", required=True, metavar="RIG", help="file to write")
    create.add_argument(
        "--kalibr",
        metavar="CAMCHAIN",
        help="attach the IMU of a Kalibr camchain-imucam.yaml (cam0.T_cam_imu, "
        "timeshift_cam_imu); cam0 is the left camera",
    )
    create.add_argument(
        "--kalibr-imu",
        metavar="IMU_YAML",
        help="Kalibr imu.yaml with the IMU's noise densities, random walks and rate",
    )
    create.add_argument(
        "--port",
        choices=["dome", "flat", "none"],
        help="ports to put on both cameras (preset default: dome; --from default: keep)",
    )
    add_port_options(create, flat_help="flat port: camera centre to inner glass surface")
    create.add_argument("--size", type=image_size, metavar="WxH", help="image size in pixels")
    create.add_argument("--fx", type=float, metavar="PX", help="focal length (fy keeps the ratio)")
    create.add_argument("--baseline-mm", type=float, metavar="MM", help="stereo baseline")
    create.add_argument(
        "--dome-center-left-mm",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="dome centre in the left camera frame (default: the paper's -0.54 0.58 2.10)",
    )
    create.add_argument(
        "--dome-center-right-mm",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="dome centre in the right camera frame (default: as the left)",
    )
    create.set_defaults(handler=_create)

    show = rsub.add_parser("show", help="print a readable summary of a rig")
    show.add_argument("rig", metavar="RIG")
    show.add_argument("--json", action="store_true", help="machine-readable JSON")
    show.set_defaults(handler=_show)

    for name, helptext in (
        ("unproject", "pixels (u,v CSV) to water rays (u,v,ox,oy,oz,dx,dy,dz CSV)"),
        ("project", "points (x,y,z CSV) to pixels (x,y,z,u,v,valid CSV)"),
    ):
        p = rsub.add_parser(name, help=helptext)
        p.add_argument("rig", metavar="RIG")
        p.add_argument("--camera", choices=["left", "right"], default="left")
        if name == "unproject":
            p.add_argument("--pixels", required=True, metavar="IN.csv", help="columns u,v")
        else:
            p.add_argument("--points", required=True, metavar="IN.csv", help="columns x,y,z (m)")
        p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
        p.set_defaults(handler=_unproject if name == "unproject" else _project)

    conv = rsub.add_parser("convert", help="convert between rig formats")
    conv.add_argument("input", metavar="IN")
    conv.add_argument("output", metavar="OUT")
    conv.add_argument(
        "--format",
        choices=["sea3d", "opencv", "colmap", "json"],
        help="output format (default from the extension: .yaml sea3d, .json, .txt colmap)",
    )
    conv.add_argument("--extrinsics", metavar="FILE", help="OpenCV stereo_calib extrinsics.yml")
    conv.add_argument("--size", type=image_size, metavar="WxH", help="image size if IN lacks it")
    conv.set_defaults(handler=_convert)

    from sea3d.cli.rig_plan import register_plan

    register_plan(rsub)


def _mm(values: list[float] | None) -> tuple[float, float, float] | None:
    return None if values is None else (values[0] * 1e-3, values[1] * 1e-3, values[2] * 1e-3)


def _create(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.geometry.rig import StereoRig
    from sea3d.io.rig_file import load_rig, save_rig
    from sea3d.refraction.presets import PAPER_DOME_CENTER_M, paper_rig, with_ports

    port_opts: dict[str, Any] = {
        "inner_radius_m": args.inner_radius_mm * 1e-3,
        "n_glass": args.n_glass,
        "n_water": args.n_water,
        "n_air": args.n_air,
        "flat_distance_m": args.flat_distance_mm * 1e-3,
    }
    if args.thickness_mm is not None:
        port_opts["thickness_m"] = args.thickness_mm * 1e-3
    left_c = _mm(args.dome_center_left_mm) or PAPER_DOME_CENTER_M
    right_c = _mm(args.dome_center_right_mm) or left_c
    port_opts["dome_center_left_m"] = left_c
    port_opts["dome_center_right_m"] = right_c

    if args.preset:
        rig = paper_rig(
            args.port or "dome",
            size_px=args.size or (1920, 1080),
            fx_px=args.fx,
            baseline_m=(args.baseline_mm * 1e-3) if args.baseline_mm else 0.107,
            **port_opts,
        )
    else:
        from sea3d.io.kalibr import is_kalibr_camchain, rig_from_kalibr

        if is_kalibr_camchain(args.from_file):
            rig = rig_from_kalibr(args.from_file, args.kalibr_imu)
        else:
            rig = load_rig(args.from_file, extrinsics=args.extrinsics, image_size=args.size)
        if args.fx is not None or args.baseline_mm is not None:
            if args.fx is not None and args.fx <= 0:
                raise ConfigError(f"--fx must be > 0, got {args.fx}")
            cams = []
            for cam in (rig.left, rig.right):
                pin = cam.lens
                if args.fx is not None:
                    pin = dataclasses.replace(pin, fx=args.fx, fy=args.fx * pin.fy / pin.fx)
                cams.append(pin)
            T = rig.T_left_right.copy()
            if args.baseline_mm is not None:
                if args.baseline_mm <= 0:
                    raise ConfigError(f"--baseline-mm must be > 0, got {args.baseline_mm}")
                T[:3, 3] *= args.baseline_mm * 1e-3 / np.linalg.norm(T[:3, 3])
            base = StereoRig(
                left=cams[0], right=cams[1], T_left_right=T, imu=rig.imu, sonar=rig.sonar
            )
            old_port = rig.left.port
            rig = base if old_port is None and args.port is None else rig
            if args.port is None and old_port is not None:
                raise ConfigError(
                    "with --fx or --baseline-mm on a rig that has ports, also give --port"
                )
            if args.port is not None:
                rig = base
        if args.port is not None:
            rig = with_ports(rig, args.port, **port_opts)
    if args.kalibr is not None:
        from sea3d.io.kalibr import with_kalibr_imu

        rig = with_kalibr_imu(rig, args.kalibr, args.kalibr_imu)
    elif args.kalibr_imu is not None and rig.imu is None:
        raise ConfigError("--kalibr-imu needs --kalibr (the camchain with T_cam_imu)")
    out = save_rig(rig, args.output)
    print(f"wrote {out}")
    return 0


def _rig_summary(rig: StereoRig) -> dict[str, Any]:
    from sea3d.io.rig_file import rig_to_dict

    data = rig_to_dict(rig)
    cams = {}
    for name in ("left", "right"):
        pin = (rig.left if name == "left" else rig.right).lens
        port = data[name]["port"]
        cams[name] = {
            "model": {"none": "pinhole", "dome": "dome-port", "flat": "flat-port"}[port["type"]],
            "K": pin.K.tolist(),
            "distortion": [float(v) for v in pin.dist],
            "image_size_px": [rig.width, rig.height],
            "port": port,
        }
    return {
        "left": cams["left"],
        "right": cams["right"],
        "T_left_right": rig.T_left_right.tolist(),
        "baseline_m": rig.baseline_m,
        "imu": data.get("imu"),
        "sonar": data.get("sonar"),
    }


def _sensor_lines(summary: dict[str, Any]) -> list[str]:
    import numpy as np

    from sea3d.geometry.se3 import R_to_rotvec

    lines = []
    imu = summary.get("imu")
    if imu is None:
        lines.append("  imu   none (odometry runs visual-only)")
    else:
        T = np.asarray(imu["T_left_imu"])
        t = T[:3, 3] * 1e3
        ang = np.degrees(np.linalg.norm(R_to_rotvec(T[:3, :3])))
        lines.append(
            f"  imu   {imu['rate_hz']:g} Hz, at ({t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}) mm in the "
            f"left frame, rotated {ang:.2f} deg; time offset {imu['time_offset_s'] * 1e3:.3f} ms"
        )
        lines.append(
            f"        gyro {imu['gyro_noise_density_radps_sqrthz']:.3g} rad/s/sqrt(Hz), random "
            f"walk {imu['gyro_random_walk_radps_sqrts']:.3g} rad/s/sqrt(s); accel "
            f"{imu['accel_noise_density_mps2_sqrthz']:.3g} m/s^2/sqrt(Hz), random walk "
            f"{imu['accel_random_walk_mps2_sqrts']:.3g} m/s^2/sqrt(s); gravity "
            f"{imu['gravity_mps2']:g} m/s^2"
        )
    sonar = summary.get("sonar")
    if sonar is not None:
        t = np.asarray(sonar["T_left_sonar"])[:3, 3] * 1e3
        lines.append(
            f"  sonar at ({t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}) mm in the left frame, beam "
            f"{sonar['beam_deg']:g} deg along its -z"
        )
    return lines


def _show(args: argparse.Namespace) -> int:
    from sea3d.io.rig_file import load_rig

    rig = load_rig(args.rig)
    summary = _rig_summary(rig)
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    lines = [f"rig {args.rig}: {rig.width}x{rig.height} px, baseline {rig.baseline_m * 1e3:.2f} mm"]
    for name in ("left", "right"):
        cam = summary[name]
        K = cam["K"]
        line = (
            f"  {name:5s} {cam['model']:9s} fx {K[0][0]:.2f} fy {K[1][1]:.2f} "
            f"cx {K[0][2]:.2f} cy {K[1][2]:.2f} px, {len(cam['distortion'])} distortion coeffs"
        )
        lines.append(line)
        port = cam["port"]
        if port["type"] == "dome":
            c = [v * 1e3 for v in port["center_m"]]
            lines.append(
                f"        dome: centre ({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) mm, inner radius "
                f"{port['inner_radius_m'] * 1e3:.2f} mm, thickness {port['thickness_m'] * 1e3:.2f} "
                f"mm, n air/glass/water {port['n_air']}/{port['n_glass']}/{port['n_water']}"
            )
        elif port["type"] == "flat":
            n = port["normal"]
            lines.append(
                f"        flat: normal ({n[0]:.4f}, {n[1]:.4f}, {n[2]:.4f}), distance "
                f"{port['distance_m'] * 1e3:.2f} mm, thickness {port['thickness_m'] * 1e3:.2f} mm, "
                f"n air/glass/water {port['n_air']}/{port['n_glass']}/{port['n_water']}"
            )
    t = rig.T_left_right[:3, 3] * 1e3
    lines.append(
        f"  right camera centre in the left frame: ({t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}) mm"
    )
    lines.extend(_sensor_lines(summary))
    print("\n".join(lines))
    return 0


def _unproject(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.io.csv_points import read_columns, write_columns
    from sea3d.io.rig_file import load_rig

    rig = load_rig(args.rig)
    cam = rig.left if args.camera == "left" else rig.right
    uv = read_columns(args.pixels, ["u", "v"])
    rays = cam.unproject(uv)
    write_columns(
        args.output,
        ["u", "v", "ox", "oy", "oz", "dx", "dy", "dz"],
        np.concatenate([uv, rays.origins, rays.directions], axis=1),
    )
    bad = int((~rays.valid).sum())
    print(
        f"wrote {len(uv)} rays to {args.output}" + (f" ({bad} without a ray: NaN)" if bad else "")
    )
    return 0


def _project(args: argparse.Namespace) -> int:
    import numpy as np

    from sea3d.io.csv_points import read_columns, write_columns
    from sea3d.io.rig_file import load_rig

    rig = load_rig(args.rig)
    cam = rig.left if args.camera == "left" else rig.right
    pts = read_columns(args.points, ["x", "y", "z"])
    uv, valid = cam.project(pts)
    table = np.concatenate([pts, uv, valid[:, None].astype(np.float64)], axis=1)
    write_columns(args.output, ["x", "y", "z", "u", "v", "valid"], table)
    print(f"wrote {len(pts)} pixels to {args.output} ({int(valid.sum())} valid)")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from sea3d.errors import RigFileError
    from sea3d.io.rig_file import load_rig, save_rig

    rig = load_rig(args.input, extrinsics=args.extrinsics, image_size=args.size)
    try:
        out = save_rig(rig, args.output, format=args.format)
    except RigFileError as err:
        raise RigFileError(f"{err} (--format sea3d, opencv, colmap or json)") from err
    print(f"wrote {out}")
    return 0
