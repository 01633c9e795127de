"""The output disk fills during a run: ``sea3d process`` stops with one line, keeps what it
wrote, and a later run resumes from there."""

from __future__ import annotations

import errno
import json

from sea3d.cli import main
from sea3d.io import result_cache

FRAMES = 6
WRITES_BEFORE_FULL = 3


def test_disk_full_stops_with_one_line_and_the_rerun_resumes(sim_session, tmp_path, capsys,
                                                             monkeypatch):
    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    argv = ["process", str(sim_session), "-o", str(tmp_path / "out"), "--poses", str(gt),
            "--workers", "0", "--max-frames", str(FRAMES), "--no-report", "--json"]
    real_write = result_cache.atomic_write
    calls = {"n": 0}

    def filling_write(path, data, *args, **kwargs):  # the cache's writes
        if str(path).endswith(".s3c"):  # frame entries (config.json is written first)
            calls["n"] += 1
        if calls["n"] > WRITES_BEFORE_FULL:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_write(path, data, *args, **kwargs)

    monkeypatch.setattr(result_cache, "atomic_write", filling_write)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("sea3d: error:") and err.count("\n") == 1
    assert "No space left on device" in err and "cache" in err
    frames = tmp_path / "out" / "cache" / "frames"
    assert len(list(frames.glob("*.s3c"))) == WRITES_BEFORE_FULL
    assert not list(frames.glob(".*tmp*"))  # no half-written entry left behind

    monkeypatch.undo()
    assert main(argv) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["frames"] == FRAMES and s["frames_from_cache"] == WRITES_BEFORE_FULL


def _full_for(name: str, monkeypatch) -> None:
    """The disk fills while ``name`` is written by the mesh and cloud writer."""
    import contextlib

    from sea3d.io import _atomic, mesh_files

    real = _atomic.atomic_open

    @contextlib.contextmanager
    def atomic_open(path, mode="w", **kw):
        with real(path, mode, **kw) as fh:
            if str(path).endswith(name):
                raw_write = fh.write

                def write(data):
                    raw_write(data[: len(data) // 2])  # part of it lands, as on a real disk
                    raise OSError(errno.ENOSPC, "No space left on device", str(path))

                fh.write = write
            yield fh

    monkeypatch.setattr(mesh_files, "atomic_open", atomic_open)


def test_disk_full_at_the_ground_truth_frame_mesh_is_one_line_and_no_cut_file(
        sim_session, tmp_path, capsys, monkeypatch):
    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    out = tmp_path / "out"
    out.mkdir()
    stale = out / ".mesh.4194999-0123abcd.tmp.ply"  # above Linux's largest pid: long dead
    stale.write_bytes(b"ply\nhalf of a mesh a killed run was writing")
    _full_for("mesh_gt_frame.ply", monkeypatch)
    assert main(["process", str(sim_session), "-o", str(out), "--poses", str(gt),
                 "--workers", "0", "--max-frames", str(FRAMES), "--no-report"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sea3d: error: cannot write mesh ") and err.count("\n") == 1, err
    assert "mesh_gt_frame.ply: [Errno 28] No space left on device" in err
    assert not (out / "mesh_gt_frame.ply").exists()
    assert not stale.exists()  # cleared at the start of the run
    assert not [p.name for p in out.iterdir() if ".tmp" in p.name]


def test_live_disk_full_at_the_cloud_is_one_line_and_no_cut_file(sim_session, tmp_path,
                                                                  capsys, monkeypatch):
    gt = sim_session.with_name(sim_session.stem + "_gt") / "poses_left.tum"
    out = tmp_path / "live"
    _full_for("cloud.ply", monkeypatch)
    assert main(["live", "--replay", str(sim_session), "-o", str(out), "--poses", str(gt),
                 "--max-frames", str(FRAMES), "--rate", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sea3d: error: cannot write point cloud ") and err.count("\n") == 1
    assert (out / "mesh.ply").is_file() and not (out / "cloud.ply").exists()
    assert not [p.name for p in out.iterdir() if ".tmp" in p.name]
