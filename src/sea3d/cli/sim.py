"""``sea3d sim``: simulate an underwater stereo session, or a calibration set, with ground truth.

    sea3d sim --scene lake --frames 300 --water coastal --out dive.mcap
    sea3d sim --scene tank --rig rig.yaml --format folder --size 960x540 --out tank_run/
    sea3d sim calibration --rig rig.yaml --board checkerboard:9x6:40mm --views 20 \\
        --medium water --out calib_water/
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from sea3d.cli._args import image_size
from sea3d.errors import SimulationError

_log = logging.getLogger(__name__)


def register(sub: Any) -> None:
    """Add ``sim`` (survey) and ``sim calibration`` to the top-level subparsers."""
    p = sub.add_parser(
        "sim",
        help="simulate an underwater stereo session (or a calibration set) with ground truth",
        description="Render a synthetic stereo session through the rig's camera models (pinhole, "
        "dome or flat port), with IMU and echosounder, and write it with ground truth in gt/.",
    )
    p.add_argument(
        "--scene", default="lake", help="built-in scene (tank, lake, reef) or a scene YAML file"
    )
    p.add_argument("--rig", type=Path, help="rig file (default: the paper's rig with dome ports)")
    p.add_argument("--frames", type=int, default=300, help="stereo frames (default 300)")
    p.add_argument("--fps", type=float, default=10.0, help="camera rate (default 10)")
    p.add_argument(
        "--water",
        default="coastal",
        choices=["none", "clear", "coastal", "turbid"],
        help="water type; none = clean images (default coastal)",
    )
    p.add_argument(
        "--trajectory",
        default="lawnmower",
        choices=["lawnmower", "orbit", "handheld"],
        help="vehicle motion (default lawnmower)",
    )
    p.add_argument("--out", type=Path, help="output: an .mcap file or a folder")
    p.add_argument(
        "--format", choices=["mcap", "folder"], help="session layout (default from --out)"
    )
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument(
        "--size",
        type=image_size,
        help="render at WxH instead of the rig's size (intrinsics scaled)",
    )
    p.add_argument(
        "--supersample", type=int, default=2, help="rays per pixel along each axis (default 2)"
    )
    p.add_argument("--no-imu-noise", action="store_true", help="exact IMU readings")
    p.add_argument(
        "--gt",
        type=Path,
        help="ground-truth folder (default: gt/ inside a folder session, "
        "<name>_gt/ next to an .mcap file)",
    )
    p.set_defaults(handler=_run_survey)
    ssub = p.add_subparsers(dest="sim_command", metavar="SUBCOMMAND")
    c = ssub.add_parser(
        "calibration",
        help="render a calibration board at varied poses with true poses",
        description="Write left/<t_ns>.png, right/<t_ns>.png and gt/boards.json (list of "
        "{t_ns, T_left_board}); the board frame is at its first inner corner, x along the "
        "first count, y along the second, z into the board.",
    )
    c.add_argument(
        "--rig",
        type=Path,
        dest="cal_rig",
        help="rig file (default: the paper's rig with dome ports)",
    )
    c.add_argument(
        "--board",
        default="checkerboard:9x6:40mm",
        help="board as for 'sea3d calibrate': checkerboard:COLSxROWS:SQUARE (inner corners) or "
        "charuco:COLSxROWS:SQUARE:MARKER[:DICT][:legacy] (squares), or a board .yaml file",
    )
    c.add_argument("--views", type=int, default=20, help="number of views (default 20)")
    c.add_argument(
        "--medium",
        choices=["water", "air"],
        default="water",
        help="water: through the ports; air: the bare pinholes (default water)",
    )
    c.add_argument(
        "--distance",
        type=float,
        nargs=2,
        default=(0.5, 2.5),
        metavar=("MIN_M", "MAX_M"),
        help="board distance range in metres (default 0.5 2.5)",
    )
    c.add_argument(
        "--water",
        dest="cal_water",
        default="none",
        choices=["none", "clear", "coastal", "turbid"],
        help="water effects on the images (default none)",
    )
    c.add_argument(
        "--size", dest="cal_size", type=image_size, help="render at WxH (intrinsics scaled)"
    )
    c.add_argument("--seed", dest="cal_seed", type=int, default=0, help="pose seed (default 0)")
    c.add_argument("--out", dest="cal_out", type=Path, required=True, help="output folder")
    c.set_defaults(handler=_run_calibration)


def _load_rig(path: Path | None, size: tuple[int, int] | None) -> Any:
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim.survey import scale_rig

    if path is None:
        return paper_rig("dome", size_px=size) if size else paper_rig("dome")
    from sea3d.io.rig_file import load_rig

    rig = load_rig(path)
    return scale_rig(rig, size) if size else rig


def _progress(total: int, desc: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", leave=True)


def _run_survey(args: argparse.Namespace) -> int:
    if args.out is None:
        raise SimulationError("sea3d sim needs --out (an .mcap file or a folder)")
    if args.frames < 1:
        raise SimulationError(f"--frames must be >= 1, got {args.frames}")
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter, layout_of
    from sea3d.sim.scene import load_scene
    from sea3d.sim.survey import SurveyConfig, simulate_survey, survey_mount, with_survey_sensors

    rig = _load_rig(args.rig, args.size)
    scene = load_scene(args.scene)
    fmt = args.format or layout_of(args.out)
    if args.gt is not None:
        gt_dir = args.gt
    elif fmt == "folder":
        gt_dir = args.out / "gt"
    else:
        gt_dir = args.out.with_name(args.out.stem + "_gt")
    config = SurveyConfig(
        frames=args.frames,
        fps=args.fps,
        trajectory=args.trajectory,
        water=args.water,
        seed=args.seed,
        supersample=args.supersample,
        imu_noise=not args.no_imu_noise,
    )
    _log.info(
        "simulating %d frames of %s (%s water) at %dx%d into %s",
        args.frames,
        scene.name,
        args.water,
        rig.width,
        rig.height,
        args.out,
    )
    mount = survey_mount(rig, config)
    session_rig = with_survey_sensors(rig, config, mount)  # the IMU and echosounder simulated
    with (
        _progress(args.frames, f"sim {scene.name}") as bar,
        SessionWriter(args.out, format=fmt, rig_yaml=rig_to_yaml(session_rig)) as writer,
    ):
        result = simulate_survey(
            scene, rig, config, writer, gt_dir, mount=mount, progress=bar.update
        )
    print(
        f"wrote {len(result.frame_t_ns)} stereo frames, {result.imu_count} IMU and "
        f"{result.sonar_count} "
        f"echosounder samples to {args.out}; ground truth in {gt_dir}"
    )
    return 0


def _run_calibration(args: argparse.Namespace) -> int:
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.sim.survey import render_calibration_set, write_calibration_set

    rig = _load_rig(args.cal_rig, args.cal_size)
    with _progress(args.views, "calibration views") as bar:
        cal = render_calibration_set(
            rig,
            args.board,
            args.views,
            args.medium,
            args.cal_seed,
            distance_range_m=tuple(args.distance),
            water=args.cal_water,
            progress=bar.update,
        )
    write_calibration_set(cal, args.cal_out)
    (args.cal_out / "rig_true.yaml").write_text(rig_to_yaml(rig))
    print(
        f"wrote {args.views} {args.medium} calibration pairs of {args.board} to {args.cal_out} "
        f"(true poses in gt/boards.json, true rig in rig_true.yaml)"
    )
    return 0
