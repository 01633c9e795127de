"""Monocular depth of every frame of a session (``sea3d mono-depth SESSION``), made metric by
our stereo depth of each pair (or by SfM points); the caller saves each aligned frame
(``on_frame``) and the summary."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sea3d._typing import F32
from sea3d.errors import MonoDepthError
from sea3d.io.session import SessionReader
from sea3d.monodepth.metric import predict_metric
from sea3d.pipeline.progress import ProgressFactory, no_progress
from sea3d.stereo.recipe import StereoDepth

__all__ = ["MonoDepthSessionResult", "monodepth_session", "sfm_sparse_depth",
           "stereo_sparse_depth"]

SparseFn = Callable[[str, int, int], np.ndarray]
"""``sparse(image_name, width, height)``: ``(height, width)`` metric depth with NaN holes."""


def stereo_sparse_depth(stereo: StereoDepth, left: np.ndarray, right: np.ndarray,
                        where: str) -> tuple[F32, np.ndarray]:
    """Our stereo depth of a pair as the sparse depth to align to, and the rectified left view
    it lives on (the view the network is then run on).

    Raises:
        MonoDepthError: an image that is not the rig's size (``where`` names it).
    """
    rig = stereo.rig
    for name, img in (("left", left), ("right", right)):
        if img.shape[:2] != (rig.height, rig.width):
            raise MonoDepthError(f"{where}: {name} image is {img.shape[1]}x{img.shape[0]} "
                                 f"but the rig is {rig.width}x{rig.height}")
    res = stereo.compute(left, right)
    return res.depth_m, res.rect_left


def sfm_sparse_depth(model_dir: str | Path, image_name: str, width: int, height: int) -> F32:
    """Sparse depth of a COLMAP model's points in one of its images (matched by name: the
    exact name, its file name, ``left/<stem>.png``, ``<stem>.png``, else the first image of
    that stem), through the model camera's own (possibly distorted) projection.

    Returns:
        (height, width) float32 metres, NaN where no point falls (nearest point per pixel).

    Raises:
        MonoDepthError: no registered image of that name, a model image of another size, or
            an image that sees no 3D point.
    """
    from sea3d.io.sfm_files import read_colmap_model
    from sea3d.monodepth import sparse_depth_from_points

    model_dir = Path(model_dir)
    rec = read_colmap_model(model_dir)
    names = {im.name: im for im in rec.images.values()}
    stem = Path(image_name).stem
    cands = [image_name, Path(image_name).name, f"left/{stem}.png", f"{stem}.png"]
    im = next((names[c] for c in cands if c in names), None)
    if im is None:
        im = next((v for k, v in names.items() if Path(k).stem == stem), None)
    if im is None or not im.has_pose:
        raise MonoDepthError(f"{model_dir}: no registered image named like {image_name!r}")
    cam = rec.cameras[im.camera_id]
    if (cam.width, cam.height) != (width, height):
        raise MonoDepthError(f"{model_dir}: image {im.name} is {cam.width}x{cam.height} in the "
                             f"model but the input is {width}x{height}")
    T = np.eye(4)
    T[:3, :4] = np.asarray(im.cam_from_world().matrix())
    pts = np.array([rec.points3D[p.point3D_id].xyz for p in im.points2D if p.has_point3D()])
    if len(pts) == 0:
        raise MonoDepthError(f"{model_dir}: image {im.name} sees no 3D points")
    pc = pts @ T[:3, :3].T + T[:3, 3]
    uv = np.asarray(cam.img_from_cam(pc), dtype=np.float64) - 0.5  # COLMAP -> our pixels
    # nearest point per pixel, with the camera's own (possibly distorted) projection
    K = np.eye(3)
    pix = np.column_stack([uv, np.ones(len(uv))]) * pc[:, 2:3]
    out: F32 = sparse_depth_from_points(pix, K, width, height)
    return out


@dataclass(frozen=True, kw_only=True)
class MonoDepthSessionResult:
    """What :func:`monodepth_session` did.

    Attributes:
        frames: per frame, ``{"t_ns": ..., **MetricDepth.info}``.
        aligned: frames whose alignment succeeded (the ones handed to ``on_frame``).
        frame: the view the depth lives in: ``rect_left`` (stereo) or ``left`` (SfM).
        median_rel_error: median over the aligned frames of their alignment's median relative
            error (None with none aligned).
    """

    frames: list[dict[str, Any]] = field(default_factory=list)
    aligned: int = 0
    frame: str = "left"
    median_rel_error: float | None = None


def monodepth_session(reader: SessionReader, model: Any, *, kind: str,
                      on_frame: Callable[[int, F32], object],
                      stereo: StereoDepth | None = None, sfm_sparse: SparseFn | None = None,
                      progress: ProgressFactory | None = None,
                      name: str | None = None) -> MonoDepthSessionResult:
    """The network's depth of each frame, aligned to stereo (each matched pair: the network
    runs on the rectified left view, stereo's holes are filled) or to SfM points (each left
    image, named ``left/<t_ns>.png``).

    Args:
        reader: an open session.
        model: the network (:class:`~sea3d.monodepth.model.OnnxDepthModel`).
        kind: the network's output kind.
        on_frame: ``on_frame(t_ns, depth_m)`` for each aligned frame (the caller saves it).
        stereo: the stereo depth of the session's rig; None: ``sfm_sparse`` aligns.
        sfm_sparse: the SfM points' sparse depth of an image (used without ``stereo``).
        progress: a bar factory, called once as ``progress("mono-depth", frames)``.
        name: the session as messages name it (default its path).

    Returns:
        :class:`MonoDepthSessionResult`; a frame that fails to align is a status in it.

    Raises:
        MonoDepthError: neither ``stereo`` nor ``sfm_sparse``, bad image sizes, the network's
            errors.
    """
    name = str(reader.path) if name is None else name
    if stereo is None and sfm_sparse is None:
        raise MonoDepthError(f"{name}: give stereo depth or SfM points to align to")
    stamps = reader.stamps("left")
    if stereo is not None:
        match = reader.match_pairs()
        todo: list[tuple[int, int | None]] = [
            (int(li), int(ri)) for li, ri in zip(match.left_index, match.right_index,
                                                 strict=True)]
    else:
        todo = [(i, None) for i in range(stamps.size)]
    frames: list[dict[str, Any]] = []
    bar = (progress or no_progress)("mono-depth", len(todo))
    try:
        for li, ri in todo:
            t_ns = int(stamps[li])
            left = reader.image("left", li, by="index")
            if stereo is not None and ri is not None:
                sparse, view = stereo_sparse_depth(
                    stereo, left, reader.image("right", ri, by="index"), f"{name} t_ns={t_ns}")
            else:
                assert sfm_sparse is not None
                sparse = sfm_sparse(f"left/{t_ns}.png", left.shape[1], left.shape[0])
                view = left
            got = predict_metric(model, view, sparse, kind=kind, fill=stereo is not None)
            if got.aligned:
                on_frame(t_ns, got.depth)
            frames.append({"t_ns": t_ns, **got.info})
            bar.update(1)
    finally:
        bar.close()
    ok = [f for f in frames if f["alignment"]["status"] == "ok"]
    return MonoDepthSessionResult(
        frames=frames, aligned=len(ok), frame="rect_left" if stereo is not None else "left",
        median_rel_error=float(np.median([f["alignment"]["median_rel_error"] for f in ok]))
        if ok else None)
