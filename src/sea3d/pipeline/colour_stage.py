"""The dive's colours in ``sea3d process --restore-colours seathru`` (older name
``water-model``): one water model per dive, fitted in the client from the first frames'
stereo range, then every frame restored with it before the ordered stages colour the mesh
and cloud with it.

Why here and not in the per-frame stage: the model needs the depth of several frames, which
only the per-frame stage makes, so a per-frame restoration would need the model before the
depth that fits it (a second pass, or a configuration, and a cache fingerprint, that changes
in the middle of a run). Restoring in the client after the fit keeps the per-frame stage a
pure function of its configuration and one pair, and keeps the cache honest with nothing to
add to its fingerprint: a cached frame holds depth and rectified images only, never colours
that depend on a model, and a rerun from the cache fits the same model again from the same
frames (the fit is seeded) and restores them the same way. The inversion is one vectorised
pass per frame (:func:`sea3d.enhance.water.restore`), cheaper than matching.

Frames before the model exists are **held**, not passed on: the first
:attr:`DiveColourConfig.fit_frames` frames with depth, taken every
:attr:`DiveColourConfig.fit_stride`-th frame (so the fit sees the start of the dive, not one
instant), are buffered with every frame between them; when the last is in (or the session
ends sooner, or ``2 fit_frames fit_stride`` frames are held without enough depth) the model
is fitted once and every held frame is restored with it and handed on in time order. If that
model is not ``ok`` (a plausibility check failed, :func:`~sea3d.enhance.water.fit_water_model`),
the first fallback step is more frames: :attr:`DiveColourConfig.more_frames` more are
gathered (and held) and the model is fitted once more over all of them; the fit's own steps
(``beta_D`` tied to a Jerlov class, backscatter alone, grey world) follow inside it. So
every frame is restored with the dive's one model and carries its status; none goes out
unrestored under an ``ok``. A dive whose water cannot be fitted at all (no frame with
range) gives every frame grey world with ``fallback-grey-world`` and the reason.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.enhance.config import SeathruConfig
from sea3d.enhance.seathru import depth_to_range
from sea3d.enhance.stage import ColourRestoreConfig, restore_colours_with_range
from sea3d.enhance.water import WaterFitConfig, WaterModel, fit_water_model
from sea3d.errors import ConfigError, EnhanceError
from sea3d.pipeline.frame_stage import FrameResult

__all__ = ["DiveColourConfig", "DiveColours", "frame_range_m", "right_range_m"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class DiveColourConfig:
    """How the dive's water model is fitted in ``sea3d process``."""

    fit_frames: int = 8
    """Frames with depth the one water model is fitted to (the Sea-thru fit of
    ``sea3d enhance --session`` pools 8 too)."""
    fit_stride: int = 2
    """Take every n-th frame of the start of the dive for the fit (8 frames spread over the
    first 16), so the fit sees more ranges than one instant; the frames between are held
    until the model exists."""
    water: SeathruConfig = field(default_factory=WaterFitConfig)
    """The fit's own settings."""
    more_frames: int = 8
    """Fallback step before the fit's own (:func:`~sea3d.enhance.water.fit_water_model`):
    when the model from ``fit_frames`` frames is not ``ok`` (a check failed), gather this many
    more frames with depth (at the same stride, held likewise) and fit once more over all of
    them: a wider range span may identify what a short one could not. 0: no second fit."""
    pool_pair: bool = True
    """Fit (and so white-balance) over both views of each fit pair, not the left alone: the
    pair gets one balance (:meth:`DiveColours.restore_right` restores the right view with
    it)."""

    def __post_init__(self) -> None:
        if self.fit_frames < 1:
            raise ConfigError(f"fit_frames must be >= 1, got {self.fit_frames}")
        if self.fit_stride < 1:
            raise ConfigError(f"fit_stride must be >= 1, got {self.fit_stride}")
        if self.more_frames < 0:
            raise ConfigError(f"more_frames must be >= 0, got {self.more_frames}")


def frame_range_m(res: FrameResult, maps: Any) -> NDArray[np.float32]:
    """``(H, W)`` float32 range along the line of sight of the rectified left pixels, metres,
    NaN invalid: the rectified depth times the length of the virtual pinhole's ray (exact for
    a pinhole rig; through a port the ray starts a few millimetres off the pinhole centre)."""
    return depth_to_range(res.depth_m, float(maps.focal_px), float(maps.focal_px),
                          float(maps.cx_px), float(maps.cy_px))


def right_range_m(res: FrameResult, maps: Any) -> NDArray[np.float32]:
    """``(H, W)`` float32 range of the rectified **right** pixels, metres, NaN invalid: each
    left pixel with depth ``z`` lands at ``u - f B / z`` on the same row of the rectified
    right view (the nearest surface kept where several land), then the right virtual
    pinhole's ray lengths (its centre is ``B`` along the rectified x axis; the same focal
    length and principal point)."""
    z = np.asarray(res.depth_m, dtype=np.float64)
    h, w = z.shape
    fb = float(maps.focal_px) * float(maps.baseline_m)
    v, u = np.nonzero(np.isfinite(z) & (z > 0))
    ur = np.rint(u - fb / z[v, u]).astype(np.int64)
    ok = (ur >= 0) & (ur < w)
    out = np.full(h * w, np.inf)
    np.minimum.at(out, v[ok] * w + ur[ok], z[v, u][ok])
    out[~np.isfinite(out)] = np.nan
    return depth_to_range(out.reshape(h, w).astype(np.float32), float(maps.focal_px),
                          float(maps.focal_px), float(maps.cx_px), float(maps.cy_px))


class DiveColours:
    """Restores a dive's frames with one water model, fitted once from its first frames.

    Feed it every per-frame result in time order (:meth:`push`), then :meth:`flush` after the
    last one; both return the results ready for the ordered stages, in time order, with
    ``color_left`` and ``colour_status`` set (failed frames pass through untouched).

    Args:
        maps: the rectification the results live on (for the range of their pixels).
        config: :class:`DiveColourConfig`.
    """

    def __init__(self, maps: Any, config: DiveColourConfig | None = None) -> None:
        self.maps = maps
        self.config = config or DiveColourConfig()
        self.model: WaterModel | None = None
        self.fit_error: str = ""
        self.fit_stamps: list[int] = []
        self.fit_s = 0.0
        self.restore_s: list[float] = []
        self.fits = 0
        self._held: list[FrameResult] = []
        self._seen_with_depth = 0
        self._samples: list[tuple[NDArray[np.uint8], NDArray[np.float32]]] = []
        self._first: WaterModel | None = None
        self.first_status = ""
        """Status of the first fit over ``fit_frames`` when it was not ``ok`` (then the model
        that restores was fitted over ``more_frames`` more); empty otherwise."""

    @property
    def fitted(self) -> bool:
        """Whether the model has been fitted (or found unfittable)."""
        return self.fits > 0

    def push(self, res: FrameResult) -> list[FrameResult]:
        """One frame in; the frames now ready out (none while the fit frames are gathered)."""
        if self.fitted:
            return [self._restore(res)]
        self._held.append(res)
        if res.status == "ok" and res.rect_left.ndim == 3:
            if self._seen_with_depth % self.config.fit_stride == 0:
                self._samples.append((res.rect_left, frame_range_m(res, self.maps)))
                if self.config.pool_pair and res.rect_right.shape == res.rect_left.shape:
                    # Both views in the fit: the pair's white balance is pooled over both.
                    self._samples.append((res.rect_right, right_range_m(res, self.maps)))
                self.fit_stamps.append(int(res.t_ns))
            self._seen_with_depth += 1
        # Held frames are bounded: where depth is rare, fit with what came in twice the span.
        want = self.config.fit_frames + (self.config.more_frames if self._extending else 0)
        max_held = 2 * want * self.config.fit_stride
        if len(self.fit_stamps) < want and len(self._held) < max_held:
            return []
        if not self._extending and self._first_fit_wants_more():
            return []
        return self._fit_and_release()

    @property
    def _extending(self) -> bool:
        return bool(self.first_status)

    def _first_fit_wants_more(self) -> bool:
        """The first fallback step: fit ``fit_frames``; if not ``ok``, keep gathering
        ``more_frames`` more before the fit that restores (True: keep holding)."""
        if self.config.more_frames == 0 or not self._samples:
            return False
        t0 = time.perf_counter()
        try:
            first = fit_water_model(self._samples, self.config.water)
        except EnhanceError as err:
            self.fit_error = str(err)  # unfittable: released now with grey world
            return False
        finally:
            self.fit_s += time.perf_counter() - t0
        if first.status == "ok":
            self._first = first
            return False
        self.first_status = first.status
        log.info("water model from the first %d frames: %s; fitting again over %d more",
                 len(self.fit_stamps), first.status, self.config.more_frames)
        return True

    def flush(self) -> list[FrameResult]:
        """After the last frame: fit with what was gathered (a short session) and release."""
        return [] if self.fitted else self._fit_and_release()

    def _fit_and_release(self) -> list[FrameResult]:
        t0 = time.perf_counter()
        self.fits += 1
        if self._first is not None:
            self.model = self._first
        elif self.fit_error:
            pass  # the first fit raised: unfittable, said there
        elif self._samples:
            try:
                self.model = fit_water_model(self._samples, self.config.water)
            except EnhanceError as err:
                self.fit_error = str(err)
        else:
            self.fit_error = "no frame with depth and colour to fit the water to"
        self.fit_s += time.perf_counter() - t0
        if self.model is not None:
            log.info("water model of the dive (%d frames): %s", len(self._samples),
                     self.model.status)
        else:
            log.warning("the dive's water cannot be fitted (%s): grey world on every frame",
                        self.fit_error)
        self._samples = []
        held, self._held = self._held, []
        return [self._restore(r) for r in held]

    def _restore(self, res: FrameResult) -> FrameResult:
        if res.status == "failed":
            return res
        tr = time.perf_counter()
        img = res.rect_left
        if self.model is None:
            from sea3d.enhance.colour import grey_world

            out = grey_world(img) if img.ndim == 3 else img
            status, colors = "fallback-grey-world", np.asarray(out, np.uint8)
        else:
            cfg = ColourRestoreConfig(enabled=True, method="water-model", water_model=self.model,
                                      seathru=self.config.water)
            got = restore_colours_with_range(img, frame_range_m(res, self.maps), cfg)
            status, colors = got.status, np.asarray(got.image, np.uint8)
        if colors.ndim == 2:
            colors = np.repeat(colors[..., None], 3, axis=2)
        dt = time.perf_counter() - tr
        self.restore_s.append(dt)
        timings = dict(res.timings_s)
        timings["restore_colours_s"] = dt
        return dataclasses.replace(res, color_left=np.ascontiguousarray(colors),
                                   colour_status=status, timings_s=timings)

    def restore_right(self, res: FrameResult) -> NDArray[np.uint8]:
        """The rectified right view restored with the dive's model (its own range,
        :func:`right_range_m`), the same white balance as the left: ``(H, W, 3)`` uint8.

        Raises:
            EnhanceError: called before the model is fitted, or without a right colour view.
        """
        if self.model is None:
            raise EnhanceError("the dive's water model is not fitted: no right view restored")
        img = res.rect_right
        if img.ndim != 3:
            raise EnhanceError(f"frame {res.t_ns}: the right view has no colour to restore")
        cfg = ColourRestoreConfig(enabled=True, method="water-model", water_model=self.model,
                                      seathru=self.config.water)
        got = restore_colours_with_range(img, right_range_m(res, self.maps), cfg)
        return np.ascontiguousarray(got.image, np.uint8)

    def summary(self) -> dict[str, Any]:
        """What summary.json and report.html say about the dive's water model."""
        out: dict[str, Any] = {
            "method": "water-model (one per dive)",
            "fit_frames_wanted": self.config.fit_frames, "fit_stride": self.config.fit_stride,
            "fit_frames_t_ns": self.fit_stamps, "fits": self.fits, "fit_s": self.fit_s,
            "pooled_over_pair": self.config.pool_pair,
            "first_fit_status": self.first_status or None,
            "restore_s_median": float(np.median(self.restore_s)) if self.restore_s else None,
        }
        if self.model is not None:
            out["water_model"] = self.model.as_dict()
        else:
            out["water_model"] = None
            out["fit_error"] = self.fit_error or "not fitted"
        return out
