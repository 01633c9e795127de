"""Echosounder against stereo on a simulated survey: stereo against the echosounder against
the truth.

Simulates a lawnmower survey of the ``lake`` scene through the paper's dome-port rig (cameras
60 degrees down, the echosounder straight down: its footprint is outside the view at the same
instant) with the simulator's echosounder (0.5 % of range noise, as the Ping's datasheet), and
runs ``sea3d eval sonar``'s evaluation with the true poses and three depth sources on the same
frames:

- the simulator's exact depth maps (what the method gives with perfect stereo),
- ours: sea3d's SGM (refraction-corrected depth),
- reference: OpenCV's StereoSGBM through the same rectification and triangulation,

each printed as median |diff|, bias and spread against the echosounder and against the truth
(the beam cast against the scene mesh from the true poses), with wall and CPU seconds.

Usage::

    python benchmarks/bench_sonar.py                       # 60 frames at 480x270
    python benchmarks/bench_sonar.py --survey /tmp/s.mcap  # reuse a survey (with its _gt/)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

from sea3d.cli import main as sea3d_main
from sea3d.io.ground_truth import find_ground_truth
from sea3d.pipeline.sonar_check import run_sonar_check
from sea3d.stereo.recipe import DepthConfig


def _fmt(c: object) -> str:
    if c is None or getattr(c, "samples", 0) == 0:
        return f"{'-':>28}"
    return (
        f"{100 * c.median_abs_diff_m:>8.2f} {100 * c.bias_m:>+9.2f} "  # type: ignore[attr-defined]
        f"{100 * c.spread_m:>9.2f}"  # type: ignore[attr-defined]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--survey", type=Path, help="an existing simulated survey (.mcap)")
    ap.add_argument("--keep", type=Path, help="simulate into this .mcap and keep it")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--engines", nargs="+", default=["sea3d", "opencv"])
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message="The TBB threading layer")  # numba's probe
    tmp = tempfile.TemporaryDirectory()
    survey = args.survey
    if survey is None:
        survey = args.keep or Path(tmp.name) / "survey.mcap"
        t0 = time.perf_counter()
        rc = sea3d_main(
            ["-q", "sim", "--scene", "lake", "--frames", str(args.frames), "--size", args.size,
             "--out", str(survey)]
        )  # fmt: skip
        if rc:
            raise SystemExit(rc)
        print(f"simulated {args.frames} frames at {args.size} in {time.perf_counter() - t0:.0f} s")
    gt = find_ground_truth(survey)
    if gt is None:
        raise SystemExit(f"{survey} has no ground-truth folder next to it")
    depth_gt = gt.depth_folder
    print(f"survey {survey}; {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    print(
        f"{'depth':<30}{'pings':>7}{'seen':>6}  {'vs echosounder (cm): |d|, bias, spread':>28}"
        f"  {'vs truth (cm): |d|, bias, spread':>28}{'wall s':>8}{'CPU s':>7}"
    )
    runs: list[tuple[str, dict]] = [("exact (simulator's depth)", {"depth_dir": depth_gt,
                                     "depth_frame": "raw"})]  # fmt: skip
    for engine in args.engines:
        label = f"{'ours' if engine.startswith('sea3d') else 'reference'}: {engine}"
        runs.append((label, {"depth": DepthConfig(engine=engine)}))
    sonar_vs_truth = None
    for label, kw in runs:
        c0, w0 = time.process_time(), time.perf_counter()
        ev, _info = run_sonar_check(survey, **kw)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        sonar_vs_truth = ev.sonar_vs_truth
        print(
            f"{label:<30}{ev.pings:>7}{ev.measured:>6}  {_fmt(ev.stereo_vs_sonar)}"
            f"  {_fmt(ev.stereo_vs_truth)}{wall:>8.1f}{cpu:>7.1f}"
        )
    print(f"{'echosounder itself':<30}{'':>13}  {'':>28}  {_fmt(sonar_vs_truth)}")
    print("Ping echosounder datasheet: range resolution 0.5 % of range (Blue Robotics)")
    tmp.cleanup()


if __name__ == "__main__":
    main()
