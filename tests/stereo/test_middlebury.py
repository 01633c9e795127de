"""Accuracy on Middlebury 2001/2003 (tsukuba, venus, cones, teddy) against OpenCV StereoSGBM.

Ground truth and scales: ../shared/data/stereo_gt/SOURCE.md (tsukuba 16, venus 8, cones and
teddy 4; 0 = unknown). The references are OpenCV StereoSGBM in modes SGBM (block sizes 3 and
5), HH (3, the best of 3/5/7/9 on these scenes) and SGBM_3WAY (5), over the same disparity
range, grey input, ``P1 = 8 w^2``, ``P2 = 32 w^2``.

sea3d's engine runs in its shipped defaults: a dense disparity (holes filled from the background
neighbour) with a confidence map (0 on filled pixels). Two comparisons, both with a margin:

* all pixels: bad-2 over every known ground-truth pixel, a missing estimate counting as bad;
* valid pixels at equal density: sea3d keeps its most confident pixels, as many as OpenCV has
  valid ones, and its bad-2 over those is compared with OpenCV's over its valid pixels.

Measured (benchmarks/bench_stereo.py --middlebury): all-pixels bad-2 3.7/1.0/8.0/6.4 % against
the best OpenCV's 5.3/9.2/22.0/23.5 %; at equal density 3.1/0.8/1.8/2.6 % against
3.7-4.6/1.4-1.7/4.1-4.8/5.6-6.7 %.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from sea3d.eval import disparity_metrics
from sea3d.eval.disparity import DisparityMetrics
from sea3d.stereo import OpenCVSgbmConfig, SgmConfig, match

# scene: (left, right, ground truth, scale, max disparity searched (range rounded to 16))
SCENES = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 15),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 31),
    "cones": ("im2.png", "im6.png", "disp2.png", 4, 63),
    "teddy": ("im2.png", "im6.png", "disp2.png", 4, 63),
}
REFERENCES = {  # name: (mode, block size)
    "SGBM w3": ("sgbm", 3),
    "SGBM w5": ("sgbm", 5),
    "HH w3": ("hh", 3),
    "SGBM_3WAY w5": ("sgbm_3way", 5),
}
# sea3d's bad-2 must be below this share of OpenCV's (the smallest measured ratio, tsukuba at
# equal density against HH w3, is 3.14 against 3.71 %: 0.85)
MARGIN = 0.92


def _load(root: Path, scene: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    left_name, right_name, gt_name, scale, max_d = SCENES[scene]
    folder = root / "stereo_gt" / scene
    if not folder.is_dir():
        pytest.skip(f"Middlebury scene {scene} not found in {folder}")
    left = cv2.cvtColor(cv2.imread(str(folder / left_name)), cv2.COLOR_BGR2RGB)
    right = cv2.cvtColor(cv2.imread(str(folder / right_name)), cv2.COLOR_BGR2RGB)
    raw = cv2.imread(str(folder / gt_name), cv2.IMREAD_UNCHANGED)
    gt = np.where(raw > 0, raw.astype(np.float32) / scale, np.nan).astype(np.float32)
    return left, right, gt, max_d


def most_confident(disparity: np.ndarray, confidence: np.ndarray, gt: np.ndarray,
                   density_percent: float) -> np.ndarray:
    """``disparity`` kept only on its most confident pixels, as many as ``density_percent`` of
    the known ground truth. Filled pixels (confidence 0) come last, nearest to a matched pixel
    first."""
    known = np.isfinite(gt) & (gt > 0)
    filled = np.isfinite(disparity) & (confidence <= 0)
    dist = cv2.distanceTransform(filled.astype(np.uint8), cv2.DIST_L2, 3)
    rank = np.where(filled, -1e-3 * dist / (1.0 + dist), confidence)  # in (-1e-3, 1]
    score = np.where(np.isfinite(disparity) & known, rank, -1.0)[known]
    n = round(density_percent / 100.0 * known.sum())
    keep = np.zeros(score.size, bool)
    keep[np.argsort(-score, kind="stable")[:n]] = True
    mask = np.zeros_like(known)
    mask[known] = keep
    return np.where(mask, disparity, np.nan)


@cache
def _scores(root: str, scene: str) -> tuple[DisparityMetrics, dict[str, tuple[DisparityMetrics,
                                                                           DisparityMetrics]]]:
    """sea3d's metrics and, per reference, (OpenCV's, sea3d's at OpenCV's density)."""
    left, right, gt, max_d = _load(Path(root), scene)
    ours = match(left, right, SgmConfig(max_disparity_px=max_d))
    m_ours = disparity_metrics(ours.disparity_px, gt)
    refs = {}
    for name, (mode, block) in REFERENCES.items():
        cfg = OpenCVSgbmConfig(max_disparity_px=max_d, mode=mode,  # type: ignore[arg-type]
                               block_size_px=block)
        m_ref = disparity_metrics(match(left, right, cfg).disparity_px, gt)
        m_eq = disparity_metrics(
            most_confident(ours.disparity_px, ours.confidence, gt, m_ref.density), gt
        )
        refs[name] = (m_ref, m_eq)
    return m_ours, refs


@pytest.mark.data
@pytest.mark.parametrize("scene", list(SCENES))
def test_default_output_is_dense_and_beats_opencv_counting_missing_pixels(
    data_dir: Path, scene: str
) -> None:
    m_ours, refs = _scores(str(data_dir), scene)
    assert m_ours.density > 99.0  # dense by default
    for name, (m_ref, _) in refs.items():
        print(f"{scene}: sea3d all-pixels bad-2 {m_ours.bad_2_all:.2f} %, {name} "
              f"{m_ref.bad_2_all:.2f} %")
        assert m_ours.bad_2_all < MARGIN * m_ref.bad_2_all, name


@pytest.mark.data
@pytest.mark.parametrize("scene", list(SCENES))
def test_default_beats_opencv_on_valid_pixels_at_equal_density(data_dir: Path, scene: str) -> None:
    _, refs = _scores(str(data_dir), scene)
    for name, (m_ref, m_eq) in refs.items():
        print(f"{scene}: at {m_ref.density:.1f} % density sea3d bad-2 {m_eq.bad_2:.2f} %, "
              f"{name} {m_ref.bad_2:.2f} %")
        assert abs(m_eq.density - m_ref.density) < 0.05
        assert m_eq.bad_2 < MARGIN * m_ref.bad_2, name
