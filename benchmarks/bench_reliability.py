"""Reliability drills, counted: the figures of docs/reliability.md.

For each drill, the cases tried and what came of them: a clear error (a ``Sea3dError``, one
line), a traceback (any other exception: must be zero), a silently wrong value (must be zero)
and data lost beyond what the damage can explain (must be zero: nothing beyond the damaged
or open chunk). The tests in ``tests/io/test_session_drills.py``, ``tests/io/test_rig_drills.py``
and ``tests/capture/test_disk_drills.py`` assert the same properties on fewer cases.

Drills: cuts of an MCAP file at every byte of a range and every record boundary; single and
multiple bit flips; damaged files of a folder session; mangled rig values and YAML text; cut
images; the recorder killed with SIGKILL at random moments; a full disk (tmpfs, else
RLIMIT_FSIZE); 200 concurrent clients on the monitor, next to the old listen backlog of 5.

Usage::

    nice python benchmarks/bench_reliability.py            # about 5 minutes on 2 busy cores
    nice python benchmarks/bench_reliability.py --quick    # fewer cases
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import logging
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.errors import RigFileError, Sea3dError, SessionError
from sea3d.io.rig_file import (
    check_rig_physics,
    rig_from_dict,
    rig_from_yaml,
    rig_to_dict,
    rig_to_yaml,
)
from sea3d.io.session import SessionWriter, convert_session, open_session, verify_session
from sea3d.io.session.common import decode_image, encode_image
from sea3d.refraction.presets import paper_rig

FRAME_NS = 33_333_333
N_PAIRS = 6
RIG_YAML = rig_to_yaml(paper_rig("dome"))
SRC = str(Path(__file__).resolve().parents[1] / "src")


# What came of one damaged session, seen from the readers and from verify.
CLASSES = ("silently wrong", "clear error", "recovered", "unaffected", "hang", "traceback")
HANG_S = 30.0  # one case (read, verify, convert) longer than this counts as a hang


class Tally:
    def __init__(self, name: str) -> None:
        self.name = name
        self.cases = self.clear = self.tracebacks = self.wrong = self.lost = self.detected = 0
        self.examples: list[str] = []
        self.classes = dict.fromkeys(CLASSES, 0)

    def classify(
        self, got: dict[str, Any] | None, ok: bool | None, seconds: float, error: str = ""
    ) -> None:
        """Count one case in one class.

        silently wrong: a value handed out that was never written, or records missing while
        verify says OK; clear error: nothing handed out, a one-line sea3d error; recovered:
        the intact part handed out, right, and the damage reported; unaffected: everything
        read back and verify OK (damage in bytes nothing depends on); hang: over HANG_S s;
        traceback: any other exception.
        """
        if error:
            kind = "traceback"
        elif seconds > HANG_S:
            kind = "hang"
        elif got is None or got.get("open_error"):
            kind = "clear error"
        elif wrong_values(got) or got.get("convert_wrong"):
            kind = "silently wrong"
        else:
            missing = any(lost_records(got).values()) or got["rig"] is None
            if ok and missing:
                kind = "silently wrong"
            elif ok:
                kind = "unaffected"
            else:
                kind = "recovered"
        self.classes[kind] += 1

    def row(self, detect: bool = False) -> str:
        det = f"{self.detected}/{self.cases}" if detect else "-"
        return (
            f"{self.name:<46}{self.cases:>7}{self.clear:>8}{self.tracebacks:>11}{self.wrong:>7}"
            f"{self.lost:>7}{det:>12}"
        )


def _frame(i: int) -> np.ndarray:
    return np.random.default_rng(i).integers(0, 256, size=(10, 14, 3), dtype=np.uint8)


TRUTH: dict[str, dict[int, Any]] = {"left": {}, "right": {}, "imu": {}, "sonar": {}}
for _i in range(N_PAIRS):
    _t = _i * FRAME_NS
    TRUTH["left"][_t] = _frame(_i)
    TRUTH["right"][_t] = _frame(100 + _i)
    for _j in range(3):
        TRUTH["imu"][_t + _j * 1000] = (np.array([_i, _j, 9.81]), np.array([0.1 * _i, 0.0, _j]))
    TRUTH["sonar"][_t + 7] = (np.float32(1.5 + _i), np.float32(0.5))


def write_session(path: Path, fmt: str) -> None:
    with SessionWriter(path, format=fmt, rig_yaml=RIG_YAML, chunk_size=2000) as w:
        for i in range(N_PAIRS):
            t = i * FRAME_NS
            w.write_stereo(t, TRUTH["left"][t], TRUTH["right"][t])
            for j in range(3):
                w.write_imu(t + j * 1000, *TRUTH["imu"][t + j * 1000])
            w.write_sonar(t + 7, *TRUTH["sonar"][t + 7])


def read_everything(path: Path) -> dict[str, Any]:
    got: dict[str, Any] = {"left": {}, "right": {}, "imu": {}, "sonar": {}, "rig": None}
    try:
        s = open_session(path)
    except SessionError:
        got["open_error"] = True
        return got
    with s:
        for stream in ("left", "right"):
            for i, t in enumerate(s.stamps(stream).tolist()):
                with contextlib.suppress(SessionError):
                    got[stream][t] = s.image(stream, i, by="index")
        imu = s.imu()
        for k, t in enumerate(imu.t_ns.tolist()):
            got["imu"][t] = (imu.accel_mps2[k], imu.gyro_radps[k])
        sonar = s.sonar()
        for k, t in enumerate(sonar.t_ns.tolist()):
            got["sonar"][t] = (sonar.range_m[k], sonar.confidence[k])
        try:
            got["rig"] = s.rig_yaml
        except SessionError:
            got["rig"] = None
    return got


def wrong_values(got: dict[str, Any]) -> bool:
    for stream in ("left", "right"):
        for t, img in got[stream].items():
            if t not in TRUTH[stream] or not np.array_equal(img, TRUTH[stream][t]):
                return True
    for stream in ("imu", "sonar"):
        for t, vals in got[stream].items():
            if t not in TRUTH[stream]:
                return True
            for k, (a, b) in enumerate(zip(vals, TRUTH[stream][t], strict=True)):
                if stream == "sonar" and k == 1 and np.isnan(a):
                    continue  # confidence unknown (its own record was lost): NaN, documented
                if not np.array_equal(np.float32(a), np.float32(b)):
                    return True
    return got["rig"] not in (None, RIG_YAML)


def chunk_regions(data: bytes) -> list[tuple[int, int, dict[str, set[int]]]]:
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import MessageIndex

    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    names = {"/cam/left/image": "left", "/cam/right/image": "right", "/imu": "imu"}
    names["/sonar"] = "sonar"
    out = []
    for ci in summary.chunk_indexes:
        stamps: dict[str, set[int]] = {}
        for cid, off in ci.message_index_offsets.items():
            stream = names.get(summary.channels[cid].topic)
            if stream is not None:
                (length,) = struct.unpack_from("<Q", data, off + 1)
                mi = MessageIndex.read(ReadDataStream(io.BytesIO(data[off + 9 : off + 9 + length])))
                stamps[stream] = {t for t, _ in mi.records}
        out.append(
            (
                ci.chunk_start_offset,
                ci.chunk_start_offset + ci.chunk_length + ci.message_index_length,
                stamps,
            )
        )
    return out


def lost_records(got: dict[str, Any]) -> dict[str, set[int]]:
    return {s: set(TRUTH[s]) - set(got[s]) for s in ("left", "right", "imu", "sonar")}


def verified(path: Path) -> bool:
    try:
        return bool(verify_session(path)["ok"])
    except SessionError:
        return False


# --------------------------------------------------------------------------- MCAP drills
def drill_cuts(data: bytes, scratch: Path, step: int) -> Tally:
    tally = Tally("MCAP cut at a byte (every record boundary +-1)")
    regions = chunk_regions(data)
    bounds, pos = [8], 8
    while pos + 9 <= len(data):
        pos += 9 + struct.unpack_from("<BQ", data, pos)[1]
        bounds.append(pos)
    cuts = sorted({b + d for b in bounds for d in (-1, 0, 1)} | set(range(1, len(data), step)))
    path = scratch / "cut.mcap"
    for cut in cuts:
        if not 0 < cut < len(data):
            continue
        tally.cases += 1
        path.write_bytes(data[:cut])
        t0 = time.monotonic()
        try:
            got = read_everything(path)
            if got.get("open_error"):
                tally.clear += 1
            if wrong_values(got):
                tally.wrong += 1
            missing = lost_records(got)
            for _start, end, stamps in regions:
                if end <= cut and any(ts & missing[s] for s, ts in stamps.items()):
                    tally.lost += 1
                    break
            ok = verified(path)
            tally.detected += not ok
            tally.classify(got, ok, time.monotonic() - t0)
        except Sea3dError:
            tally.clear += 1
            tally.classify(None, None, time.monotonic() - t0)
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"cut {cut}: {type(err).__name__}: {err}")
            tally.classify(None, None, 0.0, error=str(err))
    return tally


def _flip(data: bytes, bits: list[int]) -> bytes:
    buf = bytearray(data)
    for bit in bits:
        buf[bit // 8] ^= 1 << (bit % 8)
    return bytes(buf)


def drill_flips(
    data: bytes, scratch: Path, n: int, per_case: int, rng: np.random.Generator
) -> Tally:
    tally = Tally(f"MCAP with {per_case} random bit flip{'s' if per_case > 1 else ''}")
    regions = chunk_regions(data)
    path = scratch / "flip.mcap"
    for _ in range(n):
        bits = rng.integers(0, len(data) * 8, size=per_case).tolist()
        tally.cases += 1
        path.write_bytes(_flip(data, bits))
        t0 = time.monotonic()
        try:
            got = read_everything(path)
            if got.get("open_error"):
                tally.clear += 1
            if wrong_values(got):
                tally.wrong += 1
                tally.examples.append(f"bits {bits}: wrong value")
            if per_case == 1:
                at = bits[0] // 8
                allowed = {s: set() for s in TRUTH}
                for start, end, stamps in regions:
                    if start <= at < end:
                        allowed = {s: stamps.get(s, set()) for s in TRUTH}
                if any(not ts <= allowed[s] for s, ts in lost_records(got).items()):
                    tally.lost += 1
                    tally.examples.append(f"bit {bits[0]}: lost more than its chunk")
            ok = verified(path)
            tally.detected += not ok
            out = scratch / "flip_copy"
            try:
                convert_session(path, out)
                if wrong_values(read_everything(out)):
                    tally.wrong += 1
                    tally.examples.append(f"bits {bits}: convert copied a wrong value")
                    got["convert_wrong"] = True
            except SessionError:
                pass
            finally:
                shutil.rmtree(out, ignore_errors=True)
            tally.classify(got, ok, time.monotonic() - t0)
        except Sea3dError:
            tally.clear += 1
            tally.classify(None, None, time.monotonic() - t0)
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"bits {bits}: {type(err).__name__}: {err}")
            tally.classify(None, None, 0.0, error=str(err))
    return tally


FOLDER_DAMAGE = ("flip", "cut", "delete", "rename", "delete line", "edit line")


def damage_folder(path: Path, rng: np.random.Generator) -> list[str]:
    """One to three damages anywhere in a folder session: a flipped bit or a cut in any file
    (session.json, rig.yaml and checksums.csv included), a deleted or renamed image, a
    deleted or edited line of a CSV, the rig or checksums.csv."""
    done = []
    for _ in range(int(rng.integers(1, 4))):
        kind = FOLDER_DAMAGE[int(rng.integers(len(FOLDER_DAMAGE)))]
        files = sorted(p for p in path.rglob("*") if p.is_file())
        images = [p for p in files if p.parent.name in ("left", "right")]
        texts = [p for p in files if p.suffix in (".csv", ".yaml")]
        pool = images if kind in ("delete", "rename") else texts if "line" in kind else files
        if not pool:
            continue
        victim = pool[int(rng.integers(len(pool)))]
        done.append(f"{kind} {victim.relative_to(path)}")
        if kind == "delete":
            victim.unlink()
            continue
        if kind == "rename":
            stamp = int(victim.stem) + int(rng.integers(1, 3 * FRAME_NS))
            os.replace(victim, victim.with_name(f"{stamp}{victim.suffix}"))
            continue
        raw = bytearray(victim.read_bytes())
        if not raw:
            continue
        if kind == "flip":
            bit = int(rng.integers(len(raw) * 8))
            raw[bit // 8] ^= 1 << (bit % 8)
        elif kind == "cut":
            del raw[int(rng.integers(len(raw))) :]
        else:
            lines = bytes(raw).splitlines(keepends=True)
            k = int(rng.integers(len(lines)))
            if kind == "delete line":
                del lines[k]
            else:
                line = bytearray(lines[k])
                digits = [i for i, c in enumerate(line) if chr(c).isdigit()]
                if not digits:
                    continue
                i = digits[int(rng.integers(len(digits)))]
                line[i] = ord("0") + (line[i] - ord("0") + 1) % 10
                lines[k] = bytes(line)
            raw = bytearray(b"".join(lines))
        victim.write_bytes(bytes(raw))
    return done


def drill_folder(scratch: Path, n: int, rng: np.random.Generator) -> Tally:
    tally = Tally("folder session, damage in any file")
    base = scratch / "folder_base"
    write_session(base, "folder")
    for _ in range(n):
        path = scratch / "folder"
        shutil.rmtree(path, ignore_errors=True)
        shutil.copytree(base, path)
        tally.cases += 1
        done = damage_folder(path, rng)
        t0 = time.monotonic()
        try:
            got = read_everything(path)
            if got.get("open_error"):
                tally.clear += 1
            if wrong_values(got):
                tally.wrong += 1
                tally.examples.append(f"{done}: wrong value")
            ok = verified(path)
            tally.detected += not ok
            out = scratch / "folder_copy.mcap"
            try:
                convert_session(path, out)
                if wrong_values(read_everything(out)):
                    tally.wrong += 1
                    tally.examples.append(f"{done}: convert copied a wrong value")
                    got["convert_wrong"] = True
            except SessionError:
                pass
            finally:
                with contextlib.suppress(OSError):
                    out.unlink()
            tally.classify(got, ok, time.monotonic() - t0)
        except Sea3dError:
            tally.clear += 1
            tally.classify(None, None, time.monotonic() - t0)
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"{done}: {type(err).__name__}: {err}")
            tally.classify(None, None, 0.0, error=str(err))
    return tally


# --------------------------------------------------------------------------- rigs and images
_NASTY = [
    0,
    -1,
    1e308,
    -1e308,
    float("nan"),
    float("inf"),
    2**64,
    -(2**70),
    True,
    None,
    "",
    [],
    "x" * 9,
    [1e308] * 3,
    {"a": 1},
]


def drill_rig_values() -> Tally:
    tally = Tally("rig value replaced (every key x 15 values)")
    good = rig_to_dict(paper_rig("dome"))

    def leaves(d: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
        if isinstance(d, dict):
            return [p for k, v in d.items() for p in leaves(v, (*prefix, k))]
        return [prefix]

    for key in leaves(good):
        for value in _NASTY:
            data = copy.deepcopy(good)
            node = data
            for k in key[:-1]:
                node = node[k]
            node[key[-1]] = value
            tally.cases += 1
            try:
                rig = rig_from_dict(data, "rig.yaml")
                check_rig_physics(rig, "rig.yaml")
            except RigFileError as err:
                tally.clear += 1
                if len(str(err)) > 1000 or "\n" in str(err):
                    tally.examples.append(f"long message for {key}={value!r}")
            except Exception as err:
                tally.tracebacks += 1
                tally.examples.append(f"{key}={value!r}: {type(err).__name__}: {err}")
    return tally


def drill_rig_text(n: int, rng: np.random.Generator) -> Tally:
    from sea3d.io.rig_file import decode_rig_bytes

    tally = Tally("rig YAML text flipped, cut, spliced")
    base = RIG_YAML.encode()
    inserts = [b"&a ", b"*a", b"[", b"{", b": ", b"\x00", b"!!python/object:os.system ", b"\t"]
    for _ in range(n):
        raw = bytearray(base)
        for _k in range(int(rng.integers(1, 6))):
            pos = int(rng.integers(max(len(raw), 1)))
            kind = int(rng.integers(4))
            if kind == 0 and raw:
                raw[min(pos, len(raw) - 1)] ^= 1 << int(rng.integers(8))
            elif kind == 1:
                del raw[pos:]
            elif kind == 2:
                raw[pos:pos] = inserts[int(rng.integers(len(inserts)))]
            else:
                del raw[pos : pos + int(rng.integers(1, 20))]
        tally.cases += 1
        try:
            rig = rig_from_yaml(decode_rig_bytes(bytes(raw), "rig.yaml"), "rig.yaml")
            check_rig_physics(rig, "rig.yaml")
        except RigFileError:
            tally.clear += 1
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"{type(err).__name__}: {err}")
    # The cases, by name.
    bomb = 'a: &a ["x","x","x","x","x","x","x","x","x"]\n'
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        bomb += f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]\n"
    for text in (bomb, "a: &a [*a]\n", RIG_YAML.encode("utf-16-le"), RIG_YAML.encode("utf-16")):
        tally.cases += 1
        try:
            raw_text = text if isinstance(text, str) else decode_rig_bytes(text, "rig.yaml")
            rig_from_yaml(raw_text, "rig.yaml")
        except RigFileError:
            tally.clear += 1
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"{type(err).__name__}: {err}")
    return tally


def drill_images(n: int, rng: np.random.Generator) -> Tally:
    tally = Tally("image cut at a random byte (PNG, JPEG, JPEG XL)")
    img = rng.integers(0, 256, size=(40, 56, 3), dtype=np.uint8)
    for enc in ("png", "jpeg", "jxl"):
        data = encode_image(img, enc)
        for _ in range(n):
            cut = int(rng.integers(0, len(data)))
            tally.cases += 1
            try:
                decode_image(data[:cut], "frame")
                tally.wrong += 1  # a cut image must never decode
            except SessionError:
                tally.clear += 1
            except Exception as err:
                tally.tracebacks += 1
                tally.examples.append(f"{enc} cut {cut}: {type(err).__name__}: {err}")
    return tally


# --------------------------------------------------------------------------- processes
_KILLED = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from sea3d.capture.recorder import Recorder, RecorderConfig
    from sea3d.capture.sources import ArraySource
    from pathlib import Path
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(60, 80, 3), dtype=np.uint8) for _ in range(4)]
    cfg = RecorderConfig(out_path=Path(sys.argv[1]), min_free_bytes=0)
    src = {"left": ArraySource(imgs, rate_hz=30.0), "right": ArraySource(imgs, rate_hz=30.0)}
    rec = Recorder(cfg, src)
    import threading
    def report():
        while True:
            time.sleep(0.05)
            s = rec.stats()
            print(s["frames"]["left"], s["captured"]["left"], flush=True)
    threading.Thread(target=report, daemon=True).start()
    rec.run()
    """
)


def drill_sigkill(scratch: Path, n: int, rng: np.random.Generator) -> tuple[Tally, float]:
    """Kills; returns the tally and the most seconds of frames lost (captured, not on disk)."""
    tally = Tally("recorder killed with SIGKILL at a random moment")
    env = dict(os.environ, PYTHONPATH=SRC)
    worst_s = 0.0
    for k in range(n):
        out = scratch / f"killed_{k}.mcap"
        proc = subprocess.Popen(
            [sys.executable, "-c", _KILLED, str(out)], stdout=subprocess.PIPE, text=True, env=env
        )
        assert proc.stdout is not None
        deadline = time.monotonic() + 1.0 + 3.0 * float(rng.random())
        reported = captured = 0
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            reported, captured = (int(v) for v in line.split())
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        tally.cases += 1
        try:
            readable = len(read_everything(out)["left"])
            if readable < reported:
                tally.lost += 1  # the recorder had reported them as written
            worst_s = max(worst_s, (captured - readable) / 30.0)
        except Exception as err:
            tally.tracebacks += 1
            tally.examples.append(f"{type(err).__name__}: {err}")
        out.unlink(missing_ok=True)
    return tally, worst_s


@contextlib.contextmanager
def small_disk(where: Path, size_kib: int):
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_kib}k", "tmpfs", str(where)],
        capture_output=True,
    )
    if done.returncode != 0:
        yield None
        return
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def drill_disk(scratch: Path) -> list[str]:
    from sea3d.cli import main

    lines = []
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, size=(120, 160, 3), dtype=np.uint8) for _ in range(4)]
    src = scratch / "disk_src.mcap"
    with SessionWriter(src) as w:
        for i in range(80):
            w.write_stereo(i * FRAME_NS, imgs[i % 4], imgs[(i + 1) % 4])
    args = ["record", "--left", f"session:{src}", "--right", f"session:{src}", "--image-encoding",
            "png", "--replay-speed", "0", "--block", "--json"]  # fmt: skip
    with small_disk(scratch / "disk", 2048) as disk:
        how = "tmpfs of 2 MiB" if disk is not None else "none (mounts refused)"
        lines.append(f"  small disk: {how}")
        if disk is None:
            return lines
        import json as _json

        for name in ("full.mcap", "full_dir"):
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
                status = main([*args, "--out", str(disk / name), "--min-free-gb", "0"])
            summary = _json.loads(buf.getvalue())
            got = read_everything(disk / name)
            (shutil.rmtree if (disk / name).is_dir() else os.unlink)(disk / name)
            lines.append(
                f"  record until full ({name}): exit {status}; summary says "
                f"{summary['frames']['left']} left frames, a reader finds {len(got['left'])}; "
                "stop reason: "
                f"{summary['stop_reason'][:90]}..."
            )
        for entry in disk.iterdir():
            shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
        reserve = 1_000_000
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            main([*args, "--out", str(disk / "r.mcap"), "--min-free-gb", str(reserve / 1e9)])
        free = shutil.disk_usage(disk).free
        lines.append(
            f"  reserve of {reserve} bytes: {free} bytes free at the end, overshoot "
            f"{max(reserve - free, 0)} bytes"
        )
        with open(disk / "filler", "wb") as f, contextlib.suppress(OSError):
            while True:
                f.write(b"\0" * 65536)
                f.flush()
        for argv in (
            [*args, "--out", str(disk / "x.mcap"), "--min-free-gb", "0"],
            ["session", "convert", str(src), str(disk / "c_dir")],
        ):
            err = io.StringIO()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                status = main(argv)
            text = err.getvalue().strip().splitlines()
            lines.append(
                f"  {argv[0]} onto a full disk: exit {status}, {len(text)} line: {text[-1][:110]}"
            )
    return lines


# --------------------------------------------------------------------------- monitor
_CROWD = textwrap.dedent(
    """
    import asyncio, json, sys, time
    host, port, clients, per = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    paths = ["/stats.json", "/frame/left.jpg", "/frame/disparity.jpg"]
    async def one(path):
        t0 = time.perf_counter()
        try:
            r, w = await asyncio.wait_for(asyncio.open_connection(host, port), 30)
            w.write(f"GET {path} HTTP/1.0\\r\\nHost: x\\r\\n\\r\\n".encode())
            await w.drain()
            data = await asyncio.wait_for(r.read(), 30)
            w.close()
            ok = data.startswith(b"HTTP/1.0 200") or data.startswith(b"HTTP/1.1 200")
        except Exception:
            ok = False
        return (ok, time.perf_counter() - t0)
    async def client(k):
        return [await one(paths[(k + i) % 3]) for i in range(per)]
    async def main():
        out = await asyncio.gather(*(client(k) for k in range(clients)))
        print(json.dumps([r for c in out for r in c]))
    asyncio.run(main())
    """
)


def drill_monitor(clients: int, per: int) -> list[str]:
    import json as _json
    import threading

    from sea3d.capture import monitor
    from sea3d.capture.sources import ImageFrame

    class Provider:
        def __init__(self) -> None:
            rng = np.random.default_rng(0)
            self.images = [rng.integers(0, 256, (360, 640, 3), dtype=np.uint8) for _ in range(4)]
            self.seq = 0
            self.stop = threading.Event()
            threading.Thread(target=self.run, daemon=True).start()

        def run(self) -> None:
            while not self.stop.wait(0.05):
                self.seq += 1

        def latest(self, stream: str) -> tuple[int, ImageFrame]:
            return self.seq, ImageFrame(self.seq, self.images[(self.seq + (stream == "right")) % 4])

        def stats(self) -> dict[str, Any]:
            return {"running": True, "frames": {"left": self.seq}}

    lines = []
    for backlog, label in ((monitor.LISTEN_BACKLOG, "sea3d"), (5, "old backlog 5 (reference)")):
        provider = Provider()
        old = monitor._CrowdServer.request_queue_size
        monitor._CrowdServer.request_queue_size = backlog
        try:
            server = monitor.MonitorServer(provider, "127.0.0.1", 0).start()  # loopback only
            import resource

            r0 = resource.getrusage(resource.RUSAGE_SELF)
            argv = [sys.executable, "-c", _CROWD, "127.0.0.1", str(server.port)]
            done = subprocess.run(
                [*argv, str(clients), str(per)], capture_output=True, text=True, timeout=300
            )
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            server.stop()
        finally:
            monitor._CrowdServer.request_queue_size = old
            provider.stop.set()
        results = _json.loads(done.stdout)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        lat = np.array([r[1] for r in results])
        failed = sum(1 for r in results if not r[0])
        lines.append(
            f"  {label:<28} backlog {backlog:>5}: {len(results)} requests, p50 "
            f"{np.percentile(lat, 50):.3f} s, p99 {np.percentile(lat, 99):.3f} s, max "
            f"{lat.max():.3f} s, {failed} failed; server CPU {cpu * 1e3 / len(results):.2f} "
            f"ms per request ({cpu / 2:.2f} s for all {len(results)} on two idle cores)"
        )
    return lines


def print_classes(cuts: Tally, flips: Tally, multi: Tally, folder: Tally) -> None:
    """The damaged sessions by class, MCAP and folder, beside the round-2 figures."""
    mcap = {k: cuts.classes[k] + flips.classes[k] + multi.classes[k] for k in CLASSES}
    n_mcap = cuts.cases + flips.cases + multi.cases
    print("damaged sessions by class (read by every reader, verified, converted):")
    print(f"{'':<16}" + "".join(f"{k:>16}" for k in CLASSES) + f"{'cases':>8}")
    print(f"{'MCAP':<16}" + "".join(f"{mcap[k]:>16}" for k in CLASSES) + f"{n_mcap:>8}")
    print(
        f"{'folder':<16}" + "".join(f"{folder.classes[k]:>16}" for k in CLASSES)
        + f"{folder.cases:>8}"
    )
    print(
        "round 2 (docs/reliability.md): 650 damaged MCAP sessions, all flagged by verify, no "
        "wrong value; 1,333 hostile runs, no traceback; folder sessions were checked only by "
        "verify (a renamed image was handed out at its new stamp)"
    )


def run_file_drills(scratch: Path, rng: np.random.Generator, q: int) -> None:
    path = scratch / "s.mcap"
    write_session(path, "mcap")
    data = path.read_bytes()
    print(f"session: {len(data)} bytes, {len(chunk_regions(data))} chunks, {N_PAIRS} pairs\n")
    header = (
        f"{'drill':<46}{'cases':>7}{'clear':>8}{'traceback':>11}{'wrong':>7}{'lost':>7}"
        f"{'verify saw':>12}"
    )
    print(header)
    print("-" * len(header))
    tallies = [
        (drill_cuts(data, scratch, step=13 * q), True),
        (drill_flips(data, scratch, 2000 // q, 1, rng), True),
        (drill_flips(data, scratch, 500 // q, 8, rng), True),
        (drill_folder(scratch, 300 // q, rng), True),
        (drill_rig_values(), False),
        (drill_rig_text(2000 // q, rng), False),
        (drill_images(300 // q, rng), False),
    ]
    killed, worst_s = drill_sigkill(scratch, max(20 // q, 3), rng)
    tallies.append((killed, False))
    examples = []
    for tally, detect in tallies:
        print(tally.row(detect))
        examples += [f"{tally.name}: {e}" for e in tally.examples[:3]]
    print(
        "(clear: the case ended in a one-line sea3d error somewhere; wrong: a value handed "
        "out that was never written; lost: records of intact chunks not read back (cuts, "
        "single flips) or frames the recorder had reported written (SIGKILL); verify saw: "
        "cases where session verify reported a problem)"
    )
    print(
        f"SIGKILL: at most {worst_s:.2f} s of frames lost per kill (captured but still in "
        "the open chunk or the encoder queue; chunks close every 1 s)"
    )
    for e in examples:
        print("  example:", e)
    print()
    print_classes(tallies[0][0], tallies[1][0], tallies[2][0], tallies[3][0])


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="fewer cases")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--drills",
        default="files,disk,monitor",
        help="comma list of files (MCAP, folder, rig, image, SIGKILL drills), disk, monitor",
    )
    args = ap.parse_args()
    logging.disable(logging.CRITICAL)  # thousands of expected warnings
    rng = np.random.default_rng(args.seed)
    q = 5 if args.quick else 1
    print(
        f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}; seed {args.seed}"
        + (" (quick)" if args.quick else "")
    )
    scratch = Path(tempfile.mkdtemp(prefix="sea3d_drills_"))
    try:
        chosen = set(args.drills.split(","))
        if "files" in chosen:
            run_file_drills(scratch, rng, q)
        if "disk" in chosen:
            print("\ndisk drills:")
            for line in drill_disk(scratch):
                print(line)
        if "monitor" in chosen:
            print("\nmonitor, 200 concurrent clients x 3 requests on 127.0.0.1:")
            for line in drill_monitor(200, 3):
                print(line)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
