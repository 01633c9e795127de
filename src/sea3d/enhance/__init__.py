"""Underwater image enhancement: white balance, CLAHE on L*, UDCP dehazing, Sea-thru colour
restoration with metric stereo range, caustic removal over registered frames, and the image
quality figures that judge them (``docs/enhance.md``).

Every method takes ``uint8``, ``uint16`` or float ``[0, 1]`` images (sRGB unless told
``encoding="linear"``) and returns the input's dtype. Stage functions for ``sea3d process``
are in :mod:`sea3d.enhance.stage`.
"""

from sea3d.enhance.api import METHODS, EnhanceOutcome, enhance_image, enhance_pair
from sea3d.enhance.caustics import CausticConfig, CausticResult, remove_caustics
from sea3d.enhance.colour import grey_world, red_compensation, shades_of_grey, white_balance_pair
from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.contrast import clahe
from sea3d.enhance.metrics import (
    ReferenceMetrics,
    UciqeScore,
    UiqmScore,
    ciede2000,
    ciede2000_after_diagonal_gain,
    ciede2000_after_gain,
    colour_cast,
    compare_to_reference,
    uciqe,
    uiqm,
)
from sea3d.enhance.registry import ENHANCEMENTS
from sea3d.enhance.seathru import (
    SeathruModel,
    SeathruResult,
    apply_seathru,
    depth_to_range,
    fit_seathru,
    range_from_points,
    seathru,
)
from sea3d.enhance.udcp import udcp
from sea3d.enhance.water import (
    RestoreResult,
    WaterFitConfig,
    WaterModel,
    fit_water_model,
    restore,
)

__all__ = [
    "ENHANCEMENTS",
    "METHODS",
    "CausticConfig",
    "CausticResult",
    "EnhanceOutcome",
    "ReferenceMetrics",
    "RestoreResult",
    "SeathruConfig",
    "SeathruModel",
    "SeathruResult",
    "UciqeScore",
    "UiqmScore",
    "WaterFitConfig",
    "WaterModel",
    "apply_seathru",
    "ciede2000",
    "ciede2000_after_diagonal_gain",
    "ciede2000_after_gain",
    "clahe",
    "colour_cast",
    "compare_to_reference",
    "depth_to_range",
    "enhance_image",
    "enhance_pair",
    "fit_seathru",
    "fit_water_model",
    "grey_world",
    "range_from_points",
    "red_compensation",
    "remove_caustics",
    "restore",
    "seathru",
    "shades_of_grey",
    "uciqe",
    "udcp",
    "uiqm",
    "white_balance_pair",
]
