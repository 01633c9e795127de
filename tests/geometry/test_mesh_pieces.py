"""Dropping the small pieces of a mesh."""

from __future__ import annotations

import numpy as np

from sea3d.geometry.mesh import Mesh, drop_small_pieces


def _grid(n: int, origin: tuple[float, float, float]) -> Mesh:
    """An n x n grid of vertices on a plane: 2 (n-1)^2 triangles, one piece."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1) * 0.02 + origin
    i = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n], 1), np.stack([i + 1, i + n + 1, i + n], 1)])
    return Mesh(vertices=v, triangles=f.astype(np.int64))


def test_small_pieces_go_and_the_rest_is_kept_whole() -> None:
    big, speck, small = _grid(12, (0, 0, 0)), _grid(3, (1, 1, 1)), _grid(8, (2, 0, 0))
    mesh = Mesh.concatenate([speck, big, small])  # 8, 242 and 98 triangles
    cols = np.arange(len(mesh.vertices) * 3, dtype=np.uint8).reshape(-1, 3)
    mesh = Mesh(vertices=mesh.vertices, triangles=mesh.triangles, colors_rgb=cols)
    out, kept = drop_small_pieces(mesh, 98)
    assert len(out.triangles) == 242 + 98
    assert kept.sum() == len(out.vertices) == 144 + 64
    assert not kept[:9].any() and kept[9:].all()
    # the kept triangles are the same triangles, colours go with their vertices
    np.testing.assert_array_equal(out.vertices[out.triangles], mesh.vertices[mesh.triangles[8:]])
    np.testing.assert_array_equal(out.colors_rgb, cols[9:])
    # one more triangle needed: the 98-triangle piece goes too
    assert len(drop_small_pieces(mesh, 99)[0].triangles) == 242
    # 0 keeps everything, as it was
    same, all_kept = drop_small_pieces(mesh, 0)
    assert same is mesh and all_kept.all()


def test_pieces_touching_at_one_vertex_are_one_piece() -> None:
    a = _grid(3, (0, 0, 0))  # 8 triangles
    b = Mesh(vertices=np.array([[0.04, 0.04, 0.0], [0.1, 0.04, 0], [0.1, 0.1, 0]]),
             triangles=np.array([[0, 1, 2]]))
    joined = Mesh(vertices=np.concatenate([a.vertices, b.vertices[1:]]),
                  triangles=np.concatenate([a.triangles, [[8, 9, 10]]]))
    assert len(drop_small_pieces(joined, 9)[0].triangles) == 9
