"""Full disks, a reserve, a read-only disk: one clear line, honest counts, nothing lost.

The disk is a small tmpfs mounted for the test (CI runs as root). Where mounting is refused,
the MCAP drill falls back to ``RLIMIT_FSIZE`` in a child process (writes past the limit fail
with EFBIG, as a full disk fails with ENOSPC) and the other drills skip, saying why.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from sea3d.cli import main
from sea3d.io.session import SessionWriter, open_session

SRC = str(Path(__file__).resolve().parents[2] / "src")
FRAME_NS = 33_333_333
DISK_KIB = 2048  # the frames below are about 58 kB each as PNG: ~35 fit


@contextlib.contextmanager
def small_disk(where: Path, size_kib: int, *, read_only: bool = False) -> Iterator[Path | None]:
    """A tmpfs of ``size_kib`` mounted at ``where``, or None if this machine refuses mounts."""
    where.mkdir(parents=True, exist_ok=True)
    opts = f"size={size_kib}k" + (",ro" if read_only else "")
    if shutil.which("mount") is None:
        yield None
        return
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(where)], capture_output=True
    )
    if done.returncode != 0:
        yield None
        return
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def _source(tmp_path: Path, n: int = 80) -> Path:
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8) for _ in range(4)]
    path = tmp_path / "src.mcap"
    with SessionWriter(path) as w:
        for i in range(n):
            w.write_stereo(i * FRAME_NS, imgs[i % 4], imgs[(i + 1) % 4])
            w.write_imu(i * FRAME_NS, [0.0, 0.0, 9.81], [0.0, 0.0, 0.1])
    return path


def _record_args(src: Path, out: Path, *extra: str) -> list[str]:
    return [
        "record",
        "--left",
        f"session:{src}",
        "--right",
        f"session:{src}",
        "--imu",
        f"session:{src}",
        "--out",
        str(out),
        "--image-encoding",
        "png",
        "--replay-speed",
        "0",
        "--block",
        *extra,
    ]


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("sea3d: error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _readable(out: Path) -> dict[str, int]:
    with open_session(out) as s:
        counts = {}
        for stream in ("left", "right"):
            ok = 0
            for i in range(s.stamps(stream).size):
                s.image(stream, i, by="index")
                ok += 1
            counts[stream] = ok
        counts["imu"] = len(s.imu())
        return counts


@pytest.mark.slow
@pytest.mark.parametrize("name", ["full.mcap", "full_dir"])
def test_recording_until_the_disk_is_full_reports_what_a_reader_finds(tmp_path, capsys, name):
    src = _source(tmp_path)
    with small_disk(tmp_path / "disk", DISK_KIB) as disk:
        if disk is None:
            pytest.skip("this machine refuses mounts (see the RLIMIT_FSIZE drill)")
        out = disk / name
        status = main([*_record_args(src, out, "--min-free-gb", "0"), "--json"])
        captured = capsys.readouterr()
        assert status == 1 and "Traceback" not in captured.err
        import json

        summary = json.loads(captured.out)
        assert "the disk is full" in summary["stop_reason"]  # seen before ENOSPC
        assert "kept" in summary["stop_reason"]  # says what is on disk
        got = _readable(out)
        for stream in ("left", "right", "imu"):
            assert got[stream] == summary["frames"][stream] > 0, stream  # honest counts
        assert summary["frames"]["left"] < 80
        if name.endswith(".mcap"):
            from mcap.reader import make_reader

            with open(out, "rb") as f:
                stats = make_reader(f).get_summary()
            if stats is not None and stats.statistics is not None:  # a summary, if any, agrees
                counts = stats.statistics.channel_message_counts
                topics = {c.topic: cid for cid, c in stats.channels.items()}
                assert counts[topics["/cam/left/image"]] == got["left"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["x.mcap", "x_dir"])
def test_record_and_convert_onto_an_already_full_disk_end_in_one_line(tmp_path, capsys, name):
    src = _source(tmp_path, n=4)
    with small_disk(tmp_path / "disk", 512) as disk:
        if disk is None:
            pytest.skip("this machine refuses mounts")
        with open(disk / "filler", "wb") as f, contextlib.suppress(OSError):
            while True:
                f.write(b"\0" * 65536)
                f.flush()
        assert main([*_record_args(src, disk / name, "--min-free-gb", "0")]) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert ("No space left on device" in line or "the disk is full" in line) and name in line
        assert not (disk / name).exists()  # nothing half-made is left in the way
        assert main(["session", "convert", str(src), str(disk / f"c_{name}")]) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert "No space left on device" in line or "the disk is full" in line


@pytest.mark.slow
def test_the_reserve_is_never_overshot(tmp_path, capsys):
    src = _source(tmp_path)
    reserve_bytes = 1_000_000
    with small_disk(tmp_path / "disk", 4096) as disk:
        if disk is None:
            pytest.skip("this machine refuses mounts")
        out = disk / "r.mcap"
        status = main(_record_args(src, out, "--min-free-gb", str(reserve_bytes / 1e9)))
        text = capsys.readouterr()
        assert status == 1 and "Traceback" not in text.err
        assert "reserve" in text.out
        free = shutil.disk_usage(disk).free
        assert free >= reserve_bytes, f"{free} bytes free, under the {reserve_bytes} reserve"
        with open_session(out) as s:
            assert s.complete  # the summary fitted above the reserve too
            assert 0 < s.stamps("left").size < 80


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ro.mcap", "ro_dir"])
def test_a_read_only_disk_ends_in_one_line(tmp_path, capsys, name):
    src = _source(tmp_path, n=2)
    with small_disk(tmp_path / "disk", 512, read_only=True) as disk:
        if disk is None:
            pytest.skip("this machine refuses mounts")
        assert main([*_record_args(src, disk / name, "--min-free-gb", "0")]) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert "Read-only file system" in line and name in line


_LIMITED_CHILD = textwrap.dedent(
    """
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # a write past the limit fails with EFBIG
    limit = int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    from sea3d.cli import main
    sys.exit(main(sys.argv[2:]))
    """
)


@pytest.mark.slow
def test_a_file_size_limit_stands_in_for_a_full_disk_where_mounts_are_refused(tmp_path):
    # Runs everywhere, also where the tmpfs drills skip.
    src = _source(tmp_path)
    out = tmp_path / "limited.mcap"
    env = dict(os.environ, PYTHONPATH=SRC)
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            _LIMITED_CHILD,
            str(1_500_000),
            *_record_args(src, out, "--min-free-gb", "0"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert "File too large" in done.stdout
    written = int(re.search(r"^\s+left\s+(\d+) written", done.stdout, re.M).group(1))  # type: ignore[union-attr]
    assert _readable(out)["left"] == written > 0
