"""The nested parts of :class:`~sea3d.pipeline.process.ProcessConfig`, one per stage: light to
import, so that the CLI takes its option defaults from them (each default written once)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from sea3d.errors import ConfigError

if TYPE_CHECKING:
    from sea3d.odometry.config import OdometryConfig
    from sea3d.pipeline.colour_stage import DiveColourConfig
    from sea3d.recon.submaps import FusionConfig

__all__ = ["RESTORE_COLOURS", "ColourConfig", "ExecutorConfig", "MapConfig", "PoseConfig"]


DISPARITY_NOISE_PX = 0.25
"""Sub-pixel SGM's disparity noise, pixels (the planner's figure,
:class:`sea3d.stereo.planning.PlanConfig`): the carving margin's standard error."""


@dataclass(frozen=True, kw_only=True)
class MapConfig:
    """How the depth maps become a map: fusion into TSDF submaps, then the merge."""

    voxel_m: float = 0.02
    """TSDF voxel edge, metres."""
    integrate: Literal["trusted", "keyframes"] = "trusted"
    """Fuse every frame with a trusted pose, or keyframes only."""
    keyframes_per_submap: int = 20
    """Keyframes per TSDF submap."""
    max_submap_blocks: int = 20_000
    """Voxel blocks after which a submap is finished (bounds memory: 10 KB per block of 8^3
    voxels)."""
    cloud_voxel_m: float | None = None
    """Voxel of cloud.ply's downsampling; None: half ``voxel_m``."""
    merge_tile_m: float | None = 2.0
    """Edge of the tiles the final merge works through (bounds its memory: what one tile's
    voxels and their sums hold; the mesh is the same whatever the tiles)."""
    min_observations: int = 2
    """Mesh and cloud keep the voxels fused from at least this many depth frames (summed over
    the submaps): a surface seen once, the floater one frame's wrong depth leaves, is dropped;
    1 keeps every voxel seen."""
    min_piece_triangles: int = 100
    """Mesh pieces (triangles connected to each other) of fewer triangles than this, and the
    cloud's points on them, are dropped: the specks one frame's wrong depth leaves in open
    water (about 7x7 voxels, 14 cm across at 2 cm voxels; a piece of the scene that size lies
    on the surface and is connected to it); 0 keeps every piece."""
    hole_margin_px: int = 0
    """Depth pixels within this many pixels of a pixel without depth are not fused (where
    stereo's wrong depth gathers; it also loses true surface beside wide holes: 0 fuses every
    pixel with depth; docs/reconstruction.md, Floaters)."""
    carve_free_space: bool = False
    """Each frame takes an observation from the voxels of its submap that it sees through
    (by more than the truncation plus three standard errors of 0.25 px of disparity)."""
    min_confidence: float = 0.0
    """Depth pixels whose matching confidence is below this are not fused; 0 fuses every
    pixel with depth."""
    confidence_full: float | None = None
    """Weight each depth pixel's observation by ``min(1, confidence / confidence_full)``
    (the voxel counts of ``min_observations`` then count confident observations); None:
    every observation weighs 1."""

    def __post_init__(self) -> None:
        if not self.voxel_m > 0:
            raise ConfigError(f"voxel_m must be > 0, got {self.voxel_m}")
        if self.min_observations < 1:
            raise ConfigError(f"min_observations must be >= 1, got {self.min_observations}")
        if self.min_piece_triangles < 0:
            raise ConfigError(f"min_piece_triangles must be >= 0, got {self.min_piece_triangles}")
        if not 0 <= self.hole_margin_px <= 16:
            raise ConfigError(f"hole_margin_px must be 0..16, got {self.hole_margin_px}")
        if not 0 <= self.min_confidence < 1:
            raise ConfigError(f"min_confidence must be in [0, 1), got {self.min_confidence}")
        if self.confidence_full is not None and not 0 < self.confidence_full <= 1:
            raise ConfigError(f"confidence_full must be in (0, 1], got {self.confidence_full}")

    def fusion(self, depth_range_m: tuple[float, float], *,
               min_observations: int | None = None,
               focal_baseline_px_m: float | None = None) -> FusionConfig:
        """The fusion stage's configuration (its TSDF over the stereo depth's range);
        ``min_observations`` overrides the field (``live`` keeps voxels seen once: it fuses
        only the depth frames it keeps up with); ``focal_baseline_px_m``, the rectified
        rig's ``f B``, sizes the carving margin (None: the truncation band alone)."""
        n_obs = self.min_observations if min_observations is None else min_observations
        if n_obs < 1:
            raise ConfigError(f"min_observations must be >= 1, got {n_obs}")
        from sea3d.recon.submaps import FusionConfig
        from sea3d.recon.tsdf import TsdfConfig

        noise_per_m = (0.0 if not focal_baseline_px_m or focal_baseline_px_m <= 0
                       else DISPARITY_NOISE_PX / focal_baseline_px_m)
        return FusionConfig(tsdf=TsdfConfig(voxel_m=self.voxel_m, min_depth_m=depth_range_m[0],
                                            max_depth_m=depth_range_m[1],
                                            weight_threshold=n_obs - 0.5,
                                            hole_margin_px=self.hole_margin_px,
                                            carve_free_space=self.carve_free_space,
                                            depth_noise_per_m=noise_per_m,
                                            min_confidence=self.min_confidence,
                                            confidence_full=self.confidence_full),
                            integrate=self.integrate,
                            keyframes_per_submap=self.keyframes_per_submap,
                            max_blocks=self.max_submap_blocks)


@dataclass(frozen=True, kw_only=True)
class PoseConfig:
    """Where the poses come from: odometry (with or without the IMU), or a known trajectory."""

    use_imu: bool = True
    """Give the IMU to the odometry (``--no-imu``: visual only)."""
    poses_path: Path | None = None
    """Known poses (TUM, KITTI or EuRoC CSV of ``T_world_left``) instead of odometry."""
    odometry_config: OdometryConfig | None = None
    """Passed to ``create_odometry`` (None: its defaults)."""

    @property
    def imu_max_clock_offset_s(self) -> float:
        """The odometry's tolerance of an IMU clock against the camera's, seconds (the IMU
        decision checks the stamps with it before any odometry is made)."""
        if self.odometry_config is not None:
            return self.odometry_config.imu_max_clock_offset_s
        from sea3d.odometry.config import OdometryConfig  # the odometry loads when it runs

        return OdometryConfig().imu_max_clock_offset_s


@dataclass(frozen=True, kw_only=True)
class ColourConfig:
    """The colours of the images matched and of the mesh."""

    enhance: Any = None
    """Enhancement hook of the per-frame stage (see :class:`FrameStageConfig`)."""
    restore_colours: Literal["none", "seathru", "water-model", "seathru-per-image"] = "none"
    """The output colours after depth: ``seathru`` (or its older name ``water-model``), one
    water model fitted to the dive's first frames in the client and every frame restored with
    it (:mod:`sea3d.pipeline.colour_stage`; an inversion per frame, cheaper than matching);
    ``seathru-per-image``, a Sea-thru fitted to each image alone in the per-frame stage
    (:class:`FrameStageConfig`; seconds per frame)."""
    dive_colours: DiveColourConfig | None = None
    """How ``seathru`` fits the dive's model (None: :class:`DiveColourConfig`'s
    defaults)."""

    def __post_init__(self) -> None:
        if self.restore_colours not in RESTORE_COLOURS:
            raise ConfigError(f"restore_colours must be one of {', '.join(RESTORE_COLOURS)}, "
                              f"got {self.restore_colours!r}")

    @property
    def per_dive(self) -> bool:
        """Whether the colours come from the dive's one water model."""
        return self.restore_colours in ("seathru", "water-model")

    @property
    def per_image(self) -> bool:
        """Whether each image gets its own Sea-thru in the per-frame stage."""
        return self.restore_colours == "seathru-per-image"


RESTORE_COLOURS = ("none", "seathru", "water-model", "seathru-per-image")
"""The values of :attr:`ColourConfig.restore_colours`."""


@dataclass(frozen=True, kw_only=True)
class ExecutorConfig:
    """Where the per-frame stage runs."""

    workers: int | None = None
    """Local worker processes for the per-frame stage; None: one per core; 0: inline."""
    scheduler: str | Any | None = None
    """A Dask scheduler address (``tcp://HOST:PORT``) or ``distributed.Client``."""
    in_flight: int | None = None
    """Frames between reader and ordered stages at most; None: 2 per worker + 2."""

    def __post_init__(self) -> None:
        if self.workers is not None and self.scheduler is not None:
            raise ConfigError("give either workers or scheduler, not both")
        if self.workers is not None and self.workers < 0:
            raise ConfigError(f"workers must be >= 0, got {self.workers}")
        if self.in_flight is not None and self.in_flight < 1:
            raise ConfigError(f"in_flight must be >= 1, got {self.in_flight}")
