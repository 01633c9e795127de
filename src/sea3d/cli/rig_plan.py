"""``sea3d rig plan``: depth error, nearest range and overlap of a rig against range.

Registered under ``sea3d rig`` by :func:`register_plan` (called from :mod:`sea3d.cli.rig`).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from sea3d.cli._args import config_option, image_size

if TYPE_CHECKING:
    from sea3d.cli._args import Subcommands

__all__ = ["register_plan"]


def register_plan(rsub: Subcommands) -> None:
    """Add ``plan`` to the ``sea3d rig`` subparsers."""
    p = rsub.add_parser(
        "plan",
        help="depth error, nearest range and overlap against range (choose a baseline)",
        description="Plan a stereo rig for its working range: depth error z^2 S / (f B), "
        "nearest range f B / N, overlap of the two views, and with ports the refraction's "
        "effect (effective focal length in water, virtual-pinhole residual, the bias of "
        "ignoring the ports). Options override the rig's values; without RIG a pinhole rig "
        "is built from them (defaults: the paper's 1920x1080, fx 1082.4 px, 107 mm).",
    )
    p.add_argument("rig", nargs="?", metavar="RIG", help="rig.yaml (default: from the options)")
    p.add_argument("--fx-px", type=float, metavar="F", help="focal length in air, pixels")
    p.add_argument("--baseline-mm", type=float, metavar="B", help="baseline, millimetres")
    p.add_argument("--size", type=image_size, metavar="WxH", help="image size (intrinsics scale)")
    p.add_argument(
        "--port",
        choices=("dome", "flat", "none"),
        help="put the paper's dome or a 10 mm flat port on both cameras (default: the rig's "
        "ports; none without RIG)",
    )
    from sea3d.stereo.planning import PlanConfig

    config_option(p, PlanConfig, "max_disparity_px", "--max-disparity", dest="max_disparity",
                  type=int, metavar="N", help="disparity range")
    config_option(p, PlanConfig, "disparity_noise_px", type=float, metavar="S",
                  help="matching error, standard deviation in pixels")
    p.add_argument(
        "--range-m",
        type=float,
        nargs=2,
        metavar=("MIN", "MAX"),
        help="ranges of the table, metres (default: the nearest range to 10 m)",
    )
    config_option(p, PlanConfig, "rows", type=int, help="table rows (at least 5)")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="also draw the plan into a PNG")
    p.set_defaults(handler=_plan)


def _rig_for(args: argparse.Namespace) -> tuple[Any, str]:
    from sea3d.refraction.presets import paper_rig, with_ports
    from sea3d.stereo.planning import override_rig

    if args.rig:
        from sea3d.io.rig_file import load_rig

        rig = load_rig(args.rig)
        source = str(args.rig)
    else:
        rig = paper_rig("none")
        source = "pinhole rig from the options (paper defaults for the rest)"
    rig = override_rig(
        rig,
        fx_px=args.fx_px,
        baseline_m=None if args.baseline_mm is None else args.baseline_mm * 1e-3,
        size_px=args.size,
    )
    if args.port is not None:
        rig = with_ports(rig, args.port)
    return rig, source


def _plan(args: argparse.Namespace) -> int:
    from sea3d.stereo.planning import PlanConfig, plan_rig, plot_plan

    config = PlanConfig(
        max_disparity_px=args.max_disparity,
        disparity_noise_px=args.disparity_noise_px,
        range_m=None if args.range_m is None else (args.range_m[0], args.range_m[1]),
        rows=args.rows,
    )
    rig, source = _rig_for(args)
    plan = plan_rig(rig, config)
    if args.plot:
        plot_plan(plan, args.plot)
    if args.json:
        out = plan.as_dict()
        out["rig"] = source
        if args.plot:
            out["plot"] = str(args.plot)
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    w = sys.stdout.write
    w(f"rig          {source}\n")
    w(f"image        {plan.width}x{plan.height}, hfov {plan.hfov_deg:.1f} deg")
    w(" (in water)\n" if plan.refractive else "\n")
    w(f"focal        {plan.focal_px:.1f} px in air")
    if plan.refractive:
        w(f", {plan.focal_water_px:.1f} px in water (virtual pinhole)")
    w(f", {plan.focal_rectified_px:.1f} px rectified\n")
    w(f"baseline     {plan.baseline_m * 1000:.1f} mm\n")
    w(
        f"disparity    0..{plan.max_disparity_px} px, noise {plan.disparity_noise_px:g} px -> "
        f"nearest range {plan.min_range_m:.3f} m\n"
    )
    if plan.refractive and plan.virtual_pinhole_rms_px is not None:
        w(
            f"refraction   virtual-pinhole residual {plan.virtual_pinhole_rms_px:.2f} px RMS, "
            f"{plan.virtual_pinhole_max_px:.2f} px max over the range\n"
        )
    w("\n")
    head = f"{'range m':>9}{'disp px':>9}{'error mm':>10}{'error %':>9}{'overlap %':>10}"
    if plan.refractive:
        head += f"{'bias if ports ignored mm':>26}"
    w(head + "\n")
    for r in plan.rows:
        line = (
            f"{r.range_m:>9.3f}{r.disparity_px:>9.1f}{r.depth_error_m * 1000:>10.1f}"
            f"{r.depth_error_pct:>9.2f}{100 * r.overlap_fraction:>10.1f}"
        )
        if plan.refractive:
            bias = "-" if r.refraction_bias_m is None else f"{r.refraction_bias_m * 1000:.1f}"
            line += f"{bias:>26}"
        if not r.in_range:
            line += "  (nearer than the disparity range)"
        w(line + "\n")
    if args.plot:
        w(f"\nplot -> {args.plot}\n")
    return 0
