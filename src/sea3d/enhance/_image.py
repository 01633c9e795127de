"""Image plumbing shared by the enhancement methods: checks, value scaling and sRGB transfer.

Every method accepts ``uint8``, ``uint16`` or float images and returns the same dtype. Integer
images are scaled to ``[0, 1]`` (``/255``, ``/65535``); float images are taken as ``[0, 1]``
already. All of them are *display-encoded* (sRGB) unless a method is told
``encoding="linear"``: physics-based steps (white balance gains, Sea-thru, caustic ratios) run
on linear values obtained with the exact IEC 61966-2-1 transfer curve.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32
from sea3d.errors import EnhanceError

__all__ = [
    "DECODE_SRGB_U8",
    "Encoding",
    "as_unit_float",
    "decode",
    "encode",
    "encode_srgb_table_u8",
    "from_unit_float",
    "linear_to_srgb",
    "luminance",
    "require_rgb",
    "saturated_mask",
    "srgb_to_linear",
]

Encoding = Literal["srgb", "linear"]

# Rec. 709 / sRGB luminance weights of linear RGB (IEC 61966-2-1).
LUMA_709 = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def as_unit_float(image: object, what: str = "image") -> tuple[F32, np.dtype]:
    """``image`` as float32 in ``[0, 1]`` and its original dtype.

    Args:
        image: ``(H, W)`` or ``(H, W, 3)`` array, ``uint8``, ``uint16`` or float.
        what: name used in error messages.

    Raises:
        EnhanceError: another shape or dtype, an empty image, or non-finite float values.
    """
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3) or arr.size == 0:
        raise EnhanceError(
            f"{what}: expected an (H, W) or (H, W, 3) image, got shape {arr.shape}"
        )
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) * np.float32(1.0 / 255.0), arr.dtype
    if arr.dtype == np.uint16:
        return arr.astype(np.float32) * np.float32(1.0 / 65535.0), arr.dtype
    if arr.dtype.kind == "f":
        out = arr.astype(np.float32, copy=True)
        if not np.all(np.isfinite(out)):
            raise EnhanceError(f"{what}: float image holds NaN or infinite values")
        return np.clip(out, 0.0, None), arr.dtype
    raise EnhanceError(f"{what}: unsupported dtype {arr.dtype}; use uint8, uint16 or float")


def from_unit_float(img01: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Back to ``dtype`` from ``[0, 1]`` float (clipped; integers rounded)."""
    x = np.clip(np.asarray(img01, dtype=np.float32), 0.0, 1.0)
    if dtype == np.uint8:
        return (x * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)
    if dtype == np.uint16:
        return (x * np.float32(65535.0) + np.float32(0.5)).astype(np.uint16)
    return x.astype(dtype, copy=False)


def require_rgb(img: np.ndarray, method: str, what: str = "image") -> None:
    """Raise unless ``img`` is ``(H, W, 3)``: colour methods have no colour to work on in a
    one-channel image.

    Raises:
        EnhanceError: for a one-channel image.
    """
    if img.ndim != 3:
        raise EnhanceError(
            f"{what}: {method} needs an RGB image (H, W, 3), got a one-channel image "
            f"{img.shape}; use clahe for grey images"
        )


def srgb_to_linear(x: np.ndarray) -> F32:
    """IEC 61966-2-1 sRGB decoding of ``[0, 1]`` values to linear light."""
    v = np.asarray(x, dtype=np.float32)
    lo = v * np.float32(1.0 / 12.92)
    hi = np.power((v + np.float32(0.055)) * np.float32(1.0 / 1.055), np.float32(2.4))
    return np.where(v <= np.float32(0.04045), lo, hi).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> F32:
    """IEC 61966-2-1 sRGB encoding of linear ``[0, 1]`` values (clipped to ``[0, 1]``)."""
    v = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    lo = v * np.float32(12.92)
    hi = np.float32(1.055) * np.power(v, np.float32(1.0 / 2.4)) - np.float32(0.055)
    return np.where(v <= np.float32(0.0031308), lo, hi).astype(np.float32)


def to_linear(img01: np.ndarray, encoding: Encoding) -> F32:
    """Linear values of a ``[0, 1]`` image in ``encoding``."""
    if encoding == "linear":
        return np.asarray(img01, dtype=np.float32)
    if encoding == "srgb":
        return srgb_to_linear(img01)
    raise EnhanceError(f"encoding must be 'srgb' or 'linear', got {encoding!r}")


def from_linear(lin: np.ndarray, encoding: Encoding) -> F32:
    """Encode linear values back to ``encoding`` (clipped to ``[0, 1]``)."""
    if encoding == "linear":
        return np.clip(np.asarray(lin, dtype=np.float32), 0.0, 1.0)
    return linear_to_srgb(lin)


_CODES = np.arange(256) / 255.0
DECODE_SRGB_U8: F32 = np.where(
    _CODES <= 0.04045, _CODES / 12.92, ((_CODES + 0.055) / 1.055) ** 2.4
).astype(np.float32)
"""Linear value of each 8-bit sRGB code, correctly rounded to float32 (code 255 is exactly 1;
:func:`srgb_to_linear`, in float32, differs by at most 2e-7)."""

_ENCODE_SRGB_U8: NDArray[np.uint8] | None = None


def decode(image: object, encoding: Encoding = "srgb", what: str = "image") -> tuple[F32, np.dtype]:
    """An image in ``encoding`` as linear float32 and its original dtype (8-bit sRGB by
    :data:`DECODE_SRGB_U8`).

    Raises:
        EnhanceError: as :func:`as_unit_float`, or an unknown encoding.
    """
    arr = np.asarray(image)
    if arr.dtype == np.uint8 and encoding == "srgb" and arr.ndim in (2, 3) and arr.size:
        if arr.ndim == 2 or arr.shape[2] == 3:
            return DECODE_SRGB_U8[arr], arr.dtype
    img, dtype = as_unit_float(arr, what)
    return to_linear(img, encoding), dtype


def encode(lin: np.ndarray, dtype: np.dtype, encoding: Encoding = "srgb") -> np.ndarray:
    """Linear values back to ``encoding`` in ``dtype`` (clipped to ``[0, 1]``; integers
    rounded)."""
    return from_unit_float(from_linear(lin, encoding), dtype)


def encode_srgb_table_u8() -> NDArray[np.uint8]:
    """8-bit sRGB code of each of 65536 linear steps over ``[0, 1]`` (entry ``k``: linear
    ``k / 65535``, the curve in float64), for per-pixel kernels."""
    global _ENCODE_SRGB_U8
    if _ENCODE_SRGB_U8 is None:
        x = np.linspace(0.0, 1.0, 65536)
        s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
        _ENCODE_SRGB_U8 = (s * 255.0 + 0.5).astype(np.uint8)
    return _ENCODE_SRGB_U8


def luminance(lin_rgb: np.ndarray) -> F32:
    """Rec. 709 luminance ``(H, W)`` of a linear ``(H, W, 3)`` image."""
    return np.asarray(lin_rgb, dtype=np.float32) @ LUMA_709


def saturated_mask(img01: np.ndarray, level: float = 0.98) -> NDArray[np.bool_]:
    """``(H, W)`` True where any channel of a ``[0, 1]`` image reaches ``level`` (clipped
    highlights carry no colour information)."""
    if img01.ndim == 2:
        return np.asarray(img01 >= level)
    return np.asarray(np.any(img01 >= level, axis=2))
