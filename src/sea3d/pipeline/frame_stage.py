"""The per-frame stage of ``sea3d process``: [enhance], rectify, match, depth, fusion depth.

:func:`process_frame` is a pure function of a :class:`FrameStageConfig` and one raw stereo
pair (arrays, not paths), so it runs unchanged in the client, in a local worker process or on
a Dask worker on another machine, which needs only the sea3d package: the rig travels inside
the config (a :class:`~sea3d.geometry.rig.StereoRig` pickles), the client hands each worker the
:class:`~sea3d.stereo.recipe.StereoDepth` it built once (:func:`install_geometry`: no worker
fits the virtual pinholes again), and each process
compiles the matcher's kernels once (loaded from numba's cache, timed as ``warmup_s`` so that
reports can say it is one-off).

Depth comes out twice: ``depth_m``, exactly triangulated on the rectified grid (what the
odometry gets), and ``fusion_depth_m``, the same surface re-sampled where the rectified
view's virtual pinhole sees it (what the pinhole TSDF integrates;
:mod:`sea3d.recon.depth_resample`).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import logging
import pickle
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError, Sea3dError
from sea3d.geometry.rig import StereoRig
from sea3d.recon.depth_resample import ResampleMethod, virtual_pinhole_depth_confidence
from sea3d.stereo.recipe import DepthConfig, StereoDepth

if TYPE_CHECKING:
    from sea3d.rectify.maps import RectifyMaps

__all__ = ["FrameResult", "FrameStageConfig", "install_geometry", "process_frame",
           "rectify_pair", "stage_depth", "stage_geometry"]

log = logging.getLogger(__name__)

FrameStatus = Literal["ok", "no_depth", "failed"]
EnhanceHook = Callable[[NDArray[np.uint8]], NDArray[np.uint8]]


@dataclass(frozen=True, kw_only=True)
class FrameStageConfig:
    """Everything the per-frame stage needs (shipped to every worker)."""

    rig: StereoRig
    """The rig at the session's recorded image size."""
    size_px: tuple[int, int] | None = None
    """Process at ``(width, height)`` (raw images resized, intrinsics scaled); None: as
    recorded."""
    depth: DepthConfig = field(default_factory=DepthConfig)
    """Engine, disparity range and depth range (None ranges: from the rig, see
    :mod:`sea3d.stereo.recipe`)."""
    resample: ResampleMethod = "resample"
    """How exact depth is put into the virtual pinhole for fusion (see
    :mod:`sea3d.recon.depth_resample`)."""
    enhance: str | EnhanceHook | None = None
    """Optional enhancement of the raw images before rectification and matching (the
    mesh's colours come from the enhanced left image): a picklable callable
    ``image (H, W[, 3]) uint8 -> image`` of the same shape, or its name
    ``"package.module:function"`` (the hook for :mod:`sea3d.enhance`)."""
    restore_colours: Literal["none", "seathru"] = "none"
    """The colours of mesh and cloud: ``seathru`` restores the rectified left image after
    depth with the stereo range of its own pixels (:mod:`sea3d.enhance`; frames it cannot
    restore fall back to grey world, with the reason in ``colour_status``); ``none`` keeps
    the (enhanced) rectified image."""
    threads: int | None = None
    """Threads for numba and OpenCV inside one worker (None: the libraries' default)."""

    def __post_init__(self) -> None:
        if not isinstance(self.rig, StereoRig):
            raise ConfigError(f"rig must be a StereoRig, got {type(self.rig).__name__}")
        if not isinstance(self.depth, DepthConfig):
            raise ConfigError(f"depth must be a DepthConfig, got {type(self.depth).__name__}")
        if self.size_px is not None and (self.size_px[0] < 32 or self.size_px[1] < 24):
            raise ConfigError(f"size_px must be at least 32x24, got {self.size_px}")
        if isinstance(self.enhance, str) and ":" not in self.enhance:
            raise ConfigError(f"enhance must be 'package.module:function', got {self.enhance!r}")
        if isinstance(self.enhance, str):
            _resolve_hook(self.enhance)  # a name that cannot be found: a config error, now
        if self.restore_colours not in ("none", "seathru"):
            raise ConfigError(f"restore_colours must be none or seathru, got "
                              f"{self.restore_colours!r}")

    def fingerprint(self) -> dict[str, Any]:
        """What identifies the per-frame results (the cache is valid only for the same one)."""
        from sea3d.io.rig_file import rig_to_yaml

        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("rig", "depth")}
        d["rig_yaml"] = rig_to_yaml(self.rig)
        d["depth"] = asdict(self.depth)
        d.pop("threads")
        if self.restore_colours == "none":
            d.pop("restore_colours")  # caches written before the option stay valid
        enh = self.enhance
        if enh is not None and not isinstance(enh, str):
            d["enhance"] = f"{getattr(enh, '__module__', '?')}:{getattr(enh, '__qualname__', '?')}"
        d["size_px"] = list(self.size_px) if self.size_px else None
        return d


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameResult:
    """The per-frame stage's result for one stereo pair.

    Attributes:
        t_ns: the left image's stamp.
        status: ``ok``, ``no_depth`` (matched, but no valid depth) or ``failed`` (see message).
        message: why it failed, empty otherwise.
        rect_left, rect_right: rectified images, uint8, grey (H, W) or RGB (H, W, 3).
        depth_m: (H, W) float32 exact depth on the rectified grid, NaN invalid.
        fusion_depth_m: (H, W) float32 the same for the virtual pinhole (TSDF input).
        fusion_confidence: (H, W) uint8 the matcher's confidence of each ``fusion_depth_m``
            pixel (255 = 1, 0 without depth; :attr:`~sea3d.recon.tsdf.TsdfConfig.
            confidence_full` weights fusion by it); empty for results cached before it was
            kept (fused as fully confident).
        valid_fraction: fraction of pixels with depth.
        color_left: (H, W, 3) uint8 restored colours of ``rect_left`` for mesh and cloud
            (``restore_colours``), empty when the rectified image itself colours them.
        colour_status: Sea-thru's status (``ok``, ``fallback-grey-world``, ...), empty
            without ``restore_colours``.
        timings_s: seconds per step (``enhance_s``, ``rectify_s``, ``match_s``, ``depth_s``,
            ``rectify_right_s``, ``resample_s``, and ``warmup_s`` on a worker's first frame:
            kernel compilation).
        cache_entry: the result encoded as a cache entry where it was computed
            (:meth:`~sea3d.io.result_cache.FrameCache.encode`; empty when not asked for), so
            the caller only writes it.
        seeded: the frame got no depth of its own (:mod:`sea3d.pipeline.depth_rate`, or a
            live frame dropped to keep up): ``depth_m`` is an earlier frame's, the odometry's
            stereo seeds only; it is not fused and not cached.
    """

    t_ns: int
    status: FrameStatus
    message: str = ""
    rect_left: NDArray[np.uint8] = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    rect_right: NDArray[np.uint8] = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    depth_m: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    fusion_depth_m: NDArray[np.float32] = field(
        default_factory=lambda: np.zeros((0, 0), np.float32))
    valid_fraction: float = 0.0
    fusion_confidence: NDArray[np.uint8] = field(
        default_factory=lambda: np.zeros((0, 0), np.uint8))
    timings_s: dict[str, float] = field(default_factory=dict)
    color_left: NDArray[np.uint8] = field(default_factory=lambda: np.zeros((0, 0), np.uint8))
    colour_status: str = ""
    seeded: bool = False
    cache_entry: bytes = b""

    def colors(self) -> NDArray[np.uint8]:
        """(H, W, 3) uint8 colours for mesh and cloud: the restored ones when there are, else
        the rectified left image (grey repeated)."""
        if self.color_left.size:
            return self.color_left
        if self.rect_left.ndim == 3:
            return self.rect_left
        return np.repeat(self.rect_left[..., None], 3, axis=2)

    def to_cache(self) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
        """Arrays and metadata for :class:`sea3d.io.result_cache.FrameCache`.

        Exact: both depth maps as float32 (:data:`CACHE_DEPTH_DTYPE`) and the confidence
        as the uint8 in 16 levels the frame stage already made, so a run resumed from the
        cache fuses, tracks and fits its water model on what a fresh run had. (float16
        depth, tried: 31 % smaller entries, but a resumed run's water model and cloud
        differed from the fresh run's: ``tests/enhance/test_process_colours.py``.)
        :meth:`from_cache` reads these, float16 entries and the entries without confidence
        written before."""
        arrays: dict[str, NDArray[Any]] = {
            "rect_left": self.rect_left, "rect_right": self.rect_right,
            "depth_m": np.asarray(self.depth_m, CACHE_DEPTH_DTYPE),
            "fusion_depth_m": np.asarray(self.fusion_depth_m, CACHE_DEPTH_DTYPE),
        }
        meta: dict[str, Any] = {
            "status": self.status, "message": self.message,
            "valid_fraction": self.valid_fraction, "timings_s": self.timings_s,
        }
        if self.color_left.size:
            arrays["color_left"] = self.color_left
            meta["colour_status"] = self.colour_status
        if self.fusion_confidence.size:
            arrays["fusion_confidence"] = _coarse_confidence(self.fusion_confidence)
        return arrays, meta

    @classmethod
    def from_cache(cls, t_ns: int, arrays: dict[str, NDArray[Any]],
                   meta: dict[str, Any]) -> FrameResult:
        """Rebuild a result from a cache entry (KeyError if a field is missing)."""
        return cls(t_ns=int(t_ns), status=meta["status"], message=meta.get("message", ""),
                   rect_left=arrays["rect_left"], rect_right=arrays["rect_right"],
                   depth_m=np.asarray(arrays["depth_m"], np.float32),
                   fusion_depth_m=np.asarray(arrays["fusion_depth_m"], np.float32),
                   valid_fraction=float(meta["valid_fraction"]),
                   timings_s={k: float(v) for k, v in meta["timings_s"].items()},
                   color_left=arrays.get("color_left", np.zeros((0, 0), np.uint8)),
                   fusion_confidence=arrays.get("fusion_confidence",
                                                np.zeros((0, 0), np.uint8)),
                   colour_status=str(meta.get("colour_status", "")))


CACHE_DEPTH_DTYPE = np.float32
"""How :meth:`FrameResult.to_cache` stores depth (float16 and float32 entries are read)."""


def _coarse_confidence(conf: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """uint8 confidence rounded to multiples of 17 (16 levels, 0 and 255 kept): what the
    fusion weights read, in far fewer distinct bytes to compress."""
    q = (conf.astype(np.uint16) + 8) // 17 * 17
    out: NDArray[np.uint8] = np.minimum(q, 255).astype(np.uint8)
    return out


_INSTALLED: dict[tuple[Any, ...], StereoDepth] = {}
_BUILT: dict[tuple[Any, ...], StereoDepth] = {}


def _geometry_key(config: FrameStageConfig) -> tuple[Any, ...]:
    rig_digest = hashlib.sha1(pickle.dumps(config.rig), usedforsecurity=False).hexdigest()
    return (rig_digest, config.size_px, config.depth)


def install_geometry(config: FrameStageConfig, stereo: StereoDepth) -> None:
    """Give this process the :class:`~sea3d.stereo.recipe.StereoDepth` of ``config``, built
    elsewhere (the client), so that a worker does not fit the virtual pinholes again (seconds
    per worker at 640x360)."""
    _INSTALLED[_geometry_key(config)] = stereo


def stage_depth(config: FrameStageConfig) -> StereoDepth:
    """The :class:`~sea3d.stereo.recipe.StereoDepth` of ``config`` (its rig scaled to
    ``size_px``): as installed by :func:`install_geometry`, or built once per process and
    configuration.

    Raises:
        ConfigError, RectifyError: a rig or depth configuration that cannot be used.
    """
    key = _geometry_key(config)
    got = _INSTALLED.get(key) or _BUILT.get(key)
    if got is not None:
        return got
    rig = config.rig if config.size_px is None else config.rig.scaled(*config.size_px)
    if len(_BUILT) >= 4:
        _BUILT.pop(next(iter(_BUILT)))
    stereo = _BUILT[key] = StereoDepth(rig, config.depth)
    return stereo


def stage_geometry(config: FrameStageConfig) -> tuple[StereoRig, RectifyMaps]:
    """``(rig, maps)`` of :func:`stage_depth`: the (scaled)
    :class:`~sea3d.geometry.rig.StereoRig` and its :class:`~sea3d.rectify.maps.RectifyMaps`.

    Raises:
        ConfigError, RectifyError: an invalid rig.
    """
    stereo = stage_depth(config)
    return stereo.rig, stereo.maps


@functools.lru_cache(maxsize=8)
def _resolve_hook(name: str) -> EnhanceHook:
    module, _, attr = name.partition(":")
    try:
        fn = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as err:
        raise ConfigError(f"cannot find the enhancement {name!r}: {err}") from err
    if not callable(fn):
        raise ConfigError(f"enhancement {name!r} is not callable")
    hook: EnhanceHook = fn
    return hook


_WARM: set[str] = set()
_THREADS: list[int] = []


def _prepare_process(config: FrameStageConfig) -> float:
    """Per-process set-up: thread counts and one-off kernel compilation (returns seconds)."""
    if config.threads is not None and _THREADS != [config.threads]:
        import numba

        numba.set_num_threads(max(1, min(config.threads, numba.config.NUMBA_NUM_THREADS)))
        cv2.setNumThreads(config.threads)
        _THREADS[:] = [config.threads]
    if config.depth.engine in _WARM:
        return 0.0
    _WARM.add(config.depth.engine)
    return stage_depth(config).warm_up()


def _to_u8(img: NDArray[Any]) -> NDArray[np.uint8]:
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        return (img >> 8).astype(np.uint8)
    top = float(np.nanmax(img)) or 1.0
    return np.clip(img * (255.0 / top), 0, 255).astype(np.uint8)


def rectify_pair(stereo: StereoDepth, left: NDArray[Any], right: NDArray[Any]
                 ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The rectified uint8 ``(left, right)`` of a raw pair (at the recorded or the rig's size),
    without depth: what the odometry needs of a frame whose depth is skipped (live)."""
    from sea3d.rectify import rectify_images

    size = (stereo.maps.width, stereo.maps.height)
    if left.shape[:2] != size[::-1]:
        left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
    rl, rr = rectify_images(stereo.maps, _to_u8(left), _to_u8(right))
    return np.ascontiguousarray(rl, np.uint8), np.ascontiguousarray(rr, np.uint8)


def process_frame(config: FrameStageConfig, t_ns: int, left: NDArray[Any],
                  right: NDArray[Any], geometry: StereoDepth | None = None,
                  encode_cache_entry: bool = False) -> FrameResult:
    """Enhance (if configured), rectify, match and triangulate one raw stereo pair.

    Args:
        config: :class:`FrameStageConfig`.
        t_ns: the pair's stamp.
        left, right: raw images (H, W) or (H, W, 3) RGB, uint8 or uint16, at the recorded size.
        geometry: the :class:`~sea3d.stereo.recipe.StereoDepth` of ``config`` built by the
            caller (see :func:`install_geometry`); None builds or reuses this process's own.
        encode_cache_entry: also encode the result as its cache entry
            (:attr:`FrameResult.cache_entry`), here in the worker, not in the caller.

    Returns:
        :class:`FrameResult` (``failed`` with a message for images it cannot use, never an
        exception for valid configurations).

    Raises:
        RigFileError, RectifyError, ConfigError: the configuration itself is unusable.
    """
    timings: dict[str, float] = {}
    if geometry is not None and _geometry_key(config) not in _INSTALLED:
        install_geometry(config, geometry)
    warm = _prepare_process(config)
    if warm > 0:
        timings["warmup_s"] = warm
    stereo = stage_depth(config)
    maps = stereo.maps
    try:
        if left.shape[:2] != (maps.height, maps.width):
            if config.size_px is None:
                return FrameResult(t_ns=t_ns, status="failed", message=(
                    f"image is {left.shape[1]}x{left.shape[0]} but the rig is "
                    f"{maps.width}x{maps.height}"), timings_s=timings)
            size = (maps.width, maps.height)
            left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
        left, right = _to_u8(left), _to_u8(right)
        raw_left = left
        hook = config.enhance
        if hook is not None:
            fn = _resolve_hook(hook) if isinstance(hook, str) else hook
            te = time.perf_counter()
            left, right = fn(left), fn(right)
            timings["enhance_s"] = time.perf_counter() - te
        res = stereo.compute(left, right)
        tr = time.perf_counter()
        # the matcher's own rectified right view (the same remap), else remapped here
        rect_right = res.rect_right if res.rect_right is not None else cv2.remap(
            right, maps.map_right_x, maps.map_right_y, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT)
        timings["rectify_right_s"] = time.perf_counter() - tr
        timings.update({k: float(v) for k, v in res.timings_s.items()})
    except Sea3dError as err:
        return FrameResult(t_ns=t_ns, status="failed", message=str(err), timings_s=timings)
    t2 = time.perf_counter()
    K = maps.P_left[:3, :3]
    # the points rotated into the rectified frame as the resampling reads them (a rotated
    # copy took 4 ms of CPU per 640x360 frame with einsum, ~0.1 s with OpenBLAS's @)
    fusion, fusion_conf = virtual_pinhole_depth_confidence(
        res.depth_m, res.points_left, K, res.confidence, method=config.resample,
        focal_baseline_px_m=maps.focal_px * maps.baseline_m, rotation=maps.R_rect_left_left)
    timings["resample_s"] = time.perf_counter() - t2
    colors: NDArray[np.uint8] = np.zeros((0, 0), np.uint8)
    colour_status = ""
    if config.restore_colours == "seathru":
        tc = time.perf_counter()
        # Sea-thru needs the camera's own colours: rectify the raw image again when a hook
        # changed it before matching.
        rect_raw = np.asarray(res.rect_left if raw_left is left else cv2.remap(
            raw_left, maps.map_left_x, maps.map_left_y, cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT), np.uint8)
        colors, colour_status = _restore_colours(rect_raw, res.depth_m, res.points_left, maps)
        timings["restore_colours_s"] = time.perf_counter() - tc
    valid = float(np.isfinite(res.depth_m).mean())
    out = FrameResult(
        t_ns=t_ns,
        status="ok" if valid > 0 else "no_depth",
        rect_left=np.ascontiguousarray(res.rect_left, np.uint8),
        rect_right=np.ascontiguousarray(rect_right, np.uint8),
        depth_m=res.depth_m,
        fusion_depth_m=fusion,
        # in the 16 levels the cache keeps, so a resumed run weights as a fresh one
        fusion_confidence=_coarse_confidence(fusion_conf),
        valid_fraction=valid,
        timings_s=timings,
        color_left=colors,
        colour_status=colour_status,
    )
    if encode_cache_entry:
        from sea3d.io.result_cache import FrameCache

        out = replace(out, cache_entry=FrameCache.encode(t_ns, *out.to_cache()))
    return out


def _restore_colours(rect_left: NDArray[np.uint8], depth_m: NDArray[np.float32],
                     points_left: NDArray[np.float64], maps: RectifyMaps
                     ) -> tuple[NDArray[np.uint8], str]:
    """Sea-thru of the rectified left image with the range of the stereo points (their norms
    in the left camera frame: exact through the ports), on the pixels that have depth."""
    from sea3d.enhance.seathru import depth_to_range
    from sea3d.enhance.stage import ColourRestoreConfig, restore_colours_with_range

    has = np.isfinite(depth_m)
    if int(has.sum()) == len(points_left):
        range_m = np.full(depth_m.shape, np.nan, np.float32)
        range_m[has] = np.linalg.norm(points_left, axis=1)
    else:  # not one point per pixel with depth: the rectified pinhole's rays instead
        range_m = depth_to_range(depth_m, maps.focal_px, maps.focal_px, maps.cx_px, maps.cy_px)
    out = restore_colours_with_range(rect_left, range_m, ColourRestoreConfig(enabled=True))
    img = out.image if out.image.ndim == 3 else np.repeat(out.image[..., None], 3, axis=2)
    return np.ascontiguousarray(img, np.uint8), out.status
