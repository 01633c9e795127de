"""A triangle mesh: vertices, triangles, colours and normals (maths only, no I/O).

It lives in geometry, below io and recon, so that io can read and write meshes without
importing the reconstruction stage; :mod:`sea3d.recon` re-exports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError

__all__ = ["Mesh", "drop_small_pieces"]


@dataclass(frozen=True, kw_only=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes:
        vertices: (V, 3) float64 metres.
        triangles: (T, 3) int64 vertex indices, counter-clockwise seen from outside.
        colors_rgb: (V, 3) uint8 vertex colours, or None.
        normals: (V, 3) float64 unit vertex normals, or None.
    """

    vertices: F64
    triangles: NDArray[np.int64]
    colors_rgb: NDArray[np.uint8] | None = None
    normals: F64 | None = None

    def __post_init__(self) -> None:
        v, f = self.vertices, self.triangles
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise ReconError(f"a mesh needs vertices (V, 3) and triangles (T, 3), got {v.shape} "
                             f"and {f.shape}")
        for name, a in (("colors_rgb", self.colors_rgb), ("normals", self.normals)):
            if a is not None and a.shape != v.shape:
                raise ReconError(f"mesh {name} {a.shape} do not match vertices {v.shape}")

    @property
    def empty(self) -> bool:
        """True when the mesh has no triangles."""
        return len(self.triangles) == 0

    def transformed(self, T_b_a: F64) -> Mesh:
        """The mesh moved from frame a to frame b (normals rotated)."""
        R, t = T_b_a[:3, :3], T_b_a[:3, 3]
        return Mesh(vertices=self.vertices @ R.T + t, triangles=self.triangles,
                    colors_rgb=self.colors_rgb,
                    normals=None if self.normals is None else self.normals @ R.T)

    @staticmethod
    def concatenate(meshes: list[Mesh]) -> Mesh:
        """One mesh holding all of ``meshes`` (colours and normals kept if all have them)."""
        meshes = [m for m in meshes if len(m.vertices)]
        if not meshes:
            return Mesh(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int64))
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        cols = None
        if all(m.colors_rgb is not None for m in meshes):
            cols = np.concatenate([m.colors_rgb for m in meshes if m.colors_rgb is not None])
        nrm = None
        if all(m.normals is not None for m in meshes):
            nrm = np.concatenate([m.normals for m in meshes if m.normals is not None])
        return Mesh(
            vertices=np.concatenate([m.vertices for m in meshes]),
            triangles=np.concatenate([m.triangles + o for m, o in zip(meshes, offsets,
                                                                        strict=True)]),
            colors_rgb=cols,
            normals=nrm,
        )


def drop_small_pieces(mesh: Mesh, min_triangles: int) -> tuple[Mesh, NDArray[np.bool_]]:
    """The mesh without its pieces (sets of triangles connected through shared vertices) of
    fewer than ``min_triangles`` triangles, and which of the input's vertices it kept.

    Args:
        mesh: a welded mesh (pieces are found through shared vertex indices).
        min_triangles: pieces smaller than this go; 0 or 1 keeps every piece.

    Returns:
        ``(mesh, kept)``: the mesh (unreferenced vertices removed, order kept) and a (V,)
        mask over the input's vertices.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_v = len(mesh.vertices)
    if min_triangles <= 1 or mesh.empty:
        return mesh, np.ones(n_v, bool)
    f = mesh.triangles
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n_v, n_v))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label[f[:, 0]], minlength=label.max() + 1)
    keep_f = size[label[f[:, 0]]] >= min_triangles
    kept = np.zeros(n_v, bool)
    kept[f[keep_f].ravel()] = True
    index = np.cumsum(kept) - 1
    return Mesh(
        vertices=mesh.vertices[kept],
        triangles=index[f[keep_f]].astype(np.int64),
        colors_rgb=None if mesh.colors_rgb is None else mesh.colors_rgb[kept],
        normals=None if mesh.normals is None else mesh.normals[kept],
    ), kept
