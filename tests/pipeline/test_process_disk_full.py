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
