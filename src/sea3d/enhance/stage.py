"""The colour stage of ``sea3d process --restore-colours seathru``: Sea-thru of the rectified
left image with the stereo range of its own pixels, after depth, for the colours of the cloud,
the mesh and the frame report.

Enhancement *before* matching (``sea3d process --enhance NAME``) is not a stage function: the
name resolves to a per-image hook through the one registry,
:func:`sea3d.enhance.registry.process_enhance_hook`, and the per-frame stage applies it to the
raw images. The defaults follow what ``benchmarks/bench_enhance.py`` measured
(``docs/enhance.md``): no method lowered our SGM's bad-2 by more than 0.1 point on simulated
underwater pairs, so matching gets the raw images; Sea-thru of the output colours is opt-in.

Like every per-frame stage the function takes arrays and frozen configs, reads or writes no
files, and never raises for a frame it cannot restore: it falls back and says why
(:attr:`ColourResult.status`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from sea3d.enhance.colour import grey_world
from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.seathru import SeathruModel, apply_seathru, fit_seathru
from sea3d.enhance.water import WaterFitConfig, WaterModel
from sea3d.errors import EnhanceError

__all__ = ["ColourRestoreConfig", "ColourResult", "restore_colours_with_range"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class ColourRestoreConfig:
    """Sea-thru of the output colours, after depth."""

    enabled: bool = False
    """Opt-in: restore the colours of points, meshes and textures."""
    method: Literal["water-model", "seathru-per-image"] = "seathru-per-image"
    """``water-model``: invert the dive's :class:`WaterModel` (``water_model``, or one fitted
    to the frame when None; measured well below grey world under an independent formation
    model, ``docs/enhance.md``); ``seathru-per-image``: the per-image Sea-thru of
    :mod:`sea3d.enhance.seathru`, the default here because a water model fitted to each
    frame alone is less stable from frame to frame (log chromaticity 0.08 apart with
    slightly different range on a 192x108 frame, against 0.001); ``sea3d process
    --restore-colours water-model`` fits one per dive instead and passes the model here
    (:mod:`sea3d.pipeline.colour_stage`)."""
    water_model: WaterModel | None = None
    """The dive's water model (fitted once, :func:`fit_water_model`)."""
    seathru: SeathruConfig = field(default_factory=SeathruConfig)
    """Sea-thru settings: of the per-image Sea-thru (``method="seathru-per-image"``), or of
    the water model when its attenuation is ``water-model`` (else the water model's
    defaults)."""
    fallback: Literal["grey-world", "none"] = "grey-world"
    """What a frame gets when Sea-thru cannot run (too little depth, saturated image)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class ColourResult:
    """Restored colours of one frame.

    Attributes:
        image: the image for colouring output, the input's dtype.
        status: ``ok``, ``disabled``, a water-model fallback step
            (``attenuation-floor``, ``attenuation-unidentified``,
            ``backscatter-unidentified``),
            ``fallback-grey-world`` or ``fallback-none`` (with the reason in ``notes``).
        model: the per-image Sea-thru model, when it ran.
        water_model: the water model used, when it ran.
        notes: messages for the frame report.
    """

    image: np.ndarray
    status: str
    model: SeathruModel | None = None
    water_model: WaterModel | None = None
    notes: tuple[str, ...] = ()


def _wxh(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else str(shape)


def restore_colours_with_range(
    image: np.ndarray, range_m: np.ndarray, config: ColourRestoreConfig
) -> ColourResult:
    """Sea-thru of an image with the metric range of its own pixels (e.g. the norms of the
    stereo points in the camera frame, which are exact through dome and flat ports).

    Args:
        image: ``(H, W, 3)`` image (a grey ``(H, W)`` image falls back: no colour to restore).
        range_m: ``(H, W)`` float32 range along the line of sight, metres, NaN invalid.
        config: :class:`ColourRestoreConfig`.

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
        cfg = config.seathru
        if config.method == "water-model" and not cfg.water_model:
            cfg = WaterFitConfig()
        model: SeathruModel | WaterModel
        if cfg.water_model and config.water_model is not None:
            model = config.water_model
        else:
            model = fit_seathru([(img, range_m)], cfg)
        res = apply_seathru(img, range_m, model, cfg)
        if isinstance(model, WaterModel) and (res.status.startswith("refused")
                                              or res.status == "no-range"):
            raise EnhanceError("; ".join(res.notes) or res.status)
    except EnhanceError as err:
        _log.info("colour restoration fell back: %s", err)
        if config.fallback == "grey-world":
            return ColourResult(
                image=grey_world(image), status="fallback-grey-world", notes=(str(err),)
            )
        return ColourResult(image=image, status="fallback-none", notes=(str(err),))
    return ColourResult(
        image=res.image, status=res.status, notes=res.notes,
        model=model if isinstance(model, SeathruModel) else None,
        water_model=model if isinstance(model, WaterModel) else None,
    )
