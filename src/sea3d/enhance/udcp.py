"""UDCP, the underwater dark channel prior, as a dehazing baseline.

Drews Jr., do Nascimento, Moraes, Botelho and Campos, "Transmission estimation in underwater
single images", ICCV Workshops 2013: He, Sun and Tang's dark channel prior (CVPR 2009) taken
over the green and blue channels only, since red is absorbed and would make every underwater
pixel look "dark". On display values in ``[0, 1]`` (as the prior was derived and published)::

    dark(x)   = min_{y in patch(x)} min_{c in {G, B}} I_c(y)
    A         = I at the brightest (mean RGB) of the 0.1 % pixels with the highest dark(x)
    t~(x)     = 1 - omega * min_{y in patch(x)} min_{c in {G, B}} I_c(y) / A_c
    t(x)      = guided filter of t~ with the grey image as guide (He, Sun and Tang, ECCV 2010)
    J_c(x)    = (I_c(x) - A_c) / max(t(x), t_min) + A_c

with He et al.'s ``omega = 0.95`` and ``t_min = 0.1`` and a 15 px patch. The guided filter is
OpenCV contrib's ``cv2.ximgproc.guidedFilter``.
"""

from __future__ import annotations

import cv2
import numpy as np

from sea3d._typing import F32
from sea3d.enhance._image import as_unit_float, from_unit_float, require_rgb
from sea3d.errors import EnhanceError

__all__ = ["udcp"]


def _min_filter(x: F32, patch_px: int) -> F32:
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (patch_px, patch_px))
    return np.asarray(cv2.erode(x, kernel, borderType=cv2.BORDER_REFLECT), dtype=np.float32)


def udcp(
    image: np.ndarray,
    *,
    patch_px: int = 15,
    omega: float = 0.95,
    t_min: float = 0.1,
    top_fraction: float = 0.001,
    guided_radius_px: int | None = None,
    guided_eps: float = 1e-3,
) -> np.ndarray:
    """Dehaze with the underwater dark channel prior (see the module docstring).

    Args:
        image: ``(H, W, 3)`` RGB, ``uint8``/``uint16``/float ``[0, 1]`` (display values).
        patch_px: odd side of the dark-channel patch, pixels.
        omega: share of the haze removed (1 = all; He et al. keep 5 %).
        t_min: lower bound on the transmission.
        top_fraction: share of highest dark-channel pixels searched for the veiling light.
        guided_radius_px: guided-filter radius (default four patch sides).
        guided_eps: guided-filter regularisation (image values in ``[0, 1]``).

    Returns:
        The dehazed image, same dtype.

    Raises:
        EnhanceError: a one-channel image, an even or non-positive patch, parameters out of
            range.
    """
    if patch_px < 1 or patch_px % 2 == 0:
        raise EnhanceError(f"patch_px must be odd and positive, got {patch_px}")
    if not (0 < omega <= 1 and 0 < t_min < 1 and 0 < top_fraction <= 1):
        raise EnhanceError(
            f"need 0 < omega <= 1, 0 < t_min < 1, 0 < top_fraction <= 1; got {omega}, "
            f"{t_min}, {top_fraction}"
        )
    img, dtype = as_unit_float(image)
    require_rgb(img, "udcp")
    img = np.clip(img, 0.0, 1.0)
    gb_min = np.minimum(img[..., 1], img[..., 2])
    dark = _min_filter(gb_min, patch_px)
    n = dark.size
    k = max(1, round(top_fraction * n))
    top = np.argpartition(dark.ravel(), n - k)[n - k :]
    flat = img.reshape(-1, 3)
    brightest = top[np.argmax(flat[top].mean(axis=1))]
    A = np.maximum(flat[brightest].astype(np.float32), np.float32(1e-3))
    norm_min = np.minimum(img[..., 1] / A[1], img[..., 2] / A[2]).astype(np.float32)
    t_raw = 1.0 - np.float32(omega) * _min_filter(norm_min, patch_px)
    radius = int(guided_radius_px) if guided_radius_px is not None else 4 * patch_px
    guide = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    t = cv2.ximgproc.guidedFilter(guide, t_raw.astype(np.float32), radius, float(guided_eps))
    t = np.maximum(t, np.float32(t_min))[..., None]
    out = (img - A) / t + A
    return from_unit_float(out, dtype)
