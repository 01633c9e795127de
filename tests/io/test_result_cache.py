"""Cache entries: round trip, atomic writes, damage detected and never passed on as good."""

import json

import numpy as np
import pytest

from sea3d.io.result_cache import CacheEntryError, FrameCache, read_entry, write_entry


def test_entry_round_trip(tmp_path, rng):
    arrays = {"depth": rng.random((30, 40)).astype(np.float32),
              "img": rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)}
    arrays["depth"][3, 4] = np.nan
    write_entry(tmp_path / "e.s3c", arrays, {"status": "ok", "t": 5})
    back, meta = read_entry(tmp_path / "e.s3c")
    assert meta == {"status": "ok", "t": 5}
    np.testing.assert_array_equal(back["depth"], arrays["depth"])
    np.testing.assert_array_equal(back["img"], arrays["img"])
    assert not list(tmp_path.glob(".*tmp*")), "temporary files left behind"


@pytest.mark.parametrize("damage", ["truncate", "flip", "header"])
def test_damaged_entries_are_detected(tmp_path, rng, damage):
    write_entry(tmp_path / "e.s3c", {"a": rng.random(1000)}, {})
    data = bytearray((tmp_path / "e.s3c").read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":
        data[len(data) // 2] ^= 0x40
    else:
        data[:4] = b"JUNK"
    (tmp_path / "e.s3c").write_bytes(bytes(data))
    with pytest.raises(CacheEntryError, match=r"e\.s3c"):
        read_entry(tmp_path / "e.s3c")


def test_frame_cache_drops_damaged_entries_and_checks_its_configuration(tmp_path, rng):
    cache = FrameCache(tmp_path / "cache", {"size": [320, 180]})
    assert cache.check_fingerprint()
    cache.put(100, {"d": rng.random(10)}, {"status": "ok"})
    cache.put(200, {"d": rng.random(10)}, {"status": "ok"})
    assert cache.stamps() == {100, 200}
    p = cache.path(200)
    p.write_bytes(p.read_bytes()[:-3])
    assert cache.get(100) is not None
    assert cache.get(200) is None and not p.exists()  # recomputed next time
    other = FrameCache(tmp_path / "cache", {"size": [640, 360]})
    assert not other.check_fingerprint()
    assert other.clear() == 1 and other.check_fingerprint()


@pytest.mark.parametrize("damage", [b'{\n "size": [32', b"\x00" * 40, b"", b"[320, 180]\n"])
def test_a_damaged_configuration_file_is_named_and_can_be_rebuilt_keeping_the_frames(
        tmp_path, rng, damage):
    cache = FrameCache(tmp_path / "cache", {"size": [320, 180]})
    assert cache.check_fingerprint()
    cache.put(100, {"d": rng.random(10)}, {"status": "ok"})
    cache.put(200, {"d": rng.random(10)}, {"status": "ok"})
    cfg = tmp_path / "cache" / "config.json"
    cfg.write_bytes(damage)
    again = FrameCache(tmp_path / "cache", {"size": [320, 180]})
    with pytest.raises(CacheEntryError, match="damaged") as info:
        again.check_fingerprint()
    message = str(info.value)
    assert str(cfg) in message and "2 cached frames" in message and "\n" not in message
    assert "rebuild_cache_config" in message and "fresh" in message
    assert cfg.read_bytes() == damage and again.stamps() == {100, 200}  # nothing touched
    assert again.check_fingerprint(rebuild=True)
    assert json.loads(cfg.read_text()) == {"size": [320, 180]}
    assert again.stamps() == {100, 200} and again.get(100) is not None
    assert FrameCache(tmp_path / "cache", {"size": [320, 180]}).check_fingerprint()


def test_rebuilding_never_replaces_a_readable_configuration_of_another_run(tmp_path, rng):
    cache = FrameCache(tmp_path / "cache", {"size": [320, 180]})
    assert cache.check_fingerprint()
    cache.put(100, {"d": rng.random(10)}, {"status": "ok"})
    other = FrameCache(tmp_path / "cache", {"size": [640, 360]})
    assert not other.check_fingerprint(rebuild=True)
    assert json.loads((tmp_path / "cache" / "config.json").read_text()) == {"size": [320, 180]}


def test_filtered_entries_round_trip_exactly_and_are_smaller(tmp_path, rng):
    """Byte shuffle (floats) and row deltas (uint8 images) are lossless, NaN and wrap-around
    included; on smooth data (a depth ramp with noise, a gradient image) they compress
    better than the plain archive."""
    v, u = np.mgrid[0:180, 0:320]
    depth = (1.0 + 0.004 * u + 0.002 * v + rng.normal(0, 1e-3, u.shape)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    img = np.clip(np.stack([u, v, u + v], axis=2) * 0.6 + rng.normal(0, 2, (180, 320, 3)),
                  0, 255).astype(np.uint8)
    arrays = {"depth": depth, "img": img, "d64": rng.random((50, 60)),
              "grey": rng.integers(0, 256, (90, 100), dtype=np.uint8),
              "keys": rng.integers(-5, 5, (700, 3), dtype=np.int32)}
    n = write_entry(tmp_path / "f.s3c", arrays, {})
    back, _ = read_entry(tmp_path / "f.s3c")
    for k, a in arrays.items():
        assert back[k].dtype == a.dtype and back[k].shape == a.shape, k
        np.testing.assert_array_equal(back[k], a)

    import io as _io

    import imagecodecs  # the plain archive, as entries were written before the filters
    buf = _io.BytesIO()
    np.savez(buf, **arrays)
    assert n < 0.85 * len(imagecodecs.zstd_encode(buf.getvalue(), level=3))


def test_entries_without_filters_still_read(tmp_path, rng):
    import io as _io
    import struct
    import zlib

    import imagecodecs

    a = rng.random((40, 40)).astype(np.float32)
    buf = _io.BytesIO()
    np.savez(buf, __meta__=np.array('{"status": "ok"}'), depth=a)
    payload = imagecodecs.zstd_encode(buf.getvalue(), level=3)
    (tmp_path / "old.s3c").write_bytes(b"SEA3DC1\n" + struct.pack("<QI", len(payload),
                                       zlib.crc32(payload)) + payload)
    back, meta = read_entry(tmp_path / "old.s3c")
    assert meta == {"status": "ok"}
    np.testing.assert_array_equal(back["depth"], a)


def test_an_entry_encoded_elsewhere_is_written_as_put_writes_it(tmp_path, rng):
    """A worker encodes a frame's entry (FrameCache.encode) and the caller only writes its
    bytes: the file is the one put writes, and bytes that are not an entry are refused."""
    from sea3d.errors import SessionError

    arrays = {"depth_m": rng.random((60, 80)).astype(np.float32),
              "rect_left": rng.integers(0, 255, (60, 80), dtype=np.uint8)}
    meta = {"status": "ok", "valid_fraction": 0.5}
    a = FrameCache(tmp_path / "a", {"k": 1})
    b = FrameCache(tmp_path / "b", {"k": 1})
    a.put(7, arrays, meta)
    b.put_encoded(7, FrameCache.encode(7, arrays, meta))
    assert a.path(7).read_bytes() == b.path(7).read_bytes()
    assert a.bytes_written == b.bytes_written > 0
    back, m = b.get(7)
    assert m["t_ns"] == 7
    np.testing.assert_array_equal(back["depth_m"], arrays["depth_m"])
    with pytest.raises(SessionError, match="not a cache entry"):
        b.put_encoded(8, b"PNG....")
    assert not b.path(8).exists()
