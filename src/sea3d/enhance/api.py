"""One entry point for the single-image methods: :func:`enhance_image` by method name."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d.enhance.colour import white_balance_pair
from sea3d.enhance.registry import METHODS, enhancement, resolve
from sea3d.enhance.seathru import SeathruConfig, SeathruModel, apply_seathru, fit_seathru
from sea3d.errors import EnhanceError

__all__ = ["METHODS", "EnhanceOutcome", "enhance_image", "enhance_pair"]


@dataclass(frozen=True, kw_only=True, eq=False)
class EnhanceOutcome:
    """An enhanced image (or pair) and what was done.

    Attributes:
        images: the enhanced image(s), the inputs' dtypes.
        method: the method name.
        status: ``ok``, or what fell back (e.g. ``fallback-grey-world``).
        model: the fitted Sea-thru model (``seathru`` only).
        notes: messages worth showing.
    """

    images: tuple[np.ndarray, ...]
    method: str
    status: str = "ok"
    model: SeathruModel | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)


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
    **params: Any,
) -> EnhanceOutcome:
    """Enhance one image with the named method.

    Args:
        image: ``(H, W, 3)`` RGB (``(H, W)`` grey for ``clahe``), ``uint8``/``uint16``/float.
        method: one of :data:`METHODS` (:mod:`sea3d.enhance.registry`).
        range_m: ``(H, W)`` range in metres, NaN invalid (``seathru`` only, required there).
        seathru_config: Sea-thru settings.
        **params: keyword parameters of the method's function (e.g. ``clip_limit``).

    Raises:
        EnhanceError: unknown method, Sea-thru without range, and each method's own errors.
    """
    _check_method(method)
    if method == "seathru":
        if range_m is None:
            raise EnhanceError("seathru needs a range or depth map (--depth)")
        cfg = seathru_config or SeathruConfig()
        model = fit_seathru(image, range_m, cfg)
        res = apply_seathru(image, range_m, model, cfg)
        return EnhanceOutcome(
            images=(res.image,), method=method, status=res.status, model=model, notes=res.notes
        )
    return EnhanceOutcome(images=(_single(image, method, params),), method=method)


def enhance_pair(
    left: np.ndarray,
    right: np.ndarray,
    method: str,
    *,
    range_left_m: np.ndarray | None = None,
    range_right_m: np.ndarray | None = None,
    seathru_config: SeathruConfig | None = None,
    **params: Any,
) -> EnhanceOutcome:
    """Enhance a stereo pair so that both images keep one colour: white balances share their
    gains (:func:`white_balance_pair`), Sea-thru fits on the left and restores both with their
    own range maps; CLAHE and UDCP work per image.

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
        cfg = seathru_config or SeathruConfig()
        model = fit_seathru(left, range_left_m, cfg)
        rl = apply_seathru(left, range_left_m, model, cfg)
        rr = apply_seathru(right, range_right_m, model, cfg)
        status = rl.status if rl.status != "ok" else rr.status
        return EnhanceOutcome(
            images=(rl.image, rr.image), method=method, status=status, model=model,
            notes=rl.notes,
        )
    return EnhanceOutcome(
        images=(_single(left, method, params), _single(right, method, params)), method=method
    )
