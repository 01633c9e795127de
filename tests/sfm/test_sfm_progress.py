"""SfM reports progress through feature extraction and matching, not only mapping."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2

from sea3d.sfm import SfmConfig, SfmFrame, run_sfm
from sea3d.sfm.colmap import _count_rows, _sequential_pairs


def test_sequential_pair_count_matches_colmaps_rule() -> None:
    # overlap 2 over 5 frames: (i, i+1), (i, i+2) and the quadratic i + 1, i + 2: 4 + 3 pairs
    assert _sequential_pairs(5, 2) == 7
    assert _sequential_pairs(1, 10) == 0


def test_a_progress_poll_leaves_colmaps_wal_index_alone_and_sees_its_rows(tmp_path: Path) -> None:
    """COLMAP (its own SQLite, inside pycolmap) keeps its database in WAL mode with the -shm
    file mapped. A poll through Python's sqlite3, another copy of SQLite in the same process,
    must not rewrite that file (a reset of it under COLMAP's mapping is a SIGBUS when COLMAP
    touches it before it grows again), and must count the rows COLMAP has written so far."""
    import pycolmap

    path = tmp_path / "database.db"
    db = pycolmap.Database.open(str(path))
    try:
        camera = pycolmap.Camera(model="PINHOLE", width=32, height=24,
                                 params=[30.0, 30.0, 16.0, 12.0])
        db.write_camera(camera)
        shm = Path(f"{path}-shm")
        assert shm.is_file()  # the WAL index COLMAP maps
        for expected in (1, 2, 3):
            before = (shm.stat().st_mtime_ns, shm.stat().st_size, shm.read_bytes())
            assert _count_rows(path, "SELECT COUNT(*) FROM cameras") == expected
            assert (shm.stat().st_mtime_ns, shm.stat().st_size, shm.read_bytes()) == before
            db.write_camera(camera)
    finally:
        db.close()
    assert _count_rows(tmp_path / "missing.db", "SELECT COUNT(*) FROM cameras") is None


def test_extract_and_match_report_progress_to_the_end(
    orbit_session: Callable[..., Path], tmp_path: Path
) -> None:
    session = orbit_session()
    paths = sorted((session / "left").glob("*.png"))
    frames = [SfmFrame(name=f"{i:03d}", t_s=float(i), left=cv2.imread(str(p)), source=str(p))
              for i, p in enumerate(paths)]
    calls: list[tuple[str, int, int]] = []
    run_sfm(frames, SfmConfig(camera="left", matcher="exhaustive"), workdir=tmp_path / "w",
            progress=lambda stage, done, total: calls.append((stage, done, total)))
    stages = [c[0] for c in calls]
    for stage, total in (("extract", len(paths)), ("match", len(paths) * (len(paths) - 1) // 2)):
        mine = [c for c in calls if c[0] == stage]
        assert mine, f"no {stage} progress in {sorted(set(stages))}"
        assert mine[0][1] == 0 and mine[-1][1:] == (total, total)
        assert all(0 <= d <= t for _, d, t in mine)
    # stages come in pipeline order
    firsts = [stages.index(s) for s in ("prepare", "extract", "match", "map")]
    assert firsts == sorted(firsts)
