"""Cache entries: round trip, atomic writes, damage detected and never passed on as good."""

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
