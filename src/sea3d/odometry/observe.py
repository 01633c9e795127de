"""Frame observations from raw stereo pairs, one at a time (the sequential path).

``sea3d odometry SESSION`` uses :class:`Observer` to compute each pair's refraction-corrected
depth with one :class:`~sea3d.stereo.recipe.StereoDepth` and hand it, with the rectified pair,
to the odometry; ``sea3d process`` computes depth in parallel workers instead and builds the
same :class:`~sea3d.odometry.types.FrameObservation`. :func:`imu_chunks` slices a session's IMU
series into the samples between consecutive frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError
from sea3d.odometry.types import FrameObservation, ImuChunk
from sea3d.rectify.maps import RectifyMaps, rectify_images
from sea3d.stereo.engine import EngineConfig
from sea3d.stereo.recipe import DepthConfig, StereoDepth

__all__ = ["ObserveConfig", "Observer", "imu_chunks"]

ObserveConfig = DepthConfig
"""How depth is computed for the odometry: a :class:`~sea3d.stereo.recipe.DepthConfig`
(engine, disparity and depth range; None ranges come from the rig)."""


@dataclass
class Observer:
    """Builds :class:`FrameObservation` s of one rig.

    Args:
        stereo: the rig's :class:`~sea3d.stereo.recipe.StereoDepth` (its maps are the
            odometry's rectification).
    """

    stereo: StereoDepth

    def __post_init__(self) -> None:
        if not isinstance(self.stereo, StereoDepth):
            raise ConfigError(f"Observer needs a StereoDepth, got {type(self.stereo).__name__}")

    @property
    def maps(self) -> RectifyMaps:
        """The rig's rectification."""
        return self.stereo.maps

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """``(min, max)`` depth kept, metres (the rig's, unless the config gives them)."""
        return self.stereo.depth_range_m

    def engine(self) -> EngineConfig:
        """The stereo engine config in use."""
        return self.stereo.engine_config

    def observe(
        self,
        t_ns: int,
        left: NDArray[np.uint8],
        right: NDArray[np.uint8],
        imu: ImuChunk | None = None,
    ) -> FrameObservation:
        """Rectify a raw pair, compute its depth and package both.

        Raises:
            RectifyError: images of the wrong size. StereoError: unusable images.
        """
        left8 = _to_uint8(left)
        right8 = _to_uint8(right)
        res = self.stereo.compute(left8, right8)
        maps = self.stereo.maps
        _, rect_right = rectify_images(maps, left8, right8)
        return FrameObservation(
            t_ns=int(t_ns),
            rect_left=np.asarray(res.rect_left, dtype=np.uint8),
            rect_right=np.asarray(rect_right, dtype=np.uint8),
            depth_m=res.depth_m,
            K_rect=np.asarray(maps.P_left[:3, :3], dtype=np.float64),
            baseline_m=float(maps.baseline_m),
            R_rect_left_left=np.asarray(maps.R_rect_left_left, dtype=np.float64),
            imu=imu,
        )


def _to_uint8(img: NDArray[np.generic]) -> NDArray[np.uint8]:
    if img.dtype == np.uint8:
        return np.asarray(img)
    top = float(np.iinfo(img.dtype).max) if np.issubdtype(img.dtype, np.integer) else 1.0  # type: ignore[type-var]
    return np.clip(np.asarray(img, np.float64) * (255.0 / top), 0, 255).astype(np.uint8)


def imu_chunks(
    frame_t_ns: NDArray[np.int64],
    imu_t_ns: NDArray[np.int64],
    accel_mps2: NDArray[np.float64],
    gyro_radps: NDArray[np.float64],
) -> list[ImuChunk | None]:
    """Slice an IMU series into per-frame chunks: frame ``i`` gets the samples with
    ``t_{i-1} < t <= t_i`` (the first frame every sample up to its stamp); None where a frame
    has no sample."""
    frame_t = np.asarray(frame_t_ns, dtype=np.int64)
    t = np.asarray(imu_t_ns, dtype=np.int64)
    hi = np.searchsorted(t, frame_t, side="right")
    lo = np.concatenate([[0], hi[:-1]])
    out: list[ImuChunk | None] = []
    for a, b in zip(lo.tolist(), hi.tolist(), strict=True):
        if b <= a:
            out.append(None)
            continue
        out.append(
            ImuChunk(
                t_ns=t[a:b].copy(),
                accel_mps2=np.asarray(accel_mps2[a:b], dtype=np.float64),
                gyro_radps=np.asarray(gyro_radps[a:b], dtype=np.float64),
            )
        )
    return out
