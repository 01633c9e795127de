"""Monocular depth of every frame of a session (``sea3d mono-depth SESSION``), made metric by
our stereo depth of each pair (or by SfM points); the caller saves each aligned frame
(``on_frame``) and the summary."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d._typing import F32
from sea3d.errors import MonoDepthError
from sea3d.io.session import SessionReader
from sea3d.monodepth.metric import predict_metric
from sea3d.pipeline.progress import ProgressFactory, no_progress
from sea3d.stereo.recipe import StereoDepth

__all__ = ["MonoDepthSessionResult", "monodepth_session", "stereo_sparse_depth"]

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
