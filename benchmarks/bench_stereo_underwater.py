"""Real underwater stereo: sea3d's SGM against OpenCV on a StereoPi rig in the sea.

Data: ``../shared/data/underwater_stereo/stereopi_{bermuda1,panama}_sea`` (side-by-side frames,
left half = left camera, of a hand-held 6x9 inner-corner chessboard; see their SOURCE.md). The
rig is calibrated from the frames themselves with plain OpenCV, the pairs are rectified, and the
board's inner corners, found independently in both views, give a reference disparity plane for
every board pixel (:mod:`sea3d.eval.board_disparity`). Relative depth error
``|Z - Z_ref| / Z_ref = |d_ref / d - 1|`` needs no scale (the square size is unknown).

Prints, per engine and pooled over all pairs: the share of board pixels within 1, 2 and 5 % of
the reference depth (missing estimates count as misses), the median relative error of the valid
estimates, and their density on the board.

Run: ``PYTHONPATH=src python benchmarks/bench_stereo_underwater.py [--set bermuda1|panama|all]``
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
SETS = {"bermuda1": "stereopi_bermuda1_sea", "panama": "stereopi_panama_sea"}


def load_set(root: Path, name: str, limit: int | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Side-by-side frames split into (name, left RGB, right RGB)."""
    files = sorted(glob.glob(str(root / "underwater_stereo" / SETS[name] / "sbs" / "*.png")))
    out = []
    for f in files[:limit]:
        im = cv2.cvtColor(cv2.imread(f, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        w = im.shape[1] // 2
        out.append((Path(f).stem, np.ascontiguousarray(im[:, :w]), np.ascontiguousarray(im[:, w:])))
    return out


def engines(max_d: int) -> dict[str, object]:
    from sea3d.stereo import OpenCVSgbmConfig, make_config

    return {
        "sea3d (default)": make_config("sea3d", max_d),
        "OpenCV SGBM_3WAY w5": OpenCVSgbmConfig(max_disparity_px=max_d, mode="sgbm_3way"),
        "OpenCV SGBM_3WAY w3": OpenCVSgbmConfig(max_disparity_px=max_d, mode="sgbm_3way",
                                                block_size_px=3),
        "OpenCV SGBM w5": OpenCVSgbmConfig(max_disparity_px=max_d, mode="sgbm"),
        "OpenCV HH w5": OpenCVSgbmConfig(max_disparity_px=max_d, mode="hh"),
    }


def evaluate(root: Path, set_name: str, configs: dict[str, object] | None = None) -> dict[str, dict[str, float]]:
    """Pooled board metrics per engine for one set."""
    from sea3d.eval.board_disparity import rectified_board_set, relative_depth_errors
    from sea3d.stereo import match

    bs = rectified_board_set(load_set(root, set_name), PATTERN)
    top = max(float(np.nanmax(r.disparity_px)) for r in bs.references)
    max_d = int(np.ceil((top * 1.3 + 1) / 16) * 16) - 1
    configs = configs or engines(max_d)
    errs: dict[str, list[np.ndarray]] = {k: [] for k in configs}
    for left, right in zip(bs.left, bs.right, strict=True):
        for name, cfg in configs.items():
            d = match(left, right, cfg).disparity_px  # type: ignore[arg-type]
            errs[name].append(relative_depth_errors(d, bs.references[len(errs[name])]))
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
    out["_info"] = {"pairs": len(bs.names), "max_disparity": max_d,
                    "fit_rms_px": float(np.median([r.fit_rms_px for r in bs.references])),
                    "row_rms_px": float(np.median([r.row_rms_px for r in bs.references])),
                    "calib_rms_stereo_px": bs.rms_px[2], "baseline_squares": bs.baseline,
                    "board_px": float(sum(r.mask.sum() for r in bs.references))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("SEA3D_TEST_DATA", "../shared/data")))
    ap.add_argument("--set", choices=[*SETS, "all"], default="all")
    args = ap.parse_args()
    for set_name in SETS if args.set == "all" else [args.set]:
        t0 = time.perf_counter()
        res = evaluate(args.data, set_name)
        info = res.pop("_info")
        print(f"\n{SETS[set_name]}: {info['pairs']} pairs with the board in both views, "
              f"disparities 0..{info['max_disparity']}, {info['board_px']:.0f} board pixels; "
              f"calibration stereo RMS {info['calib_rms_stereo_px']:.3f} px, |T| "
              f"{info['baseline_squares']:.2f} squares; corner plane fit RMS "
              f"{info['fit_rms_px']:.3f} px, corner row RMS {info['row_rms_px']:.3f} px (medians)")
        print("| engine | within 1 % | within 2 % | within 5 % | median err % (valid) | density % |")
        print("|---|---|---|---|---|---|")
        for name, m in res.items():
            print(f"| {name} | {m['within_1']:.1f} | {m['within_2']:.1f} | {m['within_5']:.1f} | "
                  f"{m['median_valid']:.2f} | {m['density']:.1f} |")
        print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
