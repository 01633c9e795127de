"""Configuration, input frames and results of structure from motion.

Frames (``docs/conventions.md``): ``world`` is the model's world (COLMAP's arbitrary one for a
monocular model without priors, metric when the stereo rig or metric pose priors fix the scale);
``left``/``right`` the raw cameras. Poses are ``T_world_left`` (maps left-camera points into the
world). Pixels: ours (integer values at pixel centres); COLMAP's files put pixel centres at
``+0.5``, and the conversion happens once, where sea3d talks to pycolmap.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError
from sea3d.rectify.maps import VirtualPinholeReport

__all__ = [
    "CAMERAS",
    "MATCHERS",
    "ImageLike",
    "PosePriors",
    "RefractiveBaReport",
    "SfmConfig",
    "SfmFrame",
    "SfmResult",
]

ImageLike = np.ndarray | Callable[[], np.ndarray]
"""An image (``(H, W)`` or ``(H, W, 3)`` RGB, uint8 or uint16) or a function that loads it."""

CAMERAS = ("left", "right", "stereo")
MATCHERS = ("sequential", "exhaustive")
SELF_CALIBRATION_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


@dataclass(frozen=True, kw_only=True)
class SfmConfig:
    """How to run structure from motion (one object serves the library call and the CLI).

    Attributes:
        camera: ``left``, ``right`` (one camera of each frame) or ``stereo`` (both, as one
            COLMAP rig with the calibrated extrinsics held fixed: the model comes out metric).
        matcher: ``sequential`` (video: each frame against the next ``sequential_overlap``
            frames, plus frames 2, 4, 8 ... apart) or ``exhaustive`` (every pair; small sets).
        max_image_px: SIFT runs on images downscaled so their longer side is at most this
            (keypoints are scaled back; the model keeps the full size).
        max_features: most SIFT features per image.
        sift_first_octave: COLMAP's ``first_octave``: -1 (COLMAP's default) upsamples first,
            for finer, better localised features (field data: 0.43 px mean reprojection error
            against 0.73 px with 0) at about 3x the extraction time; 0 works on the image as it
            is (the ``fast`` preset).
        sift_peak_threshold: SIFT's contrast threshold (COLMAP's default 0.0067; with
            ``first_octave=0`` hazy underwater images need about 0.001).
        sequential_overlap: frames ahead each frame is matched with (sequential matcher).
        ba_global_ratio: COLMAP runs a global bundle adjustment each time the model grew by
            this factor (its default 1.1; 1.25 saves about a third of the mapping time on video,
            the final global adjustment is the same).
        self_calibration_model: COLMAP camera model refined when no rig is given.
        depth_range_m: working range (near, far) in metres: where the virtual pinhole of a
            port camera is fitted and its residual reported.
        refractive_ba: ``auto`` (run the refractive bundle adjustment when the virtual
            pinhole's residual over the working range exceeds ``refractive_ba_threshold_px``),
            ``on`` or ``off``.
        refractive_ba_threshold_px: see ``refractive_ba``.
        prior_position_std_m: standard deviation of pose-prior positions, metres.
        prior_max_gap_s: a frame gets a prior only if the prior trajectory has a sample within
            this time (positions are interpolated linearly between samples).
        min_frames: fewer frames than this is an error.
        num_threads: worker threads/processes (-1: all cores).
        seed: random seed of COLMAP's RANSAC and mapper (the same seed, the same model).
    """

    camera: str = "left"
    matcher: str = "sequential"
    max_image_px: int = 1600
    max_features: int = 4096
    sift_first_octave: int = -1
    sift_peak_threshold: float = 0.0067
    sequential_overlap: int = 6
    ba_global_ratio: float = 1.25
    self_calibration_model: str = "SIMPLE_RADIAL"
    depth_range_m: tuple[float, float] = (0.5, 10.0)
    refractive_ba: str = "auto"
    refractive_ba_threshold_px: float = 0.25
    prior_position_std_m: float = 0.05
    prior_max_gap_s: float = 0.5
    min_frames: int = 3
    num_threads: int = -1
    seed: int = 0

    @classmethod
    def fast(cls, **overrides: Any) -> SfmConfig:
        """A preset about 2.5x faster and less precise: SIFT without upsampling
        (``first_octave=0``, ``peak_threshold=0.001``)."""
        return cls(**{"sift_first_octave": 0, "sift_peak_threshold": 0.001, **overrides})

    def __post_init__(self) -> None:
        if self.camera not in CAMERAS:
            raise ConfigError(f"camera must be one of {', '.join(CAMERAS)}, got {self.camera!r}")
        if self.matcher not in MATCHERS:
            raise ConfigError(
                f"matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}"
            )
        if self.refractive_ba not in ("auto", "on", "off"):
            raise ConfigError(f"refractive_ba must be auto, on or off, got {self.refractive_ba!r}")
        if self.self_calibration_model not in SELF_CALIBRATION_MODELS:
            raise ConfigError(
                f"self_calibration_model must be one of {', '.join(SELF_CALIBRATION_MODELS)}, "
                f"got {self.self_calibration_model!r}"
            )
        if self.max_image_px < 64 or self.max_features < 64:
            raise ConfigError(
                f"max_image_px and max_features must be >= 64, got {self.max_image_px} and "
                f"{self.max_features}"
            )
        if self.sequential_overlap < 1 or self.min_frames < 2:
            raise ConfigError(
                f"sequential_overlap must be >= 1 and min_frames >= 2, got "
                f"{self.sequential_overlap} and {self.min_frames}"
            )
        near, far = self.depth_range_m
        if not 0 < near < far:
            raise ConfigError(
                f"depth_range_m must satisfy 0 < near < far, got {self.depth_range_m}"
            )
        if not self.ba_global_ratio > 1.0:
            raise ConfigError(f"ba_global_ratio must be > 1, got {self.ba_global_ratio}")
        if not self.prior_position_std_m > 0 or not self.prior_max_gap_s > 0:
            raise ConfigError("prior_position_std_m and prior_max_gap_s must be > 0")


@dataclass(frozen=True, kw_only=True, eq=False)
class SfmFrame:
    """One frame of the input: an image (or a stereo pair) and its time.

    Attributes:
        name: unique, file-name-safe name (the COLMAP image is ``left/<name>.png``).
        t_s: time in seconds (the session's time, or the index for an image glob); written to
            ``trajectory.tum``.
        left: the left (or only) image, or a loader.
        right: the right image, or a loader, or None.
        source: where the frame came from (a path, ``session.mcap t_ns=...``), for messages.
    """

    name: str
    t_s: float
    left: ImageLike
    right: ImageLike | None = None
    source: str = ""


@dataclass(frozen=True, kw_only=True, eq=False)
class PosePriors:
    """Positions of the left camera over time (e.g. from odometry or ground truth).

    Attributes:
        t_s: ``(N,)`` increasing times, seconds (the frames' ``t_s`` clock).
        T_world_left: ``(N, 4, 4)`` poses; their positions become COLMAP position priors.
        source: where they came from (a file name), for messages.
    """

    t_s: F64
    T_world_left: F64
    source: str = ""


@dataclass(frozen=True, kw_only=True)
class RefractiveBaReport:
    """What the refractive bundle adjustment did.

    Attributes:
        observations: observations used.
        rms_before_px, rms_after_px: RMS ray residual (angular error times the focal length,
            pixels) before and after, over the inliers.
        iterations: solver iterations (function evaluations).
        time_s: seconds.
    """

    observations: int
    rms_before_px: float
    rms_after_px: float
    iterations: int
    time_s: float


@dataclass(frozen=True, kw_only=True, eq=False)
class SfmResult:
    """A structure-from-motion model.

    Attributes:
        status: ``ok`` (every frame registered), ``partial`` (some frames not registered) or
            ``failed`` (no model: no overlap, too few matches); ``message`` says why.
        message: one line for the user.
        frames: number of input frames.
        images: number of input images (twice ``frames`` for ``camera="stereo"``).
        names: names of the registered frames, in input order.
        t_s: ``(M,)`` their times, seconds.
        T_world_left: ``(M, 4, 4)`` their left-camera poses (the right camera's own pose for
            ``camera="right"`` without a rig).
        registered_images: registered images.
        points_world: ``(P, 3)`` float64 3D points, world frame (metres when ``metric``).
        colors_rgb: ``(P, 3)`` uint8 point colours.
        point_error_px: ``(P,)`` mean reprojection error of each point, pixels.
        mean_reprojection_error_px: over all observations (COLMAP's figure), pixels.
        metric: True when the scale is metric (stereo rig, or metric pose priors).
        models: number of disconnected models COLMAP found (the largest is returned).
        cameras: ``{"left": {...}, ...}`` the COLMAP camera (model, parameters) per sensor.
        virtual: ``{"left": VirtualPinholeReport, ...}`` for port cameras remapped into a
            virtual pinhole (residual over the working range).
        refractive_ba: report of the refractive bundle adjustment, or None.
        timings_s: wall seconds per stage (``prepare_s``, ``extract_s``, ``match_s``,
            ``map_s``, ``refractive_ba_s``, ``total_s``) and CPU seconds of the three COLMAP
            stages (``extract_cpu_s``, ``match_cpu_s``, ``map_cpu_s``: all threads and worker
            processes).
        reconstruction: the ``pycolmap.Reconstruction`` (write it with
            :func:`sea3d.io.sfm_files.write_colmap_model`); None when failed.
    """

    status: str
    message: str
    frames: int
    images: int
    names: list[str]
    t_s: F64
    T_world_left: F64
    registered_images: int
    points_world: F64
    colors_rgb: NDArray[np.uint8]
    point_error_px: F64
    mean_reprojection_error_px: float
    metric: bool
    models: int
    cameras: dict[str, dict[str, Any]] = field(default_factory=dict)
    virtual: dict[str, VirtualPinholeReport] = field(default_factory=dict)
    refractive_ba: RefractiveBaReport | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    reconstruction: Any = field(default=None, repr=False)

    @property
    def registered(self) -> int:
        """Registered frames."""
        return len(self.names)
