"""TUM trajectory files: write then read, and bad lines named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sea3d.errors import SessionError
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.io.tum import read_tum, write_tum

ROUNDTRIP_M = 1e-9  # 9 decimals in the file
ROUNDTRIP_R = 1e-11  # 12 decimals of the quaternion


def test_write_then_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    T = np.tile(np.eye(4), (5, 1, 1))
    for k in range(5):
        T[k, :3, :3] = rotvec_to_R(rng.normal(0, 1.0, 3))
        T[k, :3, 3] = rng.normal(0, 3.0, 3)
    t = np.array([0.0, 0.1, 0.2, 0.35, 1.0])
    write_tum(tmp_path / "a.tum", t, T)
    t2, T2 = read_tum(tmp_path / "a.tum")
    np.testing.assert_allclose(t2, t, atol=ROUNDTRIP_M)
    np.testing.assert_allclose(T2[:, :3, 3], T[:, :3, 3], atol=ROUNDTRIP_M)
    np.testing.assert_allclose(T2[:, :3, :3], T[:, :3, :3], atol=ROUNDTRIP_R)
    # the quaternion is written scalar-last (qx qy qz qw), as TUM's tools expect
    line = (tmp_path / "a.tum").read_text().splitlines()[1].split()
    write_tum(tmp_path / "b.tum", np.zeros(1), np.eye(4)[None])
    assert (tmp_path / "b.tum").read_text().splitlines()[1].split()[4:] == [
        "0.000000000000", "0.000000000000", "0.000000000000", "1.000000000000"]
    assert len(line) == 8


def test_bad_lines_are_named(tmp_path: Path) -> None:
    p = tmp_path / "bad.tum"
    p.write_text("# header\n0 1 2 3 0 0 0 1\n1 2 3\n")
    with pytest.raises(SessionError, match=r"bad\.tum:3"):
        read_tum(p)
    p.write_text("0 1 2 3 0 0 0 0\n")
    with pytest.raises(SessionError, match="quaternion"):
        read_tum(p)
    p.write_text("# nothing\n")
    with pytest.raises(SessionError, match="no poses"):
        read_tum(p)
    with pytest.raises(SessionError, match="cannot read"):
        read_tum(tmp_path / "missing.tum")
