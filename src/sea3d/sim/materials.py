"""Surface materials: albedo (linear RGB reflectance) as a function of where a ray hits.

A material sees each hit in its object's own frame (``points_obj``, metres) so that a texture moves
with the object, plus the pixel footprint (metres) for band-limiting procedural detail. Every
material returns linear-light albedo in ``[0, 1]``; the shading and water model work in linear
light, and the image is gamma-encoded only at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.errors import SimulationError
from sea3d.sim._kernels import sand_albedo
from sea3d.sim.noise import fbm

__all__ = [
    "ArucoCubeMaterial",
    "CheckerboardMaterial",
    "ImageMaterial",
    "Material",
    "RockMaterial",
    "SandMaterial",
    "SolidMaterial",
]

AlbedoArray = NDArray[np.float32]


class Material(Protocol):
    """What a material provides."""

    hard_edges: ClassVar[bool]
    """Sharp texture edges (a board's squares, a marker's cells): the renderer supersamples
    them."""

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """Linear RGB albedo.

        Args:
            points_obj: ``(N, 3)`` float64 hit points in the object's frame, metres.
            footprint_m: ``(N,)`` float64 size of one pixel at each hit, metres.

        Returns:
            ``(N, 3)`` float32 linear reflectance in ``[0, 1]``.
        """
        ...


def _rgb(colour: tuple[float, float, float]) -> NDArray[np.float32]:
    return np.asarray(colour, dtype=np.float32)[None, :]


@dataclass(frozen=True, kw_only=True)
class SandMaterial:
    """Sand: fine grain noise (mm scale) over patchy colour and soft ripples.

    Attributes:
        colour_rgb: mean linear albedo.
        grain_m: size of the finest grain detail, metres.
        ripple_wavelength_m: wavelength of the sand ripples (0 disables them).
        contrast: relative brightness variation of the grain.
        seed: noise field.
    """

    hard_edges: ClassVar[bool] = False

    colour_rgb: tuple[float, float, float] = (0.55, 0.48, 0.33)
    grain_m: float = 0.0015
    ripple_wavelength_m: float = 0.09
    contrast: float = 0.9
    seed: int = 11

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        # Patches (decimetres), mid-scale mottling (centimetres) and grain (down to grain_m), the
        # finer two band-limited by the pixel footprint; soft ripples warped by noise.
        return sand_albedo(
            np.ascontiguousarray(points_obj, dtype=np.float64),
            np.ascontiguousarray(
                np.broadcast_to(footprint_m, (points_obj.shape[0],)), dtype=np.float64
            ),
            np.asarray(self.colour_rgb, dtype=np.float64),
            1.0 / (16.0 * self.grain_m),
            float(self.contrast),
            float(self.ripple_wavelength_m),
            int(self.seed),
        )


@dataclass(frozen=True, kw_only=True)
class RockMaterial:
    """Rock: blotchy dark/light mineral colour with crevices and fine speckle.

    Attributes:
        colour_rgb: mean linear albedo.
        seed: noise field.
    """

    hard_edges: ClassVar[bool] = False

    colour_rgb: tuple[float, float, float] = (0.30, 0.28, 0.25)
    seed: int = 23

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        blotch = fbm(points_obj, base_freq_per_m=6.0, octaves=4, seed=self.seed)
        speckle = fbm(
            points_obj,
            base_freq_per_m=80.0,
            octaves=5,
            gain=0.6,
            footprint_m=footprint_m,
            seed=self.seed + 1,
        )
        crevice = np.abs(fbm(points_obj, base_freq_per_m=12.0, octaves=3, seed=self.seed + 2) - 0.5)
        shade = 0.6 + 1.2 * (blotch - 0.5) + 1.4 * (speckle - 0.5) + np.minimum(crevice * 8, 0.4)
        tint = np.stack(
            [1.0 + 0.3 * (blotch - 0.5), np.ones_like(blotch), 1.0 - 0.3 * (blotch - 0.5)], 1
        )
        out = _rgb(self.colour_rgb) * shade[:, None] * tint
        return np.clip(out, 0.0, 1.0).astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class SolidMaterial:
    """A single colour with optional mild noise (plastic, painted metal, tank walls).

    Attributes:
        colour_rgb: linear albedo.
        noise: relative brightness variation (0 = flat colour).
        noise_freq_per_m: frequency of the first noise octave.
        seed: noise field.
    """

    hard_edges: ClassVar[bool] = False

    colour_rgb: tuple[float, float, float] = (0.5, 0.5, 0.5)
    noise: float = 0.0
    noise_freq_per_m: float = 20.0
    seed: int = 5

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        out = np.repeat(_rgb(self.colour_rgb), points_obj.shape[0], axis=0)
        if self.noise > 0:
            n = fbm(
                points_obj,
                base_freq_per_m=self.noise_freq_per_m,
                octaves=6,
                footprint_m=footprint_m,
                seed=self.seed,
            )
            out = out * (1.0 + 2.0 * self.noise * (n - 0.5))[:, None]
        return np.clip(out, 0.0, 1.0).astype(np.float32)


def _face_axes() -> tuple[FloatArray, FloatArray]:
    rights, downs = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            down = np.array([0.0, 0.0, -1.0]) if axis != 2 else np.array([0.0, -sign, 0.0])
            rights.append(np.cross(down, -n))  # right x down = -n: camera z looks into the face
            downs.append(down)
    return np.array(rights), np.array(downs)


_FACE_RIGHT, _FACE_DOWN = _face_axes()

BLACK_ALBEDO = 0.03
WHITE_ALBEDO = 0.85


@dataclass(frozen=True, kw_only=True)
class CheckerboardMaterial:
    """An analytic checkerboard on the plane z = 0 of the board frame.

    The board frame has its origin at the first inner corner, x along the ``cols`` inner corners,
    y along the ``rows`` inner corners, z into the board. Inner corners are at
    ``(i * square_m, j * square_m, 0)`` for ``i < cols``, ``j < rows``. The square at the origin's
    (+x, +y) side is black; the board has a white margin of ``margin_m`` around the squares.

    Attributes:
        cols: inner corners along x.
        rows: inner corners along y.
        square_m: square side, metres.
        margin_m: white border outside the outer squares, metres.
    """

    hard_edges: ClassVar[bool] = True  # sharp texture edges: the renderer supersamples them

    cols: int
    rows: int
    square_m: float
    margin_m: float = 0.03

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        i = np.floor(points_obj[:, 0] / self.square_m)
        j = np.floor(points_obj[:, 1] / self.square_m)
        inside = (i >= -1) & (i <= self.cols - 1) & (j >= -1) & (j <= self.rows - 1)
        black = inside & (((i + j) % 2) == 0)
        val = np.where(black, BLACK_ALBEDO, WHITE_ALBEDO).astype(np.float32)
        return np.repeat(val[:, None], 3, axis=1)

    def extent_m(self) -> tuple[float, float, float, float]:
        """Board outline in its frame: ``(x_min, x_max, y_min, y_max)`` metres."""
        s, m = self.square_m, self.margin_m
        return (-s - m, self.cols * s + m, -s - m, self.rows * s + m)

    def corners_board(self) -> FloatArray:
        """``(cols*rows, 3)`` inner corners in the board frame, x fastest, metres."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.stack(
            [ii.ravel() * self.square_m, jj.ravel() * self.square_m, np.zeros(ii.size)], axis=1
        )
        return pts.astype(np.float64)


@dataclass(frozen=True, kw_only=True)
class ImageMaterial:
    """An image mapped onto the plane z = 0 of the object frame (nearest-texel lookup).

    Pixel ``(u, v)`` of the image covers object coordinates
    ``x = x0_m + (u + 0.5) * texel_m``, ``y = y0_m + (v + 0.5) * texel_m`` at its centre.

    Attributes:
        image_rgb: ``(H, W, 3)`` float32 linear albedo.
        texel_m: size of one image pixel on the object, metres.
        x0_m: object x of the image's left edge.
        y0_m: object y of the image's top edge.
        outside_rgb: albedo outside the image.
    """

    hard_edges: ClassVar[bool] = True  # sharp texture edges: the renderer supersamples them

    image_rgb: NDArray[np.float32]
    texel_m: float
    x0_m: float = 0.0
    y0_m: float = 0.0
    outside_rgb: tuple[float, float, float] = (WHITE_ALBEDO, WHITE_ALBEDO, WHITE_ALBEDO)

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        h, w = self.image_rgb.shape[:2]
        u = np.floor((points_obj[:, 0] - self.x0_m) / self.texel_m).astype(np.int64)
        v = np.floor((points_obj[:, 1] - self.y0_m) / self.texel_m).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        out = np.repeat(_rgb(self.outside_rgb), points_obj.shape[0], axis=0)
        out[inside] = self.image_rgb[v[inside], u[inside]]
        return out

    def extent_m(self) -> tuple[float, float, float, float]:
        """Image outline in the object frame: ``(x_min, x_max, y_min, y_max)`` metres."""
        h, w = self.image_rgb.shape[:2]
        return (self.x0_m, self.x0_m + w * self.texel_m, self.y0_m, self.y0_m + h * self.texel_m)


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """An OpenCV ArUco dictionary by name (``DICT_4X4_50`` ...); raise :class:`SimulationError`."""
    key = name if name.startswith("DICT_") else f"DICT_{name}"
    if not hasattr(cv2.aruco, key):
        raise SimulationError(f"unknown ArUco dictionary {name!r} (expected e.g. DICT_4X4_50)")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, key))


@dataclass(frozen=True, kw_only=True)
class ArucoCubeMaterial:
    """A cube (centred at the object origin, side ``size_m``) with one ArUco marker per face.

    Faces in order +x, -x, +y, -y, +z, -z carry ``marker_ids``; each marker fills
    ``marker_fraction`` of its face, centred, on a white face.

    Attributes:
        size_m: cube side, metres.
        marker_ids: six marker ids.
        dictionary: OpenCV dictionary name.
        marker_fraction: marker side over face side.
    """

    hard_edges: ClassVar[bool] = True  # sharp texture edges: the renderer supersamples them

    size_m: float
    marker_ids: tuple[int, int, int, int, int, int] = (0, 1, 2, 3, 4, 5)
    dictionary: str = "DICT_4X4_50"
    marker_fraction: float = 0.8
    _markers: NDArray[np.float32] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.marker_ids) != 6:
            raise SimulationError(f"an ArUco cube needs 6 marker ids, got {self.marker_ids}")
        d = aruco_dictionary(self.dictionary)
        side = (int(d.markerSize) + 2) * 16  # 16 texels per bit, black border bit included
        imgs = []
        for mid in self.marker_ids:
            img = cv2.aruco.generateImageMarker(d, int(mid), side, borderBits=1)
            imgs.append(img.astype(np.float32) / 255.0)
        object.__setattr__(self, "_markers", np.stack(imgs))

    def albedo(self, points_obj: FloatArray, footprint_m: FloatArray) -> AlbedoArray:
        """See :class:`Material`."""
        p = points_obj / self.size_m  # in [-0.5, 0.5]
        axis = np.argmax(np.abs(p), axis=1)
        sign = np.take_along_axis(p, axis[:, None], axis=1)[:, 0] >= 0
        face = axis * 2 + (~sign).astype(np.int64)
        # In-face coordinates (a, b) in [-0.5, 0.5] along the face's "right" and "down" axes,
        # chosen so that a marker reads unmirrored to a camera outside the cube looking at it.
        right = _FACE_RIGHT[face]
        down = _FACE_DOWN[face]
        a = np.einsum("ij,ij->i", p, right)
        b = np.einsum("ij,ij->i", p, down)
        mside = self._markers.shape[1]
        f = self.marker_fraction
        u = np.floor((a / f + 0.5) * mside).astype(np.int64)
        v = np.floor((b / f + 0.5) * mside).astype(np.int64)
        inside = (u >= 0) & (u < mside) & (v >= 0) & (v < mside)
        val = np.full(points_obj.shape[0], WHITE_ALBEDO, dtype=np.float32)
        m = self._markers[face[inside], v[inside], u[inside]]
        val[inside] = BLACK_ALBEDO + (WHITE_ALBEDO - BLACK_ALBEDO) * m
        return np.repeat(val[:, None], 3, axis=1)
