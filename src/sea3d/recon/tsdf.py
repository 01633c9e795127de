"""Coloured TSDF fusion on Open3D's tensor ``VoxelBlockGrid``.

The volume holds a truncated signed distance, an observation weight and a mean colour per
voxel, in sparse blocks of ``R^3`` voxels (Curless and Levoy 1996; Open3D's hashed voxel
blocks after Niessner et al. 2013). Each integrated depth image adds one observation (weight
+1) to every voxel of the truncation band in front of and behind its surface; meshes come from
marching cubes over voxels seen more than ``weight_threshold`` times.

Against floaters (surface fused where one frame's depth was wrong), two options, both off by
default (benchmarks/results/fusion.md, "Floaters", has the measurements): ``hole_margin_px`` leaves
out the pixels beside a hole in the depth, and ``carve_free_space`` takes an observation from
every voxel holding surface that a later frame sees through (a numba pass over the volume's
blocks in the frame's view, outside those Open3D updates). With the matcher's confidence of
each pixel, ``min_confidence`` leaves out the pixels below it and ``confidence_full`` weights
each observation by it (Open3D integrates with unit weights; a numba pass over the frame's
band turns its update into the weighted one).

Never Open3D's legacy ``ScalableTSDFVolume``: it has been seen to integrate nothing in the
CPU-only wheels. ``tests/recon`` checks that a volume holds surface after integration.

Depth is float32 metres along the camera's z axis, NaN invalid, seen by a pinhole camera with
intrinsics ``K`` (pixel centres at integer coordinates, as everywhere in sea3d) and pose
``T_volume_cam``. Open3D finds a voxel's depth pixel by truncating its projection, so
:meth:`TsdfVolume.integrate` hands it the principal point shifted by half a pixel: then it
reads the nearest pixel, and a slanted surface is not biased by half a pixel's depth step.

For refractive rigs that camera is the rectified left view's virtual pinhole, and the depth
image must first be put where that pinhole sees each exactly triangulated point:
:func:`sea3d.recon.depth_resample.virtual_pinhole_depth`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.recon.types import VoxelBlocks

__all__ = ["TsdfConfig", "TsdfVolume"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class TsdfConfig:
    """How the TSDF volume is laid out and what it integrates."""

    voxel_m: float = 0.02
    """Voxel edge, metres."""
    trunc_voxels: float = 4.0
    """Truncation distance in voxels (the signed distance is clipped at this many voxels)."""
    block_resolution: int = 8
    """Voxels along a block edge (a block is the unit of allocation)."""
    min_depth_m: float = 0.1
    """Nearer depths are ignored, metres."""
    max_depth_m: float = 5.0
    """Farther depths are ignored, metres (stereo depth error grows with the square of depth)."""
    initial_blocks: int = 4096
    """Blocks allocated up front (the hash map grows as needed)."""
    weight_threshold: float = 0.5
    """Meshes and point clouds use voxels whose weight (observations) is *above* this
    (Open3D compares strictly): 0.5 uses every voxel seen at least once, 1.5 twice."""
    hole_margin_px: int = 0
    """Pixels within this many pixels (Chebyshev distance) of a pixel without depth are not
    fused: stereo's wrong depth gathers at the borders of what it could not match (on the
    simulated lake survey, 82 % of the pixels more than 10 cm off the scene lie within 2 px
    of a hole, 2 % of all pixels) and a depth camera's at its silhouettes. 0 fuses every
    pixel with depth."""
    carve_free_space: bool = False
    """After each integration, the voxels of the volume that the new frame sees through lose
    one observation (a voxel left with none is emptied): those that hold surface (a signed
    distance below the truncation) and lie in front of the frame's depth, at every pixel of
    the 3x3 neighbourhood they project to, by more than the truncation band plus three
    standard errors of that depth (:attr:`depth_noise_per_m`). Open3D updates only the
    blocks near the new frame's surface, so without this a floater left by one frame's
    wrong depth stays however often later frames look through it."""
    depth_noise_per_m: float = 0.0
    """The depth's standard error at 1 m, metres, growing with the square of depth
    (``sigma_z = depth_noise_per_m * z^2``): ``sigma_d / (f B)`` for stereo of disparity
    noise ``sigma_d`` pixels and focal length times baseline ``f B`` (pixels times metres).
    Widens the carving margin at range; 0: the truncation band alone."""
    min_confidence: float = 0.0
    """Pixels whose matching confidence (given to :meth:`TsdfVolume.integrate`) is below this
    are not fused; 0 fuses every pixel with depth. Frames given without a confidence are
    fused whole."""
    confidence_full: float | None = None
    """Weight each pixel's observation by its matching confidence ``c``: it adds
    ``min(1, c / confidence_full)`` to its voxels' weights instead of 1 (so the weight
    thresholds count confident observations: with 0.5, a pixel of confidence 0.25 counts
    half). None: every observation weighs 1 (Open3D's integration as it is)."""

    def __post_init__(self) -> None:
        if not (self.voxel_m > 0 and np.isfinite(self.voxel_m)):
            raise ReconError(f"voxel_m must be > 0, got {self.voxel_m}")
        if not self.trunc_voxels >= 1:
            raise ReconError(f"trunc_voxels must be >= 1, got {self.trunc_voxels}")
        if self.block_resolution not in (4, 8, 16):
            raise ReconError(f"block_resolution must be 4, 8 or 16, got {self.block_resolution}")
        if not 0 <= self.min_depth_m < self.max_depth_m:
            raise ReconError(f"need 0 <= min_depth_m < max_depth_m, got {self.min_depth_m}, "
                             f"{self.max_depth_m}")
        if self.initial_blocks < 1 or self.weight_threshold < 0:
            raise ReconError("initial_blocks must be >= 1 and weight_threshold >= 0")
        if not 0 <= self.hole_margin_px <= 16:
            raise ReconError(f"hole_margin_px must be 0..16, got {self.hole_margin_px}")
        if not (self.depth_noise_per_m >= 0 and np.isfinite(self.depth_noise_per_m)):
            raise ReconError(f"depth_noise_per_m must be >= 0, got {self.depth_noise_per_m}")
        if not 0 <= self.min_confidence < 1:
            raise ReconError(f"min_confidence must be in [0, 1), got {self.min_confidence}")
        if self.confidence_full is not None and not 0 < self.confidence_full <= 1:
            raise ReconError(f"confidence_full must be in (0, 1] or None, got "
                             f"{self.confidence_full}")

    @property
    def uses_confidence(self) -> bool:
        """Whether integration reads the pixels' confidence."""
        return self.min_confidence > 0 or self.confidence_full is not None

    @property
    def block_bytes(self) -> int:
        """Bytes per allocated block (tsdf, weight and 3 colour channels, float32)."""
        return self.block_resolution**3 * 5 * 4


def _check_K(K: F64) -> F64:
    k = np.asarray(K, dtype=np.float64)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ReconError(f"intrinsics must be a 3x3 pinhole K with fx, fy > 0, got {k.tolist()}")
    return k


class TsdfVolume:
    """A coloured TSDF volume (Open3D tensor ``VoxelBlockGrid`` on the CPU)."""

    def __init__(self, config: TsdfConfig | None = None) -> None:
        import open3d as o3d
        import open3d.core as o3c

        self.config = config or TsdfConfig()
        c = self.config
        self._o3d = o3d
        self._o3c = o3c
        self._device = o3c.Device("CPU:0")
        vbg: Any = o3d.t.geometry.VoxelBlockGrid
        self._vbg = vbg(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=c.voxel_m,
            block_resolution=c.block_resolution,
            block_count=c.initial_blocks,
            device=self._device,
        )
        self.frames = 0
        self.voxels_carved = 0
        """Observations taken from voxels by free-space carving, summed over the frames."""

    # -- integration --------------------------------------------------------------------
    def integrate(
        self,
        depth_m: NDArray[np.floating],
        color_rgb: NDArray[np.uint8] | None,
        K: F64,
        T_volume_cam: F64,
        confidence: NDArray[Any] | None = None,
    ) -> int:
        """Fuse one depth image (and its colours) seen from ``T_volume_cam``.

        Args:
            depth_m: (H, W) float32 metres along the camera's z axis, NaN invalid.
            color_rgb: (H, W, 3) uint8 RGB registered to the depth, or None (depth only).
            K: (3, 3) pinhole intrinsics of the depth image, pixels.
            T_volume_cam: (4, 4) pose of the camera in the volume's frame.
            confidence: (H, W) matching confidence of each depth pixel, float in [0, 1] or
                uint8 (255 = 1), read by :attr:`TsdfConfig.min_confidence` and
                :attr:`TsdfConfig.confidence_full`; None: every pixel fully confident.

        Returns:
            Number of voxel blocks the image touched (0 when it held no valid depth).

        Raises:
            ReconError: wrong shapes or a bad pose/intrinsics.
        """
        o3c, o3d, c = self._o3c, self._o3d, self.config
        depth = np.asarray(depth_m, dtype=np.float32)
        if depth.ndim != 2:
            raise ReconError(f"depth must be (H, W), got {depth.shape}")
        if color_rgb is not None and color_rgb.shape != (*depth.shape, 3):
            raise ReconError(f"colour {color_rgb.shape} does not match depth {depth.shape}")
        T = np.asarray(T_volume_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ReconError(f"T_volume_cam must be a finite 4x4 matrix, got {T.shape}")
        # Open3D reads the depth pixel of a voxel by truncating its projection (pixel k for
        # u in [k, k + 1)), while pixel centres sit at integer u (docs/conventions.md): a half
        # pixel on the principal point makes it read the nearest pixel instead. Without it a
        # floor seen at 45 degrees from 1.3 m comes out 6.6 mm low (tests/recon/test_tsdf.py).
        K_o3d = _check_K(K).copy()
        K_o3d[0, 2] += 0.5
        K_o3d[1, 2] += 0.5
        Kt = o3c.Tensor(K_o3d, o3c.float64)
        # Invalid and out-of-range depth -> 0, which Open3D skips.
        d = np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0)
        d[(d < c.min_depth_m) | (d > c.max_depth_m)] = 0.0
        if c.hole_margin_px > 0:
            side = 2 * c.hole_margin_px + 1
            inner = cv2.erode((d > 0).astype(np.uint8), np.ones((side, side), np.uint8),
                              borderType=cv2.BORDER_CONSTANT, borderValue=1)
            d[inner == 0] = 0.0
        weights: NDArray[np.float32] | None = None
        if confidence is not None and c.uses_confidence:
            conf = _confidence01(confidence, depth.shape)
            if c.min_confidence > 0:
                d[conf < c.min_confidence] = 0.0
            if c.confidence_full is not None:
                weights = np.minimum(conf * np.float32(1.0 / c.confidence_full), np.float32(1.0))
                d[weights <= 0] = 0.0
                if bool((weights[d > 0] >= 1.0).all()):
                    weights = None  # every observation weighs 1: Open3D's update as it is
        if not d.any():
            return 0  # Open3D raises when an image touches no block
        R, t = T[:3, :3], T[:3, 3]
        extrinsic = np.eye(4)
        extrinsic[:3, :3] = R.T
        extrinsic[:3, 3] = -R.T @ t
        Et = o3c.Tensor(extrinsic, o3c.float64)
        dimg = o3d.t.geometry.Image(o3c.Tensor(d))
        blocks = self._vbg.compute_unique_block_coordinates(
            dimg, Kt, Et, 1.0, c.max_depth_m, c.trunc_voxels
        )
        if blocks.shape[0] == 0:
            return 0
        if c.carve_free_space and self.frames > 0:
            self.voxels_carved += self._carve(d, K_o3d, R, t, blocks)
        before = None if weights is None else self._snapshot(blocks)
        if color_rgb is None:
            self._vbg.integrate(blocks, dimg, Kt, Et, 1.0, c.max_depth_m, c.trunc_voxels)
        else:
            col = np.ascontiguousarray(color_rgb, dtype=np.float32) * np.float32(1.0 / 255.0)
            cimg = o3d.t.geometry.Image(o3c.Tensor(col))
            self._vbg.integrate(blocks, dimg, cimg, Kt, Kt, Et, 1.0, c.max_depth_m,
                                c.trunc_voxels)
        if before is not None and weights is not None:
            self._reweight(before, weights, K_o3d, R, t)
        self.frames += 1
        return int(blocks.shape[0])

    def _snapshot(self, band_blocks: Any) -> tuple[Any, ...]:
        """The frame's band blocks (activated now, as Open3D's integration would) and a copy
        of their voxels before the integration, for :meth:`_reweight`."""
        r = self.config.block_resolution
        hm = self._vbg.hashmap()
        hm.activate(band_blocks)
        buf, ok = hm.find(band_blocks)
        sel = ok.numpy().astype(bool)
        bufs = buf.numpy().astype(np.int64)[sel]
        keys = band_blocks.numpy().astype(np.int64)[sel]
        tsdf = self._vbg.attribute("tsdf").numpy().reshape(-1, r**3)
        weight = self._vbg.attribute("weight").numpy().reshape(-1, r**3)
        color = self._vbg.attribute("color").numpy().reshape(-1, r**3, 3)
        return keys, bufs, tsdf[bufs], weight[bufs], color[bufs]

    def _reweight(self, before: tuple[Any, ...], weights: NDArray[np.float32], K_o3d: F64,
                  R_volume_cam: F64, t_volume_cam: F64) -> None:
        """Turn Open3D's unit-weight update of the band's voxels into one of weight ``w`` of
        the pixel each voxel read (:attr:`TsdfConfig.confidence_full`): the observation is
        recovered from the voxel before and after (``s = v' (W + 1) - v W``) and averaged in
        again with weight ``w``."""
        c = self.config
        r = c.block_resolution
        keys, bufs, t0, w0, c0 = before
        R_cam_volume = R_volume_cam.T
        _reweight_kernel(keys, bufs, t0, w0, c0,
                         self._vbg.attribute("tsdf").numpy().reshape(-1, r**3),
                         self._vbg.attribute("weight").numpy().reshape(-1, r**3),
                         self._vbg.attribute("color").numpy().reshape(-1, r**3, 3),
                         R_cam_volume, -R_cam_volume @ t_volume_cam, K_o3d,
                         np.ascontiguousarray(weights, np.float32), c.voxel_m, r)

    def _carve(self, depth: NDArray[np.float32], K_o3d: F64, R_volume_cam: F64,
               t_volume_cam: F64, band_blocks: Any) -> int:
        """Free-space carving of one frame (:attr:`TsdfConfig.carve_free_space`) over the
        volume's blocks outside the frame's own truncation band (Open3D updates those);
        returns the observations taken."""
        c = self.config
        r = c.block_resolution
        hm = self._vbg.hashmap()
        act = hm.active_buf_indices().numpy().astype(np.int64)
        if len(act) == 0:
            return 0
        keys = hm.key_tensor().numpy()[act].astype(np.int64)
        # Blocks the frame's band touches this frame are left to Open3D's own update.
        band_buf, band_ok = hm.find(band_blocks)
        band = band_buf.numpy().astype(np.int64)[band_ok.numpy().astype(bool)]
        keep = ~np.isin(act, band)
        act, keys = act[keep], keys[keep]
        # Blocks whose centre the camera sees within the depth range (plus a block's radius).
        block_m = r * c.voxel_m
        centres = (keys + 0.5) * block_m
        R_cam_volume = R_volume_cam.T
        pc = (centres - t_volume_cam) @ R_cam_volume.T
        radius = 0.87 * block_m
        h, w = depth.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K_o3d[0, 0] * pc[:, 0] / pc[:, 2] + K_o3d[0, 2]
            v = K_o3d[1, 1] * pc[:, 1] / pc[:, 2] + K_o3d[1, 2]
            pad = K_o3d[0, 0] * radius / np.maximum(pc[:, 2], 1e-6)
        near = (pc[:, 2] > c.min_depth_m - radius) & (pc[:, 2] < c.max_depth_m + radius)
        seen = near & (u > -pad) & (u < w + pad) & (v > -pad) & (v < h + pad)
        if not seen.any():
            return 0
        # The nearest valid depth around each pixel; a pixel without depth beside it (or
        # itself) carves nothing: a voxel at a depth edge or a hole is not seen through.
        d_min = cv2.erode(depth, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                          borderValue=0.0)
        tsdf = self._vbg.attribute("tsdf").numpy().reshape(-1, r**3)
        weight = self._vbg.attribute("weight").numpy().reshape(-1, r**3)
        return int(_carve_kernel(keys[seen], act[seen], tsdf, weight, R_cam_volume,
                                 -R_cam_volume @ t_volume_cam, K_o3d, d_min, c.voxel_m, r,
                                 c.trunc_voxels * c.voxel_m, c.depth_noise_per_m))

    # -- state --------------------------------------------------------------------------
    @property
    def block_count(self) -> int:
        """Allocated blocks."""
        return int(self._vbg.hashmap().size())

    @property
    def capacity_blocks(self) -> int:
        """Blocks the hash map has room for (memory held is about this times
        :attr:`TsdfConfig.block_bytes`)."""
        return int(self._vbg.hashmap().capacity())

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the voxel arrays (capacity, not just the used blocks)."""
        return self.capacity_blocks * self.config.block_bytes

    def export_blocks(self) -> VoxelBlocks:
        """The blocks that hold at least one observed voxel, copied out as arrays."""
        r = self.config.block_resolution
        hm = self._vbg.hashmap()
        if hm.size() == 0:
            return _empty_blocks(self.config)
        act = hm.active_buf_indices().numpy().astype(np.int64)
        keys = hm.key_tensor().numpy()[act].astype(np.int32)
        weight = self._vbg.attribute("weight").numpy()[act].reshape(-1, r, r, r)
        seen = weight.reshape(len(act), -1).max(axis=1) > 0
        act, keys, weight = act[seen], keys[seen], weight[seen]
        tsdf = self._vbg.attribute("tsdf").numpy()[act].reshape(-1, r, r, r)
        color = self._vbg.attribute("color").numpy()[act].reshape(-1, r, r, r, 3)
        return VoxelBlocks(keys=keys, tsdf=tsdf.astype(np.float32, copy=True),
                           weight=weight.astype(np.float32, copy=True),
                           color=color.astype(np.float32, copy=True),
                           voxel_m=self.config.voxel_m, trunc_voxels=self.config.trunc_voxels)

    @classmethod
    def from_blocks(cls, blocks: VoxelBlocks, config: TsdfConfig | None = None) -> TsdfVolume:
        """A volume holding ``blocks`` (the inverse of :meth:`export_blocks`).

        Raises:
            ReconError: the blocks' voxel size, truncation or block size differ from config.
        """
        cfg = config or TsdfConfig(voxel_m=blocks.voxel_m, trunc_voxels=blocks.trunc_voxels,
                                   block_resolution=blocks.block_resolution or 8)
        if len(blocks) and (abs(cfg.voxel_m - blocks.voxel_m) > 1e-12
                            or cfg.block_resolution != blocks.block_resolution
                            or abs(cfg.trunc_voxels - blocks.trunc_voxels) > 1e-12):
            raise ReconError(
                f"blocks of {blocks.voxel_m} m voxels, {blocks.block_resolution}^3 per block, "
                f"truncation {blocks.trunc_voxels} voxels do not fit a volume of "
                f"{cfg.voxel_m} m, {cfg.block_resolution}^3, {cfg.trunc_voxels}"
            )
        cfg = replace(cfg, initial_blocks=max(len(blocks), 1))
        vol = cls(cfg)
        if len(blocks) == 0:
            return vol
        o3c = vol._o3c
        buf, ok = vol._vbg.hashmap().activate(o3c.Tensor(np.ascontiguousarray(blocks.keys)))
        if not bool(ok.numpy().all()):
            raise ReconError("duplicate block keys in a set of voxel blocks")
        b = buf.numpy().astype(np.int64)
        r = cfg.block_resolution
        vol._vbg.attribute("tsdf").numpy()[b] = blocks.tsdf.reshape(-1, r, r, r, 1)
        vol._vbg.attribute("weight").numpy()[b] = blocks.weight.reshape(-1, r, r, r, 1)
        vol._vbg.attribute("color").numpy()[b] = blocks.color.reshape(-1, r, r, r, 3)
        return vol

    # -- extraction ---------------------------------------------------------------------
    def extract_mesh(self, weight_threshold: float | None = None) -> Mesh:
        """Marching-cubes mesh of the zero level set, in the volume's frame (metres).

        Args:
            weight_threshold: voxels of larger weight are used (default the config's).
        """
        wt = self.config.weight_threshold if weight_threshold is None else weight_threshold
        if self.block_count == 0:
            return Mesh(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int64))
        m = self._vbg.extract_triangle_mesh(float(wt))
        v = m.vertex.positions.numpy().astype(np.float64)
        if len(v) == 0:
            return Mesh(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int64))
        f = m.triangle.indices.numpy().astype(np.int64)
        cols = _to_u8(m.vertex.colors.numpy()) if "colors" in m.vertex else None
        nrm = m.vertex.normals.numpy().astype(np.float64) if "normals" in m.vertex else None
        if nrm is not None:
            n = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = np.divide(nrm, n, out=np.zeros_like(nrm), where=n > 0)
        return Mesh(vertices=v, triangles=f, colors_rgb=cols, normals=nrm)

    def extract_points(
        self, weight_threshold: float | None = None
    ) -> tuple[F64, NDArray[np.uint8], F64]:
        """Surface points of the zero level set: ``(points (N, 3) m, colours (N, 3) uint8,
        normals (N, 3))`` in the volume's frame."""
        wt = self.config.weight_threshold if weight_threshold is None else weight_threshold
        if self.block_count == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3))
        pc = self._vbg.extract_point_cloud(float(wt))
        p = pc.point.positions.numpy().astype(np.float64)
        if len(p) == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3))
        cols = _to_u8(pc.point.colors.numpy()) if "colors" in pc.point else np.zeros(
            (len(p), 3), np.uint8)
        nrm = pc.point.normals.numpy().astype(np.float64) if "normals" in pc.point else (
            np.zeros((len(p), 3)))
        return p, cols, nrm


@njit(parallel=True, cache=True)
def _carve_kernel(keys: Any, bufs: Any, tsdf: Any, weight: Any, R_cam_volume: Any,
                  t_cam_volume: Any, K_o3d: Any, d_min: Any, voxel_m: float, r: int,
                  trunc_m: float, noise_per_m: float) -> int:  # pragma: no cover - numba
    """Take one observation from every voxel of the given blocks that holds surface and lies
    in front of ``d_min`` (the 3x3 minimum of the frame's depth, 0 without depth) by more
    than ``trunc_m + 3 noise_per_m d^2``. Voxel ``(x, y, z)`` of block ``k`` sits at
    ``(k r + (x, y, z)) voxel_m`` (Open3D's layout: flat index ``(z r + y) r + x``); a
    voxel's pixel is its projection truncated, as Open3D reads it (``K_o3d``)."""
    h, w = d_min.shape
    n = len(bufs)
    taken = np.zeros(n, np.int64)
    fx, fy, cx, cy = K_o3d[0, 0], K_o3d[1, 1], K_o3d[0, 2], K_o3d[1, 2]
    for i in prange(n):
        b = bufs[i]
        ox, oy, oz = keys[i, 0] * r, keys[i, 1] * r, keys[i, 2] * r
        for loc in range(r * r * r):
            wt = weight[b, loc]
            if wt <= 0.0 or tsdf[b, loc] >= 0.999:
                continue
            x = (ox + loc % r) * voxel_m
            y = (oy + (loc // r) % r) * voxel_m
            z = (oz + loc // (r * r)) * voxel_m
            zc = R_cam_volume[2, 0] * x + R_cam_volume[2, 1] * y + R_cam_volume[2, 2] * z \
                + t_cam_volume[2]
            if zc <= 0.0:
                continue
            xc = R_cam_volume[0, 0] * x + R_cam_volume[0, 1] * y + R_cam_volume[0, 2] * z \
                + t_cam_volume[0]
            yc = R_cam_volume[1, 0] * x + R_cam_volume[1, 1] * y + R_cam_volume[1, 2] * z \
                + t_cam_volume[1]
            uf = fx * xc / zc + cx
            vf = fy * yc / zc + cy
            if uf < 0.0 or vf < 0.0 or uf >= w or vf >= h:
                continue
            d = d_min[int(vf), int(uf)]
            if d <= 0.0 or d - zc <= trunc_m + 3.0 * noise_per_m * d * d:
                continue
            if wt <= 1.0:
                weight[b, loc] = 0.0
                tsdf[b, loc] = 0.0
            else:
                weight[b, loc] = wt - 1.0
            taken[i] += 1
    return int(taken.sum())


@njit(parallel=True, cache=True)
def _reweight_kernel(keys: Any, bufs: Any, t0: Any, w0: Any, c0: Any, tsdf: Any, weight: Any,
                     color: Any, R_cam_volume: Any, t_cam_volume: Any, K_o3d: Any,
                     wimg: Any, voxel_m: float, r: int) -> None:  # pragma: no cover - numba
    """:meth:`TsdfVolume._reweight` over the band's blocks: every voxel whose weight the
    integration raised (by 1) gets the observation weighted by ``wimg`` at its pixel (the
    projection truncated, as Open3D reads it; voxel layout as in :func:`_carve_kernel`)."""
    h, w = wimg.shape
    fx, fy, cx, cy = K_o3d[0, 0], K_o3d[1, 1], K_o3d[0, 2], K_o3d[1, 2]
    for i in prange(len(bufs)):
        b = bufs[i]
        ox, oy, oz = keys[i, 0] * r, keys[i, 1] * r, keys[i, 2] * r
        for loc in range(r * r * r):
            wo = w0[i, loc]
            wn = weight[b, loc]
            if wn == wo:
                continue
            x = (ox + loc % r) * voxel_m
            y = (oy + (loc // r) % r) * voxel_m
            z = (oz + loc // (r * r)) * voxel_m
            zc = R_cam_volume[2, 0] * x + R_cam_volume[2, 1] * y + R_cam_volume[2, 2] * z \
                + t_cam_volume[2]
            xc = R_cam_volume[0, 0] * x + R_cam_volume[0, 1] * y + R_cam_volume[0, 2] * z \
                + t_cam_volume[0]
            yc = R_cam_volume[1, 0] * x + R_cam_volume[1, 1] * y + R_cam_volume[1, 2] * z \
                + t_cam_volume[1]
            wt = 1.0
            if zc > 0.0:
                uf = fx * xc / zc + cx
                vf = fy * yc / zc + cy
                if 0.0 <= uf < w and 0.0 <= vf < h:
                    wt = wimg[int(vf), int(uf)]
            if wt >= 1.0:
                continue
            n = wn - wo  # 1: Open3D's unit update
            s = (tsdf[b, loc] * wn - t0[i, loc] * wo) / n
            total = wo + wt
            if wt <= 0.0 or total <= 0.0:
                tsdf[b, loc] = t0[i, loc]
                weight[b, loc] = wo
                for k in range(3):
                    color[b, loc, k] = c0[i, loc, k]
                continue
            tsdf[b, loc] = (t0[i, loc] * wo + wt * s) / total
            weight[b, loc] = total
            for k in range(3):
                ck = (color[b, loc, k] * wn - c0[i, loc, k] * wo) / n
                color[b, loc, k] = (c0[i, loc, k] * wo + wt * ck) / total


def _confidence01(confidence: NDArray[Any], shape: tuple[int, ...]) -> NDArray[np.float32]:
    conf = np.asarray(confidence)
    if conf.shape != shape:
        raise ReconError(f"confidence {conf.shape} does not match depth {shape}")
    if conf.dtype == np.uint8:
        return conf.astype(np.float32) * np.float32(1.0 / 255.0)
    return np.nan_to_num(conf.astype(np.float32, copy=False), nan=0.0)


def _to_u8(colors01: NDArray[np.floating]) -> NDArray[np.uint8]:
    return np.clip(np.rint(np.asarray(colors01, np.float64) * 255.0), 0, 255).astype(np.uint8)


def _empty_blocks(config: TsdfConfig) -> VoxelBlocks:
    r = config.block_resolution
    return VoxelBlocks(
        keys=np.zeros((0, 3), np.int32),
        tsdf=np.zeros((0, r, r, r), np.float32),
        weight=np.zeros((0, r, r, r), np.float32),
        color=np.zeros((0, r, r, r, 3), np.float32),
        voxel_m=config.voxel_m,
        trunc_voxels=config.trunc_voxels,
    )
