"""``sea3d sim``: simulate an underwater stereo session, or a calibration set, with ground truth.

    sea3d sim --scene lake --frames 300 --water coastal -o dive.mcap
    sea3d sim --scene tank --rig rig.yaml --format folder --size 960x540 -o tank_run/
    sea3d sim calibration --rig rig.yaml --board checkerboard:9x6:40mm --views 20 \\
        --medium water -o calib_water/
"""

from __future__ import annotations

import argparse
import logging
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sea3d._text import plural, size_text
from sea3d.cli._args import add_output, config_option, image_size
from sea3d.errors import SimulationError
from sea3d.sim.config import DEFAULT_SCENE, CalibrationSetConfig, SurveyConfig

_log = logging.getLogger(__name__)

_WATERS = ["none", "clear", "coastal", "turbid"]

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands
    from sea3d.geometry.rig import StereoRig


def register(sub: Subcommands) -> None:
    """Add ``sim`` (survey) and ``sim calibration`` to the top-level subparsers."""
    p = sub.add_parser(
        "sim",
        help="simulate an underwater stereo session (or a calibration set) with ground truth",
        usage="sea3d sim [options]                  (a survey session)\n"
        "       sea3d sim calibration [options]      (a calibration set; see its --help)",
        description="Render a synthetic stereo session through the rig's camera models (pinhole, "
        "dome or flat port), with IMU and echosounder, and write it with ground truth in gt/. "
        "Before it starts it prints what the run will write and roughly how long it takes, and "
        "refuses to start when the disk cannot hold it.",
    )
    p.add_argument("--scene", default=DEFAULT_SCENE,
                   help=f"built-in scene (tank, lake, reef) or a scene YAML file "
                        f"(default {DEFAULT_SCENE})")
    p.add_argument(
        "--rig",
        type=Path,
        metavar="RIG",
        help="rig file (default: the paper's rig with dome ports)",
    )
    survey = partial(config_option, p, SurveyConfig)
    survey("frames", type=int, metavar="N", help="stereo frames")
    survey("fps", type=float, metavar="HZ", help="camera rate", shown="10")
    survey("water", choices=_WATERS, help="water type; none = clean images")
    survey("trajectory", choices=["lawnmower", "orbit", "handheld"], help="vehicle motion")
    add_output(p, type=Path, metavar="PATH", help="output: an .mcap file or a folder")
    p.add_argument(
        "--format", choices=["mcap", "folder"], help="session layout (default from --output)"
    )
    survey("seed", type=int, metavar="N", help="noise seed")
    p.add_argument(
        "--size",
        type=image_size,
        metavar="WxH",
        help="render at WxH instead of the rig's size (intrinsics scaled)",
    )
    survey("supersample", type=int, metavar="N", help="rays per pixel along each axis at edges")
    p.add_argument("--no-imu-noise", action="store_true", help="exact IMU readings")
    p.add_argument(
        "--clean-reference",
        action="store_true",
        help="also write every view without water, same noise seed, to GT/clean/ (the water "
        "model's coefficients are in GT/sim.json either way)",
    )
    p.add_argument(
        "--gt",
        type=Path,
        metavar="DIR",
        help="ground-truth folder (default: gt/ inside a folder session, "
        "<name>_gt/ next to an .mcap file)",
    )
    p.set_defaults(handler=_run_survey)
    ssub = p.add_subparsers(
        dest="sim_command",
        title="optional subcommand",
        description="without one, sea3d sim simulates a survey session",
    )
    c = ssub.add_parser(
        "calibration",
        prog="sea3d sim calibration",
        help="render a calibration board at varied poses with true poses",
        description="Write left/<t_ns>.png, right/<t_ns>.png and gt/boards.json (list of "
        "{t_ns, T_left_board}); the board frame is at its first inner corner, x along the "
        "first count, y along the second, z into the board.",
    )
    c.add_argument(
        "--rig",
        type=Path,
        dest="cal_rig",
        metavar="RIG",
        help="rig file (default: the paper's rig with dome ports)",
    )
    cal = partial(config_option, c, CalibrationSetConfig)
    cal("board", metavar="BOARD",
        help="board as for 'sea3d calibrate': checkerboard:COLSxROWS:SQUARE (inner corners) or "
        "charuco:COLSxROWS:SQUARE:MARKER[:DICT][:legacy] (squares), or a board .yaml file")
    cal("views", type=int, metavar="N", help="number of views")
    cal("medium", choices=["water", "air"],
        help="water: through the ports; air: the bare pinholes")
    cal("distance_range_m", "--distance", type=float, nargs=2, metavar=("MIN_M", "MAX_M"),
        dest="distance", help="board distance range in metres")
    cal("water", choices=_WATERS, dest="cal_water", help="water effects on the images")
    c.add_argument(
        "--size",
        dest="cal_size",
        type=image_size,
        metavar="WxH",
        help="render at WxH (intrinsics scaled)",
    )
    cal("seed", dest="cal_seed", type=int, metavar="N", help="pose seed")
    add_output(c, dest="cal_out", type=Path, required=True, metavar="DIR", help="output folder")
    c.set_defaults(handler=_run_calibration)


def _load_rig(path: Path | None, size: tuple[int, int] | None) -> StereoRig:
    from sea3d.refraction.presets import paper_rig

    if path is None:
        return paper_rig("dome", size_px=size) if size else paper_rig("dome")
    from sea3d.io.rig_file import load_rig

    rig = load_rig(path)
    return rig.scaled(*size) if size else rig


def _progress(total: int, desc: str) -> Any:
    from sea3d.cli._progress import bar

    return bar(total, desc, leave=True)


def _duration_text(seconds: float) -> str:
    if seconds < 1:
        return "a second"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _run_survey(args: argparse.Namespace) -> int:
    if args.out is None:
        raise SimulationError("sea3d sim needs -o/--output (an .mcap file or a folder)")
    if args.frames < 1:
        raise SimulationError(f"--frames must be >= 1, got {args.frames}")
    from sea3d.io.ground_truth import ground_truth_dir
    from sea3d.io.session import check_new_session, layout_of

    check_new_session(args.out, args.format)  # before the rig, the scene and the estimate
    from sea3d.sim.scene import load_scene
    from sea3d.sim.survey import (
        check_disk_room,
        estimate_survey_cost,
        simulate_session,
        survey_fold_note,
    )

    rig = _load_rig(args.rig, args.size)
    scene = load_scene(args.scene)
    fmt = args.format or layout_of(args.out)
    gt_dir = args.gt if args.gt is not None else ground_truth_dir(args.out,
                                                                  folder=fmt == "folder")
    config = SurveyConfig(
        frames=args.frames,
        fps=args.fps,
        trajectory=args.trajectory,
        water=args.water,
        seed=args.seed,
        supersample=args.supersample,
        imu_noise=not args.no_imu_noise,
        clean_reference=args.clean_reference,
    )
    cost = estimate_survey_cost(rig.width, rig.height, config)
    check_disk_room((args.out, gt_dir), cost.total_bytes)
    pairs = "pair" if args.frames == 1 else "pairs"
    print(
        f"simulating {args.frames} stereo {pairs} of {scene.name} ({args.water} water) at "
        f"{rig.width}x{rig.height}: about {size_text(cost.image_bytes)} of images and "
        f"{size_text(cost.gt_bytes)} of ground truth, about {_duration_text(cost.total_seconds)} "
        f"on two idle cores"
        + (" (most of it the one-off compilation of the renderer)"
           if cost.compiles and cost.startup_seconds > cost.seconds else
           " (with the one-off compilation of the renderer)" if cost.compiles else ""),
        flush=True,
    )
    note = survey_fold_note(scene, config)
    if note is not None:
        print(f"note: {note}", flush=True)
    with _progress(args.frames, f"sim {scene.name}") as bar:
        result = simulate_session(scene, rig, config, args.out, gt_dir, format=fmt,
                                  progress=bar.update)
    print(
        f"wrote {plural(len(result.frame_t_ns), 'stereo frame')}, "
        f"{plural(result.imu_count, 'IMU sample')} and "
        f"{plural(result.sonar_count, 'echosounder sample')} to {args.out}; ground truth in "
        f"{gt_dir}"
    )
    return 0


def _run_calibration(args: argparse.Namespace) -> int:
    from sea3d.io.rig_file import save_rig
    from sea3d.sim.survey import in_air, render_calibration_set, write_calibration_set

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
    # The rig that rendered the images: in air the bare pinholes, without the ports.
    save_rig(in_air(rig) if args.medium == "air" else rig, args.cal_out / "rig_true.yaml")
    print(
        f"wrote {plural(args.views, args.medium + ' calibration pair')} of {args.board} to "
        f"{args.cal_out} (true poses in gt/boards.json, true rig in rig_true.yaml)"
    )
    return 0
