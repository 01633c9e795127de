"""Port calibration accuracy against known domes: the figures of docs/calibration.md.

1. Projected corners with 0.15 px noise (no images): one dome camera for three dome centres;
   the focal length 1 % off with ``refine_focal``; a flat port tilted 1.4 degrees; both cameras
   and the extrinsics in water. 20 views at 0.5-2.5 m, tilted up to 40 degrees, 1920x1080.
2. The simulator (``sea3d.sim.render_calibration_set``): in-water pairs through the paper's
   domes (centres (-0.54, 0.58, 2.10) and (1.5, -2.0, -1.0) mm), 95 mm squares at 0.5-2.5 m,
   rendered and detected by every checkerboard detector (their corners' error against the
   true projections is printed), then calibrated: jointly (the default) from each detector's
   corners; from the sector-based corners (what ``sea3d calibrate port`` uses) also with both
   ports held at their own fits (no joint step: the joint step's effect on the extrinsics' z,
   coupled to the domes' axial offsets) and jointly with the in-air focal length 1 % off and
   ``refine_focal``.

    PYTHONPATH=src python benchmarks/bench_port_sim.py [--views 20] [--size 1920x1080]
        [--no-render]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from sea3d.calib.port import PortCalibConfig, calibrate_port, calibrate_port_rig
from sea3d.calib.synthetic import board_poses, synthetic_detections
from sea3d.calib.targets import (
    CHECKER_DETECTORS,
    Detection,
    detect_checkerboard_all,
    parse_board,
)
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction import DomePort, DomePortCamera, FlatPort, FlatPortCamera
from sea3d.refraction.presets import paper_rig

PAPER_CENTER_M = (-0.54e-3, 0.58e-3, 2.10e-3)
RIGHT_CENTER_M = (1.5e-3, -2.0e-3, -1.0e-3)
DOME = {"inner_radius_m": 31.25e-3, "thickness_m": 3.1e-3}
NOISE_PX = 0.15


def mm(v: Any, sign: bool = True) -> str:
    return "(" + ", ".join(f"{x * 1e3:{'+' if sign else ''}.3f}" for x in np.ravel(v)) + ") mm"


def pinhole(size: tuple[int, int], focal_scale: float = 1.0) -> PinholeCamera:
    pin = paper_rig("none", size_px=size).left
    assert isinstance(pin, PinholeCamera)
    return PinholeCamera(fx=pin.fx * focal_scale, fy=pin.fy * focal_scale, cx=pin.cx,
                         cy=pin.cy, width=pin.width, height=pin.height)


def synthetic(cam: Any, rng: np.random.Generator, n: int = 20) -> list[Detection]:
    board = parse_board("checkerboard:9x6:95mm")
    poses = board_poses(cam, board, n, rng, distance_range_m=(0.5, 2.5), max_tilt_deg=40)
    return [v.detections[0] for v in synthetic_detections([cam], board, poses, rng,
                                                           noise_px=NOISE_PX)]


def projected_section(size: tuple[int, int]) -> None:
    print(f"\n1. projected corners, {NOISE_PX} px noise, 20 views, {size[0]}x{size[1]}")
    start = DomePort(center_m=np.zeros(3), **DOME)
    for centre in (PAPER_CENTER_M, (2.0e-3, -1.5e-3, -2.0e-3), (-1.0e-3, -2.5e-3, 3.0e-3)):
        rng = np.random.default_rng(0)
        truth = DomePortCamera(pinhole(size), DomePort(center_m=np.asarray(centre), **DOME))
        res = calibrate_port(synthetic(truth, rng), truth.pinhole, start)
        print(f"  dome at {mm(centre)}: error {mm(res.dome_center_m - np.asarray(centre))}, "
              f"std {mm(res.dome_center_std_m, False)}, RMS {res.rms_px:.3f} px")
    rng = np.random.default_rng(0)
    truth = DomePortCamera(pinhole(size), DomePort(center_m=np.asarray(PAPER_CENTER_M), **DOME))
    res = calibrate_port(synthetic(truth, rng), pinhole(size, 1.01), start,
                         PortCalibConfig(refine_focal=True))
    assert res.camera is not None
    print(f"  focal length 1 % off, refine_focal: fx error "
          f"{100 * (res.camera.pinhole.fx / truth.pinhole.fx - 1):+.4f} %, dome error "
          f"{mm(res.dome_center_m - np.asarray(PAPER_CENTER_M))}")
    rng = np.random.default_rng(0)
    normal = np.array([0.02, -0.015, 1.0])
    flat_truth = FlatPortCamera(pinhole(size), FlatPort(normal=normal, distance_m=12e-3,
                                                        thickness_m=10e-3))
    res = calibrate_port(synthetic(flat_truth, rng), flat_truth.pinhole,
                         FlatPort(normal=np.array([0.0, 0.0, 1.0]), distance_m=10e-3,
                                  thickness_m=10e-3))
    n_true = normal / np.linalg.norm(normal)
    print(f"  flat port tilted {np.degrees(np.arccos(n_true[2])):.1f} deg at 12 mm: normal "
          f"error {np.linalg.norm(res.normal - n_true):.1e}, distance error "
          f"{(res.distance_m - 12e-3) * 1e3:+.3f} mm")
    rng = np.random.default_rng(0)
    rig = paper_rig("dome", size_px=size, dome_center_left_m=PAPER_CENTER_M,
                    dome_center_right_m=RIGHT_CENTER_M)
    board = parse_board("checkerboard:9x6:95mm")
    poses = board_poses(rig.left, board, 20, rng, distance_range_m=(0.5, 2.5), max_tilt_deg=40,
                        also_inside=[(rig.right, rig.T_right_left)])
    views = synthetic_detections([rig.left, rig.right], board, poses, rng,
                                 T_cam_left=[np.eye(4), rig.T_right_left], noise_px=NOISE_PX)
    rig_res = calibrate_port_rig(paper_rig("none", size_px=size), start, start,
                                 [v.detections[0] for v in views],
                                 [v.detections[1] for v in views])
    report_rig("  both cameras + extrinsics", rig_res, rig)


def report_rig(label: str, res: Any, truth: StereoRig, fx_true: float | None = None) -> None:
    if not res.ok:
        print(f"{label}: FAILED ({res.message})")
        return
    dt = res.T_left_right[:3, 3] - truth.T_left_right[:3, 3]
    dR = res.T_left_right[:3, :3] @ truth.T_left_right[:3, :3].T
    rot_mrad = float(np.linalg.norm(cv2.Rodrigues(dR)[0])) * 1e3
    print(f"{label}: stereo RMS {res.rms_px:.3f} px, {len(res.views)} pairs used, "
          f"{len(res.views_rejected)} rejected")
    for side, r, cam in (("left", res.left, truth.left), ("right", res.right, truth.right)):
        err = r.dome_center_m - np.asarray(cam.port.center_m)
        line = (f"     {side} dome error {mm(err)} (max {np.max(np.abs(err)) * 1e3:.3f} mm), "
                f"std {mm(r.dome_center_std_m, False)}")
        if fx_true is not None and r.camera is not None:
            line += f", fx error {100 * (r.camera.pinhole.fx / fx_true - 1):+.4f} %"
        print(line)
    print(f"     translation error {mm(dt)} (t_z {dt[2] * 1e3:+.3f} mm), rotation error "
          f"{rot_mrad:.3f} mrad")
    for a, b, why in res.views_rejected:
        print(f"     rejected {a} / {b}: {why[:110]}")


def rendered_section(views: int, size: tuple[int, int]) -> None:
    from sea3d.sim import render_calibration_set

    rig = paper_rig("dome", size_px=size, dome_center_left_m=PAPER_CENTER_M,
                    dome_center_right_m=RIGHT_CENTER_M)
    spec = "checkerboard:9x6:95mm"
    t0 = time.perf_counter()
    cal = render_calibration_set(rig, spec, views, medium="water", seed=1,
                                 distance_range_m=(0.5, 2.5), supersample=2)
    t_render = time.perf_counter() - t0
    board = parse_board(spec)
    t0 = time.perf_counter()
    found_l = [detect_checkerboard_all(im, board) for im in cal.lefts]
    found_r = [detect_checkerboard_all(im, board) for im in cal.rights]
    t_detect = time.perf_counter() - t0
    dets = {name: ([f[name].with_name(f"left{k:02d}") for k, f in enumerate(found_l)],
                   [f[name].with_name(f"right{k:02d}") for k, f in enumerate(found_r)])
            for name in CHECKER_DETECTORS}
    left, right = dets["sector"]  # what 'sea3d calibrate port' uses
    print(f"\n2. the simulator: {views} in-water pairs at {size[0]}x{size[1]} through the "
          f"paper's domes (rendered in {t_render:.0f} s, every detector in {t_detect:.0f} s: "
          f"{sum(d.ok for d in left)}/{views} left, {sum(d.ok for d in right)}/{views} right)")
    start = DomePort(center_m=np.zeros(3), **DOME)
    air = paper_rig("none", size_px=size)
    for name, (dl, dr) in dets.items():
        truth_uv = [rig.left.project(board.object_points()[1] @ T[:3, :3].T + T[:3, 3])[0]
                    for T in cal.T_left_board]
        errs = [d.corners_px - t if np.linalg.norm(d.corners_px[0] - t[0]) < np.linalg.norm(
            d.corners_px[-1] - t[0]) else d.corners_px[::-1] - t
                for d, t in zip(dl, truth_uv, strict=True) if d.ok]
        corner_rms = float(np.sqrt(np.mean(np.sum(np.concatenate(errs) ** 2, axis=1))))
        res = calibrate_port_rig(air, start, start, dl, dr)
        report_rig(f"  {name} corners (left corners {corner_rms:.3f} px RMS from the truth), "
                   f"joint", res, rig)
    for label, cfg in (("  sector corners, extrinsics with both ports fixed (no joint step)",
                        PortCalibConfig(joint_refinement=False)),):
        t0 = time.perf_counter()
        res = calibrate_port_rig(air, start, start, left, right, cfg)
        report_rig(f"{label} [{time.perf_counter() - t0:.0f} s]", res, rig)
    off = pinhole(size, 1.01)
    air_off = StereoRig(left=off, right=off, T_left_right=air.T_left_right)
    t0 = time.perf_counter()
    res = calibrate_port_rig(air_off, start, start, left, right,
                             PortCalibConfig(refine_focal=True))
    fx_true = pinhole(size).fx
    report_rig(f"  sector corners, in-air focal length 1 % off, refine_focal "
               f"[{time.perf_counter() - t0:.0f} s]",
               res, rig, fx_true=fx_true)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--no-render", action="store_true", help="only the projected corners")
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"sea3d port calibration against known domes; OpenCV {cv2.__version__}, "
          f"{os.cpu_count()} CPUs, load average {load:.1f}", flush=True)
    projected_section((1920, 1080))
    if not args.no_render:
        rendered_section(args.views, (w, h))
    return 0


if __name__ == "__main__":
    sys.exit(main())
