"""Configurations and the result type shared by every matching engine.

Conventions (``docs/conventions.md``): images are ``(H, W)`` or ``(H, W, 3)`` RGB, already
rectified so that a scene point on row ``v`` of the left image lies on row ``v`` of the right
image at ``u_right = u_left - d``; disparity is float32 pixels with NaN where invalid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError

__all__ = ["DisparityResult", "OpenCVSgbmConfig", "SgmConfig"]

OpenCVMode = Literal["sgbm", "hh", "sgbm_3way", "hh4"]
SubpixelMode = Literal["none", "parabola", "equiangular"]


def _check_common(max_disparity_px: int) -> None:
    if int(max_disparity_px) != max_disparity_px or max_disparity_px < 1:
        raise ConfigError(f"max_disparity_px must be a positive integer, got {max_disparity_px!r}")


@dataclass(frozen=True, kw_only=True)
class SgmConfig:
    """sea3d's own semi-global matcher (census costs, 8 or 16 paths, coarse-to-fine).

    The search range is ``0 <= d <= max_disparity_px`` (``max_disparity_px + 1`` candidates).
    """

    max_disparity_px: int = 63
    """Largest disparity searched, pixels (inclusive)."""
    census_width_px: int = 9
    """Census window width, pixels (odd; width * height <= 65)."""
    census_height_px: int = 7
    """Census window height, pixels (odd)."""
    census_presmooth_px: float = 0.5
    """Gaussian sigma (pixels) of a light smoothing of both images before the census; it
    keeps the census bits of low-contrast, hazy texture from flipping with noise and sampling
    phase (0 disables). The alignment refinement uses the unsmoothed images."""
    p1: int = 9
    """Penalty for a disparity change of one pixel between path neighbours (census bits)."""
    p2: int = 100
    """Penalty for larger disparity changes on a flat image; lowered across image edges."""
    p2_edge_tau: float = 12.0
    """Intensity step (grey levels of 0-255) at which P2 halves: P2 * tau / (tau + |dI|)."""
    paths: Literal[8, 16] = 8
    """Number of aggregation paths."""
    subpixel: SubpixelMode = "parabola"
    """Subpixel refinement of the winning disparity."""
    uniqueness: float = 0.03
    """Minimum relative cost margin of the winner over the best non-neighbouring disparity."""
    lr_max_diff_px: int = 1
    """Left-right consistency tolerance, pixels; negative disables the check."""
    pyramid_levels: int | None = None
    """Coarse-to-fine levels above full resolution; None chooses from the image size and range."""
    full_search_budget: int = 24_000_000
    """With ``pyramid_levels=None``: search the full range at once if H * W * D stays below."""
    coarse_search_budget: int = 2_000_000
    """With ``pyramid_levels=None``: otherwise add levels until the coarsest full volume
    (H * W * D, each halved per level) stays below this."""
    trial_step_fraction: float = 0.01
    """With ``pyramid_levels=None`` and a full volume inside ``full_search_budget``: match one
    level coarser first and keep searching only a band around its answer (with ``paths``) when
    fewer than this fraction of the full-resolution pixels need a band wider than one chunk of
    16 (the coarse map's depth steps, where a coarse level misplaces thin structures); else
    search the full range. Measured: 0.000 on the simulated dive's sea floor and on venus,
    0.027-0.030 on cones and teddy, whose full search is the more accurate. 0 always searches
    the full range."""
    band_margin_px: int = 2
    """Coarse-to-fine: extra disparities searched on each side of the coarse estimate."""
    band_max_px: int = 48
    """Coarse-to-fine: widest per-pixel search band, disparities (a multiple of 16). Bands
    come in chunks of 16 centred on the range of the coarse disparities around the pixel; where
    that range is wider than this, on the coarse disparity at the pixel itself."""
    band_paths: Literal[4, 8, 16] = 4
    """Coarse-to-fine: paths aggregated on the banded (finer) levels. The coarsest level
    (and a full search) always uses ``paths``; within a narrow band around the coarse answer
    4 paths (horizontal and vertical) measured as accurate as 8 on Middlebury and synthetic
    1080p scenes, at half the cost."""
    band_radius_px: int = 1
    """Coarse-to-fine: half-size of the coarse window whose disparities span the band."""
    refine_iterations: int = 1
    """Gauss-Newton steps of direct image alignment (gain, offset, disparity) that refine each
    disparity after the cost-curve fit, removing its pixel-locking bias; 0 disables."""
    refine_window_px: int = 15
    """Odd window size of that refinement, pixels (3..15)."""
    refine_row_step: int = 3
    """The refinement reads every this many rows of its window, symmetrically about the centre
    (15 px window, step 3: rows -6, -3, 0, 3, 6): the same reach for a third of the work,
    measured within 0.003 px EPE of reading every row on Middlebury and the coastal pairs."""
    refine_weight_cutoff: float = 40.0
    """Window pixels in the refinement weigh ``(1 - (dI / c)^2)^2`` (Tukey's biweight of their
    grey-level difference ``dI`` to the centre, 0 beyond ``c``), so a window straddling an
    edge leans on the centre's side; 0 weighs all alike."""
    median_px: int = 3
    """Size of the NaN-aware median filter applied to the result (0 or 1 disables)."""
    speckle_size_px: int = 100
    """Speckle removal: largest connected blob (pixels) that is removed; 0 disables."""
    speckle_range_px: float = 2.0
    """Speckle removal: disparity step that separates blobs, pixels."""
    fill_max_px: int | None = None
    """Fill invalid pixels along rows with the farther (background) of their two valid
    neighbours, as suits occlusions: ``None`` (default) fills every hole, so the disparity is
    dense; ``N`` fills runs of up to ``N`` pixels; 0 leaves every invalid pixel NaN. Filled
    pixels get confidence 0, so users who fuse 3D can drop them (``sea3d depth`` does)."""

    def __post_init__(self) -> None:
        _check_common(self.max_disparity_px)
        for name in ("census_width_px", "census_height_px"):
            v = getattr(self, name)
            if v < 1 or v % 2 == 0:
                raise ConfigError(f"{name} must be an odd positive integer, got {v}")
        if self.census_width_px * self.census_height_px > 65:
            raise ConfigError(
                "census window too large for 64-bit signatures: "
                f"{self.census_width_px}x{self.census_height_px}"
            )
        if not (0 < self.p1 < self.p2 <= 1500):
            raise ConfigError(f"need 0 < p1 < p2 <= 1500, got p1={self.p1}, p2={self.p2}")
        if self.paths not in (8, 16):
            raise ConfigError(f"paths must be 8 or 16, got {self.paths}")
        if self.band_paths not in (4, 8, 16):
            raise ConfigError(f"band_paths must be 4, 8 or 16, got {self.band_paths}")
        if self.subpixel not in ("none", "parabola", "equiangular"):
            raise ConfigError(f"unknown subpixel mode {self.subpixel!r}")
        if self.pyramid_levels is not None and not (0 <= self.pyramid_levels <= 6):
            raise ConfigError(f"pyramid_levels must be in 0..6, got {self.pyramid_levels}")
        if self.band_max_px < 16 or self.band_max_px % 16 or self.band_margin_px < 0:
            raise ConfigError(
                f"band_max_px must be a positive multiple of 16, got {self.band_max_px}; "
                f"band_margin_px must be >= 0, got {self.band_margin_px}"
            )
        if self.refine_window_px % 2 == 0 or not (3 <= self.refine_window_px <= 15):
            raise ConfigError(
                f"refine_window_px must be odd and in 3..15, got {self.refine_window_px}"
            )
        if self.census_presmooth_px < 0 or self.refine_weight_cutoff < 0:
            raise ConfigError("census_presmooth_px and refine_weight_cutoff must be >= 0")
        if self.fill_max_px is not None and self.fill_max_px < 0:
            raise ConfigError(f"fill_max_px must be None or >= 0, got {self.fill_max_px}")
        if self.refine_row_step < 1:
            raise ConfigError(f"refine_row_step must be >= 1, got {self.refine_row_step}")
        if not 0 <= self.trial_step_fraction <= 1:
            raise ConfigError(
                f"trial_step_fraction must be in 0..1, got {self.trial_step_fraction}")
        if self.p2_edge_tau <= 0 or self.uniqueness < 0:
            raise ConfigError("p2_edge_tau must be > 0 and uniqueness >= 0")


@dataclass(frozen=True, kw_only=True)
class OpenCVSgbmConfig:
    """OpenCV's StereoSGBM, the reference engine.

    The search range ``0 <= d <= max_disparity_px`` is widened to OpenCV's ``numDisparities``,
    the next multiple of 16. Penalties follow OpenCV's advice: ``P1 = 8 * C * w^2``,
    ``P2 = 32 * C * w^2`` with ``C`` channels and block size ``w``. The output is descaled from
    OpenCV's fixed point (value / 16) and invalid pixels become NaN.
    """

    max_disparity_px: int = 63
    """Largest disparity searched, pixels (inclusive; rounded up to a multiple of 16 minus 1)."""
    mode: OpenCVMode = "sgbm"
    """``sgbm`` (5 paths), ``hh`` (8 paths, full volume), ``sgbm_3way``, ``hh4``."""
    block_size_px: int = 5
    """Matched block size, pixels (odd)."""
    uniqueness_ratio: int = 10
    """OpenCV's uniquenessRatio, percent."""
    disp12_max_diff_px: int = 1
    """Left-right check tolerance, pixels; negative disables."""
    speckle_window_px: int = 100
    """Speckle filter blob size, pixels; 0 disables."""
    speckle_range_px: int = 2
    """Speckle filter disparity step, pixels."""
    pre_filter_cap: int = 63
    """OpenCV's preFilterCap."""
    use_color: bool = False
    """Match RGB (C = 3) instead of grey (C = 1)."""

    def __post_init__(self) -> None:
        _check_common(self.max_disparity_px)
        if self.mode not in ("sgbm", "hh", "sgbm_3way", "hh4"):
            raise ConfigError(f"unknown OpenCV SGBM mode {self.mode!r}")
        if self.block_size_px < 1 or self.block_size_px % 2 == 0:
            raise ConfigError(f"block_size_px must be odd and positive, got {self.block_size_px}")

    @property
    def num_disparities(self) -> int:
        """OpenCV's numDisparities: ``max_disparity_px + 1`` rounded up to a multiple of 16."""
        return int(-(-(self.max_disparity_px + 1) // 16) * 16)


@dataclass(frozen=True, kw_only=True, eq=False)
class DisparityResult:
    """The output of every engine.

    Attributes:
        disparity_px: ``(H, W)`` float32, left view, pixels; NaN where invalid.
        confidence: ``(H, W)`` float32 in [0, 1]; 0 where invalid or filled (not matched).
            Engines without a confidence measure give 1 on valid pixels.
        timings_s: wall-clock seconds per stage; ``match_s`` is the whole matching call
            without start-up (JIT compilation) and file I/O.
        engine: engine name, ``"sea3d"`` or ``"opencv"``.
    """

    disparity_px: NDArray[np.float32]
    confidence: NDArray[np.float32]
    timings_s: dict[str, float] = field(default_factory=dict)
    engine: str = ""

    @property
    def measured(self) -> NDArray[np.bool_]:
        """``(H, W)`` bool: pixels matched, not filled (valid with confidence > 0)."""
        return self.valid & (self.confidence > 0)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """``(H, W)`` bool: pixels with a finite disparity."""
        return np.isfinite(self.disparity_px)

    @property
    def valid_fraction(self) -> float:
        """Fraction of pixels with a valid disparity, in [0, 1]."""
        return float(self.valid.mean()) if self.disparity_px.size else 0.0
