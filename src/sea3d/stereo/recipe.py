"""One stereo-depth recipe: :class:`StereoDepth` built once from a rig and a :class:`DepthConfig`.

Every command that turns raw stereo pairs into metric depth (``sea3d depth``, ``process``,
``odometry``, ``enhance`` with stereo, ``mono-depth`` with stereo, the demo, the live preview,
the echosounder check) builds one :class:`StereoDepth` and calls :meth:`StereoDepth.compute` on
each pair. It holds what costs time to build and never changes during a dive: the
rectification maps (with the virtual-pinhole fits of refractive rigs), the disparity range and
the matching engine's configuration. It pickles, so a worker process or a Dask worker gets it
whole and fits nothing again.

The depth range
---------------

For a rectified pair with focal length ``f`` (pixels) and baseline ``B`` (metres), depth and
disparity are ``z = f B / d``. The matcher searches ``d`` in ``0 .. d_max``, so the nearest depth
it can see is ``z_min = f B / d_max``. A matching error of ``sigma_d`` pixels becomes a depth error

    ``sigma_z = z^2 sigma_d / (f B) = z sigma_d / d``

(first order), i.e. the *relative* depth error is ``sigma_d / d``: it depends only on the
disparity. A depth is worth keeping while that relative error stays small. With sub-pixel SGM's
typical ``sigma_d = 0.25 px`` on textured scenes (the figure :class:`~sea3d.stereo.planning.
PlanConfig` also uses) and a largest acceptable relative error of 1/16 (6.25 %, one standard
deviation), the smallest useful disparity is

    ``d_min = sigma_d / (1/16) = 4 px``  (:data:`MIN_USEFUL_DISPARITY_PX`),

and the farthest useful depth ``z_max = f B / d_min``. Below 4 px the error doubles by every
halving of ``d`` and a one-pixel mismatch (the usual gross error of SGM near occlusions) moves the
point by a quarter of its depth or more.

Unless the user gives them, :class:`StereoDepth` takes

- ``d_max`` from the image width with OpenCV's rule of its ``stereo_match`` sample: ``W / 8``
  rounded up to a multiple of 16 (``((W / 8) + 15) & -16`` disparities, searched as
  ``0 .. d_max`` with ``d_max`` one less). A disparity of ``W / 8`` leaves 7/8 of the left view
  overlapping the right; nearer than that, too little of the image has a partner to be worth
  the search time; or, when ``min_depth_m`` is given, the disparity that reaches it
  (:func:`~sea3d.stereo.depth.max_disparity_for_depth`);
- ``min_depth_m = f B / d_max`` and ``max_depth_m = f B / d_min``,

with ``f`` and ``B`` of the rectified views: for a pinhole rig they are the rig's own; for a port
rig they are those of the virtual pinholes fitted for rectification (a flat port magnifies by
about the water's index, a centred dome not at all). The virtual pinholes are fitted over the
range first estimated from the lens focal length (times ``n_water / n_air`` behind a flat
port) and the baseline, so one fit serves both.

Examples (``f B`` of the rectified views in px m; range in m): a car rig with ``B = 0.54 m``,
``f = 718 px`` at 1241x376 (``f B = 388``, ``d_max = 159``): 2.44 .. 97; the paper's dome rig at
640x360 (``f B = 37.8``, ``d_max = 79``): 0.48 .. 9.44, at 1920x1080 (``d_max = 239``):
0.47 .. 28.3; its flat-port rig at 640x360 (``f B = 62.1``, magnified by the water): 0.79 .. 15.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d.errors import ConfigError, StereoError
from sea3d.geometry.rig import StereoRig
from sea3d.rectify.maps import RectifyMaps, rectify_rig
from sea3d.refraction.ports import FlatPort
from sea3d.stereo.depth import DepthResult, compute_depth, max_disparity_for_depth
from sea3d.stereo.engine import EngineConfig, make_config

__all__ = [
    "ENGINES",
    "MIN_USEFUL_DISPARITY_PX",
    "DepthConfig",
    "StereoDepth",
    "default_max_disparity",
]

ENGINES = ("sea3d", "sea3d-gpu", "opencv", "opencv-sgbm", "opencv-hh", "opencv-3way",
           "opencv-hh4")
"""The matching engines :func:`~sea3d.stereo.engine.make_config` knows."""

MIN_USEFUL_DISPARITY_PX = 4.0
"""The smallest disparity whose depth is kept by default: relative depth error
``sigma_d / d = 0.25 / 4 = 1/16`` (see the module docstring), pixels."""


def default_max_disparity(width_px: int) -> int:
    """The disparity search range for an image ``width_px`` wide: OpenCV's ``stereo_match``
    rule ``((W / 8) + 15) & -16`` disparities, i.e. ``d_max`` = that minus one (a ``16 k - 1``,
    OpenCV's multiples of 16), at least 15 and below the image width.

    Raises:
        ConfigError: a width under 17 px (no range of 16 disparities fits).
    """
    w = int(width_px)
    if w < 17:
        raise ConfigError(f"an image {w} px wide is too narrow for stereo matching")
    n = ((w // 8) + 15) & -16
    n = min(max(n, 16), (w - 1) // 16 * 16)
    return n - 1


@dataclass(frozen=True, kw_only=True)
class DepthConfig:
    """How stereo depth is computed: engine, disparity range, depth range.

    Attributes:
        engine: ``sea3d`` (own SGM, CPU), ``sea3d-gpu`` (CuPy), ``opencv`` (StereoSGBM;
            ``opencv-hh``, ``opencv-3way`` its other modes).
        max_disparity_px: largest disparity searched (``0 .. max_disparity_px``), pixels; None
            derives it from ``min_depth_m`` if given, else from the image width (module doc).
        min_depth_m: nearest depth, metres; None: ``f B / max_disparity_px``.
        max_depth_m: farthest depth kept, metres; None: ``f B /`` :data:`MIN_USEFUL_DISPARITY_PX`.
        min_confidence: matched pixels below this confidence get no depth (the default drops
            the filled, unmatched pixels of sea3d's dense disparity; 0 keeps them).
        engine_options: overrides of the engine's config fields (``(name, value)`` pairs, or
            a mapping on construction), e.g. ``{"paths": 4, "fill_max_px": 0}`` for sea3d.

    Raises:
        ConfigError: an unknown engine, a disparity range under 1 px, depths that are not
            ``0 < min < max`` (finite), or a negative confidence.
    """

    engine: str = "sea3d"
    max_disparity_px: int | None = None
    min_depth_m: float | None = None
    max_depth_m: float | None = None
    min_confidence: float = 1e-6
    engine_options: tuple[tuple[str, Any], ...] = field(default=())

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise ConfigError(f"unknown engine {self.engine!r}; choose one of "
                              f"{', '.join(ENGINES)}")
        if self.max_disparity_px is not None:
            if int(self.max_disparity_px) != self.max_disparity_px or self.max_disparity_px < 1:
                raise ConfigError(
                    f"max disparity must be an integer >= 1 px, got {self.max_disparity_px}")
            object.__setattr__(self, "max_disparity_px", int(self.max_disparity_px))
        for name in ("min_depth_m", "max_depth_m"):
            value = getattr(self, name)
            if value is None:
                continue
            value = float(value)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a finite depth > 0 m, got {value}")
            object.__setattr__(self, name, value)
        lo, hi = self.min_depth_m, self.max_depth_m
        if lo is not None and hi is not None and not lo < hi:
            raise ConfigError(f"need min_depth_m < max_depth_m, got {lo} and {hi}")
        if not (math.isfinite(self.min_confidence) and self.min_confidence >= 0):
            raise ConfigError(f"min_confidence must be >= 0, got {self.min_confidence}")
        opts = self.engine_options
        items = sorted(opts.items()) if isinstance(opts, dict) else [tuple(p) for p in opts]
        for item in items:
            if len(item) != 2 or not isinstance(item[0], str):
                raise ConfigError(f"engine_options must be (name, value) pairs, got {item!r}")
        object.__setattr__(self, "engine_options", tuple((str(k), v) for k, v in items))


def _lens_focal_in_water(rig: StereoRig) -> float:
    """The left lens's focal length as seen through its port: magnified by about
    ``n_water / n_air`` behind a flat port (paraxially), unchanged behind a dome or in air."""
    cam = rig.left
    f = float(cam.lens.fx)
    port = cam.port
    if cam.is_refractive and isinstance(port, FlatPort):
        f *= port.n_water / port.n_air
    return f


class StereoDepth:
    """Rectification, disparity range and engine of one rig, built once; depth of each pair.

    Args:
        rig: the stereo rig at the size of the images that :meth:`compute` gets.
        config: :class:`DepthConfig` (default: sea3d's engine, ranges from the rig).

    Raises:
        ConfigError: a configuration the rig cannot meet (a disparity range as wide as the
            image). RectifyError: the rig cannot be rectified.
    """

    def __init__(self, rig: StereoRig, config: DepthConfig | None = None) -> None:
        cfg = config if config is not None else DepthConfig()
        if not isinstance(rig, StereoRig):
            raise ConfigError(f"StereoDepth needs a StereoRig, got {type(rig).__name__}")
        self._rig = rig
        self._config = cfg
        width = rig.width
        # The range over which the virtual pinholes are fitted: the user's, else estimated
        # from the lens (the rectified focal length is known only after the fit).
        d_max0 = cfg.max_disparity_px or default_max_disparity(width)
        fb0 = _lens_focal_in_water(rig) * rig.baseline_m
        fit_lo = cfg.min_depth_m if cfg.min_depth_m is not None else fb0 / d_max0
        fit_hi = cfg.max_depth_m if cfg.max_depth_m is not None else fb0 / MIN_USEFUL_DISPARITY_PX
        if not fit_lo < fit_hi:  # a user's max below the estimated nearest (or the reverse)
            fit_lo, fit_hi = (fit_hi / 2, fit_hi) if cfg.max_depth_m is not None else (
                fit_lo, 2 * fit_lo)
        self._maps = rectify_rig(rig, depth_range_m=(fit_lo, fit_hi))
        maps = self._maps
        if cfg.max_disparity_px is not None:
            d_max = cfg.max_disparity_px
        elif cfg.min_depth_m is not None:
            d_max = max_disparity_for_depth(maps, cfg.min_depth_m)
        else:
            d_max = default_max_disparity(width)
        if d_max + 1 > width:
            raise ConfigError(f"a disparity range of 0..{d_max} px does not fit images "
                              f"{width} px wide")
        self._max_disparity_px = int(d_max)
        fb = maps.focal_px * maps.baseline_m
        lo = cfg.min_depth_m if cfg.min_depth_m is not None else fb / d_max
        hi = cfg.max_depth_m if cfg.max_depth_m is not None else fb / MIN_USEFUL_DISPARITY_PX
        if not lo < hi:
            raise ConfigError(
                f"the depth range {lo:.3g}..{hi:.3g} m is empty for this rig (f B = {fb:.3g} "
                f"px m, disparities 0..{d_max} px)")
        self._depth_range_m = (float(lo), float(hi))
        self._engine = make_config(cfg.engine, self._max_disparity_px,
                                   **dict(cfg.engine_options))

    # -- what it was built from and with ---------------------------------------------------
    @property
    def rig(self) -> StereoRig:
        """The rig (at the images' size)."""
        return self._rig

    @property
    def config(self) -> DepthConfig:
        """The configuration as given (None fields stay None; see the properties)."""
        return self._config

    @property
    def maps(self) -> RectifyMaps:
        """The rectification maps (virtual pinholes of refractive rigs fitted once)."""
        return self._maps

    @property
    def engine_config(self) -> EngineConfig:
        """The matching engine's configuration."""
        return self._engine

    @property
    def max_disparity_px(self) -> int:
        """Largest disparity searched, rectified pixels."""
        return self._max_disparity_px

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """``(min, max)`` depth along the rectified left z axis, metres: the user's, or from
        ``f B`` and the disparity range (module doc). Depth beyond ``max`` is dropped."""
        return self._depth_range_m

    @property
    def min_depth_m(self) -> float:
        """Nearest depth, metres (``depth_range_m[0]``)."""
        return self._depth_range_m[0]

    @property
    def max_depth_m(self) -> float:
        """Farthest depth kept, metres (``depth_range_m[1]``)."""
        return self._depth_range_m[1]

    def __repr__(self) -> str:
        lo, hi = self._depth_range_m
        return (f"StereoDepth({self._config.engine}, {self._rig.width}x{self._rig.height}, "
                f"d 0..{self._max_disparity_px} px, z {lo:.3g}..{hi:.3g} m, "
                f"{'refractive' if self._maps.refractive else 'pinhole'})")

    # -- work ------------------------------------------------------------------------------
    def warm_up(self) -> float:
        """Compile the engine's kernels now (numba; loaded from its cache after the first
        run) so that the first :meth:`compute` is not slow; returns the seconds it took
        (0 for engines that compile nothing)."""
        if self._config.engine == "sea3d":
            from sea3d.stereo.sgm import warm_up

            return float(warm_up())
        return 0.0

    def compute(self, left: np.ndarray, right: np.ndarray) -> DepthResult:
        """Rectify, match and triangulate one raw pair (see
        :func:`~sea3d.stereo.depth.compute_depth`).

        Args:
            left, right: raw images ``(H, W)`` or ``(H, W, 3)`` RGB at the rig's size.

        Returns:
            :class:`~sea3d.stereo.depth.DepthResult`: depth float32 metres (NaN invalid,
            nothing beyond ``max_depth_m``), disparity, points in the left camera frame.

        Raises:
            RectifyError: images of another size. StereoError: invalid images.
        """
        for name, img in (("left", left), ("right", right)):
            if getattr(img, "ndim", 0) not in (2, 3):
                raise StereoError(f"{name} image must be (H, W) or (H, W, 3), got "
                                  f"{getattr(img, 'shape', type(img).__name__)}")
        return compute_depth(self._maps, left, right, self._engine,
                             max_depth_m=self._depth_range_m[1],
                             min_confidence=self._config.min_confidence)
