"""The paper's folder layout: one PNG per frame named by its stamp, CSVs for IMU and sonar.

::

    session/
      left/<t_ns>.png      right/<t_ns>.png     (or .jpg)
      imu.csv              t_ns,ax,ay,az,wx,wy,wz,crc32   (m/s^2, rad/s)
      sonar.csv            t_ns,range_m,confidence,crc32  (m, 0..1)
      rig.yaml             the rig file (optional)
      checksums.csv        stream,file,bytes,crc32: one line per image (and the rig)
      session.json         format, version, image encoding, counts, "complete"

The ``crc32`` column (8 hex digits, CRC-32 of the line before it) and ``checksums.csv`` let a
reader refuse damaged readings and images instead of passing them on; folders without them
(the paper's) are read as before, unchecked.

Every image is written under a temporary name (``.<t_ns>.<pid>-<token>.tmp.png``, see
:mod:`sea3d.io._atomic`) and renamed when complete,
so a crash never leaves a half-written image under its final name. CSV lines are flushed as they
are written; a torn last line is skipped with a warning when read.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import time
import zlib
from pathlib import Path
from typing import IO, Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.io._atomic import atomic_write, is_temp_name
from sea3d.io.disk_space import disk_free_bytes
from sea3d.io.session.common import (
    ImuSeries,
    SessionWriteError,
    SonarSeries,
    check_rig_yaml,
    decode_image,
    sort_stamps,
)
from sea3d.io.session.reader import SessionReader

__all__ = ["FolderSessionReader", "FolderSessionWriter"]

_log = logging.getLogger(__name__)

# The last column is the CRC-32 (8 hex digits) of the line's text before it, so that a damaged
# reading is skipped, never passed on; files without it (the paper's) are read as well.
IMU_COLUMNS = "t_ns,ax,ay,az,wx,wy,wz"
SONAR_COLUMNS = "t_ns,range_m,confidence"
IMU_HEADER = IMU_COLUMNS + ",crc32"
SONAR_HEADER = SONAR_COLUMNS + ",crc32"
SESSION_FORMAT = "sea3d-session"
SESSION_VERSION = 1
CHECKSUM_HEADER = "stream,file,bytes,crc32"
_EXT = {"png": ".png", "jpeg": ".jpg", "jxl": ".jxl"}
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".jxl", ".tif", ".tiff", ".pgm", ".ppm")
_NAME_RE = re.compile(r"^(\d+)$")


def _meta_crc(meta: dict[str, Any]) -> str:
    """CRC-32 of session.json's content without its own ``crc32`` key (8 hex digits)."""
    body = {k: v for k, v in meta.items() if k != "crc32"}
    return f"{zlib.crc32(json.dumps(body, sort_keys=True).encode()):08x}"


def _why(err: OSError) -> str:
    return err.strerror or str(err)


def create_writer(
    path: Path, rig_yaml: str | None, image_encoding: str, *, min_free_bytes: int = 0, **_: Any
) -> FolderSessionWriter:
    """The folder storage's writer (chunk options of other storages do not apply).

    Raises:
        SessionError: a raw encoding, an invalid rig, or a folder holding a session;
            SessionWriteError: the folder cannot be created.
    """
    if image_encoding not in _EXT:
        raise SessionError(
            f"{path}: a folder session stores png, jxl or jpeg images, not {image_encoding!r}"
        )
    check_rig_yaml(rig_yaml, path)  # the same check as for MCAP
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionWriteError(f"cannot create {path}: {err.strerror or err}", kept="") from err
    return FolderSessionWriter(path, rig_yaml, image_encoding, min_free_bytes=min_free_bytes)


class FolderSessionWriter:
    """Backend of :class:`~sea3d.io.session.SessionWriter` for the folder layout (not public).

    ``counts`` holds what a reader will use: an image counts once it is renamed to its final
    name and listed in ``checksums.csv`` (with its size and CRC-32), a CSV line once flushed.
    """

    def __init__(
        self, path: Path, rig_yaml: str | None, image_encoding: str, *, min_free_bytes: int = 0
    ) -> None:
        if image_encoding not in _EXT:
            raise SessionError(
                f"{path}: a folder session stores png, jxl or jpeg images, not {image_encoding!r}"
            )
        if path.exists() and not path.is_dir():
            raise SessionError(f"{path} exists and is not a folder")
        if (path / "session.json").exists() or any(
            (path / s).is_dir() and any((path / s).iterdir()) for s in ("left", "right")
        ):
            raise SessionError(f"{path} already holds a session; refusing to overwrite it")
        self.path = path
        self.ext = _EXT[image_encoding]
        self.image_encoding = image_encoding
        self.min_free_bytes = int(min_free_bytes)
        self.counts: dict[str, int] = {}
        self.last_t_ns: int | None = None
        self.bytes_written = 0
        self.broken: str | None = None
        self._csv: dict[str, IO[str]] = {}
        self._created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        self._rig_sum: dict[str, int] | None = None
        try:
            for s in ("left", "right"):
                (path / s).mkdir(parents=True, exist_ok=True)
            rig_bytes = None if rig_yaml is None else rig_yaml.encode("utf-8")
            if rig_bytes is not None:
                atomic_write(path / "rig.yaml", rig_bytes)
                self._rig_sum = {"bytes": len(rig_bytes), "crc32": zlib.crc32(rig_bytes)}
            self._write_json({}, complete=False)
            for name, header in (
                ("imu", IMU_HEADER),
                ("sonar", SONAR_HEADER),
                ("checksums", CHECKSUM_HEADER),
            ):
                f = open(path / f"{name}.csv", "w", encoding="ascii", newline="\n")
                self._csv[name] = f
                f.write(header + "\n")
                f.flush()
            if rig_bytes is not None:
                self._line("checksums", f"rig,rig.yaml,{len(rig_bytes)},{zlib.crc32(rig_bytes)}\n")
        except OSError as err:
            for opened in self._csv.values():
                try:
                    opened.close()
                except OSError:
                    pass
            for name in ("imu.csv", "sonar.csv", "checksums.csv", "session.json", "rig.yaml"):
                with contextlib.suppress(OSError):  # nothing usable: do not block a new attempt
                    (path / name).unlink()
            for sub in ("left", "right", ""):
                with contextlib.suppress(OSError):
                    (path / sub).rmdir() if sub else path.rmdir()
            raise SessionWriteError(f"cannot write {path}: {_why(err)}", kept="nothing") from err

    def _kept(self) -> str:
        parts = [f"{n} {s}" for s, n in self.counts.items() if n]
        last = "" if self.last_t_ns is None else f" up to t_ns={self.last_t_ns}"
        return (", ".join(parts) or "no records") + last

    def _check(self, size: int) -> None:
        if self.broken is not None:
            raise SessionWriteError(self.broken, kept=self._kept())
        free = disk_free_bytes(self.path)
        if free - size - 65536 < self.min_free_bytes:  # room for session.json at close
            if self.min_free_bytes > 0:
                self.broken = (
                    f"{self.path}: free space would fall under the "
                    f"{self.min_free_bytes / 1e9:.2f} GB reserve ({free / 1e9:.2f} GB free)"
                )
            else:
                self.broken = f"{self.path}: the disk is full ({free} bytes free)"
            raise SessionWriteError(self.broken, kept=self._kept())

    def _failed(self, what: str, err: OSError) -> SessionWriteError:
        self.broken = f"{self.path}: writing {what} failed: {_why(err)}"
        return SessionWriteError(self.broken, kept=self._kept())

    def _done(self, stream: str, t_ns: int, size: int) -> None:
        self.counts[stream] = self.counts.get(stream, 0) + 1
        self.bytes_written += size
        self.last_t_ns = t_ns if self.last_t_ns is None else max(self.last_t_ns, t_ns)

    def committed(self, stream: str) -> int:
        return self.counts.get(stream, 0)

    def _write_json(self, counts: dict[str, int], *, complete: bool) -> None:
        meta = {
            "format": SESSION_FORMAT,
            "version": SESSION_VERSION,
            "layout": "folder",
            "image_encoding": self.image_encoding,
            "stamp_unit": "ns",
            "created_utc": self._created,
            "counts": counts,
            "complete": complete,
            # Every image (and the rig) has a line in checksums.csv; the rig's is kept here
            # too, so that a damaged or deleted line never leaves the rig unchecked.
            "checksums": True,
            "rig": self._rig_sum,
        }
        meta["crc32"] = _meta_crc(meta)
        atomic_write(self.path / "session.json", json.dumps(meta, indent=2) + "\n")

    def _line(self, name: str, line: str) -> None:
        f = self._csv[name]
        f.write(line)
        f.flush()

    def write_encoded(
        self, stream: str, t_ns: int, data: bytes, fmt: str = "", height: int = 0, width: int = 0
    ) -> None:
        del fmt, height, width  # the file name and the image's own header say them
        self._check(len(data))
        name = f"{t_ns}{self.ext}"
        try:
            # no fsync per frame: a frame lost to a power cut fails its CRC-32 when read
            atomic_write(self.path / stream / name, data, fsync=False)
        except OSError as err:
            raise self._failed(f"{stream}/{name}", err) from err
        try:
            self._line("checksums", f"{stream},{name},{len(data)},{zlib.crc32(data)}\n")
        except OSError as err:
            raise self._failed("checksums.csv", err) from err
        # counted once listed: a reader uses no image without its line in checksums.csv
        self._done(stream, t_ns, len(data))

    def write_raw(self, stream: str, t_ns: int, image: np.ndarray) -> None:
        raise SessionError(f"{self.path}: a folder session stores no raw images")

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
        text = f"{t_ns}," + ",".join(repr(float(v)) for v in (*accel, *gyro))
        line = f"{text},{zlib.crc32(text.encode()):08x}\n"
        self._check(len(line))
        try:
            self._line("imu", line)
        except OSError as err:
            raise self._failed("imu.csv", err) from err
        self._done("imu", t_ns, len(line))

    def write_sonar(self, t_ns: int, range_m: np.float32, confidence: np.float32) -> None:
        text = f"{t_ns},{range_m!s},{confidence!s}"
        line = f"{text},{zlib.crc32(text.encode()):08x}\n"
        self._check(len(line))
        try:
            self._line("sonar", line)
        except OSError as err:
            raise self._failed("sonar.csv", err) from err
        self._done("sonar", t_ns, len(line))

    def flush(self) -> None:
        if self.broken is not None:
            raise SessionWriteError(self.broken, kept=self._kept())
        try:
            for f in self._csv.values():
                f.flush()
        except OSError as err:
            raise self._failed("CSV files", err) from err

    def close(self, counts: dict[str, int]) -> None:
        del counts
        error: OSError | None = None
        for f in self._csv.values():
            try:
                f.close()
            except OSError as err:  # a torn last line is skipped by the reader
                error = error or err
        try:
            self._write_json(
                {s: self.counts.get(s, 0) for s in ("left", "right", "imu", "sonar")},
                complete=self.broken is None and error is None,
            )
        except OSError as err:
            error = error or err
        if error is not None:
            raise SessionWriteError(
                f"{self.path}: closing failed: {_why(error)}", kept=self._kept()
            ) from error


class FolderSessionReader(SessionReader):
    """Reader for the folder layout (see the module docstring).

    Args:
        path: the session folder.
        name_unit: unit of the numbers in image file names, ``"ns"`` (sea3d) or ``"us"``
            (the paper's recordings); stamps are always returned in nanoseconds.

    Raises:
        SessionError: if the folder does not exist or holds no session files.
    """

    format = "folder"

    def __init__(self, path: Path, *, name_unit: str = "ns") -> None:
        super().__init__(path)
        if not self.path.is_dir():
            raise SessionError(f"session folder {self.path} does not exist")
        if name_unit not in ("ns", "us"):
            raise SessionError(f"name_unit must be 'ns' or 'us', got {name_unit!r}")
        self.meta: dict[str, Any] = {}
        meta_path = self.path / "session.json"
        meta_damaged = False
        if meta_path.is_file():
            try:
                self.meta = json.loads(meta_path.read_text(encoding="utf-8"))
                if not isinstance(self.meta, dict):
                    raise ValueError("not a JSON object")
            except (OSError, ValueError) as err:
                self.meta, meta_damaged = {}, True
                self.problems.append(f"{meta_path}: cannot parse ({err}); ignoring it")
                _log.warning("%s: cannot parse (%s); ignoring it", meta_path, err)
            if "crc32" in self.meta and self.meta["crc32"] != _meta_crc(self.meta):
                self.meta, meta_damaged = {}, True
                self.problems.append(f"{meta_path} is damaged (CRC-32 mismatch); ignoring it")
                _log.warning("%s is damaged (CRC-32 mismatch); ignoring it", meta_path)
        if self.meta.get("stamp_unit") == "us":
            name_unit = "us"
        self._scale = 1000 if name_unit == "us" else 1
        # A folder written by sea3d lists every image (and the rig) in checksums.csv and says
        # so in session.json: then nothing unlisted or mismatching is handed out. Folders
        # without (the paper's) are read unchecked, as before.
        self.checksummed = bool(self.meta.get("checksums")) or meta_damaged
        sums_path = self.path / "checksums.csv"
        if self.meta.get("checksums") and not sums_path.is_file():
            raise SessionError(
                f"{sums_path} is missing, so the images of this session cannot be checked "
                "(session.json says it was written)"
            )
        self._checksums = self._read_checksums()
        if sums_path.is_file():
            self.checksummed = True
        self._rig = None
        self._read_rig()
        self._files: dict[str, list[str]] = {}
        self._stamps: dict[str, np.ndarray] = {}
        for s in ("left", "right"):
            self._index_images(s)
        has_any = any(len(v) for v in self._files.values()) or any(
            (self.path / f).is_file() for f in ("imu.csv", "sonar.csv", "session.json")
        )
        if not has_any:
            raise SessionError(
                f"{self.path} holds no session: no left/ or right/ images, imu.csv, sonar.csv "
                "or session.json"
            )
        if self.checksummed:
            self._check_listed_images()
        self._imu: ImuSeries | None = None
        self._sonar: SonarSeries | None = None

    def _problem(self, message: str) -> None:
        self.problems.append(message)
        _log.warning("%s", message)

    def _read_rig(self) -> None:
        """Read ``rig.yaml``, checked against checksums.csv or session.json's copy of its
        checksum; a rig that cannot be checked in a checked folder is refused, not guessed."""
        from sea3d.errors import RigFileError
        from sea3d.io.rig_file import read_rig_text

        rig_path = self.path / "rig.yaml"
        want = self._checksums.get(("rig", "rig.yaml"))
        recorded = self.meta.get("rig")
        if isinstance(recorded, dict):
            try:
                from_meta = (int(recorded["bytes"]), int(recorded["crc32"]))
            except (KeyError, TypeError, ValueError):
                from_meta = None
            if want is None:
                want = from_meta
                if from_meta is not None and (self.path / "checksums.csv").is_file():
                    self._problem(
                        f"{self.path / 'checksums.csv'}: the line of rig.yaml is missing or "
                        "damaged; the rig is checked against session.json's copy instead"
                    )
            elif from_meta is not None and from_meta != want:
                want = from_meta  # session.json is written once, at start and at close
        if not rig_path.is_file():
            if want is not None or isinstance(recorded, dict):
                self._rig_problem = (
                    f"{rig_path} is missing, though the session was recorded with a rig"
                )
                self._problem(self._rig_problem)
            return
        try:
            data = rig_path.read_bytes()
            if want is None and self.checksummed:
                raise RigFileError(
                    f"{rig_path} cannot be checked: its line in checksums.csv is missing or "
                    "damaged; give the rig file separately"
                )
            if want is not None and (len(data), zlib.crc32(data)) != want:
                raise RigFileError(
                    f"{rig_path}: the stored rig is damaged ({len(data)} bytes with "
                    f"CRC-32 {zlib.crc32(data)}; it was written with {want[0]} bytes "
                    f"and CRC-32 {want[1]})"
                )
            self._rig = read_rig_text(rig_path)
        except (RigFileError, OSError) as err:
            self._rig_problem = str(err)
            self._problem(str(err))

    def _check_listed_images(self) -> None:
        """Every image listed in checksums.csv must be on disk (a deleted or renamed image
        is reported, never silently absent); the counts session.json recorded at close
        must match."""
        for stream in ("left", "right"):
            present = set(self._files[stream])
            missing = sorted(
                name for (st, name) in self._checksums if st == stream and name not in present
            )
            if missing:
                self._problem(
                    f"{self.path / stream}: {len(missing)} images listed in checksums.csv are "
                    f"missing (deleted or renamed), e.g. {missing[0]}"
                )
        counts = self.meta.get("counts") if self.meta.get("complete") else None
        if isinstance(counts, dict):
            for stream in ("left", "right"):
                want = counts.get(stream)
                have = len(self._files[stream]) + self.skipped.get(stream, 0)
                if isinstance(want, int) and want != have:
                    self._problem(
                        f"{self.path}: session.json counts {want} {stream} records, the "
                        f"folder holds {have}"
                    )

    def _index_images(self, stream: str) -> None:
        folder = self.path / stream
        names: list[str] = []
        stamps: list[int] = []
        if folder.is_dir():
            for entry in sorted(os.listdir(folder)):
                full = folder / entry
                if is_temp_name(entry):
                    _log.warning(
                        "%s: incomplete write left by an interrupted recording; ignored", full
                    )
                    continue
                stem, suffix = os.path.splitext(entry)
                if suffix.lower() not in _IMAGE_SUFFIXES:
                    if not entry.startswith("."):
                        _log.warning("%s: not an image file; ignored", full)
                    continue
                m = _NAME_RE.match(stem)
                if m is None:
                    _log.warning(
                        "%s: name is not an integer stamp (<t_ns>%s); ignored", full, suffix
                    )
                    continue
                names.append(entry)
                stamps.append(int(m.group(1)) * self._scale)
        # File listing order means nothing: sort numerically; for equal stamps prefer the
        # canonical name (no leading zeros) and report the others.
        by_stamp = sorted(
            range(len(stamps)),
            key=lambda i: (
                stamps[i],
                os.path.splitext(names[i])[0] != str(stamps[i] // self._scale),
                names[i],
            ),
        )
        kept: list[int] = []
        for i in by_stamp:
            if kept and stamps[kept[-1]] == stamps[i]:
                _log.warning(
                    "%s has the same stamp as %s (t_ns=%d); ignored",
                    folder / names[i],
                    names[kept[-1]],
                    stamps[i],
                )
                continue
            kept.append(i)
        if self.checksummed:
            unlisted = [i for i in kept if (stream, names[i]) not in self._checksums]
            if unlisted:
                self.skipped[stream] = self.skipped.get(stream, 0) + len(unlisted)
                self._problem(
                    f"{folder}: {len(unlisted)} images have no line in checksums.csv (renamed, "
                    f"added, or cut short?) and cannot be checked; not used, e.g. "
                    f"{names[unlisted[0]]}"
                )
                kept = [i for i in kept if (stream, names[i]) in self._checksums]
        names = [names[i] for i in kept]
        arr = np.asarray([stamps[i] for i in kept], dtype=np.int64)
        order = np.arange(arr.size)
        self._files[stream] = [names[i] for i in order.tolist()]
        self._stamps[stream] = arr[order]

    def stamps(self, stream: str) -> np.ndarray:
        if stream in self._stamps:
            return self._stamps[stream]
        if stream == "imu":
            return self.imu().t_ns
        if stream == "sonar":
            return self.sonar().t_ns
        raise SessionError(f"unknown stream {stream!r}; expected left, right, imu or sonar")

    def _read_checksums(self) -> dict[tuple[str, str], tuple[int, int]]:
        """(stream, file name) -> (bytes, CRC-32) from ``checksums.csv``; torn lines skipped."""
        path = self.path / "checksums.csv"
        out: dict[tuple[str, str], tuple[int, int]] = {}
        if not path.is_file():
            return out
        try:
            lines = path.read_text(encoding="ascii", errors="replace").splitlines()
        except OSError as err:
            _log.warning("%s: cannot read (%s); images are not checked", path, err)
            return out
        if not lines or lines[0].strip() != CHECKSUM_HEADER:
            _log.warning("%s: header %r differs from %r", path, lines[:1], CHECKSUM_HEADER)
        ambiguous: set[tuple[str, str]] = set()
        for lineno, line in enumerate(lines[1:], start=2):
            parts = line.split(",")
            try:
                if len(parts) != 4 or parts[0] not in ("left", "right", "rig"):
                    raise ValueError(f"{len(parts)} fields")
                key, value = (parts[0], parts[1]), (int(parts[2]), int(parts[3]))
            except ValueError:
                self.problems.append(f"{path} line {lineno}: {line!r} is not a checksum line")
                _log.warning("%s line %d: %r is not a checksum line; skipped", path, lineno, line)
                continue
            if key in out and out[key] != value:
                ambiguous.add(key)
            out[key] = value
        for key in ambiguous:  # two different checksums: neither can be trusted
            del out[key]
            self.problems.append(f"{path}: {key[0]}/{key[1]} has two different checksums")
            _log.warning("%s: %s/%s has two different checksums; not used", path, *key)
        return out

    def _record_name(self, stream: str, index: int) -> str:
        return str(self.path / stream / self._files[stream][index])

    def _stored_bytes(self, stream: str, index: int) -> bytes:
        name = self._record_name(stream, index)
        try:
            data = Path(name).read_bytes()
        except OSError as err:
            raise SessionError(f"cannot read {name}: {err.strerror or err}") from err
        want = self._checksums.get((stream, self._files[stream][index]))
        if want is not None and (len(data), zlib.crc32(data)) != want:
            raise SessionError(
                f"{name} (t_ns={int(self._stamps[stream][index])}) is damaged: {len(data)} "
                f"bytes with CRC-32 {zlib.crc32(data)}, checksums.csv says {want[0]} bytes "
                f"with {want[1]}"
            )
        return data

    def _read_image(self, stream: str, index: int) -> np.ndarray:
        name = self._record_name(stream, index)
        data = self._stored_bytes(stream, index)
        return decode_image(data, f"{name} (t_ns={int(self._stamps[stream][index])})")

    def image_bytes(self, stream: str, index: int) -> tuple[bytes, str]:
        """The stored (encoded) bytes of an image and its format (``png``, ``jpeg``, ...),
        checked against ``checksums.csv`` when the folder has one."""
        name = self._record_name(stream, index)
        suffix = os.path.splitext(name)[1].lower().lstrip(".")
        fmt = {"jpg": "jpeg", "tif": "tiff"}.get(suffix, suffix)
        return self._stored_bytes(stream, index), fmt

    def check(self) -> list[str]:
        """Read the CSVs too, so that every problem the readers see is in :attr:`problems`
        (images, the rig and the counts of session.json are checked when the folder is
        opened, the CSVs when they are first read).

        Returns the new problems (also in :attr:`problems`).
        """
        before = len(self.problems)
        self.imu()
        self.sonar()
        return self.problems[before:]

    def checks(self) -> tuple[str, str]:
        if not self.checksummed:
            return (
                "nothing (a folder without checksums.csv, as the paper's)",
                "images, rig and CSV lines (damage cannot be detected)",
            )
        return (
            "the image list and rig against checksums.csv and session.json, the counts of "
            "session.json, every CSV line's CRC-32",
            "image bytes (checked as each image is read; run `sea3d session verify`)",
        )

    def _check_count(self, stream: str, readable: int) -> None:
        """A CSV cut or with lines deleted at a line boundary shows no damage of its own: its
        count must match the one session.json recorded at close."""
        counts = self.meta.get("counts") if self.meta.get("complete") else None
        want = counts.get(stream) if isinstance(counts, dict) else None
        have = readable + self.skipped.get(stream, 0)
        if isinstance(want, int) and want != have:
            self._problem(
                f"{self.path}: session.json counts {want} {stream} records, the folder holds "
                f"{have} ({stream}.csv lines deleted or added?); using the {readable} intact ones"
            )

    @property
    def image_encoding(self) -> str | None:
        enc = self.meta.get("image_encoding")
        return str(enc) if enc else None

    def _read_csv(self, name: str, columns: str, ncols: int) -> tuple[np.ndarray, np.ndarray]:
        path = self.path / name
        if not path.is_file():
            return np.zeros(0, np.int64), np.zeros((0, ncols - 1), np.float64)
        stamps: list[int] = []
        rows: list[list[float]] = []
        stream = name.removesuffix(".csv")
        with_crc = False  # set by a header with the crc32 column: then every line has one
        with open(path, encoding="ascii", errors="replace") as f:
            for lineno, line in enumerate(f, start=1):
                text = line.strip()
                if not text:
                    continue
                if lineno == 1 and text[0].isdigit() and self.checksummed:
                    self._problem(f"{path}: the header line {columns},crc32 is missing")
                if lineno == 1 and not text[0].isdigit():
                    with_crc = text.replace(" ", "") == columns + ",crc32"
                    if text.replace(" ", "") not in (columns, columns + ",crc32"):
                        _log.warning(
                            "%s: header %r differs from %r; reading columns by position",
                            path,
                            text,
                            columns,
                        )
                    continue
                parts = text.split(",")
                try:
                    if len(parts) == ncols + 1:
                        body, _, crc = text.rpartition(",")
                        if crc != f"{zlib.crc32(body.encode()):08x}":  # as written
                            raise ValueError("damaged (CRC-32 mismatch)")
                        parts = parts[:-1]
                    elif len(parts) != ncols or with_crc:
                        raise ValueError(
                            f"{len(parts)} fields, expected {ncols}"
                            + (" + crc32" if with_crc else "")
                        )
                    t = int(parts[0])
                    vals = [float(p) for p in parts[1:]]
                except ValueError as err:
                    torn = not line.endswith("\n")
                    self.skipped[stream] = self.skipped.get(stream, 0) + 1
                    _log.warning(
                        "%s line %d: %s (%r); skipped%s",
                        path,
                        lineno,
                        err,
                        text[:60],
                        " (torn last line of an interrupted recording)" if torn else "",
                    )
                    continue
                stamps.append(t)
                rows.append(vals)
        t_arr = np.asarray(stamps, dtype=np.int64)
        v_arr = np.asarray(rows, dtype=np.float64).reshape(-1, ncols - 1)
        order = sort_stamps(t_arr, str(path))
        return t_arr[order], v_arr[order]

    def imu(self) -> ImuSeries:
        if self._imu is None:
            t, v = self._read_csv("imu.csv", IMU_COLUMNS, 7)
            self._imu = ImuSeries(t_ns=t, accel_mps2=v[:, :3].copy(), gyro_radps=v[:, 3:].copy())
            self._check_count("imu", len(self._imu))
        return self._imu

    def sonar(self) -> SonarSeries:
        if self._sonar is None:
            t, v = self._read_csv("sonar.csv", SONAR_COLUMNS, 3)
            self._sonar = SonarSeries(
                t_ns=t, range_m=v[:, 0].astype(np.float32), confidence=v[:, 1].astype(np.float32)
            )
            self._check_count("sonar", len(self._sonar))
        return self._sonar

    def size_bytes(self) -> int:
        total = 0
        for root, _dirs, files in os.walk(self.path):
            for f in files:
                try:
                    total += os.path.getsize(os.path.join(root, f))
                except OSError:
                    pass
        return total
