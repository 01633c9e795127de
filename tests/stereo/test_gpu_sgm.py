"""The GPU SGM engine: known disparities, agreement with the CPU engine, clear errors.

Tests marked ``gpu`` run only where CuPy sees an NVIDIA GPU; CI has none, so they skip there and
run on a lent GPU machine (see benchmarks/bench_stereo_gpu.py for the figures).
"""

import numpy as np
import pytest

from sea3d.errors import ConfigError, StereoError
from sea3d.stereo.gpu_sgm import GpuSgmConfig, gpu_available, match_gpu_sgm

needs_gpu = pytest.mark.skipif(not gpu_available(), reason="no CUDA GPU with CuPy")

# Sub-pixel accuracy of a fronto-parallel shifted texture: the parabola fit leaves a bias of a
# few tenths of a pixel at most; 0.5 px bounds a correct matcher and catches an off-by-one.
SHIFT_TOL_PX = 0.5


def _textured_pair(rng, h=120, w=200, shift=7):
    base = rng.integers(0, 256, (h, w + shift)).astype(np.float32)
    # Smooth a little so that census windows see structure, not single-pixel noise only.
    base = (base + np.roll(base, 1, 1) + np.roll(base, 1, 0)) / 3.0
    # A texture point at column X is seen at u_left = X and u_right = X - shift: d = shift.
    left = base[:, :w]
    right = base[:, shift:] * 0.8 + 20.0  # brightness change between views (caustics, haze)
    return left.astype(np.uint8), np.clip(right, 0, 255).astype(np.uint8)


def test_config_validation():
    with pytest.raises(ConfigError, match=r"1\.\.1023"):
        GpuSgmConfig(max_disparity_px=2000)
    with pytest.raises(ConfigError, match="odd"):
        GpuSgmConfig(census_width_px=8)


@pytest.mark.skipif(gpu_available(), reason="only meaningful without a GPU")
def test_without_gpu_the_error_says_what_to_use():
    img = np.zeros((10, 40), np.uint8)
    with pytest.raises(StereoError, match="needs CuPy"):
        match_gpu_sgm(img, img, GpuSgmConfig(max_disparity_px=8))


@pytest.mark.gpu
@needs_gpu
def test_constant_shift_is_recovered(rng):
    left, right = _textured_pair(rng)
    disp, timings = match_gpu_sgm(left, right, GpuSgmConfig(max_disparity_px=31))
    inner = disp[10:-10, 40:-10]
    assert np.isfinite(inner).mean() > 0.95
    assert np.nanmedian(np.abs(inner - 7.0)) < SHIFT_TOL_PX
    assert timings["match_s"] > 0


@pytest.mark.gpu
@needs_gpu
def test_agrees_with_the_cpu_engine(rng):
    from sea3d.stereo import SgmConfig, match

    left, right = _textured_pair(rng, h=160, w=240, shift=12)
    gpu, _ = match_gpu_sgm(left, right, GpuSgmConfig(max_disparity_px=47))
    cpu = match(left, right, SgmConfig(max_disparity_px=47, pyramid_levels=0,
                                       fill_max_px=0)).disparity_px
    both = np.isfinite(gpu) & np.isfinite(cpu)
    assert both.mean() > 0.8
    assert np.median(np.abs(gpu[both] - cpu[both])) < SHIFT_TOL_PX


@pytest.mark.gpu
@needs_gpu
def test_bad_input(rng):
    a = np.zeros((20, 40), np.uint8)
    with pytest.raises(StereoError, match="differ in size"):
        match_gpu_sgm(a, np.zeros((20, 41), np.uint8), GpuSgmConfig(max_disparity_px=8))
    with pytest.raises(StereoError, match="as wide as the image"):
        match_gpu_sgm(a, a, GpuSgmConfig(max_disparity_px=60))


def test_engine_name_selects_the_gpu_config():
    from sea3d.stereo import make_config

    config = make_config("sea3d-gpu", 64)
    assert isinstance(config, GpuSgmConfig)
    assert config.max_disparity_px == 64
