"""Enhancement of every stereo pair of a session (``sea3d enhance --session``): Sea-thru's range
from our stereo depth, one water model per dive, and a status per pair; the caller writes the
enhanced images (``on_pair``) and prints the result."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d.enhance.api import enhance_pair
from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.seathru import range_from_points
from sea3d.enhance.water import WaterModel, fit_water_model
from sea3d.errors import EnhanceError
from sea3d.io.session import SessionReader
from sea3d.io.session.common import StereoPair
from sea3d.pipeline.progress import ProgressFactory, no_progress
from sea3d.stereo.recipe import StereoDepth

__all__ = ["EnhanceSessionResult", "SessionEnhancement", "enhance_session", "session_water_model",
           "stereo_ranges"]

log = logging.getLogger(__name__)

RangeFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``(left, right) -> (range_left_m, range_right_m)``: each image's range along its rays."""


@dataclass(frozen=True, kw_only=True)
class EnhanceSessionResult:
    """What :func:`enhance_session` did.

    Attributes:
        pairs: stereo pairs handed to ``on_pair``.
        status_counts: ``{status: pairs}``; ``unchanged`` counts the pairs whose enhancement
            failed and that were handed on as they came.
        water_model: the dive's water model (Sea-thru's water-model path), else None.
    """

    pairs: int
    status_counts: dict[str, int] = field(default_factory=dict)
    water_model: WaterModel | None = None


def stereo_ranges(stereo: StereoDepth) -> RangeFn:
    """Each image's range from our stereo depth of the pair (left, and right through the rig's
    extrinsics)."""
    rig = stereo.rig
    T_right_left = np.linalg.inv(rig.T_left_right)

    def ranges(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        res = stereo.compute(left, right)
        pts_l = res.points_left
        pts_r = pts_l @ T_right_left[:3, :3].T + T_right_left[:3, 3]
        return range_from_points(pts_l, rig.left), range_from_points(pts_r, rig.right)

    return ranges


def session_water_model(session: SessionReader, ranges: RangeFn, most: int = 8,
                        config: SeathruConfig | None = None) -> WaterModel:
    """One water model for the whole dive, fitted to up to ``most`` pairs spread over it (both
    images, each with its own stereo range), with ``config`` (the water model's defaults when
    None).

    Raises:
        EnhanceError: the frames cannot be fitted (:func:`~sea3d.enhance.water.fit_water_model`).
    """
    n = len(session.match_pairs())
    pick = set(np.linspace(0, n - 1, min(n, most)).round().astype(int).tolist())
    frames = []
    for k, pair in enumerate(session.pairs()):
        if k in pick:
            rl, rr = ranges(pair.left, pair.right)
            frames += [(pair.left, rl), (pair.right, rr)]
    model = fit_water_model(frames, config)
    log.info("water model of the dive (%d frames): %s", len(frames), model.as_dict())
    return model


class SessionEnhancement:
    """The enhancement of every stereo pair of a session, checked and prepared (Sea-thru's
    stereo range and the dive's water model) before anything is written; :meth:`run` then
    enhances each pair.

    Args:
        session: an open session.
        method: an enhancement name (:data:`sea3d.enhance.registry.METHODS`).
        stereo: the stereo depth of the session's rig (needed by ``seathru``).
        seathru_config: the Sea-thru settings; with ``attenuation="water-model"`` (or None,
            its defaults) one water model is fitted to the dive, else each left image fits
            its own per-image Sea-thru.
        params: keyword parameters of the method (e.g. ``clip_limit``).
        name: the session as messages name it (default its path).

    Raises:
        EnhanceError: ``seathru`` without ``stereo``, a water model that cannot be fitted, or
            a session without pairs.
    """

    def __init__(self, session: SessionReader, method: str, *,
                 stereo: StereoDepth | None = None,
                 seathru_config: SeathruConfig | None = None,
                 params: dict[str, Any] | None = None, name: str | None = None) -> None:
        self.session, self.method = session, method
        self.seathru_config, self.params = seathru_config, dict(params or {})
        self.name = str(session.path) if name is None else name
        self.ranges: RangeFn | None = None
        self.water_model: WaterModel | None = None
        if method == "seathru":
            if stereo is None:
                raise EnhanceError(f"{self.name}: Sea-thru needs stereo depth of the session's "
                                   "rig")
            self.ranges = stereo_ranges(stereo)
            if seathru_config is None or seathru_config.water_model:
                self.water_model = session_water_model(session, self.ranges,
                                                       config=seathru_config)
        self.pairs = len(session.match_pairs())
        if self.pairs == 0:
            raise EnhanceError(f"{self.name}: no stereo pairs to enhance")

    def run(self, on_pair: Callable[[StereoPair, np.ndarray, np.ndarray, str], object], *,
            progress: ProgressFactory | None = None) -> EnhanceSessionResult:
        """Enhance each pair and hand it to ``on_pair(pair, left, right, status)`` (the caller
        writes the images). A pair whose enhancement fails (no depth, saturated) does not end
        the session: it is handed on unchanged with status ``unchanged``, and a warning says
        why. ``progress`` is called once as ``progress(f"enhance {method}", pairs)``."""
        statuses: dict[str, int] = {}
        bar = (progress or no_progress)(f"enhance {self.method}", self.pairs)
        try:
            for pair in self.session.pairs():
                kw: dict[str, Any] = dict(self.params)
                if self.ranges is not None:
                    rl, rr = self.ranges(pair.left, pair.right)
                    kw.update(range_left_m=rl, range_right_m=rr,
                              seathru_config=self.seathru_config, water_model=self.water_model)
                try:
                    res = enhance_pair(pair.left, pair.right, self.method, **kw)
                    lo, ro, status = res.images[0], res.images[1], res.status
                except EnhanceError as err:
                    log.warning("frame %d kept unchanged: %s", pair.t_ns, err)
                    lo, ro, status = pair.left, pair.right, "unchanged"
                statuses[status] = statuses.get(status, 0) + 1
                on_pair(pair, lo, ro, status)
                bar.update(1)
        finally:
            bar.close()
        return EnhanceSessionResult(pairs=sum(statuses.values()), status_counts=statuses,
                                    water_model=self.water_model)


def enhance_session(session: SessionReader, method: str, *,
                    on_pair: Callable[[StereoPair, np.ndarray, np.ndarray, str], object],
                    stereo: StereoDepth | None = None,
                    seathru_config: SeathruConfig | None = None,
                    params: dict[str, Any] | None = None,
                    progress: ProgressFactory | None = None,
                    name: str | None = None) -> EnhanceSessionResult:
    """Enhance each stereo pair of ``session`` with ``method``: :class:`SessionEnhancement`
    then its :meth:`~SessionEnhancement.run` (see both for the arguments).

    Raises:
        EnhanceError: as :class:`SessionEnhancement`.
    """
    return SessionEnhancement(session, method, stereo=stereo, seathru_config=seathru_config,
                              params=params, name=name).run(on_pair, progress=progress)
