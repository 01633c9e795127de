"""Image-quality figures for enhancement: full-reference (PSNR, SSIM, CIEDE2000, CIEDE2000 after
one global exposure gain) and no-reference (UIQM, UCIQE, colour cast).

Full-reference figures use scikit-image (``peak_signal_noise_ratio``, ``structural_similarity``
with ``data_range`` set, ``rgb2lab`` and ``deltaE_ciede2000``, which implements Sharma, Wu and
Dalal 2005). Images are sRGB in ``[0, 1]`` (integer images are scaled); an optional mask picks
the pixels that count (e.g. the simulator's pixels that see a surface).

"CIEDE2000 after gain" scales the *linear* image by the one scalar ``g`` that minimises the mean
CIEDE2000 to the reference (a bounded 1-D search over ``log2 g`` in ``[-5, 5]``): a method's
colour is judged apart from its overall exposure, which no method can know.

No-reference scores, as specified in their papers (constants below; where a paper leaves a
detail open, the choice made here is written next to it, and ``docs/enhance.md`` lists where
circulating implementations differ):

UIQM, Panetta, Gao and Agaian, "Human-visual-system-inspired underwater image quality
measures", IEEE J. Oceanic Engineering 41(3), 2016, on 8-bit RGB values (0-255)::

    UIQM   = 0.0282 UICM + 0.2953 UISM + 3.5753 UIConM
    UICM   = -0.0268 sqrt(mu_RG^2 + mu_YB^2) + 0.1586 sqrt(s2_RG + s2_YB),
             RG = R - G, YB = (R + G) / 2 - B, mu = asymmetric alpha-trimmed mean with
             alpha_L = alpha_R = 0.1 (drop ceil(0.1 K) lowest, floor(0.1 K) highest of K),
             s2 = mean squared deviation from mu over all K pixels
    UISM   = sum_c lambda_c EME(|Sobel(c)| * c),  lambda = (0.299, 0.587, 0.114)
    EME    = 2 / (k1 k2) sum_blocks log(I_max / I_min)
    UIConM = logAMEE(I), I = (R + G + B) / 3:
             (1 / (k1 k2)) (x) PLIP-sum_blocks -r log r,
             r = (I_max (-) I_min) / (I_max (+) I_min)

with the PLIP operations of Panetta, Wharton and Agaian (IEEE SMC-B 38(1), 2008):
``a (+) b = a + b - a b / gamma``, ``a (-) b = k (a - b) / (k - b)``,
``c (x) a = gamma - gamma (1 - a / gamma)^c``, ``gamma = k = 1026``. Choices: blocks of
``block_px`` x ``block_px`` pixels (8 by default; a partial last row or column of blocks is
dropped), natural logarithms, ``log((I_max + 1) / (I_min + 1))`` in EME so that blocks with a
zero minimum stay finite, the block sum taken with PLIP addition (a plain sum exceeds gamma on
large images, where the PLIP scalar product is undefined), and the entropy sign ``-r log r`` of
Agaian's AMEE (so that UIConM is non-negative, as its weight 3.5753 > 0 requires).

UCIQE, Yang and Sowmya, "An underwater color image quality evaluation metric", IEEE TIP 24(12),
2015, in CIELAB (D65)::

    UCIQE = 0.4680 sigma_c + 0.2745 con_l + 0.2576 mu_s

with ``sigma_c`` the standard deviation of chroma ``C* = sqrt(a*^2 + b*^2)``, ``con_l`` the
difference between the 99th and 1st percentiles of L*, and ``mu_s`` the mean saturation.
Choices: L* and C* divided by 100 (unit range), and saturation ``C* / sqrt(C*^2 + L*^2)``
(bounded in [0, 1], defined for black).

Both no-reference scores reward over-saturation and over-enhancement (the tests show it); use
them to compare like with like, never alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize, minimize_scalar
from skimage.color import deltaE_ciede2000, rgb2lab
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from sea3d._typing import F64
from sea3d.enhance._image import as_unit_float, linear_to_srgb, srgb_to_linear
from sea3d.errors import EnhanceError

__all__ = [
    "UCIQE_COEFFS",
    "UIQM_COEFFS",
    "ReferenceMetrics",
    "UciqeScore",
    "UiqmScore",
    "ciede2000",
    "ciede2000_after_diagonal_gain",
    "ciede2000_after_gain",
    "colour_cast",
    "compare_to_reference",
    "uciqe",
    "uiqm",
]


UIQM_COEFFS = (0.0282, 0.2953, 3.5753)  # Panetta et al. 2016: UICM, UISM, UIConM weights
UICM_COEFFS = (-0.0268, 0.1586)  # Panetta et al. 2016: mean and spread terms of UICM
UICM_ALPHA = 0.1  # alpha_L = alpha_R, Panetta et al. 2016
UISM_LAMBDA = (0.299, 0.587, 0.114)  # Panetta et al. 2016 (Rec. 601 luma weights)
PLIP_GAMMA = 1026.0  # gamma = k = 1026, Panetta, Wharton and Agaian 2008 (8-bit images)
UCIQE_COEFFS = (0.4680, 0.2745, 0.2576)  # Yang and Sowmya 2015

_GAIN_SEARCH_PIXELS = 60_000


def _pair(image: object, reference: object) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    a, _ = as_unit_float(image, "image")
    b, _ = as_unit_float(reference, "reference")
    if a.shape != b.shape:
        raise EnhanceError(
            f"image {a.shape[1]}x{a.shape[0]} and reference {b.shape[1]}x{b.shape[0]} differ "
            f"in size (or channels: {a.shape} vs {b.shape})"
        )
    if a.ndim != 3:
        raise EnhanceError(f"colour metrics need (H, W, 3) images, got {a.shape}")
    return np.clip(a, 0, 1), np.clip(b, 0, 1)


def _mask(mask: object | None, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    if mask is None:
        return np.ones(shape[:2], dtype=bool)
    m = np.asarray(mask, dtype=bool)
    if m.shape != shape[:2]:
        raise EnhanceError(f"mask {m.shape} does not match the image {shape[:2]}")
    if not m.any():
        raise EnhanceError("the evaluation mask selects no pixel")
    return m


def ciede2000(image: object, reference: object, mask: object | None = None) -> float:
    """Mean CIEDE2000 colour difference (scikit-image) over the masked pixels.

    Args:
        image: ``(H, W, 3)`` sRGB image.
        reference: ``(H, W, 3)`` sRGB image of the same size.
        mask: ``(H, W)`` bool pixels to count, or None for all.

    Raises:
        EnhanceError: different sizes, one-channel images, an empty mask.
    """
    a, b = _pair(image, reference)
    m = _mask(mask, a.shape)
    lab_a = rgb2lab(a[m][None].astype(np.float64))
    lab_b = rgb2lab(b[m][None].astype(np.float64))
    return float(np.mean(deltaE_ciede2000(lab_a, lab_b)))


def ciede2000_after_gain(
    image: object, reference: object, mask: object | None = None
) -> tuple[float, float]:
    """Mean CIEDE2000 after the one global exposure gain (on linear RGB) that minimises it.

    Returns:
        ``(mean delta E00, gain)``.

    Raises:
        EnhanceError: as :func:`ciede2000`.
    """
    a, b = _pair(image, reference)
    m = _mask(mask, a.shape)
    lin_a = srgb_to_linear(a[m]).astype(np.float64)
    lab_b_all = rgb2lab(b[m][None].astype(np.float64))
    n = lin_a.shape[0]
    idx = np.linspace(0, n - 1, min(n, _GAIN_SEARCH_PIXELS)).astype(np.int64)
    sub_a, sub_lab_b = lin_a[idx], lab_b_all[:, idx]

    def cost(log2_gain: float, px: F64 = sub_a, lab_ref: F64 = sub_lab_b) -> float:
        enc = linear_to_srgb(px * 2.0**log2_gain).astype(np.float64)
        return float(np.mean(deltaE_ciede2000(rgb2lab(enc[None]), lab_ref)))

    res = minimize_scalar(cost, bounds=(-5.0, 5.0), method="bounded", options={"xatol": 1e-3})
    log2_g = float(res.x) if cost(float(res.x)) <= cost(0.0) else 0.0
    return cost(log2_g, lin_a, lab_b_all), float(2.0**log2_g)


def ciede2000_after_diagonal_gain(
    image: object, reference: object, mask: object | None = None
) -> tuple[float, tuple[float, float, float]]:
    """Mean CIEDE2000 after the per-channel gains (on linear RGB) that minimise it: the colour
    error left once any global white balance is forgiven, i.e. what a method got wrong that
    no choice of white point could fix (range-dependent colour, haze, contrast).

    Returns:
        ``(mean delta E00, (g_R, g_G, g_B))``.

    Raises:
        EnhanceError: as :func:`ciede2000`.
    """
    a, b = _pair(image, reference)
    m = _mask(mask, a.shape)
    lin_a = srgb_to_linear(a[m]).astype(np.float64)
    lin_b = srgb_to_linear(b[m]).astype(np.float64)
    lab_b_all = rgb2lab(b[m][None].astype(np.float64))
    n = lin_a.shape[0]
    idx = np.linspace(0, n - 1, min(n, _GAIN_SEARCH_PIXELS // 12)).astype(np.int64)
    sub_a, sub_lab_b = lin_a[idx], lab_b_all[:, idx]

    def cost(log2_g: F64, px: F64 = sub_a, lab_ref: F64 = sub_lab_b) -> float:
        g = 2.0 ** np.clip(log2_g, -8.0, 8.0)
        enc = linear_to_srgb(px * g).astype(np.float64)
        return float(np.mean(deltaE_ciede2000(rgb2lab(enc[None]), lab_ref)))

    num, den = np.median(lin_b, axis=0), np.median(lin_a, axis=0)
    x0 = np.log2(np.where((num > 1e-6) & (den > 1e-6), num / np.maximum(den, 1e-6), 1.0))
    res = minimize(cost, x0, method="Powell", options={"xtol": 1e-2, "ftol": 1e-4, "maxfev": 90})
    best = np.asarray(res.x if cost(res.x) <= cost(x0) else x0, dtype=np.float64)
    g = 2.0 ** np.clip(best, -8.0, 8.0)
    return cost(best, lin_a, lab_b_all), (float(g[0]), float(g[1]), float(g[2]))


@dataclass(frozen=True, kw_only=True)
class ReferenceMetrics:
    """Full-reference figures of an image against a reference.

    Attributes:
        psnr_db: peak signal-to-noise ratio, dB (data range 1).
        ssim: mean structural similarity (data range 1, channels averaged).
        ciede2000: mean CIEDE2000.
        ciede2000_gain: mean CIEDE2000 after the best global exposure gain.
        gain: that gain (linear).
        ciede2000_diag: mean CIEDE2000 after the best per-channel gains.
        diag_gains: those gains (linear R, G, B).
        n_pixels: pixels evaluated.
    """

    psnr_db: float
    ssim: float
    ciede2000: float
    ciede2000_gain: float
    gain: float
    ciede2000_diag: float
    diag_gains: tuple[float, float, float]
    n_pixels: int

    def as_dict(self) -> dict[str, float | int]:
        """Plain dict (JSON)."""
        return asdict(self)


def compare_to_reference(
    image: object, reference: object, mask: object | None = None
) -> ReferenceMetrics:
    """PSNR, SSIM, CIEDE2000 and CIEDE2000 after gain of ``image`` against ``reference``.

    SSIM is computed on the whole image (scikit-image, 7x7 windows, ``data_range=1``,
    ``channel_axis=2``) and its map averaged over the mask.

    Raises:
        EnhanceError: different sizes, one-channel images, an empty mask.
    """
    a, b = _pair(image, reference)
    m = _mask(mask, a.shape)
    with np.errstate(divide="ignore"):
        psnr = float(peak_signal_noise_ratio(b[m], a[m], data_range=1.0))
    _, ssim_map = structural_similarity(b, a, data_range=1.0, channel_axis=2, full=True)
    ssim = float(np.mean(np.asarray(ssim_map).mean(axis=2)[m]))
    de = ciede2000(a, b, m)
    de_g, gain = ciede2000_after_gain(a, b, m)
    de_d, gains = ciede2000_after_diagonal_gain(a, b, m)
    return ReferenceMetrics(
        psnr_db=psnr, ssim=ssim, ciede2000=de, ciede2000_gain=de_g, gain=gain,
        ciede2000_diag=de_d, diag_gains=gains, n_pixels=int(m.sum()),
    )


# ---------------------------------------------------------------------------------- UIQM


@dataclass(frozen=True, kw_only=True)
class UiqmScore:
    """UIQM and its three parts (Panetta et al. 2016)."""

    uiqm: float
    uicm: float
    uism: float
    uiconm: float

    def as_dict(self) -> dict[str, float]:
        """Plain dict (JSON)."""
        return asdict(self)


def _alpha_trimmed_mean(x: F64, alpha: float = UICM_ALPHA) -> float:
    """Asymmetric alpha-trimmed mean: drop ``ceil(alpha K)`` lowest and ``floor(alpha K)``
    highest of the K sorted values (Panetta et al. 2016)."""
    s = np.sort(x.ravel())
    k = s.size
    lo, hi = int(np.ceil(alpha * k)), int(np.floor(alpha * k))
    if k - lo - hi <= 0:
        return float(np.mean(s))
    return float(np.mean(s[lo : k - hi]))


def _uicm(rgb255: F64) -> float:
    r, g, b = rgb255[..., 0], rgb255[..., 1], rgb255[..., 2]
    rg = (r - g).ravel()
    yb = ((r + g) / 2.0 - b).ravel()
    mu_rg, mu_yb = _alpha_trimmed_mean(rg), _alpha_trimmed_mean(yb)
    s2_rg = float(np.mean((rg - mu_rg) ** 2))
    s2_yb = float(np.mean((yb - mu_yb) ** 2))
    c_mu, c_s = UICM_COEFFS
    return c_mu * float(np.hypot(mu_rg, mu_yb)) + c_s * float(np.sqrt(s2_rg + s2_yb))


def _blocks(x: F64, block_px: int) -> F64:
    """``(k2, k1, block, block)`` view of the whole blocks of a 2-D array."""
    k2, k1 = x.shape[0] // block_px, x.shape[1] // block_px
    if k1 == 0 or k2 == 0:
        raise EnhanceError(
            f"image {x.shape[1]}x{x.shape[0]} is smaller than one {block_px} px block"
        )
    y = x[: k2 * block_px, : k1 * block_px]
    return y.reshape(k2, block_px, k1, block_px).swapaxes(1, 2)


def _eme(x: F64, block_px: int) -> float:
    blk = _blocks(x, block_px)
    mx, mn = blk.max(axis=(2, 3)), blk.min(axis=(2, 3))
    return float(2.0 / mx.size * np.sum(np.log((mx + 1.0) / (mn + 1.0))))


def _uism(rgb255: F64, block_px: int) -> float:
    total = 0.0
    for c, lam in enumerate(UISM_LAMBDA):
        ch = np.ascontiguousarray(rgb255[..., c])
        gx = cv2.Sobel(ch, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
        gy = cv2.Sobel(ch, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
        total += lam * _eme(np.hypot(gx, gy) * ch, block_px)
    return total


def _plip_add(a: F64, b: F64) -> F64:
    return a + b - a * b / PLIP_GAMMA


def _plip_sub(a: F64, b: F64) -> F64:
    return PLIP_GAMMA * (a - b) / (PLIP_GAMMA - b)


def _plip_mean(values: F64) -> float:
    """``(1 / N) (x) (v_1 (+) ... (+) v_N)``: the PLIP sum is ``gamma - gamma prod(1 - v /
    gamma)``, so the scalar product gives ``gamma - gamma * geomean(1 - v / gamma)``."""
    v = np.asarray(values, dtype=np.float64).ravel()
    return float(PLIP_GAMMA - PLIP_GAMMA * np.exp(np.mean(np.log1p(-v / PLIP_GAMMA))))


def _uiconm(rgb255: F64, block_px: int) -> float:
    intensity = rgb255.mean(axis=2)
    blk = _blocks(intensity, block_px)
    mx, mn = blk.max(axis=(2, 3)), blk.min(axis=(2, 3))
    den = _plip_add(mx, mn)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(den > 0, _plip_sub(mx, mn) / den, 0.0)
        ent = np.where(r > 0, -r * np.log(r), 0.0)
    return _plip_mean(ent)


def uiqm(image: object, *, block_px: int = 8) -> UiqmScore:
    """UIQM of an sRGB image (Panetta et al. 2016; see the module docstring for the formula,
    the constants and the choices made where the paper is open).

    Args:
        image: ``(H, W, 3)`` RGB; values are taken on the 0-255 scale.
        block_px: side of the EME / logAMEE blocks, pixels.

    Raises:
        EnhanceError: a one-channel image or one smaller than a block.
    """
    img, _ = as_unit_float(image)
    if img.ndim != 3:
        raise EnhanceError(f"UIQM needs an (H, W, 3) image, got {img.shape}")
    if block_px < 2:
        raise EnhanceError(f"block_px must be >= 2, got {block_px}")
    rgb = np.clip(img, 0, 1).astype(np.float64) * 255.0
    uicm, uism, uiconm = _uicm(rgb), _uism(rgb, block_px), _uiconm(rgb, block_px)
    c1, c2, c3 = UIQM_COEFFS
    return UiqmScore(uiqm=c1 * uicm + c2 * uism + c3 * uiconm, uicm=uicm, uism=uism, uiconm=uiconm)


# ---------------------------------------------------------------------------------- UCIQE


@dataclass(frozen=True, kw_only=True)
class UciqeScore:
    """UCIQE and its three parts (Yang and Sowmya 2015)."""

    uciqe: float
    sigma_c: float
    con_l: float
    mu_s: float

    def as_dict(self) -> dict[str, float]:
        """Plain dict (JSON)."""
        return asdict(self)


def uciqe(image: object) -> UciqeScore:
    """UCIQE of an sRGB image (Yang and Sowmya 2015; see the module docstring).

    Raises:
        EnhanceError: a one-channel image.
    """
    img, _ = as_unit_float(image)
    if img.ndim != 3:
        raise EnhanceError(f"UCIQE needs an (H, W, 3) image, got {img.shape}")
    lab = rgb2lab(np.clip(img, 0, 1).astype(np.float64))
    lum = lab[..., 0].ravel() / 100.0
    chroma = np.hypot(lab[..., 1], lab[..., 2]).ravel() / 100.0
    sigma_c = float(np.std(chroma))
    p1, p99 = np.percentile(lum, [1.0, 99.0])
    con_l = float(p99 - p1)
    norm = np.hypot(chroma, lum)
    with np.errstate(invalid="ignore", divide="ignore"):
        sat = np.where(norm > 0, chroma / norm, 0.0)
    mu_s = float(np.mean(sat))
    c1, c2, c3 = UCIQE_COEFFS
    return UciqeScore(
        uciqe=c1 * sigma_c + c2 * con_l + c3 * mu_s, sigma_c=sigma_c, con_l=con_l, mu_s=mu_s
    )


def colour_cast(image: object, mask: object | None = None) -> float:
    """Colour cast: the CIELAB chroma ``sqrt(mean(a*)^2 + mean(b*)^2)`` of the image's mean
    a*, b* (0 for an image whose colours average to grey).

    Raises:
        EnhanceError: a one-channel image, a mask of another size.
    """
    img, _ = as_unit_float(image)
    if img.ndim != 3:
        raise EnhanceError(f"colour cast needs an (H, W, 3) image, got {img.shape}")
    m = _mask(mask, img.shape)
    lab = rgb2lab(np.clip(img[m], 0, 1)[None].astype(np.float64))[0]
    return float(np.hypot(lab[:, 1].mean(), lab[:, 2].mean()))
