"""Drills on recorded sessions: every cut, random bit flips, mangled images.

The properties, for any damage:

- no traceback: reading, verifying and converting raise nothing but :class:`SessionError`;
- no silently wrong output: every value a reader returns equals what was written;
- bounded loss: a file cut at byte ``b`` keeps every record of the chunks that end before
  ``b``; one flipped bit loses at most the records of the chunk it falls in;
- verify notices: ``verify_session`` reports a problem for every single flipped bit.

The ``ci`` hypothesis profile (default) tries a few dozen random cases per property;
``SEA3D_DRILLS=full`` tries a thousand. ``benchmarks/bench_reliability.py`` prints the figures
of docs/reliability.md.
"""

from __future__ import annotations

import functools
import io
import logging
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from sea3d.errors import SessionError
from sea3d.io.rig_file import rig_to_yaml
from sea3d.io.session import SessionWriter, convert_session, open_session, verify_session
from sea3d.io.session.common import decode_image, encode_image
from sea3d.refraction.presets import paper_rig


def _examples(ci: int) -> int:
    """Examples per property: ``ci`` in the default profile, 1000 with SEA3D_DRILLS=full."""
    return 1000 if os.environ.get("SEA3D_DRILLS") == "full" else ci


FRAME_NS = 33_333_333
RIG_YAML = rig_to_yaml(paper_rig("dome"))
N_PAIRS = 6


def _frame(i: int) -> np.ndarray:
    return np.random.default_rng(i).integers(0, 256, size=(10, 14, 3), dtype=np.uint8)


def _truth() -> dict[str, dict[int, Any]]:
    out: dict[str, dict[int, Any]] = {"left": {}, "right": {}, "imu": {}, "sonar": {}}
    for i in range(N_PAIRS):
        t = i * FRAME_NS
        out["left"][t] = _frame(i)
        out["right"][t] = _frame(100 + i)
        for j in range(3):
            out["imu"][t + j * 1000] = (np.array([i, j, 9.81]), np.array([0.1 * i, 0.0, j]))
        out["sonar"][t + 7] = (np.float32(1.5 + i), np.float32(0.5))
    return out


TRUTH = _truth()


def _write(path: Path, fmt: str) -> None:
    # A tiny chunk size closes a chunk after each pair: many chunks to damage.
    with SessionWriter(path, format=fmt, rig_yaml=RIG_YAML, chunk_size=2000) as w:
        for i in range(N_PAIRS):
            t = i * FRAME_NS
            w.write_stereo(t, TRUTH["left"][t], TRUTH["right"][t])
            for j in range(3):
                w.write_imu(t + j * 1000, *TRUTH["imu"][t + j * 1000])
            w.write_sonar(t + 7, *TRUTH["sonar"][t + 7])


@functools.cache
def _mcap_bytes() -> bytes:
    with _scratch() as path:
        _write(path, "mcap")
        return path.read_bytes()


@pytest.fixture(scope="module")
def mcap_bytes() -> bytes:
    return _mcap_bytes()


def _chunk_regions(data: bytes) -> list[tuple[int, int, dict[str, set[int]]]]:
    """(start, end, {stream: stamps}) per chunk with its message indexes, from the official
    mcap reader's summary (independent of sea3d's reader)."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import MessageIndex

    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    stream_of = {
        "/cam/left/image": "left",
        "/cam/right/image": "right",
        "/imu": "imu",
        "/sonar": "sonar",
    }
    regions = []
    for ci in summary.chunk_indexes:
        stamps: dict[str, set[int]] = {}
        for cid, off in ci.message_index_offsets.items():
            stream = stream_of.get(summary.channels[cid].topic)
            if stream is None:
                continue
            (length,) = struct.unpack_from("<Q", data, off + 1)
            index = MessageIndex.read(ReadDataStream(io.BytesIO(data[off + 9 : off + 9 + length])))
            stamps[stream] = {t for t, _ in index.records}
        end = ci.chunk_start_offset + ci.chunk_length + ci.message_index_length
        regions.append((ci.chunk_start_offset, end, stamps))
    return regions


RIG_LOST = "<the reader said the stored rig cannot be used>"
"""``got["rig"]`` when the reader raised SessionError (apart from None: "no rig stored")."""


def read_everything(path: Path) -> dict[str, Any]:
    """Everything a reader hands out; damaged records raise SessionError and count as lost."""
    got: dict[str, Any] = {"left": {}, "right": {}, "imu": {}, "sonar": {}, "rig": RIG_LOST}
    try:
        s = open_session(path)
    except SessionError:
        return got
    with s:
        for stream in ("left", "right"):
            for i, t in enumerate(s.stamps(stream).tolist()):
                try:
                    got[stream][t] = s.image(stream, i, by="index")
                except SessionError:
                    pass
        imu = s.imu()
        for k, t in enumerate(imu.t_ns.tolist()):
            got["imu"][t] = (imu.accel_mps2[k], imu.gyro_radps[k])
        sonar = s.sonar()
        for k, t in enumerate(sonar.t_ns.tolist()):
            got["sonar"][t] = (sonar.range_m[k], sonar.confidence[k])
        try:
            got["rig"] = s.rig_yaml
        except SessionError:
            got["rig"] = RIG_LOST
    return got


def assert_nothing_wrong(got: dict[str, Any], *, rig_may_be_unseen: bool = False) -> None:
    """Every value handed out is the value written (no silently wrong output).

    The rig is written with every session: a reader hands it out as written or says it cannot
    (SessionError), and says "no rig stored" (None) only where ``rig_may_be_unseen``: damage
    that can remove every trace of the rig record from an MCAP (a cut before it, many flips).
    """
    for stream in ("left", "right"):
        for t, img in got[stream].items():
            assert t in TRUTH[stream], f"{stream} stamp {t} was never written"
            np.testing.assert_array_equal(img, TRUTH[stream][t])
    for stream in ("imu", "sonar"):
        for t, vals in got[stream].items():
            assert t in TRUTH[stream], f"{stream} stamp {t} was never written"
            for k, (a, b) in enumerate(zip(vals, TRUTH[stream][t], strict=True)):
                if stream == "sonar" and k == 1 and np.isnan(a):
                    continue  # confidence unknown (its own record was lost): NaN, documented
                np.testing.assert_array_equal(np.float32(a), np.float32(b))
    rigs = (None, RIG_LOST, RIG_YAML) if rig_may_be_unseen else (RIG_LOST, RIG_YAML)
    assert got["rig"] in rigs, f"the reader handed out the rig {got['rig']!r}"


def lost(got: dict[str, Any]) -> dict[str, set[int]]:
    return {s: set(TRUTH[s]) - set(got[s]) for s in ("left", "right", "imu", "sonar")}


def _record_boundaries(data: bytes) -> list[int]:
    pos, out = 8, [8]
    while pos + 9 <= len(data):
        _op, length = struct.unpack_from("<BQ", data, pos)
        pos += 9 + length
        out.append(pos)
    return out


@pytest.mark.slow
def test_a_cut_at_every_record_boundary_keeps_every_complete_chunk(mcap_bytes, tmp_path, caplog):
    regions = _chunk_regions(mcap_bytes)
    first_rig_end = mcap_bytes.index(b"rig.yaml") + 200 + len(RIG_YAML)  # generous
    path = tmp_path / "cut.mcap"
    # Every record boundary; the thorough run also one byte either side of each.
    shifts = (-1, 0, 1) if os.environ.get("SEA3D_DRILLS") == "full" else (0,)
    cuts = sorted({c + d for c in _record_boundaries(mcap_bytes) for d in shifts})
    caplog.set_level(logging.ERROR)
    for cut in cuts:
        if not 0 < cut < len(mcap_bytes):
            continue
        path.write_bytes(mcap_bytes[:cut])
        got = read_everything(path)
        assert_nothing_wrong(got, rig_may_be_unseen=cut < first_rig_end)
        missing = lost(got)
        for _start, end, stamps in regions:
            if end <= cut:  # a complete chunk: nothing of it may be lost
                for stream, ts in stamps.items():
                    assert not ts & missing[stream], f"cut at {cut} lost a complete chunk"
        if cut >= first_rig_end:
            assert got["rig"] == RIG_YAML
        assert not _verified(path)


def _flip(data: bytes, bits: list[int]) -> bytes:
    buf = bytearray(data)
    for bit in bits:
        buf[bit // 8] ^= 1 << (bit % 8)
    return bytes(buf)


@pytest.mark.slow
@settings(max_examples=_examples(60))
@given(bit=st.integers(min_value=0))
def test_one_flipped_bit_loses_at_most_its_chunk_and_verify_sees_it(bit):
    mcap_bytes = _mcap_bytes()
    bit %= len(mcap_bytes) * 8
    flipped = _flip(mcap_bytes, [bit])
    with _scratch() as path:
        path.write_bytes(flipped)
        got = read_everything(path)
        assert_nothing_wrong(got)
        at = bit // 8
        allowed: dict[str, set[int]] = {s: set() for s in ("left", "right", "imu", "sonar")}
        for start, end, stamps in _chunk_regions(mcap_bytes):
            if start <= at < end:
                allowed = {s: stamps.get(s, set()) for s in allowed}
        for stream, ts in lost(got).items():
            assert ts <= allowed[stream], f"bit {bit} (byte {at}) lost {stream} {sorted(ts)}"
        assert got["rig"] == RIG_YAML  # two CRC-checked copies
        assert not _verified(path), f"verify missed the flipped bit {bit} (byte {at})"


@pytest.mark.slow
@settings(max_examples=_examples(30))
@given(bits=st.lists(st.integers(min_value=0), min_size=2, max_size=12))
def test_many_flipped_bits_give_errors_or_true_values_never_wrong_ones(bits):
    mcap_bytes = _mcap_bytes()
    flipped = _flip(mcap_bytes, [b % (len(mcap_bytes) * 8) for b in bits])
    with _scratch() as path:
        path.write_bytes(flipped)
        got = read_everything(path)
        assert_nothing_wrong(got, rig_may_be_unseen=True)
        _verified(path)  # must not raise anything but SessionError
        out = path.with_name("converted")
        try:
            convert_session(path, out)
        except SessionError:
            pass
        else:  # a copy holds the rig if the reader could hand it out
            assert_nothing_wrong(read_everything(out), rig_may_be_unseen=got["rig"] != RIG_YAML)


# --------------------------------------------------------------------------- folders
# One damage: (file, kind, where) with ``file`` and ``where`` fractions in [0, 1) picking the
# file (sorted, session.json included) and the byte, bit or line. Renames and deletions apply
# to images; line deletions and edits to the CSVs, the rig and checksums.csv.
_KINDS = ("flip", "cut", "delete", "rename", "delete_line", "edit_line")


def _damage_folder(path: Path, ops: list[tuple[float, str, float]]) -> list[str]:
    """Apply ``ops`` to the folder session at ``path``; returns what was done, for messages."""
    done = []
    for pick, kind, where in ops:
        files = sorted(p for p in path.rglob("*") if p.is_file())
        images = [p for p in files if p.parent.name in ("left", "right")]
        texts = [p for p in files if p.suffix in (".csv", ".yaml")]
        pool = images if kind in ("delete", "rename") else texts if "line" in kind else files
        if not pool:
            continue
        victim = pool[int(pick * len(pool))]
        raw = bytearray(victim.read_bytes())
        if kind == "delete":
            victim.unlink()
        elif kind == "rename":  # to a stamp that was never written (or onto another image)
            stamp = int(victim.stem) + int(where * 3 * FRAME_NS) + 1
            os.replace(victim, victim.with_name(f"{stamp}{victim.suffix}"))
        elif not raw:
            continue
        elif kind == "flip":
            bit = int(where * len(raw) * 8)
            raw[bit // 8] ^= 1 << (bit % 8)
        elif kind == "cut":
            del raw[int(where * len(raw)) :]
        else:
            lines = bytes(raw).splitlines(keepends=True)
            k = int(where * len(lines))
            if kind == "delete_line":
                del lines[k]
            else:  # a plausible edit: one digit changed (a different value, same shape)
                line = bytearray(lines[k])
                digits = [i for i, c in enumerate(line) if chr(c).isdigit()]
                if not digits:
                    continue
                i = digits[int(where * 7919) % len(digits)]
                line[i] = ord("0") + (line[i] - ord("0") + 1) % 10
                lines[k] = bytes(line)
            raw = bytearray(b"".join(lines))
        if kind not in ("delete", "rename"):
            victim.write_bytes(bytes(raw))
        done.append(f"{kind} {victim.relative_to(path)} at {where:.3f}")
    return done


def _check_damaged_folder(path: Path, ops: list[tuple[float, str, float]]) -> None:
    _write(path, "folder")
    done = _damage_folder(path, ops)
    got = read_everything(path)
    assert_nothing_wrong(got)
    ok = _verified(path)
    lost_any = any(lost(got).values()) or got["rig"] is RIG_LOST
    # verify agrees with the readers: whatever a reader could not hand out, verify reports.
    assert not (ok and lost_any), f"verify says OK but the readers lost records after {done}"
    if any(d.split()[0] in ("delete", "rename", "delete_line") for d in done):
        assert not ok, f"verify missed {done}"
    out = path.with_name(path.name + "_converted.mcap")
    try:
        convert_session(path, out)
    except SessionError:
        return
    converted = read_everything(out)
    # never a damaged image at a wrong stamp, verifying clean; the rig if it could be read
    assert_nothing_wrong(converted, rig_may_be_unseen=got["rig"] != RIG_YAML)


_FOLDER_CASES = {
    # the drill's failure: checksums.csv's rig line damaged and a '#' of the rig turned '!'
    "rig_flip_and_its_checksum_line_damaged": [(0.0, "flip_rig_hash", 0.0)],
    "renamed_image": [(0.0, "rename", 0.5)],
    "renamed_last_image": [(0.99, "rename", 0.1)],
    "deleted_image": [(0.3, "delete", 0.0)],
    "deleted_imu_line": [(0.0, "delete_line", 0.5)],
    "deleted_sonar_line": [(0.9, "delete_line", 0.5)],
    "edited_imu_line": [(0.0, "edit_line", 0.6)],
    "rig_line_deleted_from_checksums": [(0.0, "delete_rig_checksum", 0.0)],
    "rig_line_deleted_and_rig_edited": [(0.0, "delete_rig_checksum", 0.0), (0.5, "edit_rig", 0.4)],
    "edited_rig": [(0.0, "edit_rig", 0.4)],
    "cut_checksums": [(0.0, "cut_checksums", 0.1)],
}


def _special(path: Path, kind: str, where: float) -> None:
    rig, sums = path / "rig.yaml", path / "checksums.csv"
    if kind == "flip_rig_hash":
        raw = bytearray(rig.read_bytes())
        raw[raw.index(b"#")] ^= 0x02  # '#' -> '!'
        rig.write_bytes(bytes(raw))
        text = bytearray(sums.read_bytes())
        text[text.index(b"rig,") + 1] ^= 0x01  # 'rig' -> 'rhg': no longer a checksum line
        sums.write_bytes(bytes(text))
    elif kind == "delete_rig_checksum":
        lines = sums.read_text().splitlines(keepends=True)
        sums.write_text("".join(ln for ln in lines if not ln.startswith("rig,")))
    elif kind == "edit_rig":
        text = rig.read_text()
        rig.write_text(text.replace("fx_px: ", "fx_px: 1", 1))
    elif kind == "cut_checksums":
        data = sums.read_bytes()
        sums.write_bytes(data[: int(where * len(data))])


@pytest.mark.parametrize("case", sorted(_FOLDER_CASES))
def test_damaged_folder_cases_never_hand_out_wrong_values_and_verify_agrees(case, tmp_path):
    path = tmp_path / "s"
    ops = _FOLDER_CASES[case]
    plain = [op for op in ops if op[1] in _KINDS]
    special = [op for op in ops if op[1] not in _KINDS]
    _write(path, "folder")
    for _pick, kind, where in special:
        _special(path, kind, where)
    done = _damage_folder(path, plain)
    got = read_everything(path)
    assert_nothing_wrong(got)
    report = verify_session(path)
    assert not report["ok"], f"verify missed {case} ({done})"
    out = tmp_path / "converted.mcap"
    try:
        convert_session(path, out)
    except SessionError:
        return
    assert_nothing_wrong(read_everything(out), rig_may_be_unseen=got["rig"] != RIG_YAML)


@pytest.mark.slow
@settings(max_examples=_examples(30), deadline=None)
@given(
    ops=st.lists(
        st.tuples(
            st.floats(0, 1, exclude_max=True),
            st.sampled_from(_KINDS),
            st.floats(0, 1, exclude_max=True),
        ),
        min_size=1,
        max_size=4,
    )
)
@example(ops=[(0.5, "rename", 0.5)])
@example(ops=[(0.25, "delete_line", 0.0)])  # the header of imu.csv
@example(ops=[(0.9375, "flip", 0.484375), (0.96875, "cut", 0.0)])  # session.json and sonar
@example(ops=[(0.0, "delete_line", 0.5), (0.99, "edit_line", 0.3)])
@example(ops=[(0.99, "delete", 0.0), (0.7, "flip", 0.01)])
def test_folder_sessions_with_damaged_files_never_hand_out_wrong_values(ops):
    with _scratch() as path:
        _check_damaged_folder(path.with_suffix(""), ops)


def _verified(path: Path) -> bool:
    """verify_session's verdict; a clear SessionError (not a session at all) counts as found."""
    try:
        return bool(verify_session(path)["ok"])
    except SessionError:
        return False


class _scratch:
    """A temporary file path outside hypothesis' function-scoped fixture check."""

    def __enter__(self) -> Path:
        import tempfile

        self.dir = tempfile.TemporaryDirectory(prefix="sea3d_drill_")
        return Path(self.dir.name) / "s.mcap"

    def __exit__(self, *exc: object) -> None:
        self.dir.cleanup()


# --------------------------------------------------------------------------- images
_IMAGE = np.random.default_rng(7).integers(0, 256, size=(40, 56, 3), dtype=np.uint8)
_ENCODED = {enc: encode_image(_IMAGE, enc) for enc in ("png", "jpeg", "jxl")}


@settings(max_examples=_examples(60))
@given(enc=st.sampled_from(sorted(_ENCODED)), frac=st.floats(0.0, 1.0, exclude_max=True))
def test_a_cut_image_is_refused_never_decoded_half_grey(enc, frac):
    data = _ENCODED[enc]
    cut = int(frac * len(data))
    with pytest.raises(SessionError, match=r"cut short|cannot decode|damaged"):
        decode_image(data[:cut], f"frame.{enc}")


@settings(max_examples=_examples(40))
@given(bit=st.integers(min_value=8 * 8))  # past the PNG signature
def test_a_flipped_bit_in_a_png_is_refused_by_its_chunk_crcs(bit):
    data = bytearray(_ENCODED["png"])
    bit %= len(data) * 8
    data[bit // 8] ^= 1 << (bit % 8)
    try:
        img = decode_image(bytes(data), "frame.png")
    except SessionError:
        return
    np.testing.assert_array_equal(img, _IMAGE)  # only a flip in unused bytes may decode


def test_truncated_jpeg_file_is_refused_by_read_image_file(tmp_path):
    from sea3d.io.session.common import read_image_file

    path = tmp_path / "left.jpg"
    path.write_bytes(_ENCODED["jpeg"][: len(_ENCODED["jpeg"]) // 2])
    with pytest.raises(SessionError, match=r"left\.jpg: JPEG is cut short"):
        read_image_file(path)
