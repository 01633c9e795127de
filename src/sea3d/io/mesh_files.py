"""Mesh and point-cloud files (PLY, OBJ, STL, OFF, GLB through Open3D), written atomically.

Meshes are written as binary PLY with vertex colours (uchar RGB) and normals when present;
point clouds as binary PLY with colours and normals. A file is written under a temporary
name beside the target and renamed into place, so a reader never sees half a file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.io._atomic import atomic_open, atomic_path

__all__ = [
    "CLOUD_SUFFIXES",
    "MESH_SUFFIXES",
    "read_compact_mesh",
    "read_mesh",
    "read_point_cloud",
    "write_compact_mesh",
    "write_mesh",
    "write_point_cloud",
]

# Output suffixes the writers accept (any case): PLY by sea3d itself, the rest by Open3D.
MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".gltf", ".glb")
CLOUD_SUFFIXES = (".ply", ".pcd", ".pts", ".xyz", ".xyzn", ".xyzrgb")


def _write_ply(path: Path, vertices: NDArray[np.float64], *,
               colors_rgb: NDArray[np.uint8] | None = None,
               normals: NDArray[np.float64] | None = None,
               triangles: NDArray[np.int64] | None = None) -> None:
    """Binary little-endian PLY, atomically: double x y z, [double nx ny nz], [uchar red
    green blue] per vertex, [``list uchar int vertex_indices`` per triangle].

    Written here, not by Open3D: Open3D's PLY writer reports success after writes that
    failed (a full disk: a file cut short, or with vertices and no faces); Python's file
    writes raise instead.

    Raises:
        OSError: the file cannot be written (nothing is left under ``path``).
    """
    n = len(vertices)
    fields: list[tuple[str, str]] = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
            "property double x", "property double y", "property double z"]
    if normals is not None:
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        head += ["property double nx", "property double ny", "property double nz"]
    if colors_rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        head += ["property uchar red", "property uchar green", "property uchar blue"]
    rec = np.empty(n, dtype=fields)
    for i, k in enumerate("xyz"):
        rec[k] = vertices[:, i]
        if normals is not None:
            rec["n" + k] = normals[:, i]
    if colors_rgb is not None:
        for i, k in enumerate(("red", "green", "blue")):
            rec[k] = colors_rgb[:, i]
    faces = None
    if triangles is not None:
        head += [f"element face {len(triangles)}", "property list uchar int vertex_indices"]
        faces = np.empty(len(triangles), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        faces["n"], faces["v"] = 3, triangles
    head.append("end_header")
    with atomic_open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode("ascii"))
        fh.write(rec.tobytes())
        if faces is not None:
            fh.write(faces.tobytes())


def write_mesh(path: str | os.PathLike[str], mesh: Mesh) -> None:
    """Write a :class:`~sea3d.geometry.mesh.Mesh` (format from the extension, PLY binary).

    Raises:
        ReconError: the file cannot be written (a full disk included: nothing is then left
            under ``path``).
    """
    p = Path(path)
    if len(mesh.vertices) == 0 or len(mesh.triangles) == 0:
        raise ReconError(
            f"cannot write mesh {p}: the mesh is empty ({len(mesh.vertices)} vertices, "
            f"{len(mesh.triangles)} triangles): nothing was fused into it (no depth inside "
            "the fusion volume?)"
        )
    vertices = np.ascontiguousarray(mesh.vertices, np.float64)
    triangles = np.ascontiguousarray(mesh.triangles, np.int64)
    try:
        if p.suffix.lower() == ".ply":
            _write_ply(p, vertices, colors_rgb=mesh.colors_rgb, triangles=triangles,
                       normals=None if mesh.normals is None else np.asarray(mesh.normals))
            return
        import open3d as o3d

        m = o3d.geometry.TriangleMesh()
        m.vertices = o3d.utility.Vector3dVector(vertices)
        m.triangles = o3d.utility.Vector3iVector(triangles.astype(np.int32))
        if mesh.colors_rgb is not None:
            m.vertex_colors = o3d.utility.Vector3dVector(
                mesh.colors_rgb.astype(np.float64) / 255.0)
        if mesh.normals is not None:
            m.vertex_normals = o3d.utility.Vector3dVector(np.ascontiguousarray(mesh.normals))
        with atomic_path(p) as tmp:
            if not o3d.io.write_triangle_mesh(tmp, m, write_ascii=False, compressed=False):
                raise ReconError(
                    f"cannot write mesh {p} (Open3D refused the format {p.suffix!r})"
                )
            back = o3d.io.read_triangle_mesh(tmp)  # Open3D does not report failed writes
            if len(back.triangles) != len(triangles):
                raise ReconError(f"cannot write mesh {p}: {len(back.triangles)} of "
                                 f"{len(triangles)} triangles read back (is the disk full?)")
    except OSError as err:
        raise ReconError(f"cannot write mesh {p}: {err}") from err


def write_point_cloud(
    path: str | os.PathLike[str],
    points: NDArray[np.float64],
    colors_rgb: NDArray[np.uint8] | None = None,
    normals: NDArray[np.float64] | None = None,
) -> None:
    """Write a point cloud (PLY binary, or any format Open3D knows by extension).

    Args:
        points: (N, 3) metres. colors_rgb: (N, 3) uint8 or None. normals: (N, 3) or None.

    Raises:
        ReconError: mismatched shapes or an unwritable file (a full disk included: nothing
            is then left under ``path``).
    """
    p = Path(path)
    pts = np.asarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ReconError(f"points must be (N, 3), got {pts.shape}")
    for name, a in (("colours", colors_rgb), ("normals", normals)):
        if a is not None and np.asarray(a).shape != pts.shape:
            raise ReconError(f"{name} {np.asarray(a).shape} do not match points {pts.shape}")
    try:
        if p.suffix.lower() == ".ply":
            _write_ply(p, pts,
                       colors_rgb=None if colors_rgb is None else np.asarray(colors_rgb),
                       normals=None if normals is None else np.asarray(normals, np.float64))
            return
        import open3d as o3d

        pc = o3d.geometry.PointCloud()
        pc.points = o3d.utility.Vector3dVector(pts)
        if colors_rgb is not None:
            pc.colors = o3d.utility.Vector3dVector(np.asarray(colors_rgb, np.float64) / 255.0)
        if normals is not None:
            pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64))
        with atomic_path(p) as tmp:
            if not o3d.io.write_point_cloud(tmp, pc, write_ascii=False, compressed=False):
                raise ReconError(f"cannot write point cloud {p} (format {p.suffix!r})")
            back = o3d.io.read_point_cloud(tmp)  # Open3D does not report failed writes
            if len(back.points) != len(pts):
                raise ReconError(f"cannot write point cloud {p}: {len(back.points)} of "
                                 f"{len(pts)} points read back (is the disk full?)")
    except OSError as err:
        raise ReconError(f"cannot write point cloud {p}: {err}") from err


_PLY_BYTES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2,
              "int16": 2, "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_ply_whole(p: Path) -> None:
    """Refuse a binary PLY file shorter than its header announces (a polygon list counted
    at its smallest, a triangle): Open3D reads such a file cut short by a full disk or a
    killed writer as a smaller mesh, without a word. Other files are left to Open3D.

    Raises:
        ReconError: the file is cut short.
    """
    if p.suffix.lower() != ".ply":
        return
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    newline = head.find(b"\n", end)
    if not head.startswith(b"ply") or end < 0 or newline < 0:
        return
    need, count, per_item = newline + 1, 0, 0
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and not words[1:2] == ["binary_little_endian"] \
                and not words[1:2] == ["binary_big_endian"]:
            return  # ASCII
        if words[0] == "element" and len(words) == 3:
            need += count * per_item
            count, per_item = int(words[2]) if words[2].isdigit() else 0, 0
        elif words[0] == "property" and len(words) >= 3:
            if words[1] == "list" and len(words) == 5:
                if words[2] not in _PLY_BYTES or words[3] not in _PLY_BYTES:
                    return
                polygon = words[4] in ("vertex_indices", "vertex_index")
                per_item += _PLY_BYTES[words[2]] + (3 * _PLY_BYTES[words[3]] if polygon else 0)
            elif words[1] in _PLY_BYTES:
                per_item += _PLY_BYTES[words[1]]
            else:
                return
    need += count * per_item
    size = p.stat().st_size
    if size < need:
        raise ReconError(f"{p} is cut short: {size} bytes where its header announces at "
                         f"least {need} (written by a run that was killed or whose disk "
                         "filled); write it again")


def read_mesh(path: str | os.PathLike[str]) -> Mesh:
    """Read a triangle mesh; a file without triangles comes back as a mesh of its vertices
    only (``triangles`` empty), so point clouds can be evaluated too.

    Raises:
        ReconError: missing or unreadable file, one with no vertices, or a binary PLY file
            cut short.
    """
    import open3d as o3d

    p = Path(path)
    if not p.is_file():
        raise ReconError(f"mesh {p} does not exist")
    _check_ply_whole(p)
    m = o3d.io.read_triangle_mesh(p)
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.triangles, np.int64).reshape(-1, 3)
    if len(v) == 0:
        pc = o3d.io.read_point_cloud(p)
        v = np.asarray(pc.points, np.float64)
        if len(v) == 0:
            raise ReconError(f"{p} holds no vertices (not a mesh or point cloud Open3D reads)")
        cols = _colours_u8(pc.colors) if pc.has_colors() else None
        return Mesh(vertices=v, triangles=np.zeros((0, 3), np.int64), colors_rgb=cols)
    cols = _colours_u8(m.vertex_colors) if m.has_vertex_colors() else None
    nrm = np.asarray(m.vertex_normals, np.float64) if m.has_vertex_normals() else None
    return Mesh(vertices=v, triangles=f, colors_rgb=cols, normals=nrm)


def read_point_cloud(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64],
                                                           NDArray[np.uint8] | None]:
    """Points (N, 3) and colours (N, 3) uint8 (or None) of a point-cloud file.

    Raises:
        ReconError: missing, unreadable or empty file, or a binary PLY file cut short.
    """
    import open3d as o3d

    p = Path(path)
    if not p.is_file():
        raise ReconError(f"point cloud {p} does not exist")
    _check_ply_whole(p)
    pc = o3d.io.read_point_cloud(p)
    pts = np.asarray(pc.points, np.float64)
    if len(pts) == 0:
        raise ReconError(f"{p} holds no points")
    cols = _colours_u8(pc.colors) if pc.has_colors() else None
    return pts, cols


def _colours_u8(colors01: object) -> NDArray[np.uint8]:
    """Open3D's (N, 3) colours in [0, 1] as uint8 0-255, rounded to nearest."""
    return np.clip(np.rint(np.asarray(colors01) * 255), 0, 255).astype(np.uint8)


def write_compact_mesh(path: str | os.PathLike[str], mesh: Mesh) -> None:
    """Write ``mesh`` as a scratch ``.npz`` (float32 vertices, int32 triangles, uint8 colours;
    no normals): the live view's finished submaps, read back with :func:`read_compact_mesh`.

    Raises:
        OSError: the file cannot be written (nothing is left under ``path``).
    """
    colours = (mesh.colors_rgb if mesh.colors_rgb is not None
               else np.zeros((0, 3), np.uint8))
    with atomic_path(path, fsync=False) as tmp, open(tmp, "wb") as f:
        np.savez(f, vertices=mesh.vertices.astype(np.float32),
                 triangles=mesh.triangles.astype(np.int32), colors=colours)


def read_compact_mesh(path: str | os.PathLike[str]) -> Mesh:
    """A mesh written by :func:`write_compact_mesh` (float64 vertices, int64 triangles)."""
    with np.load(path) as z:
        col = z["colors"]
        return Mesh(vertices=z["vertices"].astype(np.float64),
                    triangles=z["triangles"].astype(np.int64),
                    colors_rgb=col if len(col) else None)
