"""On-disk caches of the process pipeline: per-frame results (and finished TSDF submaps).

They hold named numpy arrays plus a JSON header in one file per entry, in this container::

    b"SEA3DC1\\n" | uint64 payload length | uint32 CRC-32 of the payload | payload

where the payload is an uncompressed ``.npz`` archive (``allow_pickle`` off) compressed with
Zstandard (level 1: at 640x360 level 3 took 31 ms of CPU per frame against 7.5 ms for
an entry 0.1 % smaller, and the client writes every frame). Before compression, lossless
filters make the arrays compress better
(listed in the archive's ``__codec__`` member, so entries written without them still read):
float arrays are byte-shuffled (all first bytes, then all second bytes...: exponents and high
mantissa bytes compress, noise bytes stay apart) and 2-D-or-more uint8 arrays (images) are
delta-coded along their second axis (PNG's "Sub" filter). At 640x360 a frame's entry (two
RGB rectified images, two float32 depth maps) drops from 2.65 MB to about 1.7 MB.

An entry is written under a temporary name and renamed into place
(atomic on POSIX), so a killed run leaves whole entries or none; on reading, the magic,
length and checksum are checked and a damaged entry is reported (and recomputed by the
pipeline), never passed on as good.

- :class:`FrameCache`: ``OUT/cache/frames/<t_ns>.s3c``; ``OUT/cache/config.json`` holds the
  fingerprint of the per-frame configuration the entries were made with.
- finished TSDF submaps (``OUT/submaps/<id>.s3c``) use the same entries:
  :class:`sea3d.pipeline.submap_store.DiskSubmapStore`.
"""

from __future__ import annotations

import io
import json
import logging
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import CacheEntryError, SessionError
from sea3d.io._atomic import atomic_write

__all__ = ["CacheEntryError", "FrameCache", "encode_entry", "read_entry", "write_entry",
           "write_entry_bytes"]

log = logging.getLogger(__name__)

_MAGIC = b"SEA3DC1\n"
_HEAD = struct.Struct("<QI")
_SUFFIX = ".s3c"


_ZSTD_LEVEL = 1
_MIN_FILTERED = 4096  # bytes: smaller arrays are stored as they are


def _encode(a: NDArray[Any]) -> tuple[NDArray[Any], list[Any] | None]:
    """A lossless filtered copy of ``a`` and how to undo it (None: stored as it is)."""
    a = np.ascontiguousarray(a)
    if a.nbytes < _MIN_FILTERED:
        return a, None
    if a.dtype.kind == "f":
        shuffled = a.reshape(-1).view(np.uint8).reshape(-1, a.dtype.itemsize).T
        return np.ascontiguousarray(shuffled), ["shuffle", a.dtype.str, list(a.shape)]
    if a.dtype == np.uint8 and a.ndim >= 2:
        return np.diff(a, axis=1, prepend=np.uint8(0)), ["delta1", a.dtype.str, list(a.shape)]
    return a, None


def _decode(a: NDArray[Any], how: list[Any]) -> NDArray[Any]:
    kind, dtype, shape = how[0], np.dtype(how[1]), tuple(int(n) for n in how[2])
    if kind == "shuffle":
        # byte plane k holds byte k of every value: written plane by plane (a strided copy of
        # each contiguous plane), about 5x faster than numpy's copy of the transpose
        out = np.empty((a.shape[1], a.shape[0]), np.uint8)
        for k in range(a.shape[0]):
            out[:, k] = a[k]
        return out.view(dtype).reshape(shape)
    if kind == "delta1":
        return np.cumsum(a, axis=1, dtype=np.uint8).reshape(shape)
    raise ValueError(f"unknown array filter {kind!r}")


def encode_entry(arrays: dict[str, NDArray[Any]], meta: dict[str, Any]) -> bytes:
    """One entry's bytes, as :func:`write_entry` writes them (a worker can encode what the
    caller then writes with :func:`write_entry_bytes`)."""
    import imagecodecs

    buf = io.BytesIO()
    codec: dict[str, list[Any]] = {}
    filtered: dict[str, NDArray[Any]] = {}
    for name, arr in arrays.items():
        filtered[name], how = _encode(np.asarray(arr))
        if how is not None:
            codec[name] = how
    members: dict[str, Any] = {"__meta__": np.array(json.dumps(meta)),
                               "__codec__": np.array(json.dumps(codec)), **filtered}
    np.savez(buf, **members)
    payload = imagecodecs.zstd_encode(buf.getvalue(), level=_ZSTD_LEVEL)
    return _MAGIC + _HEAD.pack(len(payload), zlib.crc32(payload) & 0xFFFFFFFF) + payload


def write_entry(path: Path, arrays: dict[str, NDArray[Any]], meta: dict[str, Any]) -> int:
    """Write one entry atomically; returns its size in bytes.

    Raises:
        SessionError: the file cannot be written.
    """
    return write_entry_bytes(path, encode_entry(arrays, meta))


def write_entry_bytes(path: Path, data: bytes) -> int:
    """Write an entry's bytes (:func:`encode_entry`) atomically; returns their size.

    Raises:
        SessionError: the file cannot be written, or ``data`` is not an entry.
    """
    if data[:len(_MAGIC)] != _MAGIC:
        raise SessionError(f"not a cache entry for {path}")
    try:
        # no fsync per frame: a torn entry fails its CRC-32 and the frame is computed again
        atomic_write(path, data, fsync=False)
    except OSError as err:
        raise SessionError(f"cannot write cache entry {path}: {err}") from err
    return len(data)


def read_entry(path: Path) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """Read and check one entry: ``(arrays, meta)``.

    Raises:
        CacheEntryError: missing, truncated, checksum mismatch or unreadable content.
    """
    import imagecodecs

    try:
        data = path.read_bytes()
    except OSError as err:
        raise CacheEntryError(f"cannot read cache entry {path}: {err}") from err
    n0 = len(_MAGIC) + _HEAD.size
    if len(data) < n0 or data[: len(_MAGIC)] != _MAGIC:
        raise CacheEntryError(f"{path} is not a sea3d cache entry (bad header)")
    length, crc = _HEAD.unpack(data[len(_MAGIC):n0])
    payload = data[n0:]
    if len(payload) != length:
        raise CacheEntryError(f"{path} is truncated ({len(payload)} of {length} bytes)")
    if zlib.crc32(payload) & 0xFFFFFFFF != crc:
        raise CacheEntryError(f"{path} fails its checksum")
    try:
        with np.load(io.BytesIO(imagecodecs.zstd_decode(payload)), allow_pickle=False) as z:
            codec = json.loads(str(z["__codec__"])) if "__codec__" in z.files else {}
            arrays = {k: _decode(z[k], codec[k]) if k in codec else z[k]
                      for k in z.files if k not in ("__meta__", "__codec__")}
            meta = json.loads(str(z["__meta__"]))
    except Exception as err:  # any decoding failure means a damaged entry
        raise CacheEntryError(f"{path} cannot be decoded: {err}") from err
    return arrays, meta


class FrameCache:
    """Per-frame results of the process pipeline, by frame stamp.

    Args:
        root: the cache folder (``OUT/cache``).
        fingerprint: identifies the per-frame configuration; entries made with another one
            are not used (see :meth:`check_fingerprint`).
    """

    def __init__(self, root: Path, fingerprint: dict[str, Any]) -> None:
        self.root = Path(root)
        self.frames_dir = self.root / "frames"
        self.fingerprint = fingerprint
        self.bytes_written = 0

    def check_fingerprint(self, *, rebuild: bool = False) -> bool:
        """True if the folder is empty or was made with the same configuration; writes the
        fingerprint for a new cache.

        Args:
            rebuild: a damaged ``config.json`` (cut short, not JSON) is written again with
                this run's fingerprint and the entries are kept (each is still checked as it
                is read); only right when they were made with this configuration. A readable
                ``config.json`` of another configuration is never replaced.

        Raises:
            CacheEntryError: ``config.json`` is damaged (without ``rebuild``); the message
                names it and says how many cached frames it holds.
            SessionError: unreadable or unwritable ``config.json``.
        """
        cfg = self.root / "config.json"
        text = json.dumps(self.fingerprint, indent=1, sort_keys=True)
        try:
            if cfg.is_file():
                try:
                    stored = json.loads(cfg.read_bytes())
                except (json.JSONDecodeError, UnicodeDecodeError) as err:
                    damage = f"not JSON ({err})"
                else:
                    if isinstance(stored, dict):
                        return bool(stored == json.loads(text))
                    damage = f"not a JSON object ({type(stored).__name__})"
                n = len(self.stamps())
                if not rebuild:
                    raise CacheEntryError(
                        f"{cfg} is damaged: {damage}; it no longer says which configuration "
                        f"the {n} cached frames were made with. If this run's configuration "
                        "and session are theirs, rerun with rebuild_cache_config to keep them "
                        "(each is still checked as it is read), or with fresh to discard them"
                    )
                log.warning("%s was damaged (%s): written again for this configuration, "
                            "keeping the %d cached frames", cfg, damage, n)
            self.root.mkdir(parents=True, exist_ok=True)
            atomic_write(cfg, text + "\n")
        except OSError as err:
            raise SessionError(f"cannot use the cache folder {self.root}: {err}") from err
        return True

    def clear(self) -> int:
        """Remove every entry and the fingerprint; returns the number of entries removed."""
        n = 0
        if self.frames_dir.is_dir():
            for p in self.frames_dir.glob(f"*{_SUFFIX}"):
                p.unlink()
                n += 1
        cfg = self.root / "config.json"
        if cfg.exists():
            cfg.unlink()
        return n

    def path(self, t_ns: int) -> Path:
        """The entry file of a frame."""
        return self.frames_dir / f"{int(t_ns)}{_SUFFIX}"

    def stamps(self) -> set[int]:
        """Stamps with an entry on disk (not yet checked)."""
        if not self.frames_dir.is_dir():
            return set()
        out = set()
        for p in self.frames_dir.glob(f"*{_SUFFIX}"):
            try:
                out.add(int(p.stem))
            except ValueError:
                continue
        return out

    def put(self, t_ns: int, arrays: dict[str, NDArray[Any]], meta: dict[str, Any]) -> None:
        """Store one frame's result."""
        self.bytes_written += write_entry(self.path(t_ns), arrays, {**meta, "t_ns": int(t_ns)})

    @staticmethod
    def encode(t_ns: int, arrays: dict[str, NDArray[Any]], meta: dict[str, Any]) -> bytes:
        """One frame's entry, encoded (where the result is computed) for :meth:`put_encoded`."""
        return encode_entry(arrays, {**meta, "t_ns": int(t_ns)})

    def put_encoded(self, t_ns: int, data: bytes) -> None:
        """Store one frame's entry made by :meth:`encode`."""
        self.bytes_written += write_entry_bytes(self.path(t_ns), data)

    def get(self, t_ns: int) -> tuple[dict[str, NDArray[Any]], dict[str, Any]] | None:
        """One frame's result, or None when absent or damaged (a damaged entry is logged and
        removed, so the frame is computed again)."""
        p = self.path(t_ns)
        if not p.is_file():
            return None
        try:
            arrays, meta = read_entry(p)
        except CacheEntryError as err:
            log.warning("%s; recomputing that frame", err)
            p.unlink(missing_ok=True)
            return None
        if meta.get("t_ns") != int(t_ns):
            log.warning("%s holds frame %s, not %d; recomputing", p, meta.get("t_ns"), t_ns)
            p.unlink(missing_ok=True)
            return None
        return arrays, meta
