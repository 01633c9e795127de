"""Frame observations from raw stereo pairs, one at a time (the sequential path).

``sea3d odometry SESSION`` uses :class:`Observer` to rectify each pair, compute its
refraction-corrected depth with :func:`sea3d.stereo.depth.compute_depth` and hand both to the
odometry; ``sea3d process`` computes depth in parallel workers instead and builds the same
:class:`~sea3d.odometry.types.FrameObservation`. :func:`imu_chunks` slices a session's IMU
series into the samples between consecutive frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sea3d.geometry.rig import StereoRig
from sea3d.odometry.types import FrameObservation, ImuChunk
from sea3d.rectify.maps import RectifyMaps, rectify_images
from sea3d.stereo.depth import compute_depth, max_disparity_for_depth
from sea3d.stereo.engine import EngineConfig, make_config
from sea3d.stereo.recipe import (
    MIN_USEFUL_DISPARITY_PX,
    DepthConfig,
    StereoDepth,
    default_max_disparity,
)

__all__ = ["ObserveConfig", "Observer", "imu_chunks"]


@dataclass(frozen=True, kw_only=True)
class ObserveConfig:
    """How depth is computed for the odometry (the fields of
    :class:`~sea3d.stereo.recipe.DepthConfig` the odometry exposes).

    Attributes:
        engine: stereo engine (``sea3d``, ``sea3d-gpu``, ``opencv``, ...; see
            :func:`sea3d.stereo.make_config`).
        min_depth_m: nearest depth searched (sets the disparity range), metres; None: from the
            rig, ``f B / d_max`` with OpenCV's disparity range for the image width.
        max_depth_m: depths beyond this are dropped, metres; None: from the rig, ``f B / 4 px``
            (the farthest depth whose relative error stays near 1/16; KITTI's car rig: 97 m).
        max_disparity_px: disparity search range, pixels; None: from ``min_depth_m`` or the
            image width.
    """

    engine: str = "sea3d"
    min_depth_m: float | None = None
    max_depth_m: float | None = None
    max_disparity_px: int | None = None

    def __post_init__(self) -> None:
        self.depth_config()  # the same checks as every other command's depth

    def depth_config(self) -> DepthConfig:
        """This configuration as the one depth recipe's :class:`DepthConfig`.

        Raises:
            ConfigError: an unknown engine or an empty depth range.
        """
        return DepthConfig(
            engine=self.engine,
            min_depth_m=self.min_depth_m,
            max_depth_m=self.max_depth_m,
            max_disparity_px=self.max_disparity_px,
        )


@dataclass
class Observer:
    """Builds :class:`FrameObservation` s of one rig.

    Build it with :meth:`for_rig` (the one depth recipe,
    :class:`~sea3d.stereo.recipe.StereoDepth`: ranges from the rig and the port). Built from
    bare rectification ``maps`` (older callers) the same rules apply to the rectified ``f B``.

    Args:
        maps: the rig's rectification.
        config: :class:`ObserveConfig`.
    """

    maps: RectifyMaps
    config: ObserveConfig = field(default_factory=ObserveConfig)
    _engine: EngineConfig | None = None
    _stereo: StereoDepth | None = None

    @classmethod
    def for_rig(cls, rig: StereoRig, config: ObserveConfig | None = None) -> Observer:
        """An observer whose depth is :class:`StereoDepth` ``(rig, config.depth_config())``.

        Raises:
            ConfigError: a depth range the rig cannot meet. RectifyError: an unrectifiable rig.
        """
        cfg = config or ObserveConfig()
        stereo = StereoDepth(rig, cfg.depth_config())
        return cls(maps=stereo.maps, config=cfg, _stereo=stereo)

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """``(min, max)`` depth kept, metres."""
        if self._stereo is not None:
            return self._stereo.depth_range_m
        fb = float(self.maps.focal_px * self.maps.baseline_m)
        lo = self.config.min_depth_m or fb / self._max_disparity()
        hi = self.config.max_depth_m or fb / MIN_USEFUL_DISPARITY_PX
        return float(lo), float(hi)

    def _max_disparity(self) -> int:
        c = self.config
        if c.max_disparity_px is not None:
            return int(c.max_disparity_px)
        if c.min_depth_m is not None:
            return int(max_disparity_for_depth(self.maps, c.min_depth_m))
        return default_max_disparity(int(self.maps.width))

    def engine(self) -> EngineConfig:
        """The stereo engine config in use."""
        if self._stereo is not None:
            return self._stereo.engine_config
        if self._engine is None:
            self._engine = make_config(self.config.engine, self._max_disparity())
        return self._engine

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
        if self._stereo is not None:
            res = self._stereo.compute(left8, right8)
        else:
            res = compute_depth(
                self.maps, left8, right8, self.engine(), max_depth_m=self.depth_range_m[1]
            )
        _, rect_right = rectify_images(self.maps, left8, right8)
        return FrameObservation(
            t_ns=int(t_ns),
            rect_left=np.asarray(res.rect_left, dtype=np.uint8),
            rect_right=np.asarray(rect_right, dtype=np.uint8),
            depth_m=res.depth_m,
            K_rect=np.asarray(self.maps.P_left[:3, :3], dtype=np.float64),
            baseline_m=float(self.maps.baseline_m),
            R_rect_left_left=np.asarray(self.maps.R_rect_left_left, dtype=np.float64),
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
