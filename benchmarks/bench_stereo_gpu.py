"""GPU SGM against OpenCV StereoSGBM (CPU) and sea3d's CPU SGM, on the same inputs.

Accuracy on Middlebury (bad-2.0 %, density) and speed at 1920x1080 and 3840x2160 with 256
disparities. Needs CuPy and an NVIDIA GPU; run it where one is lent:

    python benchmarks/bench_stereo_gpu.py --data ../shared/data [--repeats 5]

``--cpu-only`` prints the CPU columns alone (sea3d CPU SGM, OpenCV) on a machine without a GPU.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from sea3d.eval.disparity import disparity_metrics
from sea3d.io.depth_files import read_disparity
from sea3d.stereo import make_config, match
from sea3d.stereo.gpu_sgm import GpuSgmConfig, match_gpu_sgm

SCENES = {  # left, right, ground truth, scale, max disparity
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 15),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 31),
    "cones": ("im2.png", "im6.png", "disp2.png", 4, 63),
    "teddy": ("im2.png", "im6.png", "disp2.png", 4, 63),
}


def _read(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"cannot read {path}")
    return img[..., ::-1].copy()


def _find(folder: Path, stem: str) -> Path:
    for cand in folder.iterdir():
        if cand.stem == Path(stem).stem:
            return cand
    raise SystemExit(f"{folder}: no {stem}")


def _median_time(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def accuracy(data: Path, gpu: bool = True) -> None:
    print("Middlebury bad-2.0 % (lower is better) / density %")
    print(f"{'scene':8s} {'gpu sgm':>16s} {'cpu sgm':>16s} {'opencv hh':>16s}")
    for name, (l, r, g, scale, dmax) in SCENES.items():
        folder = data / "stereo_gt" / name
        left, right = _read(_find(folder, l)), _read(_find(folder, r))
        gt = read_disparity(_find(folder, g), scale=scale)
        cpu = match(left, right, make_config("sea3d", dmax)).disparity_px
        ocv = match(left, right, make_config("opencv-hh", dmax)).disparity_px
        cells = [] if gpu else ["-"]
        ests = [cpu, ocv]
        if gpu:
            ests.insert(0, match_gpu_sgm(left, right, GpuSgmConfig(max_disparity_px=dmax))[0])
        for est in ests:
            m = disparity_metrics(est, gt)
            cells.append(f"{m.bad_2:6.2f} / {m.density:5.1f}")
        print(f"{name:8s} " + " ".join(f"{c:>16s}" for c in cells))


def speed(repeats: int, gpu: bool = True, sizes: tuple[tuple[int, int], ...] = ((1920, 1080),
                                                                             (3840, 2160))) -> None:
    rng = np.random.default_rng(0)
    for w, h in sizes:
        base = cv2.GaussianBlur(rng.integers(0, 256, (h, w + 64)).astype(np.uint8), (3, 3), 0)
        _speed_one(base[:, :w].copy(), base[:, 64:].copy(), repeats, gpu)  # disparity 64


def _speed_one(left: np.ndarray, right: np.ndarray, repeats: int, gpu: bool = True) -> None:
    h, w = left.shape
    gpu_cfg = GpuSgmConfig(max_disparity_px=255)
    if gpu:
        t_gpu = _median_time(lambda: match_gpu_sgm(left, right, gpu_cfg), repeats)
        _, tim = match_gpu_sgm(left, right, gpu_cfg)
    ocv = make_config("opencv", 255)
    t_ocv = _median_time(lambda: match(left, right, ocv), max(1, repeats // 2))
    ocv3 = make_config("opencv-3way", 255)
    t_ocv3 = _median_time(lambda: match(left, right, ocv3), max(1, repeats // 2))
    cpu = make_config("sea3d", 255)
    t_cpu = _median_time(lambda: match(left, right, cpu), max(1, repeats // 2))
    print(f"{w}x{h}, 256 disparities, median of {repeats} (CPU engines: {max(1, repeats // 2)}"
          f"); load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}:")
    if not gpu:
        print(f"  sea3d CPU SGM         {t_cpu:8.3f} s  wall ratio sea3d/3WAY {t_cpu / t_ocv3:.3f}")
        print(f"  OpenCV MODE_SGBM      {t_ocv:8.3f} s")
        print(f"  OpenCV SGBM_3WAY      {t_ocv3:8.3f} s")
        return
    print(
        f"  sea3d GPU SGM         {t_gpu:8.3f} s  (device match {tim['match_s']:.3f} s, "
        f"upload {tim['upload_s']:.3f} s, download {tim['download_s']:.3f} s)"
    )
    print(f"  sea3d CPU SGM         {t_cpu:8.3f} s  ratio GPU/CPU {t_gpu / t_cpu:.3f}")
    print(f"  OpenCV MODE_SGBM      {t_ocv:8.3f} s  ratio GPU/OpenCV {t_gpu / t_ocv:.3f}")
    print(f"  OpenCV SGBM_3WAY      {t_ocv3:8.3f} s  ratio GPU/OpenCV {t_gpu / t_ocv3:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpu-only", action="store_true",
                        help="no GPU: print the CPU engines' columns only (1080p speed)")
    args = parser.parse_args()
    gpu = not args.cpu_only
    if (args.data / "stereo_gt").is_dir():
        accuracy(args.data, gpu)
    speed(args.repeats, gpu, ((1920, 1080), (3840, 2160)) if gpu else ((1920, 1080),))


if __name__ == "__main__":
    main()
