"""A network's depth made metric: predict, align to sparse metric depth, fill its holes."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from sea3d._typing import F32
from sea3d.errors import MonoDepthError
from sea3d.monodepth.align import align_depth, fill_holes

__all__ = ["MetricDepth", "predict_metric"]


class _Predicts(Protocol):
    def predict(self, image: np.ndarray) -> tuple[F32, dict[str, float]]: ...


@dataclass(frozen=True, kw_only=True)
class MetricDepth:
    """One image's depth from :func:`predict_metric`.

    Attributes:
        depth: ``(H, W)`` float32: metres when aligned (or a metric network), else the
            network's raw output; NaN where there is none.
        info: JSON-ready figures: ``timings_s`` (``preprocess_s``, ``inference_s``,
            ``resize_s``, ``align_s``), ``alignment`` (None without sparse depth, else its
            ``status``, ``message``, ``scale``, ``shift``, ``samples``, ``inliers``,
            ``median_rel_error``), ``sparse_fraction``, ``valid_fraction`` and, when holes
            were filled, ``filled_fraction``.
    """

    depth: F32
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def aligned(self) -> bool:
        """The alignment to sparse depth succeeded."""
        al = self.info.get("alignment")
        return al is not None and al["status"] == "ok"


def predict_metric(model: _Predicts, view: np.ndarray, sparse: np.ndarray | None, *,
                   kind: str, fill: bool) -> MetricDepth:
    """The network's depth of ``view``, aligned to ``sparse`` metric depth when given.

    Args:
        model: the network (:class:`~sea3d.monodepth.model.OnnxDepthModel`).
        view: ``(H, W, 3)`` RGB image (or ``(H, W)``).
        sparse: ``(H, W)`` metric depth in metres with NaN holes, on ``view``'s pixels, or None.
        kind: the network's output kind (``inverse``, ``depth``, ``metric``).
        fill: fill ``sparse``'s holes with the aligned prediction (dense sparse depth: stereo,
            a depth map) when the alignment succeeds.

    Returns:
        :class:`MetricDepth`; an alignment that fails on valid input is a status in ``info``.

    Raises:
        MonoDepthError: ``sparse`` not the size of the prediction, or the network's errors.
    """
    pred, timings = model.predict(view)
    info: dict[str, Any] = {"timings_s": timings}
    if sparse is None:
        info["alignment"] = None
        return MetricDepth(depth=pred, info=info)
    if sparse.shape != pred.shape:
        raise MonoDepthError(f"the sparse depth is {sparse.shape[1]}x{sparse.shape[0]} but the "
                             f"image is {pred.shape[1]}x{pred.shape[0]}")
    t0 = time.perf_counter()
    aligned, al = align_depth(pred, sparse, kind=kind)
    info["alignment"] = {"status": al.status, "message": al.message, "scale": al.scale,
                         "shift": al.shift, "samples": al.samples, "inliers": al.inliers,
                         "median_rel_error": al.median_rel_error}
    out = aligned
    valid_sparse = float(np.mean(np.isfinite(sparse)))
    if fill and al.status == "ok":
        out, filled = fill_holes(sparse, aligned)
        info["filled_fraction"] = float(filled.mean())
    info["sparse_fraction"] = valid_sparse
    info["valid_fraction"] = float(np.mean(np.isfinite(out)))
    timings["align_s"] = time.perf_counter() - t0
    return MetricDepth(depth=out, info=info)
