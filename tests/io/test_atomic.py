"""The one atomic write (issue 18 item 6): all or nothing, one temporary-name convention."""

from __future__ import annotations

import os
import stat

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
