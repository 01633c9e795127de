"""The depth scheduler: the per-frame stage over a frame source, results back in time order.

At most ``window`` frames are between the reader and the ordered stages at any time
(submitted, running, or finished and waiting for their turn). Each result is cached by frame
stamp as it arrives (``OUT/cache``), and a frame already in the cache is not computed again,
so a killed run resumes. Results are handed on in time order, whatever order the executor
finishes them in.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from sea3d.errors import ExecutorError, SessionError
from sea3d.pipeline.frame_source import FramePair, SessionFrames
from sea3d.pipeline.frame_stage import FrameResult, FrameStageConfig, process_frame

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from sea3d.io.result_cache import FrameCache
    from sea3d.pipeline.depth_rate import DepthRate
    from sea3d.pipeline.executors import Executor
    from sea3d.stereo.recipe import StereoDepth

__all__ = ["DepthScheduler", "StageTimer"]

log = logging.getLogger(__name__)


class StageTimer:
    """Seconds per named step, summed."""

    def __init__(self) -> None:
        self.s: dict[str, float] = {}

    def add(self, key: str, seconds: float) -> None:
        self.s[key] = self.s.get(key, 0.0) + float(seconds)


class DepthScheduler:
    """Runs :func:`~sea3d.pipeline.frame_stage.process_frame` on an executor over a source.

    Args:
        source: the frames (:class:`~sea3d.pipeline.frame_source.SessionFrames`).
        executor: where the per-frame stage runs (:mod:`sea3d.pipeline.executors`).
        stage: the per-frame stage's configuration.
        stereo: what to hand each call as its stereo recipe (``executor.share(...)``).
        cache: a :class:`~sea3d.io.result_cache.FrameCache`.
        window: frames in flight at most.
        timer: where read and cache times are added.
        on_depth: called once per frame as its depth is ready (a progress bar's update).
        depth_rate: which frames get depth of their own
            (:class:`~sea3d.pipeline.depth_rate.DepthRate`, asked in time order as frames
            are submitted); None: every frame.
        rectify: ``rectify(left, right) -> (rect_left, rect_right)`` for the frames that get
            no depth (run here, in the client: milliseconds); needed with ``depth_rate``.

    A frame without depth of its own is handed on with ``seeded=True`` and the latest depth
    map before it (in time order) as ``depth_m``, unmoved (the caller moves it to the frame's
    pose: :meth:`~sea3d.pipeline.depth_rate.DepthRate.seed`). It is not cached.
    """

    def __init__(self, source: SessionFrames, executor: Executor, stage: FrameStageConfig,
                 stereo: StereoDepth, cache: FrameCache, *, window: int, timer: StageTimer,
                 on_depth: Callable[[int], object] = lambda n: None,
                 depth_rate: DepthRate | None = None,
                 rectify: Callable[[NDArray[Any], NDArray[Any]],
                                   tuple[NDArray[np.uint8], NDArray[np.uint8]]] | None = None
                 ) -> None:
        if depth_rate is not None and rectify is None:
            raise ValueError("a depth rate needs rectify for the frames without depth")
        self.depth_rate, self.rectify = depth_rate, rectify
        self.seeded = 0
        self.source, self.executor, self.stage = source, executor, stage
        self.stereo, self.cache, self.window = stereo, cache, window
        self.timer, self.on_depth = timer, on_depth
        self.from_cache = 0
        self.unreadable = 0
        self._cached = cache.stamps()
        self._pending: dict[int, Any] = {}

    def _cached_result(self, t_ns: int) -> FrameResult | None:
        tr = time.perf_counter()
        got = self.cache.get(t_ns)
        self.timer.add("cache_read_s", time.perf_counter() - tr)
        if got is None:
            return None
        try:
            # Its stage timings are of the run that computed it: this run matched nothing for it.
            return dataclasses.replace(FrameResult.from_cache(t_ns, *got), timings_s={})
        except (KeyError, ValueError, TypeError) as err:
            log.warning("cache entry of frame %d is incomplete (%s); recomputing", t_ns, err)
            self.cache.path(t_ns).unlink(missing_ok=True)
            return None

    def _submit(self, pair: FramePair, ready: dict[int, FrameResult | None]) -> None:
        t = pair.t_ns
        own_depth = self.depth_rate is None or self.depth_rate.wants_depth(t)
        if t in self._cached:
            res = self._cached_result(t)
            if res is not None:
                ready[t] = res
                self.from_cache += 1
                self.on_depth(1)
                return
        tr = time.perf_counter()
        try:
            left, right = self.source.read(pair)
        except SessionError as err:
            log.warning("frame t_ns=%d cannot be read (%s); skipped", t, err)
            ready[t] = None
            self.unreadable += 1
            self.on_depth(1)
            return
        finally:
            self.timer.add("read_s", time.perf_counter() - tr)
        if not own_depth:
            assert self.rectify is not None
            tr = time.perf_counter()
            rl, rr = self.rectify(left, right)
            self.timer.add("rectify_client_s", time.perf_counter() - tr)
            ready[t] = FrameResult(t_ns=t, status="ok", rect_left=rl, rect_right=rr,
                                   seeded=True)
            self.seeded += 1
            self.on_depth(1)
            return
        self._pending[t] = self.executor.submit(process_frame, self.stage, t, left, right,
                                                self.stereo, True)

    def _collect(self, ready: dict[int, FrameResult | None]) -> None:
        self.executor.wait_first(self._pending.values())
        for t_done in [k for k, f in self._pending.items() if f.done()]:
            try:
                res = self._pending.pop(t_done).result()
            except ExecutorError as err:
                lost = sorted([t_done] + [
                    t for t, f in self._pending.items()
                    if f.done() and not f.cancelled() and isinstance(f.exception(),
                                                                      ExecutorError)])
                raise ExecutorError(
                    f"frames t_ns={', '.join(map(str, lost))} were not computed: {err}; a "
                    "rerun into the same folder resumes from the frames cached so far"
                ) from err
            tw = time.perf_counter()
            if res.cache_entry:  # encoded by the worker: only written here
                self.cache.put_encoded(t_done, res.cache_entry)
                res = dataclasses.replace(res, cache_entry=b"")
            else:
                self.cache.put(t_done, *res.to_cache())
            self.timer.add("cache_write_s", time.perf_counter() - tw)
            ready[t_done] = res
            self.on_depth(1)

    def results(self) -> Iterator[tuple[FramePair, FrameResult | None]]:
        """Every pair of the source with its result (None: unreadable), in time order."""
        pairs = self.source.pairs
        ready: dict[int, FrameResult | None] = {}
        submit_i = 0
        seed: Any = None
        try:
            for pair in pairs:
                while True:  # keep the window full, then wait for this pair if need be
                    while submit_i < len(pairs) and (len(self._pending) + len(ready)
                                                     < self.window):
                        self._submit(pairs[submit_i], ready)
                        submit_i += 1
                    if pair.t_ns in ready:
                        break
                    self._collect(ready)
                res = ready.pop(pair.t_ns)
                if res is not None and res.seeded:
                    d = seed if seed is not None else np.full(res.rect_left.shape[:2],
                                                              np.nan, np.float32)
                    res = dataclasses.replace(res, depth_m=d,
                                              valid_fraction=float(np.isfinite(d).mean()))
                elif res is not None and res.status == "ok":
                    seed = res.depth_m
                    if self.depth_rate is not None:
                        self.depth_rate.observe_depth(res.depth_m)
                yield pair, res
        finally:
            self.cancel()

    def cancel(self) -> None:
        """Cancel the calls still in flight."""
        for f in self._pending.values():
            f.cancel()
        self._pending.clear()
