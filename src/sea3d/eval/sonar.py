"""Echosounder against stereo: the stereo range along the echosounder's beam, per ping.

The paper added a single-beam echosounder "as an approximate ground truth for stereo depth".
Its footprint is often outside the cameras' view at the same instant (in the simulator's
mount the beam points 30-36 degrees off the optical axis, beyond the half field of view), so
the range is measured in the depth maps of the frames around the ping, through the poses:

1. the beam axis at the ping's time, ``T_world_left(t) @ T_left_sonar`` (poses interpolated
   between frames; the beam points along the echosounder's -z);
2. for each depth view within ``window_s`` of the ping, the axis is marched through the depth
   map (project each point of the axis, compare its depth with the map's) to the first place
   where it passes behind the seen surface, and a plane fitted to the depth map's 3D points
   around that pixel is intersected with the axis: that view's range;
3. the ping's stereo range is the median over the views that see the crossing (outliers past
   three robust standard deviations dropped).

Without poses only the frame nearest in time is used (the same-instant local surface fit),
which measures only pings whose footprint that frame sees. With a beam angle > 0 the echo is
modelled as the nearest surface inside the cone: each of 17 rays (the axis, and rings of 8 at
half and the full half-angle) is measured as the axis is, and the shortest range is the echo.

Statistics (:class:`RangeComparison`): median absolute difference, bias (median of the signed
differences, estimate minus reference), spread (1.4826 x the median absolute deviation of the
differences: a robust standard deviation), RMSE, all in metres.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import GeometryError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.se3 import check_T, invert_T

__all__ = [
    "PING_DATASHEET",
    "BeamRange",
    "DepthView",
    "RangeComparison",
    "SonarEvaluation",
    "beam_axis",
    "beam_directions",
    "compare_ranges",
    "evaluate_sonar",
    "interpolate_pose",
    "range_in_view",
    "stereo_range",
]

_log = logging.getLogger(__name__)

# Blue Robotics Ping (Ping2) echosounder: 115 kHz, 100 m range, 25 degree beam (the first Ping:
# 30 m, 30 degrees), from the Ping sonar technical guide
# (https://bluerobotics.com/learn/ping-sonar-technical-guide/); range resolution 0.5 % of range
# as Blue Robotics' product page lists it. The simulator's echosounder noise (0.5 % of range,
# one standard deviation) follows the same figure.
PING_DATASHEET: dict[str, Any] = {
    "model": "Blue Robotics Ping2",
    "resolution_fraction_of_range": 0.005,
    "beam_deg": 25.0,
    "max_range_m": 100.0,
    "frequency_khz": 115.0,
    "source": "https://bluerobotics.com/learn/ping-sonar-technical-guide/ (range, beam, "
    "frequency); Blue Robotics product page (resolution 0.5 % of range)",
}


@dataclass(frozen=True, kw_only=True, eq=False)
class DepthView:
    """One frame's depth map, posed.

    Attributes:
        t_ns: the frame's stamp.
        depth_m: (H, W) float32 metres along ``camera``'s z axis, NaN invalid.
        camera: the camera whose pixels and z axis the depth map is in: the rectified left
            virtual pinhole for ``sea3d depth`` output, or the raw left camera model (pinhole
            or refractive) for depth along the raw camera's z (the simulator's ground truth).
        T_world_camera: (4, 4) pose of that camera.
    """

    t_ns: int
    depth_m: NDArray[np.float32]
    camera: CameraModel
    T_world_camera: F64

    def __post_init__(self) -> None:
        d = np.asarray(self.depth_m)
        if d.ndim != 2 or d.shape != (self.camera.height, self.camera.width):
            raise GeometryError(
                f"depth map of t_ns={self.t_ns} is {d.shape}, the camera is "
                f"{self.camera.width}x{self.camera.height}"
            )
        object.__setattr__(self, "T_world_camera", check_T(self.T_world_camera, "T_world_camera"))
        finite = d[np.isfinite(d)]
        object.__setattr__(self, "_max_depth", float(finite.max()) if finite.size else float("nan"))

    @property
    def max_depth_m(self) -> float:
        """The farthest valid depth in the map, metres (NaN for an empty map)."""
        return float(self._max_depth)  # type: ignore[attr-defined]


@dataclass(frozen=True, kw_only=True)
class BeamRange:
    """The stereo range along one beam.

    Attributes:
        range_m: metres from the echosounder along its axis (NaN when not measured).
        views_used: depth views whose crossing went into the median.
        spread_m: robust spread of the per-view ranges (NaN with fewer than 2).
        status: ``ok``, ``not_seen`` (no view saw the beam meet a surface) or ``no_pose``.
    """

    range_m: float
    views_used: int
    spread_m: float
    status: str


@dataclass(frozen=True, kw_only=True)
class RangeComparison:
    """An estimate against a reference over the samples where both exist (metres).

    Attributes:
        samples: pairs compared.
        median_abs_diff_m: median of ``|estimate - reference|``.
        bias_m: median of ``estimate - reference``.
        spread_m: 1.4826 x median absolute deviation of the differences.
        rmse_m: root mean square difference.
        median_abs_diff_pct: median of ``|estimate - reference| / reference``, percent.
    """

    samples: int
    median_abs_diff_m: float
    bias_m: float
    spread_m: float
    rmse_m: float
    median_abs_diff_pct: float


@dataclass(frozen=True, kw_only=True)
class SonarEvaluation:
    """Per-ping ranges and their comparisons.

    Attributes:
        t_ns: (P,) ping stamps.
        sonar_range_m: (P,) the echosounder's ranges (NaN where it had none).
        stereo_range_m: (P,) the stereo ranges (NaN where not measured).
        truth_range_m: (P,) true ranges, or None.
        views_used: (P,) depth views per ping.
        method: how the stereo range was measured (see the module docstring).
        stereo_vs_sonar, stereo_vs_truth, sonar_vs_truth: :class:`RangeComparison`
            (the last two None without truth).
        pings: echosounder samples in the session; ``measured``: with a stereo range.
        datasheet: :data:`PING_DATASHEET`.
    """

    t_ns: NDArray[np.int64]
    sonar_range_m: F64
    stereo_range_m: F64
    truth_range_m: F64 | None
    views_used: NDArray[np.int64]
    method: str
    stereo_vs_sonar: RangeComparison
    stereo_vs_truth: RangeComparison | None
    sonar_vs_truth: RangeComparison | None
    pings: int
    measured: int
    datasheet: dict[str, Any] = field(default_factory=lambda: dict(PING_DATASHEET))

    def summary(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict (no per-ping arrays)."""
        out: dict[str, Any] = {
            "samples": self.stereo_vs_sonar.samples,
            "median_abs_diff_m": self.stereo_vs_sonar.median_abs_diff_m,
            "bias_m": self.stereo_vs_sonar.bias_m,
            "spread_m": self.stereo_vs_sonar.spread_m,
            "rmse_m": self.stereo_vs_sonar.rmse_m,
            "median_abs_diff_pct": self.stereo_vs_sonar.median_abs_diff_pct,
            "pings": self.pings,
            "measured": self.measured,
            "method": self.method,
            "stereo_vs_truth": None
            if self.stereo_vs_truth is None
            else asdict(self.stereo_vs_truth),
            "sonar_vs_truth": None if self.sonar_vs_truth is None else asdict(self.sonar_vs_truth),
            "datasheet": dict(self.datasheet),
        }
        return out


# ----------------------------------------------------------------------------- geometry


def interpolate_pose(
    t_frames_ns: NDArray[np.int64], T_frames: F64, t_ns: int, *, max_gap_ns: int
) -> F64 | None:
    """Pose at ``t_ns`` between the two frames around it (translation linear, rotation by
    slerp); None outside the frames by more than ``max_gap_ns``."""
    from scipy.spatial.transform import Rotation, Slerp

    t = np.asarray(t_frames_ns, dtype=np.int64)
    if t.size == 0:
        return None
    j = int(np.searchsorted(t, t_ns))
    if j == 0 or j == t.size:
        k = 0 if j == 0 else t.size - 1
        return np.array(T_frames[k]) if abs(int(t[k]) - int(t_ns)) <= max_gap_ns else None
    t0, t1 = int(t[j - 1]), int(t[j])
    if t1 - t0 > 2 * max_gap_ns and min(t_ns - t0, t1 - t_ns) > max_gap_ns:
        return None
    a = (t_ns - t0) / (t1 - t0) if t1 > t0 else 0.0
    rots = Rotation.from_matrix(np.stack([T_frames[j - 1][:3, :3], T_frames[j][:3, :3]]))
    R = Slerp([0.0, 1.0], rots)([a]).as_matrix()[0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = (1 - a) * T_frames[j - 1][:3, 3] + a * T_frames[j][:3, 3]
    return T


def beam_axis(T_world_left: F64, T_left_sonar: F64) -> tuple[F64, F64]:
    """Origin (3,) and unit direction (3,) of the beam axis in the world: the echosounder's
    origin and its -z axis."""
    T = np.asarray(T_world_left, dtype=np.float64) @ np.asarray(T_left_sonar, dtype=np.float64)
    d = -T[:3, 2]
    return T[:3, 3].copy(), d / np.linalg.norm(d)


def beam_directions(direction: F64, beam_deg: float) -> F64:
    """(K, 3) unit directions sampling a cone of full angle ``beam_deg`` around
    ``direction``: the axis alone for 0, else the axis and rings of 8 at half and the full
    half-angle (17 rays)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    if beam_deg <= 0:
        return d[None, :]
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    half = np.radians(beam_deg) / 2
    out = [d]
    for theta in (half / 2, half):
        for phi in np.arange(8) * (np.pi / 4):
            out.append(np.cos(theta) * d + np.sin(theta) * (np.cos(phi) * e1 + np.sin(phi) * e2))
    return np.asarray(out)


def _plane_range(
    view: DepthView, u: int, v: int, o_c: F64, d_c: F64, window_px: int
) -> float | None:
    """Intersect the axis (camera frame) with a plane fitted to the depth map around (u, v)."""
    h, w = view.depth_m.shape
    u0, u1 = max(0, u - window_px), min(w, u + window_px + 1)
    v0, v1 = max(0, v - window_px), min(h, v + window_px + 1)
    patch = view.depth_m[v0:v1, u0:u1]
    vv, uu = np.nonzero(np.isfinite(patch))
    if vv.size < 8:
        return None
    uv = np.stack([uu + u0, vv + v0], axis=1).astype(np.float64)
    z = patch[vv, uu].astype(np.float64)
    rays = view.camera.unproject(uv)
    dz = rays.directions[:, 2]
    ok = rays.valid & (dz > 1e-9)
    if ok.sum() < 8:
        return None
    s = (z[ok] - rays.origins[ok, 2]) / dz[ok]
    pts = rays.origins[ok] + s[:, None] * rays.directions[ok]
    c = pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[2]
    rms = sv[2] / np.sqrt(len(pts))
    denom = float(n @ d_c)
    if rms > 0.02 + 0.01 * float(np.median(z)) or abs(denom) < 0.1:
        return None
    return float(n @ (c - o_c)) / denom


def range_in_view(
    view: DepthView,
    origin_w: F64,
    direction_w: F64,
    *,
    min_range_m: float = 0.2,
    max_range_m: float = 20.0,
    step_m: float = 0.01,
    window_px: int = 3,
) -> float:
    """Range along a ray (world frame) to the surface that one depth view sees, or NaN.

    The ray is marched in ``step_m`` steps from ``min_range_m``; the surface is crossed where
    the ray's depth in the view passes the depth map's (first such place, with no jump that
    would mean an occlusion edge); the crossing is refined by a plane fitted to the depth
    map's points in a (2 window_px + 1)^2 window, or by linear interpolation where the patch
    is not planar.
    """
    T_c_w = invert_T(view.T_world_camera)
    o_c = T_c_w[:3, :3] @ origin_w + T_c_w[:3, 3]
    d_c = T_c_w[:3, :3] @ direction_w
    # beyond the farthest depth the view holds there is nothing to cross
    far = view.max_depth_m
    if not np.isfinite(far):
        return float("nan")
    if d_c[2] > 1e-9:
        max_range_m = min(max_range_m, (far + 0.1 - o_c[2]) / d_c[2])
    s = np.arange(min_range_m, max_range_m, step_m)
    if s.size < 2:
        return float("nan")
    pts = o_c[None, :] + s[:, None] * d_c[None, :]
    front = pts[:, 2] > 0.05
    if not front.any():
        return float("nan")
    uv, ok = view.camera.project(pts[front])
    idx = np.flatnonzero(front)
    h, w = view.depth_m.shape
    ui = np.rint(uv[:, 0])
    vi = np.rint(uv[:, 1])
    with np.errstate(invalid="ignore"):
        inside = ok & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    if not inside.any():
        return float("nan")
    idx, ui, vi = idx[inside], ui[inside].astype(int), vi[inside].astype(int)
    depth = view.depth_m[vi, ui].astype(np.float64)
    f = pts[idx, 2] - depth  # < 0: the ray is in front of the seen surface
    good = np.isfinite(f)
    idx, ui, vi, f = idx[good], ui[good], vi[good], f[good]
    if f.size < 2:
        return float("nan")
    cross = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0))
    for k in cross:
        a, b = int(idx[k]), int(idx[k + 1])
        jump = abs(f[k + 1] - f[k])
        if b - a > 3 or jump > 5 * step_m + 0.02 + 0.02 * s[b]:
            continue  # an occlusion edge or a hole, not a surface
        s_lin = s[a] + (s[b] - s[a]) * (-f[k]) / (f[k + 1] - f[k])
        s_plane = _plane_range(view, int(ui[k + 1]), int(vi[k + 1]), o_c, d_c, window_px)
        if s_plane is not None and abs(s_plane - s_lin) <= 2 * step_m + 0.02:
            return float(s_plane)
        return float(s_lin)
    return float("nan")


def _robust_median(values: Sequence[float]) -> tuple[float, float, int]:
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), 0
    med = float(np.median(x))
    spread = 1.4826 * float(np.median(np.abs(x - med))) if x.size >= 2 else float("nan")
    if x.size >= 3:
        keep = np.abs(x - med) <= 3 * max(spread, 0.01)
        x = x[keep]
        med = float(np.median(x))
        spread = 1.4826 * float(np.median(np.abs(x - med))) if x.size >= 2 else float("nan")
    return med, spread, int(x.size)


def stereo_range(
    views: Sequence[DepthView],
    origin_w: F64,
    direction_w: F64,
    t_ns: int,
    *,
    window_s: float = 5.0,
    max_views: int = 12,
    beam_deg: float = 0.0,
    **march: Any,
) -> BeamRange:
    """The stereo range of one ping (see the module docstring).

    Args:
        views: depth views, any order.
        origin_w, direction_w: the beam axis in the world.
        t_ns: the ping's stamp; views within ``window_s`` are used, nearest in time first.
        window_s: 0 uses the nearest view only (the same-instant fit).
        max_views: stop after this many views saw the crossing.
        beam_deg: 0 for the axis, else the cone's full angle (nearest surface in the cone).
        **march: passed to :func:`range_in_view`.
    """
    if not views:
        return BeamRange(
            range_m=float("nan"), views_used=0, spread_m=float("nan"), status="not_seen"
        )
    dt = np.array([abs(v.t_ns - t_ns) for v in views], dtype=np.float64) * 1e-9
    order = np.argsort(dt, kind="stable")
    if window_s <= 0:
        order = order[:1]
    else:
        order = order[dt[order] <= window_s]
    dirs = beam_directions(direction_w, beam_deg)
    # each ray's range from the views that see it; the echo is the nearest ray's
    best = BeamRange(range_m=float("nan"), views_used=0, spread_m=float("nan"), status="not_seen")
    for d in dirs:
        found: list[float] = []
        for k in order:
            r = range_in_view(views[int(k)], origin_w, d, **march)
            if np.isfinite(r):
                found.append(r)
                if len(found) >= max_views:
                    break
        med, spread, n = _robust_median(found)
        if n and not (best.range_m <= med):
            best = BeamRange(range_m=med, views_used=n, spread_m=spread, status="ok")
    return best


def compare_ranges(estimate: npt.ArrayLike, reference: npt.ArrayLike) -> RangeComparison:
    """Compare two range series sample by sample where both are finite (see the module doc)."""
    e = np.asarray(estimate, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if e.shape != r.shape:
        raise GeometryError(f"range series differ in length: {e.shape} and {r.shape}")
    ok = np.isfinite(e) & np.isfinite(r)
    d = e[ok] - r[ok]
    if d.size == 0:
        nan = float("nan")
        return RangeComparison(
            samples=0, median_abs_diff_m=nan, bias_m=nan, spread_m=nan, rmse_m=nan,
            median_abs_diff_pct=nan,
        )  # fmt: skip
    bias = float(np.median(d))
    return RangeComparison(
        samples=int(d.size),
        median_abs_diff_m=float(np.median(np.abs(d))),
        bias_m=bias,
        spread_m=1.4826 * float(np.median(np.abs(d - bias))),
        rmse_m=float(np.sqrt(np.mean(d**2))),
        median_abs_diff_pct=float(100 * np.median(np.abs(d) / np.abs(r[ok]))),
    )


def evaluate_sonar(
    *,
    sonar_t_ns: NDArray[np.int64],
    sonar_range_m: F64,
    frame_t_ns: NDArray[np.int64] | None,
    T_world_left: F64 | None,
    views: Sequence[DepthView],
    T_left_sonar: F64,
    beam_deg: float = 0.0,
    window_s: float = 5.0,
    truth_range_m: F64 | None = None,
    method_note: str = "",
    progress: Any = None,
    **march: Any,
) -> SonarEvaluation:
    """The stereo range of every ping and the comparisons (see the module docstring).

    Args:
        sonar_t_ns, sonar_range_m: (P,) the echosounder's samples (NaN for no echo).
        frame_t_ns, T_world_left: (F,), (F, 4, 4) poses of the left camera at the frames;
            None for no poses (each ping then uses the view nearest in time, in its frame).
        views: depth views, posed in the same world as ``T_world_left`` (with no poses, each
            in its own left-camera frame: ``T_world_camera`` = left -> that camera).
        T_left_sonar: (4, 4) echosounder in the left camera frame.
        beam_deg: cone angle (0: the axis).
        window_s: views within this time of a ping are used (ignored without poses).
        truth_range_m: (P,) true ranges along the same beam model, or None.
        method_note: how poses and depth were obtained, for the report.
        progress: called with 1 after each ping.
    """
    t_s = np.asarray(sonar_t_ns, dtype=np.int64)
    r_s = np.asarray(sonar_range_m, dtype=np.float64)
    stereo = np.full(t_s.shape, np.nan)
    used = np.zeros(t_s.shape, dtype=np.int64)
    by_t = {v.t_ns: v for v in views}
    view_t = np.array(sorted(by_t), dtype=np.int64)
    frame_gap = int(np.median(np.diff(view_t))) if view_t.size > 1 else 100_000_000
    for i, t in enumerate(t_s.tolist()):
        if frame_t_ns is not None and T_world_left is not None:
            gap = int(np.median(np.diff(frame_t_ns))) if len(frame_t_ns) > 1 else frame_gap
            T = interpolate_pose(frame_t_ns, T_world_left, int(t), max_gap_ns=gap)
            if T is not None:
                o, d = beam_axis(T, T_left_sonar)
                br = stereo_range(
                    views, o, d, int(t), window_s=window_s, beam_deg=beam_deg, **march
                )
                stereo[i], used[i] = br.range_m, br.views_used
        elif view_t.size:
            j = int(np.argmin(np.abs(view_t - t)))
            if abs(int(view_t[j]) - t) <= frame_gap:
                o, d = beam_axis(np.eye(4), T_left_sonar)
                br = stereo_range(
                    [by_t[int(view_t[j])]], o, d, int(t), window_s=0, beam_deg=beam_deg, **march
                )
                stereo[i], used[i] = br.range_m, br.views_used
        if progress is not None:
            progress(1)
    if frame_t_ns is not None and T_world_left is not None:
        method = (
            f"beam axis through the depth maps of the frames within {window_s:g} s (poses), "
            "local plane fit at the crossing, median over frames"
        )
    else:
        method = "same-instant local plane fit (no poses): only pings seen by their own frame"
    if beam_deg > 0:
        method += f"; nearest surface in a {beam_deg:g} degree cone (17 rays)"
    if method_note:
        method = f"{method}; {method_note}"
    truth = None if truth_range_m is None else np.asarray(truth_range_m, dtype=np.float64)
    return SonarEvaluation(
        t_ns=t_s,
        sonar_range_m=r_s,
        stereo_range_m=stereo,
        truth_range_m=truth,
        views_used=used,
        method=method,
        stereo_vs_sonar=compare_ranges(stereo, r_s),
        stereo_vs_truth=None if truth is None else compare_ranges(stereo, truth),
        sonar_vs_truth=None if truth is None else compare_ranges(r_s, truth),
        pings=int(t_s.size),
        measured=int(np.isfinite(stereo).sum()),
    )
