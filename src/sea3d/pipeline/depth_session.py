"""Stereo depth of every pair of a session (``sea3d depth --session``): the loop, its checks and
its figures; the caller saves each pair's depth (``on_pair``) and prints the result."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sea3d.errors import StereoError
from sea3d.io.session import SessionReader
from sea3d.pipeline.progress import ProgressFactory, no_progress
from sea3d.stereo.depth import DepthResult
from sea3d.stereo.recipe import StereoDepth

__all__ = ["DepthSessionResult", "depth_session"]


@dataclass(frozen=True, kw_only=True)
class DepthSessionResult:
    """What :func:`depth_session` did.

    Attributes:
        pairs: stereo pairs matched and handed to ``on_pair``.
        unpaired_left, unpaired_right: frames of each camera without a partner.
        mean_valid_fraction: mean over the pairs of the fraction of pixels with finite depth
            (0 with no pairs).
        refractive: the rig's rectification models a port.
        max_disparity_px: the matcher's disparity range.
        depth_range_m: ``(near, far)`` metres kept.
    """

    pairs: int
    unpaired_left: int
    unpaired_right: int
    mean_valid_fraction: float
    refractive: bool
    max_disparity_px: int
    depth_range_m: tuple[float, float]


def depth_session(session: SessionReader, stereo: StereoDepth, *,
                  on_pair: Callable[[int, DepthResult], object],
                  progress: ProgressFactory | None = None,
                  name: str | None = None) -> DepthSessionResult:
    """Depth of each stereo pair of ``session`` with ``stereo`` (built for the session's rig).

    Args:
        session: an open session.
        stereo: the stereo depth of the session's rig at its image size.
        on_pair: ``on_pair(t_ns, result)`` for each pair, in time order (the caller saves it).
        progress: a bar factory, called once as ``progress("depth", pairs)``.
        name: the session as messages name it (default its path).

    Returns:
        :class:`DepthSessionResult`.

    Raises:
        StereoError: no stereo pairs, or a frame whose size is not the rig's.
    """
    name = str(session.path) if name is None else name
    rig = stereo.rig
    match = session.match_pairs()
    n_pairs = len(match.left_index)
    if n_pairs == 0:
        raise StereoError(f"{name}: no stereo pairs to process")
    stereo.warm_up()
    valid: list[float] = []
    bar = (progress or no_progress)("depth", n_pairs)
    try:
        for pair in session.pairs():
            if pair.left.shape[:2] != (rig.height, rig.width):
                raise StereoError(
                    f"{name}: frame {pair.t_ns} is {pair.left.shape[1]}x"
                    f"{pair.left.shape[0]} but the rig is {rig.width}x{rig.height}"
                )
            res = stereo.compute(pair.left, pair.right)
            on_pair(pair.t_ns, res)
            valid.append(float(np.isfinite(res.depth_m).mean()))
            bar.update(1)
    finally:
        bar.close()
    return DepthSessionResult(
        pairs=len(valid), unpaired_left=match.unpaired_left, unpaired_right=match.unpaired_right,
        mean_valid_fraction=float(np.mean(valid)) if valid else 0.0,
        refractive=bool(stereo.maps.refractive), max_disparity_px=stereo.max_disparity_px,
        depth_range_m=stereo.depth_range_m)
