"""Trajectory accuracy: association by time, alignment, ATE and RPE.

Definitions (the conventions of the TUM RGB-D benchmark and of evo, re-derived here; evo is
GPL and is neither used nor copied, its stored results are golden values in the tests):

- **Association** (evo's rule, so that files with repeated stamps give evo's figure): every
  pose of the trajectory with fewer poses (the estimate when both have as many) is paired
  with the pose of the other whose stamp is nearest, the first of equals, within
  ``max_diff``; a pose of the longer one may serve several. A repeated stamp of the shorter
  trajectory thus keeps all its poses (each paired), one of the longer keeps only its first.
  Unstamped (KITTI) trajectories are paired by index.
- **Alignment** of the estimate onto the reference (Umeyama 1991, closed form on the matched
  positions): ``se3`` (rotation and translation), ``sim3`` (and scale, for monocular or
  badly scaled estimates), or ``none``. The aligned estimate is ``S @ T_est`` with
  ``S = [s R | t]``.
- **ATE** (absolute trajectory error, evo's APE on the translation part): for each pair
  ``e_i = |p_ref,i - p_est,i|`` after alignment, in metres; the rotation part is the angle of
  ``R_ref,i^T R_est,i`` in degrees.
- **RPE** (relative pose error) per distance ``delta``: along the estimate's path (as evo
  does; ``along="reference"`` uses the reference's), the stamps ``k_0 < k_1 < ...`` where the
  path travelled since the previous one first reaches ``delta``; for consecutive ones
  ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` with reference ``Q`` and estimate ``P``, the error is
  ``|t(E)|`` (metres) and the angle of ``R(E)`` (degrees). Inverses are rigid (``R^T``).
  ``drift_pct`` is the RMSE as a percentage of ``delta``.
- **Meaning**: ``warnings`` says when a figure cannot mean anything: the alignment's rotation
  (hence the rotation error) when the reference spreads across its second axis by less than
  3 times the ATE (TUM fr1/xyz: 7.6 times; a still drone: about 1); the RPE when the path is
  jitter about a still point, has under 5 pairs, or the error exceeds the distance.

Statistics of every error array: rmse, mean, median, std (population), min, max, sse, p90.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import GeometryError, OdometryError
from sea3d.geometry.se3 import umeyama

__all__ = [
    "ErrorStats",
    "RpeResult",
    "TrajectoryMetrics",
    "associate",
    "error_stats",
    "evaluate_trajectory",
    "path_length_m",
    "umeyama",
]

Align = Literal["se3", "sim3", "none"]
I64 = NDArray[np.int64]


@dataclass(frozen=True, kw_only=True)
class ErrorStats:
    """Statistics of an error array (units of the errors)."""

    count: int
    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    p90: float


def error_stats(errors: NDArray[np.floating]) -> ErrorStats:
    """:class:`ErrorStats` of a 1-D array (all NaN for an empty one)."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        nan = float("nan")
        return ErrorStats(count=0, rmse=nan, mean=nan, median=nan, std=nan, min=nan, max=nan,
                          sse=nan, p90=nan)
    sse = float(np.sum(e * e))
    return ErrorStats(
        count=int(e.size),
        rmse=float(np.sqrt(sse / e.size)),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        sse=sse,
        p90=float(np.percentile(e, 90)),
    )


@dataclass(frozen=True, kw_only=True)
class RpeResult:
    """Relative pose error over one distance."""

    delta_m: float
    """Path distance between the two poses of each pair, metres."""
    along: str
    """Whose path chose the pairs: ``estimate`` or ``reference``."""
    translation_m: ErrorStats
    """Translation error of the relative motion, metres."""
    rotation_deg: ErrorStats
    """Rotation error of the relative motion, degrees."""
    drift_pct: float
    """``100 * translation_m.rmse / delta_m``."""


@dataclass(frozen=True, kw_only=True)
class TrajectoryMetrics:
    """Figures of an estimate against a reference trajectory."""

    matched: int
    """Poses paired by time (or index)."""
    estimate_poses: int
    reference_poses: int
    align: str
    scale: float
    """Scale of the alignment (1 unless ``sim3``)."""
    T_ref_est: list[list[float]]
    """The alignment ``S`` (4x4, rotation block times ``scale``) as nested lists."""
    path_length_m: float
    """Length of the matched reference path, metres."""
    ate_m: ErrorStats
    """Absolute translation error after alignment, metres."""
    ate_rotation_deg: ErrorStats
    """Absolute rotation error after alignment, degrees."""
    rpe: list[RpeResult] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    """Why some figures mean nothing (a path too short, too still or too straight); each
    names the figure. Empty when every figure is meaningful."""
    rotation_meaningful: bool = True
    """False when the alignment's rotation is not determined by the path, so neither is the
    rotation error."""

    @property
    def ate_rmse_m(self) -> float:
        """RMSE of the ATE, metres (the headline figure)."""
        return self.ate_m.rmse

    def as_dict(self) -> dict[str, object]:
        """Plain values for JSON, with the headline ``ate_rmse_m`` at the top level."""
        d = asdict(self)
        d["ate_rmse_m"] = self.ate_rmse_m
        d["ate_rmse_pct_of_path"] = (
            100.0 * self.ate_rmse_m / self.path_length_m if self.path_length_m > 0 else None
        )
        return d


def associate(t_est_ns: NDArray[np.integer], t_ref_ns: NDArray[np.integer],
              max_diff_ns: int) -> tuple[I64, I64]:
    """Pair stamps by nearest time within ``max_diff_ns``, as evo's association does.

    Every stamp of the shorter array (``t_est_ns`` when the lengths are equal) is paired with
    the nearest stamp of the other, the first of equally near ones; the longer one's stamps
    may be used more than once, and repeated stamps in the shorter one are each paired.

    Args:
        t_est_ns, t_ref_ns: (N,) and (M,) integer nanoseconds, sorted (repeats allowed; the
            first of a run of equal stamps is the one the longer array offers).
        max_diff_ns: largest accepted difference.

    Returns:
        ``(i_est, i_ref)``, (K,) int64 each, in the shorter array's order.
    """
    a = np.asarray(t_est_ns, dtype=np.int64)
    b = np.asarray(t_ref_ns, dtype=np.int64)
    if a.size == 0 or b.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    swap = b.size < a.size
    short, long_ = (b, a) if swap else (a, b)
    j = np.searchsorted(long_, short, side="left")  # first stamp >= each short stamp
    after = np.minimum(j, long_.size - 1)
    before = np.maximum(j - 1, 0)
    before = np.searchsorted(long_, long_[before], side="left")  # first of its run
    d_before = np.where(j > 0, np.abs(short - long_[before]), np.iinfo(np.int64).max)
    d_after = np.where(j < long_.size, np.abs(long_[after] - short), np.iinfo(np.int64).max)
    pick = np.where(d_before <= d_after, before, after)  # the earlier one on a tie
    diff = np.minimum(d_before, d_after)
    ok = diff <= max_diff_ns
    i_short = np.flatnonzero(ok).astype(np.int64)
    i_long = pick[ok].astype(np.int64)
    return (i_long, i_short) if swap else (i_short, i_long)


def path_length_m(positions: F64, trusted: NDArray[np.bool_] | None = None,
                  segments: NDArray[np.int64] | None = None) -> float:
    """Length of a camera path through (N, 3) positions, metres.

    A step between two consecutive frames counts when both frames are trusted and in the same
    segment: the steps into and out of an untrusted frame, and the jump from one segment to
    the next, are left out, so a stretch without a trustworthy pose adds nothing. Without
    ``trusted`` and ``segments`` every step counts: the length of the polyline (a reference
    trajectory).

    Args:
        positions: (N, 3) positions, in time order.
        trusted: (N,) whether each frame's pose is trusted; None trusts every frame.
        segments: (N,) each frame's segment id; None puts every frame in one segment.

    Returns:
        The summed length of the counted steps; 0 for fewer than two positions.
    """
    p = np.asarray(positions, dtype=np.float64)
    if len(p) < 2:
        return 0.0
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    ok = np.ones(len(step), dtype=bool)
    if trusted is not None:
        t = np.asarray(trusted, dtype=bool)
        ok &= t[1:] & t[:-1]
    if segments is not None:
        g = np.asarray(segments)
        ok &= g[1:] == g[:-1]
    return float(step[ok].sum())


def _rigid_inv(T: F64) -> F64:
    """Inverse of (N, 4, 4) transforms with ``R^T`` (rigid), as evo computes it."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def _angle_deg(R: F64) -> F64:
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.asarray(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))), dtype=np.float64)


def _path_ids(positions: F64, delta_m: float) -> I64:
    """Indices where the path travelled since the previous index first reaches ``delta_m``."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    ids = []
    acc = 0.0
    for i, s in enumerate(steps.tolist(), start=1):
        acc += s
        if acc >= delta_m:
            ids.append(i)
            acc = 0.0
    return np.asarray(ids, dtype=np.int64)


def _rpe(Q: F64, P: F64, delta_m: float, along: str) -> RpeResult:
    ids = _path_ids((P if along == "estimate" else Q)[:, :3, 3], delta_m)
    i, j = ids[:-1], ids[1:]
    rel_q = _rigid_inv(Q[i]) @ Q[j]
    rel_p = _rigid_inv(P[i]) @ P[j]
    E = _rigid_inv(rel_q) @ rel_p
    trans = error_stats(np.linalg.norm(E[:, :3, 3], axis=1))
    rot = error_stats(_angle_deg(E[:, :3, :3]))
    drift = 100.0 * trans.rmse / delta_m if trans.count else float("nan")
    return RpeResult(delta_m=float(delta_m), along=along, translation_m=trans, rotation_deg=rot,
                     drift_pct=drift)


# Subsampling a path by this many poses keeps at least this fraction of its length when the
# path is motion; a still camera's jitter loses most of it (its steps are noise, not travel)
_STILL_SUBSAMPLE = 10
_STILL_LENGTH_RATIO = 0.5
# The alignment's rotation is determined when the path spreads across two axes by this many
# times the position error (and at least a millimetre)
_ROTATION_SPREAD_ATE = 3.0
_ROTATION_SPREAD_MIN_M = 1e-3
_RPE_MIN_PAIRS = 5


def _motion_ratio(positions: F64) -> float:
    """Length of the path through every ``_STILL_SUBSAMPLE``-th pose over its full length
    (about 1 for travel, about ``1 / _STILL_SUBSAMPLE`` for jitter about a still point)."""
    full = path_length_m(positions)
    if full <= 0 or len(positions) < 3 * _STILL_SUBSAMPLE:
        return 1.0
    sub = np.concatenate([positions[::_STILL_SUBSAMPLE], positions[-1:]])
    return path_length_m(sub) / full


def _meaning_warnings(Q: F64, ate: ErrorStats, rot: ErrorStats, rpes: list[RpeResult],
                      align: str) -> tuple[list[str], bool]:
    """Warnings for figures the path cannot support (see :attr:`TrajectoryMetrics.warnings`)."""
    out: list[str] = []
    pos = Q[:, :3, 3]
    rotation_ok = True
    if align != "none":
        ev = np.sort(np.linalg.eigvalsh(np.cov((pos - pos.mean(axis=0)).T)))[::-1]
        spread = float(np.sqrt(max(ev[1], 0.0)))
        need = max(_ROTATION_SPREAD_ATE * ate.rmse, _ROTATION_SPREAD_MIN_M)
        if spread < need:
            rotation_ok = False
            out.append(
                f"the reference path spreads only {spread:.3g} m across its second axis (need "
                f"{need:.3g} m: {_ROTATION_SPREAD_ATE:g} x the ATE): too short, still or "
                f"straight for the {align} alignment's rotation to be determined, so the "
                f"rotation error ({rot.rmse:.1f} deg) means nothing; use align 'none' for "
                "estimates that share the reference's start"
            )
    ratio = _motion_ratio(pos)
    still = ratio < _STILL_LENGTH_RATIO
    for r in rpes:
        why = None
        if still:
            why = (f"the reference path is mostly jitter about a still point (subsampled it "
                   f"keeps {ratio:.0%} of its length)")
        elif r.translation_m.count < _RPE_MIN_PAIRS:
            why = f"only {r.translation_m.count} pose pairs (need {_RPE_MIN_PAIRS})"
        elif r.drift_pct > 100.0:
            why = "its error exceeds the distance itself"
        if why:
            out.append(f"RPE over {r.delta_m:g} m ({r.drift_pct:.0f} %) means nothing: {why}")
    return out, rotation_ok


def default_rpe_deltas(length_m: float) -> list[float]:
    """RPE distances for a path: 1, 10 and 100 m, those shorter than half the path (at least
    the path's tenth, for short paths)."""
    deltas = [d for d in (1.0, 10.0, 100.0) if d <= 0.5 * length_m]
    if not deltas and length_m > 0:
        deltas = [float(f"{0.1 * length_m:.2g}")]
    return deltas


def evaluate_trajectory(
    t_est_ns: NDArray[np.integer],
    T_world_est: F64,
    t_ref_ns: NDArray[np.integer],
    T_world_ref: F64,
    *,
    align: Align = "se3",
    max_diff_s: float = 0.01,
    by_index: bool = False,
    rpe_deltas_m: list[float] | None = None,
    rpe_along: Literal["estimate", "reference"] = "estimate",
) -> TrajectoryMetrics:
    """ATE and RPE of an estimated trajectory against a reference (see the module docstring).

    Args:
        t_est_ns, T_world_est: (N,) int64 stamps and (N, 4, 4) estimated poses.
        t_ref_ns, T_world_ref: (M,) and (M, 4, 4) reference poses.
        align: ``se3``, ``sim3`` or ``none``.
        max_diff_s: association tolerance, seconds.
        by_index: pair pose k with pose k (unstamped KITTI files); needs N == M.
        rpe_deltas_m: RPE distances; None picks :func:`default_rpe_deltas` of the path.
        rpe_along: whose path chooses the RPE pairs.

    Returns:
        :class:`TrajectoryMetrics`.

    Raises:
        OdometryError: bad shapes, an unknown alignment, fewer than 3 (2 with ``none``)
            matched poses, or ``by_index`` with different lengths.
    """
    ie: I64
    ir: I64
    Pe = np.asarray(T_world_est, dtype=np.float64)
    Qr = np.asarray(T_world_ref, dtype=np.float64)
    te = np.asarray(t_est_ns, dtype=np.int64).reshape(-1)
    tr = np.asarray(t_ref_ns, dtype=np.int64).reshape(-1)
    for name, T, t in (("estimate", Pe, te), ("reference", Qr, tr)):
        if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] != t.shape[0]:
            raise OdometryError(f"{name}: need (N,) stamps and (N, 4, 4) poses, got {t.shape} "
                                f"and {T.shape}")
    if align not in ("se3", "sim3", "none"):
        raise OdometryError(f"unknown alignment {align!r}; use se3, sim3 or none")
    if rpe_along not in ("estimate", "reference"):
        raise OdometryError(f"rpe_along must be 'estimate' or 'reference', got {rpe_along!r}")
    if by_index:
        if len(Pe) != len(Qr):
            raise OdometryError(f"pairing by index needs equal lengths, got {len(Pe)} estimated "
                                f"and {len(Qr)} reference poses")
        ie = ir = np.asarray(np.arange(len(Pe)), dtype=np.int64).reshape(-1)
    else:
        ie, ir = associate(te, tr, round(max_diff_s * 1e9))
    need = 2 if align == "none" else 3
    if len(ie) < need:
        raise OdometryError(
            f"only {len(ie)} of {len(Pe)} estimated poses have a reference pose within "
            f"{max_diff_s} s (need {need}); check the time base or max_diff_s"
        )
    P, Q = Pe[ie], Qr[ir]
    S = np.eye(4)
    scale = 1.0
    if align != "none":
        try:
            R, t_align, scale = umeyama(P[:, :3, 3], Q[:, :3, 3], with_scale=align == "sim3")
        except GeometryError as err:
            raise OdometryError(str(err)) from err
        S[:3, :3] = scale * R
        S[:3, 3] = t_align
        Pa = P.copy()
        Pa[:, :3, :3] = R @ P[:, :3, :3]
        Pa[:, :3, 3] = P[:, :3, 3] @ (scale * R).T + t_align
        P = Pa
    ate = error_stats(np.linalg.norm(P[:, :3, 3] - Q[:, :3, 3], axis=1))
    rot = error_stats(_angle_deg(np.swapaxes(Q[:, :3, :3], -1, -2) @ P[:, :3, :3]))
    length = path_length_m(Q[:, :3, 3])
    deltas = default_rpe_deltas(length) if rpe_deltas_m is None else list(rpe_deltas_m)
    rpes = []
    for d in deltas:
        if not d > 0:
            raise OdometryError(f"RPE distances must be > 0 m, got {d}")
        rpes.append(_rpe(Q, P, float(d), rpe_along))
    warnings, rotation_ok = _meaning_warnings(Q, ate, rot, rpes, align)
    return TrajectoryMetrics(
        matched=len(ie),
        estimate_poses=len(Pe),
        reference_poses=len(Qr),
        align=align,
        scale=float(scale),
        T_ref_est=S.tolist(),
        path_length_m=length,
        ate_m=ate,
        ate_rotation_deg=rot,
        rpe=rpes,
        warnings=warnings,
        rotation_meaningful=rotation_ok,
    )


__all__ += ["default_rpe_deltas"]
