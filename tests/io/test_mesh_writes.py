"""Meshes and clouds are written whole or not at all: a full disk is an error, never a file
cut short under its final name (Open3D's own PLY writer reports success after failed
writes), and a killed run's temporary files are cleared by the next run into the folder."""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import sys

import numpy as np
import pytest

from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.io import _atomic, mesh_files
from sea3d.io.mesh_files import read_mesh, read_point_cloud, write_mesh, write_point_cloud

BYTES_BEFORE_FULL = 1000


def _mesh(rng: np.random.Generator, n: int = 500) -> Mesh:
    v = rng.random((n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Mesh(vertices=v, triangles=rng.integers(0, n, (2 * n, 3)),
                colors_rgb=rng.integers(0, 256, (n, 3), dtype=np.uint8), normals=normals)


def _filling_atomic_open(limit: int):
    """``atomic_open`` whose file raises ENOSPC once ``limit`` bytes are written."""
    real = _atomic.atomic_open

    @contextlib.contextmanager
    def atomic_open(path, mode="w", **kw):
        with real(path, mode, **kw) as fh:
            written = [0]
            raw_write = fh.write

            def write(data):
                if written[0] + len(data) > limit:
                    raise OSError(errno.ENOSPC, "No space left on device", str(path))
                written[0] += len(data)
                return raw_write(data)

            fh.write = write
            yield fh

    return atomic_open


def test_ply_mesh_and_cloud_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    m = _mesh(rng)
    write_mesh(tmp_path / "m.ply", m)
    back = read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(back.vertices, m.vertices)  # written as doubles: exact
    np.testing.assert_array_equal(back.triangles, m.triangles)
    np.testing.assert_array_equal(back.colors_rgb, m.colors_rgb)
    write_point_cloud(tmp_path / "c.ply", m.vertices, m.colors_rgb, m.normals)
    pts, cols = read_point_cloud(tmp_path / "c.ply")[:2]
    np.testing.assert_array_equal(pts, m.vertices)
    np.testing.assert_array_equal(cols, m.colors_rgb)


@pytest.mark.parametrize("what", ["mesh", "cloud"])
def test_a_full_disk_leaves_no_file_under_the_final_name(tmp_path, monkeypatch, what):
    rng = np.random.default_rng(0)
    m = _mesh(rng)
    target = tmp_path / f"{what}.ply"
    target.write_bytes(b"the previous run's file")
    monkeypatch.setattr(mesh_files, "atomic_open", _filling_atomic_open(BYTES_BEFORE_FULL))
    with pytest.raises(ReconError, match=rf"cannot write .*{what}.ply: \[Errno 28\] No space"):
        if what == "mesh":
            write_mesh(target, m)
        else:
            write_point_cloud(target, m.vertices, m.colors_rgb)
    assert target.read_bytes() == b"the previous run's file"
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no temporary left


def test_a_file_size_limit_in_a_child_process_is_an_error_not_a_cut_file(tmp_path):
    """A real short write (RLIMIT_FSIZE stands in for a full disk: EFBIG for ENOSPC)."""
    code = f"""
import resource, sys
import numpy as np
from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.io.mesh_files import write_mesh
rng = np.random.default_rng(0)
m = Mesh(vertices=rng.random((20000, 3)), triangles=rng.integers(0, 20000, (30000, 3)))
resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
try:
    write_mesh({str(tmp_path / "mesh.ply")!r}, m)
except ReconError as err:
    print(err)
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=120, check=True)
    assert "File too large" in got.stdout
    assert got.stderr == ""  # nothing printed by a library underneath
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait(30)
    (tmp_path / "cache" / "frames").mkdir(parents=True)
    stale = [tmp_path / f".mesh.{dead.pid}-0123abcd.tmp.ply",
             tmp_path / "cache" / "frames" / f".100.{dead.pid}-89abcdef.tmp.s3c"]
    kept = [tmp_path / f".cloud.{os.getppid()}-0123abcd.tmp.ply",  # a process still running
            tmp_path / ".mesh.tmp.ply.bak", tmp_path / "mesh.ply"]  # not ours to remove
    for p in stale + kept:
        p.write_bytes(b"x")
    removed = _atomic.remove_stale_temps(tmp_path)
    assert sorted(removed) == sorted(stale)
    assert all(p.exists() for p in kept) and not any(p.exists() for p in stale)


@pytest.mark.parametrize("writer", ["sea3d", "open3d"])
def test_a_ply_cut_short_is_refused_not_read_as_a_smaller_mesh(tmp_path, writer):
    """What a full disk left before writes were checked (a mesh with vertices and no faces,
    796 of its vertices): Open3D reads it as a smaller mesh; it is now an error."""
    import open3d as o3d

    rng = np.random.default_rng(0)
    m = _mesh(rng)
    path = tmp_path / "mesh.ply"
    if writer == "sea3d":
        write_mesh(path, m)
    else:
        om = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(m.vertices),
                                       o3d.utility.Vector3iVector(m.triangles.astype(np.int32)))
        assert o3d.io.write_triangle_mesh(str(path), om)
    whole = path.read_bytes()
    assert len(read_mesh(path).triangles) == len(m.triangles)
    for cut in (len(whole) - 1, len(whole) // 2, len(whole) // 5):
        path.write_bytes(whole[:cut])
        with pytest.raises(ReconError, match=r"mesh.ply is cut short"):
            read_mesh(path)
    cloud = tmp_path / "cloud.ply"
    write_point_cloud(cloud, m.vertices, m.colors_rgb)
    cloud.write_bytes(cloud.read_bytes()[:-3])
    with pytest.raises(ReconError, match=r"cloud.ply is cut short"):
        read_point_cloud(cloud)
