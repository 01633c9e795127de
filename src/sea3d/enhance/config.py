"""Sea-thru's settings: one frozen config for every way of restoring colours with range, the
dive's water model (``attenuation="water-model"``) and the per-image stages alike.

A few numbers have a default per attenuation mode (measured separately for each,
``docs/enhance.md``): left out, they are set when the config is made.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from sea3d.enhance._image import Encoding
from sea3d.errors import EnhanceError

__all__ = ["ATTENUATIONS", "SeathruConfig"]

Attenuation = Literal["water-model", "fit", "fit-scaled", "illuminant", "none"]
ATTENUATIONS: tuple[str, ...] = ("water-model", "fit", "fit-scaled", "illuminant", "none")
"""The attenuation modes of :attr:`SeathruConfig.attenuation`."""

_BY_MODE: Any = None
# (water-model, per-image) defaults of the numbers that have one per mode.
_MODE_DEFAULTS: dict[str, tuple[float, float]] = {
    "range_bins": (12, 10),
    "work_max_side_px": (240, 400),
    "max_restore_gain": (20.0, 30.0),
}


@dataclass(frozen=True, kw_only=True)
class SeathruConfig:
    """Sea-thru settings; every stage can be switched off."""

    backscatter: bool = True
    """Estimate and remove backscatter (stage 1; the water model always does)."""
    attenuation: Attenuation = "illuminant"
    """Stage 2: ``water-model`` fits one wideband water (``B_inf``, ``beta_B``, ``beta_D`` per
    channel) to one frame or many frames of a dive, then inverts it in every frame
    (:mod:`sea3d.enhance.water`); the per-image stages divide by the range-gated
    ``illuminant`` map (the paper's coarse estimate, Eq. 12-13), ``fit`` the paper's
    ``beta_D(z)`` to it (Eq. 14), ``fit-scaled`` (the same with a free per-channel scale of
    the illuminant instead of ``f``), or ``none``."""
    white_balance: Literal["grey-world", "locus", "auto", "none"] = "grey-world"
    """Stage 3, after the inversion: ``grey-world`` over every fitted frame's restored pixels
    with range (as Sea-thru white-balances its ``J``, Akkaynak and Treibitz, CVPR 2019,
    Sec. 4), or ``none``. The water model also has ``locus`` (removes an ambient light that
    crossed ``d >= 0`` metres of the same water: gains ``exp(beta_D d)``, the ``d`` that brings
    the scene closest to grey) and ``auto`` (none where ``beta_D`` is identified, grey world
    where not)."""
    exposure: Literal["white-point", "none"] = "white-point"
    """Scale the result so the ``white_point_percentile`` of its brightest channel is 1."""
    holes: Literal["inpaint", "mask"] = "inpaint"
    """Pixels without range: restore with range filled from around them, or leave them out
    (``mask``: they get the white balance and exposure only)."""
    backscatter_fit: Literal["eq10", "envelope"] = "envelope"
    """Per-image stages: ``envelope``, the highest backscatter curve that stays below the
    dark level of every range bin (measured robust where the darkest pixels are not black);
    ``eq10``: the paper's least-squares fit of Eq. 10 to the dark pixels."""
    range_bins: int = _BY_MODE
    """Range bins for the dark-pixel search (default 12 for the water model, over the pooled
    span; 10, the paper's, for the per-image stages)."""
    dark_percentile: float = 1.0
    """Per bin, the share (percent) of darkest pixels taken as backscatter (the paper's 1)."""
    lsac_p: float = 0.002
    """Illuminant: LSAC update weight ``p`` at the working resolution; the averaging support
    spans about ``1 / sqrt(p)`` working pixels."""
    lsac_range_tolerance: float = 0.05
    """Illuminant: LSAC neighbours must lie within this fraction of the pixel's range."""
    lsac_f: float = 2.0
    """Illuminant = ``f`` x local average (the paper's f = 2)."""
    work_max_side_px: int = _BY_MODE
    """Longer image side at which range holes are filled and the LSAC runs (default 240 for
    the water model, 400 for the per-image stages)."""
    denoise: bool = True
    """Per-image stages: smooth the restored image where the restoration amplified it
    (stage 4): the noise of far, attenuated pixels grows with the gain, chroma noise most."""
    denoise_chroma_sigma_px: float = 2.0
    """Gaussian of the chroma (linear RGB minus luminance), pixels."""
    denoise_luma_sigma_px: float = 0.8
    """Gaussian of the luminance, pixels."""
    denoise_full_gain: float = 8.0
    """Noise gain (largest channel gain of restoration, white balance and exposure) at which
    the smoothed image fully replaces the restored one (blend weight
    ``log2(gain) / log2(denoise_full_gain)``, 0 at gain 1)."""
    white_point_percentile: float = 99.5
    """Percentile of the brightest channel mapped to 1 by ``exposure="white-point"``."""
    max_restore_gain: float = _BY_MODE
    """Cap on the attenuation compensation ``exp(beta_D z)`` and on the white-balance gains
    (default 20 for the water model, 30 for the per-image stages)."""
    saturation_level: float = 0.98
    """Pixels with a channel at or above this (``[0, 1]``) are left out of every fit."""
    min_valid_fraction: float = 0.02
    """Least share of pixels with range: below it a per-image fit refuses the image and the
    water model gives the frame its white balance only."""
    fit_pixels: int = 4000
    """Fit of ``beta_D(z)``: pixels sampled (evenly over the image)."""
    encoding: Encoding = "srgb"
    """Encoding of input and output: ``srgb`` (decoded to linear inside) or ``linear``."""
    min_range_ratio: float = 1.25
    """Water model: ``beta_D`` is identified only if the 95th percentile of range is at least
    this many times the 5th (a narrow span cannot tell attenuation from albedo)."""
    min_bins: int = 4
    """Water model: least populated range bins for the fits."""
    min_texture: float = 0.5 / 255.0
    """Water model: pixels whose 5x5 standard deviation of brightness (``[0, 1]``) is below
    this are left out of the fits: a flat region (open water) holds no albedo, and stereo range
    there is unreliable."""
    max_fill_fraction: float = 0.03
    """Water model with ``holes="inpaint"``: pixels farther than this fraction of the longer
    image side from any pixel with range (open water, where there is no surface to give range)
    are not filled: they get the white balance and exposure only, never an invented range."""
    below_floor: Literal["white-balance", "floor"] = "white-balance"
    """Water model: a fitted ``beta_D`` below what any natural water has (metric range):
    ``white-balance`` does not invert the water at all (status ``backscatter-unidentified``:
    the fit could not tell the direct signal from the backscatter, so neither fitted term is
    trusted); ``floor`` raises those channels to the floor and keeps the backscatter fitted
    again with it (``attenuation-floor``)."""
    metric_range: bool = True
    """Water model: the range is in metres, so the fitted ``beta_D`` is also checked against
    what any natural water has. False for range in other units (a board's squares), where
    only the unit-free limits hold."""

    @classmethod
    def as_published(cls, **overrides: object) -> SeathruConfig:
        """Sea-thru as the paper describes it: Eq. 10 backscatter, Eq. 14 ``beta_D(z)`` fit."""
        kw: dict[str, object] = {"backscatter_fit": "eq10", "attenuation": "fit", **overrides}
        return cls(**kw)  # type: ignore[arg-type]

    @property
    def water_model(self) -> bool:
        """The attenuation is the dive's wideband water model."""
        return self.attenuation == "water-model"

    def __post_init__(self) -> None:
        if self.attenuation not in ATTENUATIONS:
            raise EnhanceError(f"unknown attenuation mode {self.attenuation!r}")
        for name, (water, per_image) in _MODE_DEFAULTS.items():
            if getattr(self, name) is None:
                value = water if self.water_model else per_image
                object.__setattr__(self, name, type(value)(value))
        self._check_stages()
        self._check_numbers()

    def _check_stages(self) -> None:
        if self.white_balance not in ("grey-world", "locus", "auto", "none"):
            raise EnhanceError(f"unknown white balance {self.white_balance!r}")
        if self.white_balance in ("locus", "auto") and not self.water_model:
            raise EnhanceError(f"white_balance {self.white_balance!r} needs attenuation "
                               "'water-model'")
        if self.water_model and not self.backscatter:
            raise EnhanceError("the water model always fits backscatter: backscatter=False "
                               "needs a per-image attenuation")
        if self.exposure not in ("white-point", "none"):
            raise EnhanceError(f"unknown exposure mode {self.exposure!r}")
        if self.backscatter_fit not in ("eq10", "envelope"):
            raise EnhanceError(f"unknown backscatter fit {self.backscatter_fit!r}")
        if self.holes not in ("inpaint", "mask"):
            raise EnhanceError(f"holes must be 'inpaint' or 'mask', got {self.holes!r}")
        if self.below_floor not in ("white-balance", "floor"):
            raise EnhanceError(f"below_floor must be white-balance or floor, got "
                               f"{self.below_floor!r}")

    def _check_numbers(self) -> None:
        if self.range_bins < (3 if self.water_model else 1):
            raise EnhanceError(f"range_bins must be >= {3 if self.water_model else 1}, got "
                               f"{self.range_bins}")
        if not (0 < self.dark_percentile < 50):
            raise EnhanceError(f"dark_percentile must be in (0, 50), got {self.dark_percentile}")
        if not (0 < self.lsac_p < 1) or self.lsac_range_tolerance <= 0 or self.lsac_f <= 0:
            raise EnhanceError("need 0 < lsac_p < 1, lsac_range_tolerance > 0, lsac_f > 0")
        if self.work_max_side_px < 16:
            raise EnhanceError(f"work_max_side_px must be >= 16, got {self.work_max_side_px}")
        if not self.max_restore_gain >= 1:
            raise EnhanceError(f"max_restore_gain must be >= 1, got {self.max_restore_gain}")
        if not (50 < self.white_point_percentile <= 100):
            raise EnhanceError("white_point_percentile must be in (50, 100]")
        if self.denoise_full_gain <= 1 or min(self.denoise_chroma_sigma_px,
                                              self.denoise_luma_sigma_px) < 0:
            raise EnhanceError("need denoise_full_gain > 1 and non-negative denoise sigmas")
        if not (0 < self.min_valid_fraction <= 1):
            raise EnhanceError("min_valid_fraction must be in (0, 1]")
