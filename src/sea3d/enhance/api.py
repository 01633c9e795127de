"""One entry point for the single-image methods: :func:`enhance_image` by method name."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d.enhance.colour import white_balance_pair
from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.registry import METHODS, enhancement, resolve
from sea3d.enhance.seathru import SeathruModel, apply_seathru, fit_seathru
from sea3d.enhance.water import WaterFitConfig, WaterModel
from sea3d.errors import EnhanceError

__all__ = ["METHODS", "EnhanceOutcome", "enhance_image", "enhance_pair"]


@dataclass(frozen=True, kw_only=True, eq=False)
class EnhanceOutcome:
    """An enhanced image (or pair) and what was done.

    Attributes:
        images: the enhanced image(s), the inputs' dtypes.
        method: the method name.
        status: ``ok``, or what fell back (e.g. ``fallback-grey-world``).
        model: the fitted per-image Sea-thru model (``seathru`` with a ``seathru_config``).
        water_model: the water model used (``seathru`` by default).
        notes: messages worth showing.
    """

    images: tuple[np.ndarray, ...]
    method: str
    status: str = "ok"
    model: SeathruModel | None = None
    water_model: WaterModel | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)


def _seathru(
    frames: list[tuple[np.ndarray, np.ndarray]], config: SeathruConfig | None,
    water_model: WaterModel | None,
) -> EnhanceOutcome:
    """Sea-thru of these frames, then each frame restored with its own range: the water model
    is fitted to all of them (or is the dive's ``water_model``); a per-image Sea-thru is
    fitted to the first (pooling a pair measured worse in turbid water, docs/enhance.md)."""
    cfg = config or WaterFitConfig()
    model: SeathruModel | WaterModel
    if cfg.water_model and water_model is not None:
        model = water_model
    else:
        model = fit_seathru(frames if cfg.water_model else frames[:1], cfg)
    outs = [apply_seathru(img, rng, model, cfg) for img, rng in frames]
    bad = [o.status for o in outs if o.status != "ok"]
    notes = tuple(dict.fromkeys(n for o in outs for n in o.notes))
    return EnhanceOutcome(
        images=tuple(o.image for o in outs), method="seathru", status=bad[0] if bad else "ok",
        model=model if isinstance(model, SeathruModel) else None,
        water_model=model if isinstance(model, WaterModel) else None, notes=notes,
    )


def _check_method(method: str) -> None:
    enhancement(method)  # raises for an unknown name


def _single(image: np.ndarray, method: str, params: dict[str, Any]) -> np.ndarray:
    out: np.ndarray = resolve(enhancement(method).function)(image, **params)
    return out


def enhance_image(
    image: np.ndarray,
    method: str,
    *,
    range_m: np.ndarray | None = None,
    seathru_config: SeathruConfig | None = None,
    water_model: WaterModel | None = None,
    **params: Any,
) -> EnhanceOutcome:
    """Enhance one image with the named method.

    ``seathru`` inverts a :class:`~sea3d.enhance.water.WaterModel` (``water_model``, fitted
    once per dive by :func:`~sea3d.enhance.water.fit_water_model`, or fitted to this image
    alone when None): measured well below grey world where the per-image Sea-thru of
    :mod:`sea3d.enhance.seathru` was not (``docs/enhance.md``). A ``seathru_config`` with
    another attenuation than ``water-model`` runs that per-image Sea-thru instead.

    Args:
        image: ``(H, W, 3)`` RGB (``(H, W)`` grey for ``clahe``), ``uint8``/``uint16``/float.
        method: one of :data:`METHODS` (:mod:`sea3d.enhance.registry`).
        range_m: ``(H, W)`` range in metres, NaN invalid (``seathru`` only, required there).
        seathru_config: the Sea-thru settings (:class:`~sea3d.enhance.config.SeathruConfig`;
            None: the water model's defaults); ``water_model`` is used only with
            ``attenuation="water-model"``.
        water_model: the dive's water model (``seathru``).
        **params: keyword parameters of the method's function (e.g. ``clip_limit``).

    Raises:
        EnhanceError: unknown method, Sea-thru without range (or with range from another
            grid, or none usable), and each method's own errors.
    """
    _check_method(method)
    if method == "seathru":
        if range_m is None:
            raise EnhanceError("seathru needs a range or depth map (range_m)")
        return _seathru([(image, range_m)], seathru_config, water_model)
    return EnhanceOutcome(images=(_single(image, method, params),), method=method)


def enhance_pair(
    left: np.ndarray,
    right: np.ndarray,
    method: str,
    *,
    range_left_m: np.ndarray | None = None,
    range_right_m: np.ndarray | None = None,
    seathru_config: SeathruConfig | None = None,
    water_model: WaterModel | None = None,
    **params: Any,
) -> EnhanceOutcome:
    """Enhance a stereo pair so that both images keep one colour: white balances share their
    gains (:func:`white_balance_pair`), Sea-thru's water model is fitted to both images (or
    given; a per-image Sea-thru is fitted to the left) and restores each with its own range
    map; CLAHE and UDCP work per image.

    Raises:
        EnhanceError: as :func:`enhance_image`.
    """
    _check_method(method)
    if enhancement(method).pair_balance:
        lo, ro = white_balance_pair(left, right, method, **params)
        return EnhanceOutcome(images=(lo, ro), method=method)
    if method == "seathru":
        if range_left_m is None or range_right_m is None:
            raise EnhanceError("seathru needs a range map for each image of the pair")
        return _seathru([(left, range_left_m), (right, range_right_m)], seathru_config,
                        water_model)
    return EnhanceOutcome(
        images=(_single(left, method, params), _single(right, method, params)), method=method
    )
