"""The one atomic write: all or nothing, one temporary-name convention."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from sea3d.io._atomic import atomic_open, atomic_path, atomic_write, is_temp_name, temp_path


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "summary.json"
    atomic_write(target, "old\n")
    with pytest.raises(RuntimeError), atomic_open(target, "w") as fh:
        fh.write("half of the new")
        raise RuntimeError("disk went away")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_files_get_the_umask_mode_and_replace_the_target(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write(tmp_path / "a" / "rig.yaml", b"x: 1\n")
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "a" / "rig.yaml").stat().st_mode)
    assert mode == 0o644
    atomic_write(tmp_path / "a" / "rig.yaml", "x: 2\n", fsync=False)
    assert (tmp_path / "a" / "rig.yaml").read_text() == "x: 2\n"


def test_temporary_names_are_hidden_unique_keep_the_suffix_and_are_recognised(tmp_path):
    a, b = temp_path(tmp_path / "mesh.ply"), temp_path(tmp_path / "mesh.ply")
    assert a != b and a.parent == tmp_path and a.suffix == ".ply" and a.name.startswith(".")
    assert is_temp_name(a.name) and is_temp_name(".500000000.png.tmp")  # the older leftovers
    assert not is_temp_name("500000000.png") and not is_temp_name("mesh.ply")
    with atomic_path(tmp_path / "m.ply") as tmp:
        assert tmp.suffix == ".ply"
        tmp.write_bytes(b"ply\n")
    assert (tmp_path / "m.ply").read_bytes() == b"ply\n"


@pytest.mark.parametrize("name", ["d.pfm", "d.npy", "d.tiff", "gt.tiff", "z.png"])
def test_depth_and_disparity_writers_are_atomic(tmp_path, monkeypatch, name):
    """A writer that fails half-way keeps the old map and leaves no temporary: disparity (PFM,
    NPY, TIFF), ground-truth depth and 16-bit depth PNGs all go through atomic_path."""
    import numpy as np

    from sea3d.io import depth_files, ground_truth

    def write(p, a):
        if name.startswith("gt"):
            ground_truth.write_gt_depth(p, a)
        elif name.endswith(".png"):
            depth_files.write_depth_png_mm(p, a)
        else:
            depth_files.write_disparity(p, a)

    def read(p):
        if name.startswith("gt"):
            return ground_truth.read_gt_depth(p)
        if name.endswith(".png"):
            return depth_files.read_depth_png_mm(p)
        return depth_files.read_disparity(p)

    old = np.full((4, 5), 2.0, np.float32)
    target = tmp_path / name
    write(target, old)
    assert np.array_equal(read(target), old)

    def broken(*args, **kwargs):
        # Write half of a file under whatever (temporary) name the writer chose, then fail.
        Path(args[0]).write_bytes(b"half")
        raise OSError("disk went away")

    monkeypatch.setattr(np, "save", broken)
    monkeypatch.setattr(depth_files.cv2, "imwrite", broken)
    real_fdopen = os.fdopen

    class HalfFile:
        """The PFM writer's file: the header goes out, then the disk fails."""

        def __init__(self, fh):
            self.fh, self.writes = fh, 0

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, data):
            self.writes += 1
            if self.writes > 1:
                raise OSError("disk went away")
            return self.fh.write(data)

        def __getattr__(self, attr):
            return getattr(self.fh, attr)

    monkeypatch.setattr(os, "fdopen", lambda fd, *a, **k: HalfFile(real_fdopen(fd, *a, **k)))
    import tifffile

    monkeypatch.setattr(tifffile, "imwrite", broken)
    with pytest.raises(Exception, match="disk went away"):
        write(target, np.zeros((4, 5), np.float32))
    monkeypatch.undo()
    assert np.array_equal(read(target), old)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
