"""Synthetic board detections: board corners projected through any camera model with known
poses and pixel noise. Used by tests and benchmarks, and to plan a capture (how many views, at
which ranges) before going into the water.

For rendered images with blur, haze and caustics use the simulator (``sea3d sim calibration``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.calib.targets import BoardSpec, Detection, DetectionStatus
from sea3d.errors import ConfigError
from sea3d.geometry.camera import CameraModel

__all__ = ["BoardRenderer", "SyntheticView", "board_poses", "synthetic_detections"]


@dataclass(frozen=True, kw_only=True, eq=False)
class SyntheticView:
    """One synthetic view: the true pose and what each camera detected.

    Attributes:
        T_left_board: ``(4, 4)`` true board pose in the left (or only) camera, metres.
        detections: one :class:`Detection` per camera (left first).
    """

    T_left_board: FloatArray
    detections: tuple[Detection, ...]


def board_poses(camera: CameraModel, board: BoardSpec, n_views: int, rng: np.random.Generator,
                *, distance_range_m: tuple[float, float] = (0.5, 2.5),
                max_tilt_deg: float = 45.0, require_inside: bool = True,
                also_inside: Sequence[tuple[CameraModel, FloatArray]] = ()) -> list[FloatArray]:
    """Board poses ``T_cam_board`` (4x4) that spread over the image and the range.

    The board centre is put on the viewing ray of a pixel drawn on a jittered grid over the
    image (so the views cover it), at a distance spread evenly over ``distance_range_m``, and
    tilted about both in-plane axes by up to ``max_tilt_deg``, with a small roll. With
    ``require_inside``, each pose is redrawn (moving towards the image centre) until every
    corner and the board's printed outline are in the image, if that happens within 24
    tries; ``also_inside`` lists other cameras ``(camera, T_camera_left)`` that must see the
    whole board too (a stereo rig).

    Raises:
        ConfigError: ``n_views < 1`` or a bad range.
    """
    if n_views < 1:
        raise ConfigError(f"n_views must be >= 1; got {n_views}")
    d0, d1 = distance_range_m
    if not 0 < d0 <= d1:
        raise ConfigError(f"distance_range_m must be 0 < near <= far; got {distance_range_m}")
    _, corners = board.object_points()
    centre_board = corners.mean(axis=0)
    from sea3d.calib.targets import board_origin_offset_m

    ox, oy = board_origin_offset_m(board)
    bw, bh = board.size_m
    outline = np.array([[-ox, -oy, 0], [bw - ox, -oy, 0], [bw - ox, bh - oy, 0],
                        [-ox, bh - oy, 0]], dtype=np.float64)
    pts = np.concatenate([corners, outline])
    w, h = camera.width, camera.height
    cols = int(np.ceil(np.sqrt(n_views * w / h)))
    rows = int(np.ceil(n_views / cols))
    cells = [(c, r) for r in range(rows) for c in range(cols)]
    order = rng.permutation(len(cells))[:n_views]
    distances = np.linspace(d0, d1, n_views)[rng.permutation(n_views)]
    poses = []
    for k, idx in enumerate(order):
        c, r = cells[idx]
        u = (c + rng.uniform(0.2, 0.8)) / cols * w
        v = (r + rng.uniform(0.2, 0.8)) / rows * h
        T = np.eye(4)
        for attempt in range(24):
            # Pull the target towards the image centre until the whole board is in view.
            pull = min(1.0, attempt / 12.0)
            uu = u + pull * (w / 2 - u)
            vv = v + pull * (h / 2 - v)
            T = _pose_at(camera, centre_board, uu, vv, float(distances[k]), max_tilt_deg, rng)
            if not require_inside or (_inside(camera, pts, T, margin_px=2.0) and all(
                    _inside(cam, pts, T_cl @ T, margin_px=2.0) for cam, T_cl in also_inside)):
                break
        poses.append(T)
    return poses


def _pose_at(camera: CameraModel, centre_board: FloatArray, u: float, v: float, distance: float,
             max_tilt_deg: float, rng: np.random.Generator) -> FloatArray:
    ray = camera.unproject(np.array([[u, v]]))
    direction = ray.directions[0]
    origin = ray.origins[0]
    if not (np.all(np.isfinite(direction)) and np.all(np.isfinite(origin))):
        direction, origin = np.array([0.0, 0.0, 1.0]), np.zeros(3)
    centre = origin + distance * direction
    tilt = np.deg2rad(rng.uniform(-max_tilt_deg, max_tilt_deg, size=2))
    roll = np.deg2rad(rng.uniform(-15.0, 15.0))
    R = cv2.Rodrigues(np.array([tilt[0], tilt[1], roll]).reshape(3, 1))[0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ centre_board
    return T


def _inside(camera: CameraModel, pts: FloatArray, T: FloatArray, margin_px: float) -> bool:
    p = pts @ T[:3, :3].T + T[:3, 3]
    if np.any(p[:, 2] <= 0):
        return False
    uv, valid = camera.project(p)
    return bool(valid.all() and np.all(uv >= margin_px) and np.all(
        uv[:, 0] <= camera.width - 1 - margin_px) and np.all(
        uv[:, 1] <= camera.height - 1 - margin_px))


def _detect(camera: CameraModel, board: BoardSpec, T_cam_board: FloatArray, noise_px: float,
            rng: np.random.Generator, name: str, min_corners: int,
            allow_partial: bool) -> Detection:
    ids, pts = board.object_points()
    p_cam = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    uv, valid = camera.project(p_cam)
    w, h = camera.width, camera.height
    inside = valid & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (
        uv[:, 1] <= h - 1) & (p_cam[:, 2] > 0)
    uv = uv[inside] + rng.normal(0.0, noise_px, size=(int(inside.sum()), 2))
    full = bool(inside.all())
    if not allow_partial and not full:
        status = DetectionStatus.NOT_FOUND
        return Detection(status=status, corners_px=np.zeros((0, 2)),
                         ids=np.zeros(0, np.int64), points_board_m=np.zeros((0, 3)),
                         image_size=(w, h), message="board partly outside the image",
                         name=name)
    status = DetectionStatus.DETECTED if int(inside.sum()) >= min_corners else (
        DetectionStatus.PARTIAL if inside.any() else DetectionStatus.NOT_FOUND)
    return Detection(status=status, corners_px=uv, ids=ids[inside], points_board_m=pts[inside],
                     image_size=(w, h), message=f"{int(inside.sum())} synthetic corners",
                     name=name)


def synthetic_detections(cameras: Sequence[CameraModel], board: BoardSpec,
                         poses_left: Sequence[FloatArray], rng: np.random.Generator, *,
                         T_cam_left: Sequence[FloatArray] | None = None, noise_px: float = 0.15,
                         min_corners: int = 6, partial_ok: bool = True) -> list[SyntheticView]:
    """Project the board through each camera for every pose and add Gaussian pixel noise.

    Args:
        cameras: camera models (left first); any :class:`CameraModel`.
        board: the board.
        poses_left: ``T_left_board`` per view.
        rng: the noise generator.
        T_cam_left: per camera, the transform from the left camera frame into that camera's
            frame (``T_right_left`` for the right camera); default identity for the first and
            required for the others.
        noise_px: standard deviation of the noise per coordinate, pixels.
        min_corners: fewer visible corners make the detection ``PARTIAL``.
        partial_ok: checkerboards: if False (as OpenCV detectors behave), a board partly
            outside the image is ``NOT_FOUND``; ChArUco and tag grids always allow subsets.
            If True, checkerboards keep their visible corners.

    Returns:
        One :class:`SyntheticView` per pose; names ``cam{i}_{k:03d}``.
    """
    if T_cam_left is None:
        if len(cameras) != 1:
            raise ConfigError("T_cam_left is needed for more than one camera")
        T_cam_left = [np.eye(4)]
    if len(T_cam_left) != len(cameras):
        raise ConfigError("give one T_cam_left per camera")
    allow_partial = partial_ok or board.kind != "checkerboard"
    out = []
    for k, T in enumerate(poses_left):
        dets = []
        for i, (cam, T_cl) in enumerate(zip(cameras, T_cam_left, strict=True)):
            dets.append(_detect(cam, board, T_cl @ T, noise_px, rng, f"cam{i}_{k:03d}",
                                min_corners, allow_partial))
        out.append(SyntheticView(T_left_board=np.asarray(T, dtype=np.float64),
                                 detections=tuple(dets)))
    return out


class BoardRenderer:
    """Render images of a board seen through any camera model (ray casting onto the board
    plane), for end-to-end tests of detection and calibration without the full simulator.

    The camera's rays are computed once (``camera.unproject`` of every pixel centre, with
    ``supersample`` x ``supersample`` rays per pixel); each view then intersects them with the
    board plane and samples a rendered board texture bilinearly. The board is printed with a
    white border one square wide on a grey background.

    Args:
        camera: any :class:`CameraModel`.
        board: the board.
        texture_px_per_m: resolution of the board texture.
        supersample: rays per pixel along each axis (anti-aliasing).
    """

    def __init__(self, camera: CameraModel, board: BoardSpec, *, texture_px_per_m: float = 4000.0,
                 supersample: int = 2) -> None:
        from sea3d.calib.targets import board_origin_offset_m, render_board

        self.camera = camera
        self.board = board
        self.supersample = int(supersample)
        self.margin_m = board.square_m
        self.px_per_m = float(texture_px_per_m)
        self.texture = render_board(board, px_per_m=self.px_per_m, margin_m=self.margin_m)
        ox, oy = board_origin_offset_m(board)
        self.origin_px = ((self.margin_m + ox) * self.px_per_m - 0.5,
                          (self.margin_m + oy) * self.px_per_m - 0.5)
        s = self.supersample
        w, h = camera.width, camera.height
        offs = (np.arange(s) + 0.5) / s - 0.5
        us = (np.arange(w)[None, :, None, None] + offs[None, None, None, :]) * np.ones(
            (h, 1, s, 1))
        vs = (np.arange(h)[:, None, None, None] + offs[None, None, :, None]) * np.ones(
            (1, w, 1, s))
        uv = np.stack([us.ravel(), vs.ravel()], axis=1)
        rays = camera.unproject(uv)
        self._origins = rays.origins
        self._dirs = rays.directions
        self._shape = (h, w, s, s)

    def render(self, T_cam_board: FloatArray, *, background: int = 110,
               blur_px: float = 0.0) -> NDArray[np.uint8]:
        """``(H, W)`` uint8 image of the board at pose ``T_cam_board`` (board -> camera)."""
        R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
        # Rays in the board frame; the board is the plane z = 0.
        o = (self._origins - t) @ R
        d = self._dirs @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -o[:, 2] / d[:, 2]
        hit = o + lam[:, None] * d
        ok = np.isfinite(lam) & (lam > 0)
        mx = np.where(ok, hit[:, 0] * self.px_per_m + self.origin_px[0], -1e6).astype(np.float32)
        my = np.where(ok, hit[:, 1] * self.px_per_m + self.origin_px[1], -1e6).astype(np.float32)
        h, w, s, _ = self._shape
        samples = cv2.remap(self.texture, mx.reshape(h, -1), my.reshape(h, -1), cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=background)
        img = samples.reshape(h, w, s, s).astype(np.float32).mean(axis=(2, 3))
        if blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur_px)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)
