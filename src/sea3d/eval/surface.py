"""Surface accuracy and completeness of a reconstructed mesh (or point cloud) in metres.

Both surfaces are sampled uniformly by area (a seeded numpy generator, so figures repeat):

- **accuracy**: distance from each sample of the estimate to the reference surface;
- **completeness**: distance from each sample of the reference to the estimate.

Distances to a mesh are exact point-to-triangle distances (Open3D's ``RaycastingScene``);
distances to a point cloud are nearest-neighbour distances (scipy's ``cKDTree``). At each
threshold ``tau`` the *precision* is the fraction of estimate samples within ``tau`` of the
reference, the *recall* the fraction of reference samples within ``tau`` of the estimate, and
the *F-score* their harmonic mean (Knapitsch et al., "Tanks and Temples", 2017). Default
thresholds: 1, 2 and 5 cm (half, one and two and a half voxels at the default 2 cm voxel).

A reference usually covers more than one survey saw: ``crop_margin_m`` keeps only reference
samples inside the estimate's bounding box grown by that margin; callers that know what was
seen (the simulator's ground-truth depth) pass those points as ``reference_points``.

Both surfaces must be in one frame. A mesh of ``sea3d process`` lives in the odometry's world
(its first left camera), a scene mesh in the ground truth's: :func:`align_by_trajectories`
finds the transform from the two trajectories (Umeyama on associated poses, SE(3) or Sim(3)),
:func:`align_by_icp` refines or finds it from the surfaces themselves (Open3D's ICP), and each
states its residual in a :class:`SurfaceAlignment`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError
from sea3d.eval.trajectory import ErrorStats, error_stats

__all__ = [
    "SurfaceAlignment",
    "SurfaceMetrics",
    "align_by_icp",
    "align_by_trajectories",
    "point_to_mesh_distance",
    "sample_surface",
    "surface_metrics",
]

I64 = NDArray[np.int64]

DEFAULT_THRESHOLDS_M = (0.01, 0.02, 0.05)


@dataclass(frozen=True, kw_only=True)
class SurfaceMetrics:
    """Accuracy and completeness, metres; precision, recall and F-score per threshold.

    ``reference_outside`` is the fraction of the reference samples used for completeness that
    lie outside the estimate's bounding box: when it is large, completeness mostly measures
    surface the estimate never saw (crop it with ``crop_margin_m``).
    """

    accuracy_m: ErrorStats
    completeness_m: ErrorStats
    thresholds_m: tuple[float, ...]
    precision: tuple[float, ...]
    recall: tuple[float, ...]
    fscore: tuple[float, ...]
    estimate_samples: int
    reference_samples: int
    reference_outside: float = 0.0

    def as_dict(self) -> dict[str, object]:
        """Plain values for JSON."""
        return asdict(self)


def sample_surface(vertices: F64, triangles: NDArray[np.integer], n: int,
                   rng: np.random.Generator) -> F64:
    """``n`` points uniformly distributed by area over a triangle mesh.

    Args:
        vertices: (V, 3) metres. triangles: (T, 3) vertex indices.
        n: number of samples.
        rng: the generator (seeded by the caller).

    Returns:
        (n, 3) float64 points.

    Raises:
        ReconError: an empty mesh or one of zero area.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    if len(f) == 0 or len(v) == 0:
        raise ReconError("cannot sample an empty mesh")
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = float(area.sum())
    if not total > 0:
        raise ReconError("cannot sample a mesh of zero area")
    k = rng.choice(len(f), size=n, p=area / total)
    r1 = np.sqrt(rng.random(n))
    r2 = rng.random(n)
    w0, w1, w2 = 1.0 - r1, r1 * (1.0 - r2), r1 * r2
    return a[k] * w0[:, None] + b[k] * w1[:, None] + c[k] * w2[:, None]


def point_to_mesh_distance(points: F64, vertices: F64, triangles: NDArray[np.integer]) -> F64:
    """Exact unsigned distance (metres) from (N, 3) points to a triangle mesh."""
    import open3d as o3d

    _Tensor: Any = o3d.core.Tensor

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        _Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        _Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)),
    )
    q = _Tensor(np.ascontiguousarray(points, dtype=np.float32))
    return np.asarray(scene.compute_distance(q).numpy(), dtype=np.float64)


def _nn_distance(points: F64, cloud: F64) -> F64:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(cloud).query(points, k=1, workers=-1)
    return np.asarray(d, dtype=np.float64)


def _draw_samples(v: F64, f: NDArray[np.integer] | None, samples: int,
                  rng: np.random.Generator) -> F64:
    """(samples, 3) points of a surface: drawn on its triangles ``f``, or ``samples`` of its
    points ``v`` (all of them when fewer).

    Raises:
        ReconError: ``v`` is not a non-empty (N, 3) array.
    """
    v = np.asarray(v, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ReconError(f"a surface needs (N, 3) points, got {v.shape}")
    if f is not None and len(f):
        return sample_surface(v, f, samples, rng)
    if len(v) > samples:
        return v[rng.choice(len(v), size=samples, replace=False)]
    return v


def surface_metrics(
    est_vertices: F64,
    est_triangles: NDArray[np.integer] | None,
    ref_vertices: F64,
    ref_triangles: NDArray[np.integer] | None,
    *,
    samples: int = 200_000,
    thresholds_m: tuple[float, ...] = DEFAULT_THRESHOLDS_M,
    crop_margin_m: float | None = None,
    reference_points: F64 | None = None,
    seed: int = 0,
) -> SurfaceMetrics:
    """Accuracy and completeness of an estimated surface against a reference.

    Args:
        est_vertices, est_triangles: the estimate, a mesh or (triangles None) a point cloud.
        ref_vertices, ref_triangles: the reference, likewise.
        samples: points sampled on each mesh (a point cloud is used as it is, subsampled to
            at most this many).
        thresholds_m: distances for precision, recall and F-score.
        crop_margin_m: keep reference samples inside the estimate's bounding box grown by this.
        reference_points: (M, 3) points of the reference that were observable; replaces the
            reference samples for completeness (accuracy still measures to the full reference).
        seed: sampling seed.

    Returns:
        :class:`SurfaceMetrics`.

    Raises:
        ReconError: empty inputs or no reference sample left after cropping.
    """
    rng = np.random.default_rng(seed)

    def draw(v: F64, f: NDArray[np.integer] | None) -> F64:
        return _draw_samples(v, f, samples, rng)

    est_s = draw(est_vertices, est_triangles)
    ref_s = draw(ref_vertices, ref_triangles) if reference_points is None else draw(
        reference_points, None)
    if crop_margin_m is not None:
        lo = est_s.min(axis=0) - crop_margin_m
        hi = est_s.max(axis=0) + crop_margin_m
        ref_s = ref_s[np.all((ref_s >= lo) & (ref_s <= hi), axis=1)]
        if len(ref_s) == 0:
            raise ReconError("no reference surface lies inside the estimate's bounding box")
    est_v = np.asarray(est_vertices, dtype=np.float64)
    outside = ~np.all((ref_s >= est_v.min(axis=0)) & (ref_s <= est_v.max(axis=0)), axis=1)
    ref_has_mesh = ref_triangles is not None and len(ref_triangles) > 0
    est_has_mesh = est_triangles is not None and len(est_triangles) > 0
    acc = (point_to_mesh_distance(est_s, ref_vertices, ref_triangles)  # type: ignore[arg-type]
           if ref_has_mesh else _nn_distance(est_s, np.asarray(ref_vertices, np.float64)))
    comp = (point_to_mesh_distance(ref_s, est_vertices, est_triangles)  # type: ignore[arg-type]
            if est_has_mesh else _nn_distance(ref_s, np.asarray(est_vertices, np.float64)))
    prec = tuple(float(np.mean(acc <= t)) for t in thresholds_m)
    rec = tuple(float(np.mean(comp <= t)) for t in thresholds_m)
    fs = tuple(2 * p * r / (p + r) if p + r > 0 else 0.0 for p, r in zip(prec, rec, strict=True))
    return SurfaceMetrics(
        accuracy_m=error_stats(acc),
        completeness_m=error_stats(comp),
        thresholds_m=tuple(float(t) for t in thresholds_m),
        precision=prec,
        recall=rec,
        fscore=fs,
        estimate_samples=len(est_s),
        reference_samples=len(ref_s),
        reference_outside=float(np.mean(outside)),
    )


# ------------------------------------------------------------------------------- alignment


@dataclass(frozen=True, kw_only=True)
class SurfaceAlignment:
    """A similarity ``x_ref = T_ref_est x_est`` that puts the estimate into the reference's frame.

    Attributes:
        T_ref_est: (4, 4); its rotation block carries ``scale``.
        scale: 1.0 unless Sim(3) was fitted.
        method: ``"none"``, ``"trajectory-se3"``, ``"trajectory-sim3"``, ``"icp"`` or
            ``"trajectory-se3+icp"`` (and so on).
        residual_m: RMS residual of the fit, metres: of the associated camera positions for a
            trajectory fit, of ICP's inlier correspondences for ICP; None for ``"none"``.
        residual_of: what ``residual_m`` measures, in words.
        pairs: associated poses (trajectory) or inlier correspondences (ICP).
        fitness: ICP only: fraction of the estimate's samples with a correspondence.
    """

    T_ref_est: F64
    scale: float = 1.0
    method: str = "none"
    residual_m: float | None = None
    residual_of: str = ""
    pairs: int = 0
    fitness: float | None = None

    def as_dict(self) -> dict[str, object]:
        """Plain values for JSON."""
        d = asdict(self)
        d["T_ref_est"] = np.asarray(self.T_ref_est).tolist()
        return d

    def apply(self, points: F64) -> F64:
        """(N, 3) points of the estimate in the reference's frame."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.T_ref_est[:3, :3].T + self.T_ref_est[:3, 3]


NO_ALIGNMENT = SurfaceAlignment(T_ref_est=np.eye(4))


def align_by_trajectories(
    t_est_ns: NDArray[np.integer],
    T_est: F64,
    t_ref_ns: NDArray[np.integer],
    T_ref: F64,
    *,
    with_scale: bool = False,
    by_index: bool = False,
    max_diff_s: float = 0.01,
    axis_m: float = 1.0,
) -> SurfaceAlignment:
    """The transform from the estimate's world to the reference's, from their trajectories.

    Poses are paired by time (or by index), and Umeyama fits the pairs. Positions alone leave
    the rotation about a straight survey leg undetermined, so each pose also contributes the
    tips of its three axes ``axis_m`` out (after scaling, for Sim(3)): orientations pin it.

    Args:
        t_est_ns, T_est: (N,) stamps and (N, 4, 4) ``T_world_cam`` of the estimate.
        t_ref_ns, T_ref: (M,) and (M, 4, 4) of the reference.
        with_scale: fit Sim(3) (monocular or unscaled estimates); else SE(3).
        by_index: pair the i-th poses (files without times) instead of by time.
        max_diff_s: largest stamp difference of a pair.
        axis_m: length of the axis tips, metres.

    Returns:
        :class:`SurfaceAlignment` with the RMS position residual of the pairs.

    Raises:
        ReconError: fewer than 3 pairs, or an estimate that does not move.
    """
    from sea3d.errors import GeometryError
    from sea3d.eval.trajectory import associate, umeyama

    Te = np.asarray(T_est, dtype=np.float64)
    Tr = np.asarray(T_ref, dtype=np.float64)
    if by_index:
        n = min(len(Te), len(Tr))
        i: I64 = np.arange(n, dtype=np.int64)
        j: I64 = i
    else:
        i, j = associate(np.asarray(t_est_ns), np.asarray(t_ref_ns), round(max_diff_s * 1e9))
    if i.size < 3:
        raise ReconError(f"only {i.size} poses of the trajectories pair up (by "
                         f"{'index' if by_index else 'time'}); alignment needs at least 3")
    pe, pr = Te[i, :3, 3], Tr[j, :3, 3]
    try:
        s = umeyama(pe, pr, with_scale=True)[2] if with_scale else 1.0

        def points(p: F64, T: F64) -> F64:
            return np.concatenate([p, *(p + axis_m * T[:, :3, a] for a in range(3))])

        R, t, _ = umeyama(points(s * pe, Te[i]), points(pr, Tr[j]), with_scale=False)
    except GeometryError as err:
        raise ReconError(f"cannot align the trajectories: {err}") from err
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = s * R, t
    res = pe @ T[:3, :3].T + T[:3, 3] - pr
    return SurfaceAlignment(
        T_ref_est=T, scale=float(s), method="trajectory-sim3" if with_scale else "trajectory-se3",
        residual_m=float(np.sqrt(np.mean(np.sum(res * res, axis=1)))),
        residual_of="RMS distance of the aligned camera positions to the reference's",
        pairs=int(i.size))


def align_by_icp(
    est_vertices: F64,
    est_triangles: NDArray[np.integer] | None,
    ref_vertices: F64,
    ref_triangles: NDArray[np.integer] | None,
    *,
    init: SurfaceAlignment = NO_ALIGNMENT,
    max_distance_m: float | None = None,
    samples: int = 50_000,
    iterations: int = 50,
    seed: int = 0,
) -> SurfaceAlignment:
    """Rigid ICP (Open3D, point to plane) of the estimate onto the reference, from ``init``.

    ICP converges only from a start within about ``max_distance_m`` of the answer: start it from
    a trajectory alignment, or use it alone on surfaces that already roughly overlap.

    Args:
        est_vertices, est_triangles: the estimate (triangles None: a point cloud).
        ref_vertices, ref_triangles: the reference.
        init: the starting alignment (its scale is kept).
        max_distance_m: largest correspondence distance; default 2 % of the reference's
            bounding-box diagonal.
        samples: points sampled on each surface.
        iterations: ICP iterations at most.
        seed: sampling seed.

    Returns:
        :class:`SurfaceAlignment`; ``residual_m`` is the RMS of the inlier correspondences and
        ``fitness`` their share of the estimate's samples.

    Raises:
        ReconError: empty surfaces, or no correspondence within ``max_distance_m``.
    """
    import open3d as o3d

    rng = np.random.default_rng(seed)

    def draw(v: F64, f: NDArray[np.integer] | None) -> F64:
        return _draw_samples(v, f, samples, rng)

    src = init.apply(draw(est_vertices, est_triangles))
    dst = draw(ref_vertices, ref_triangles)
    if max_distance_m is None:
        max_distance_m = 0.02 * float(np.linalg.norm(dst.max(axis=0) - dst.min(axis=0)))
    pc_src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
    pc_dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(dst))
    pc_dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(
        radius=2 * max_distance_m, max_nn=30))
    reg = o3d.pipelines.registration
    r = reg.registration_icp(
        pc_src, pc_dst, max_distance_m, np.eye(4),
        reg.TransformationEstimationPointToPlane(),
        reg.ICPConvergenceCriteria(max_iteration=iterations))
    if len(r.correspondence_set) == 0:
        raise ReconError(f"ICP found no correspondence within {max_distance_m:.3g} m: the "
                         "surfaces do not overlap (align by trajectories first)")
    T_icp = np.asarray(r.transformation, dtype=np.float64)
    moved = src @ T_icp[:3, :3].T + T_icp[:3, 3]
    d = (point_to_mesh_distance(moved, np.asarray(ref_vertices, np.float64), ref_triangles)
         if ref_triangles is not None and len(ref_triangles) else _nn_distance(moved, dst))
    inliers = d[d <= max_distance_m]
    method = "icp" if init.method == "none" else f"{init.method}+icp"
    return SurfaceAlignment(
        T_ref_est=T_icp @ init.T_ref_est, scale=init.scale, method=method,
        residual_m=float(np.sqrt(np.mean(inliers**2))) if inliers.size else None,
        residual_of=f"RMS distance to the reference of the aligned samples within "
                    f"{max_distance_m:.3g} m of it",
        pairs=int(inliers.size), fitness=float(inliers.size / len(moved)))
