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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError
from sea3d.eval.trajectory import ErrorStats, error_stats

__all__ = ["SurfaceMetrics", "point_to_mesh_distance", "sample_surface", "surface_metrics"]

I64 = NDArray[np.int64]

DEFAULT_THRESHOLDS_M = (0.01, 0.02, 0.05)


@dataclass(frozen=True, kw_only=True)
class SurfaceMetrics:
    """Accuracy and completeness, metres; precision, recall and F-score per threshold."""

    accuracy_m: ErrorStats
    completeness_m: ErrorStats
    thresholds_m: tuple[float, ...]
    precision: tuple[float, ...]
    recall: tuple[float, ...]
    fscore: tuple[float, ...]
    estimate_samples: int
    reference_samples: int

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
        v = np.asarray(v, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise ReconError(f"a surface needs (N, 3) points, got {v.shape}")
        if f is not None and len(f):
            return sample_surface(v, f, samples, rng)
        if len(v) > samples:
            return v[rng.choice(len(v), size=samples, replace=False)]
        return v

    est_s = draw(est_vertices, est_triangles)
    ref_s = draw(ref_vertices, ref_triangles) if reference_points is None else draw(
        reference_points, None)
    if crop_margin_m is not None:
        lo = est_s.min(axis=0) - crop_margin_m
        hi = est_s.max(axis=0) + crop_margin_m
        ref_s = ref_s[np.all((ref_s >= lo) & (ref_s <= hi), axis=1)]
        if len(ref_s) == 0:
            raise ReconError("no reference surface lies inside the estimate's bounding box")
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
    )
