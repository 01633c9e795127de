"""Stage functions for ``sea3d process``: enhancement before matching, and Sea-thru on the
output colours after depth.

Like every per-frame stage they take arrays and frozen configs and read or write no files.
How ``process`` should call them (the order of the per-frame stages in ``DESIGN.md``)::

    rect_l, rect_r = rectify(raw_l, raw_r)
    rect_l_m, rect_r_m = enhance_pair_for_matching(rect_l, rect_r, cfg.match)  # identity by default
    disparity = match(rect_l_m, rect_r_m)            # dense SGM
    feats = detect(enhance_for_features(rect_l, cfg.features))  # odometry front end
    depth = disparity_to_depth(...)
    colours = restore_colours(rect_l, depth, focal_px, cx_px, cy_px, cfg.colour)
    # colours.image colours the point cloud / TSDF; colours.status goes into the frame report

The defaults follow what ``benchmarks/bench_enhance.py`` measured (``docs/enhance.md``): on
simulated underwater pairs no method lowered our SGM's bad-2 by more than 0.1 point, and
every one raised it by 2-5 points in turbid water, so matching gets the raw images
(``method="none"``); CLAHE on L* gives 1.5-2.2x the correct sparse feature matches under
caustics, so a feature front end may take it; Sea-thru of the output colours is opt-in.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sea3d.enhance.api import enhance_image, enhance_pair
from sea3d.enhance.colour import grey_world
from sea3d.enhance.contrast import clahe
from sea3d.enhance.seathru import SeathruConfig, SeathruModel, depth_to_range, seathru
from sea3d.errors import EnhanceError

__all__ = [
    "PROCESS_ENHANCE",
    "ColourConfig",
    "ColourResult",
    "FeatureEnhanceConfig",
    "MatchEnhanceConfig",
    "enhance_for_features",
    "enhance_for_matching",
    "enhance_pair_for_matching",
    "process_enhance_hook",
    "restore_colours",
    "restore_colours_with_range",
]

_log = logging.getLogger(__name__)

MatchMethod = Literal["none", "grey-world", "shades-of-grey", "red-comp", "clahe", "udcp"]

PROCESS_ENHANCE: dict[str, str | None] = {
    "none": None,
    "grey-world": "sea3d.enhance.colour:grey_world",
    "shades-of-grey": "sea3d.enhance.colour:shades_of_grey",
    "red-comp": "sea3d.enhance.colour:red_compensation",
    "clahe": "sea3d.enhance.contrast:clahe",
    "udcp": "sea3d.enhance.udcp:udcp",
}
"""``sea3d process --enhance NAME``: the per-image hook (``module:function``) each name
stands for, applied by the per-frame stage to the raw images before rectification and
matching. ``none`` is the measured default (none helped our SGM; docs/enhance.md);
each hook works on one image, so white balances are per image, not shared by the pair."""


def process_enhance_hook(name: str) -> str | None:
    """The hook of a :data:`PROCESS_ENHANCE` name, or ``name`` itself when it is already a
    ``module:function`` path.

    Raises:
        EnhanceError: neither a known name nor a ``module:function`` path.
    """
    if name in PROCESS_ENHANCE:
        return PROCESS_ENHANCE[name]
    if ":" in name:
        return name
    raise EnhanceError(
        f"unknown enhancement {name!r}: use one of {', '.join(PROCESS_ENHANCE)} or "
        "package.module:function"
    )


@dataclass(frozen=True, kw_only=True)
class MatchEnhanceConfig:
    """What to apply to a rectified pair before dense matching."""

    method: MatchMethod = "none"
    """``none`` (measured best for SGM), or a method of :data:`sea3d.enhance.METHODS`
    except ``seathru`` (it needs the depth that matching produces)."""
    clahe_clip_limit: float = 2.0
    """Clip limit when ``method="clahe"``."""

    def __post_init__(self) -> None:
        if self.method not in ("none", "grey-world", "shades-of-grey", "red-comp", "clahe", "udcp"):
            raise EnhanceError(f"unknown matching enhancement {self.method!r}")


@dataclass(frozen=True, kw_only=True)
class FeatureEnhanceConfig:
    """What to apply to an image before sparse feature detection (odometry, loop closure)."""

    method: Literal["none", "clahe"] = "clahe"
    """``clahe`` on L* (measured to raise correct matches under caustics) or ``none``."""
    clahe_clip_limit: float = 2.0
    """CLAHE clip limit."""
    clahe_tiles: tuple[int, int] = (8, 8)
    """CLAHE tile grid (x, y)."""

    def __post_init__(self) -> None:
        if self.method not in ("none", "clahe"):
            raise EnhanceError(f"unknown feature enhancement {self.method!r}")


@dataclass(frozen=True, kw_only=True)
class ColourConfig:
    """Sea-thru of the output colours, after depth."""

    enabled: bool = False
    """Opt-in: restore the colours of points, meshes and textures."""
    seathru: SeathruConfig = field(default_factory=SeathruConfig)
    """Sea-thru settings."""
    fallback: Literal["grey-world", "none"] = "grey-world"
    """What a frame gets when Sea-thru cannot run (too little depth, saturated image)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class ColourResult:
    """Restored colours of one frame.

    Attributes:
        image: the image for colouring output, the input's dtype.
        status: ``ok``, ``disabled``, ``fallback-grey-world`` or ``fallback-none`` (with the
            reason in ``notes``).
        model: the Sea-thru model, when it ran.
        notes: messages for the frame report.
    """

    image: np.ndarray
    status: str
    model: SeathruModel | None = None
    notes: tuple[str, ...] = ()


def enhance_for_matching(image: np.ndarray, config: MatchEnhanceConfig) -> np.ndarray:
    """One image before matching (white balances computed on this image alone)."""
    if config.method == "none":
        return image
    params: dict[str, Any] = (
        {"clip_limit": config.clahe_clip_limit} if config.method == "clahe" else {}
    )
    return enhance_image(image, config.method, **params).images[0]


def enhance_pair_for_matching(
    left: np.ndarray, right: np.ndarray, config: MatchEnhanceConfig
) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair before matching; white balances share one set of gains."""
    if config.method == "none":
        return left, right
    params: dict[str, Any] = (
        {"clip_limit": config.clahe_clip_limit} if config.method == "clahe" else {}
    )
    out = enhance_pair(left, right, config.method, **params).images
    return out[0], out[1]


def enhance_for_features(image: np.ndarray, config: FeatureEnhanceConfig) -> np.ndarray:
    """An image (RGB or grey) before feature detection."""
    if config.method == "none":
        return image
    return clahe(image, clip_limit=config.clahe_clip_limit, tile_grid=config.clahe_tiles)


def _wxh(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else str(shape)


def restore_colours(
    image: np.ndarray,
    depth_m: np.ndarray,
    focal_px: float,
    cx_px: float,
    cy_px: float,
    config: ColourConfig,
    *,
    fy_px: float | None = None,
) -> ColourResult:
    """Sea-thru of a rectified left image with its metric depth (the depth stage's output).

    Args:
        image: ``(H, W, 3)`` rectified left image.
        depth_m: ``(H, W)`` float32 depth along the rectified z axis, metres, NaN invalid.
        focal_px, cx_px, cy_px: rectified intrinsics (``fy_px`` defaults to ``focal_px``).
        config: :class:`ColourConfig`.

    Returns:
        :class:`ColourResult`, as :func:`restore_colours_with_range`.

    Raises:
        EnhanceError: only for a malformed image (wrong shape or dtype).
    """
    if not config.enabled:
        return ColourResult(image=image, status="disabled")
    if np.asarray(depth_m).shape != np.asarray(image).shape[:2]:
        raise EnhanceError(
            f"depth is {_wxh(np.asarray(depth_m).shape)} but the image is "
            f"{_wxh(np.asarray(image).shape)}"
        )
    range_m = depth_to_range(depth_m, focal_px, fy_px or focal_px, cx_px, cy_px)
    return restore_colours_with_range(image, range_m, config)


def restore_colours_with_range(
    image: np.ndarray, range_m: np.ndarray, config: ColourConfig
) -> ColourResult:
    """Sea-thru of an image with the metric range of its own pixels (e.g. the norms of the
    stereo points in the camera frame, which are exact through dome and flat ports).

    Args:
        image: ``(H, W, 3)`` image (a grey ``(H, W)`` image falls back: no colour to restore).
        range_m: ``(H, W)`` float32 range along the line of sight, metres, NaN invalid.
        config: :class:`ColourConfig`.

    Returns:
        :class:`ColourResult`; never raises for bad range or a saturated frame: it falls back
        as ``config.fallback`` says and reports why.

    Raises:
        EnhanceError: only for a range map of another size than the image.
    """
    if not config.enabled:
        return ColourResult(image=image, status="disabled")
    img = np.asarray(image)
    if np.asarray(range_m).shape != img.shape[:2]:
        raise EnhanceError(
            f"range is {_wxh(np.asarray(range_m).shape)} but the image is {_wxh(img.shape)}"
        )
    if img.ndim != 3:
        return ColourResult(image=image, status="fallback-none",
                            notes=("a grey image has no colour to restore",))
    try:
        res = seathru(image, range_m, config.seathru)
    except EnhanceError as err:
        _log.info("colour restoration fell back: %s", err)
        if config.fallback == "grey-world":
            return ColourResult(
                image=grey_world(image), status="fallback-grey-world", notes=(str(err),)
            )
        return ColourResult(image=image, status="fallback-none", notes=(str(err),))
    return ColourResult(image=res.image, status=res.status, model=res.model, notes=res.notes)
