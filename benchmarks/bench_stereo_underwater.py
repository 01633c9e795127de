"""Underwater stereo: sea3d's SGM against OpenCV on real sea frames and simulated coastal water.

Real: ``../shared/data/underwater_stereo/stereopi_bermuda1_sea`` (a StereoPi rig in the sea,
side-by-side 320x240 frames, left half = left camera, of a hand-held 6x9 inner-corner chessboard
over sand; see its SOURCE.md). The rig is calibrated from the frames themselves with plain
OpenCV, the pairs are rectified, and the board's inner corners, found independently in both
views, give a reference disparity plane for every board pixel (:mod:`sea3d.eval.board_disparity`).
Relative depth error ``|Z - Z_ref| / Z_ref = |d_ref / d - 1|`` needs no scale (the square size is
unknown). The Panama set is left out: its own stereo calibration is poorly constrained (SOURCE.md)
and rectifies the board out of the right view.

Simulated: the lake scene of ``sea3d.sim`` in coastal water at 640x360, as in
``bench_stereo.py --underwater``, against the renderer's disparity.

Both tables show the steps that took sea3d from behind OpenCV to ahead: the wider alignment
refinement window, the pre-smoothing before the census, and the dense output.

Run: ``PYTHONPATH=src python benchmarks/bench_stereo_underwater.py [--real] [--sim]``
"""

from __future__ import annotations

import argparse
import glob
import os
import time
from pathlib import Path

import cv2
import numpy as np

PATTERN = (9, 6)
REAL_SET = "stereopi_bermuda1_sea"


def load_frames(root: Path, limit: int | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The Bermuda side-by-side frames split into (name, left RGB, right RGB)."""
    files = sorted(glob.glob(str(root / "underwater_stereo" / REAL_SET / "sbs" / "*.png")))
    out = []
    for f in files[:limit]:
        im = cv2.cvtColor(cv2.imread(f, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        w = im.shape[1] // 2
        out.append((Path(f).stem, np.ascontiguousarray(im[:, :w]),
                    np.ascontiguousarray(im[:, w:])))
    return out


def engines(max_d: int) -> dict[str, object]:
    """sea3d (default, its matched pixels only, and the earlier settings step by step) and
    OpenCV's modes, over the same range."""
    from sea3d.stereo import OpenCVSgbmConfig, SgmConfig

    old = {"refine_window_px": 5, "refine_row_step": 1, "refine_weight_cutoff": 0.0,
           "census_presmooth_px": 0.0, "fill_max_px": 0}
    out: dict[str, object] = {
        "sea3d before (5 px refinement, no pre-smoothing, holes)": SgmConfig(
            max_disparity_px=max_d, **old),
        "  + 15 px weighted refinement": SgmConfig(
            max_disparity_px=max_d, **{**old, "refine_window_px": 15, "refine_row_step": 2,
                                       "refine_weight_cutoff": 25.0}),
        "  + census pre-smoothing 0.5 px (= --no-fill)": SgmConfig(max_disparity_px=max_d,
                                                                   fill_max_px=0),
        "  + dense fill (= sea3d default)": SgmConfig(max_disparity_px=max_d),
    }
    for mode, name in (("sgbm_3way", "SGBM_3WAY"), ("sgbm", "SGBM"), ("hh", "HH")):
        for block in (3, 5, 7):
            out[f"OpenCV {name} w{block}"] = OpenCVSgbmConfig(
                max_disparity_px=max_d, mode=mode, block_size_px=block  # type: ignore[arg-type]
            )
    return out


def evaluate_real(root: Path, configs: dict[str, object] | None = None,
                  limit: int | None = None) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    """Pooled board metrics per engine on the Bermuda frames, and facts about the set."""
    from sea3d.eval.board_disparity import rectified_board_set, relative_depth_errors
    from sea3d.stereo import match

    bs = rectified_board_set(load_frames(root, limit), PATTERN)
    top = max(float(np.nanmax(r.disparity_px)) for r in bs.references if r.mask.any())
    max_d = int(np.ceil((top * 1.3 + 1) / 16) * 16) - 1
    configs = configs or engines(max_d)
    errs: dict[str, list[np.ndarray]] = {k: [] for k in configs}
    for i, (left, right) in enumerate(zip(bs.left, bs.right, strict=True)):
        for name, cfg in configs.items():
            d = match(left, right, cfg).disparity_px  # type: ignore[arg-type]
            errs[name].append(relative_depth_errors(d, bs.references[i]))
    out = {}
    for name, lst in errs.items():
        e = np.concatenate(lst)
        valid = np.isfinite(e)
        out[name] = {
            "within_1": 100 * float(np.mean(e <= 0.01)),
            "within_2": 100 * float(np.mean(e <= 0.02)),
            "within_5": 100 * float(np.mean(e <= 0.05)),
            "median_valid": 100 * float(np.median(e[valid])) if valid.any() else float("nan"),
            "density": 100 * float(valid.mean()),
        }
    info = {"pairs": float(len(bs.names)), "max_disparity": float(max_d),
            "fit_rms_px": float(np.median([r.fit_rms_px for r in bs.references])),
            "row_rms_px": float(np.median([r.row_rms_px for r in bs.references])),
            "calib_rms_stereo_px": bs.rms_px[2], "baseline_squares": bs.baseline,
            "board_px": float(sum(r.mask.sum() for r in bs.references))}
    return out, info


def simulated_pairs(width: int = 640, height: int = 360) -> list[tuple[str, np.ndarray,
                                                                       np.ndarray, np.ndarray,
                                                                       int]]:
    """The two coastal-water views of bench_stereo.py --underwater: (name, left, right, true
    disparity, max disparity)."""
    import bench_stereo

    from sea3d.refraction.presets import paper_rig
    from sea3d.sim import simulate_pair

    out = []
    for h_m, tilt in ((1.5, 30.0), (2.5, 45.0)):
        rig = paper_rig(port="none", size_px=(width, height))
        left, right, gt = simulate_pair(rig, "lake", bench_stereo._look_down(h_m, tilt),
                                        "coastal", seed=0)
        d_gt = (rig.left.fx * rig.baseline_m / gt.depth_m).astype(np.float32)  # type: ignore[attr-defined]
        md = int(np.ceil((np.nanmax(d_gt) + 1) / 16) * 16) - 1
        out.append((f"{h_m} m, {tilt:.0f} deg", left, right, d_gt, md))
    return out


def _print_real(root: Path) -> None:
    t0 = time.perf_counter()
    res, info = evaluate_real(root)
    print(f"\n{REAL_SET}: {info['pairs']:.0f} pairs with the board in both views, disparities "
          f"0..{info['max_disparity']:.0f}, {info['board_px']:.0f} board pixels; calibration "
          f"stereo RMS {info['calib_rms_stereo_px']:.3f} px, |T| {info['baseline_squares']:.2f} "
          f"squares; corner plane fit RMS {info['fit_rms_px']:.3f} px, corner row RMS "
          f"{info['row_rms_px']:.3f} px (medians)")
    print("| engine | within 1 % | within 2 % | within 5 % | median err % (valid) | density % |")
    print("|---|---|---|---|---|---|")
    for name, m in res.items():
        print(f"| {name} | {m['within_1']:.1f} | {m['within_2']:.1f} | {m['within_5']:.1f} | "
              f"{m['median_valid']:.3f} | {m['density']:.1f} |")
    print(f"({time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.1f})")


def _print_sim() -> None:
    from sea3d.eval import disparity_metrics
    from sea3d.stereo import match

    print("\nlake scene, coastal water, 640x360 (bad-X over pixels known in both; EPE px)")
    print("| view | engine | bad-0.5 % | bad-1 % | bad-2 % | EPE px | density % |")
    print("|---|---|---|---|---|---|---|")
    for name, left, right, d_gt, md in simulated_pairs():
        for eng, cfg in engines(md).items():
            m = disparity_metrics(match(left, right, cfg).disparity_px, d_gt)  # type: ignore[arg-type]
            print(f"| {name} | {eng} | {m.bad_0_5:.2f} | {m.bad_1:.2f} | {m.bad_2:.3f} | "
                  f"{m.epe_px:.3f} | {m.density:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path,
                    default=Path(os.environ.get("SEA3D_TEST_DATA", "../shared/data")))
    ap.add_argument("--real", action="store_true", help="only the real StereoPi sea frames")
    ap.add_argument("--sim", action="store_true", help="only the simulated coastal pairs")
    args = ap.parse_args()
    both = not (args.real or args.sim)
    if args.real or both:
        _print_real(args.data)
    if args.sim or both:
        _print_sim()


if __name__ == "__main__":
    main()
