"""Ratio-test matching of ORB descriptors for loop verification."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.odometry.loop import PlaceFeatures, QueryMatcher, hamming


def _place(desc: np.ndarray) -> PlaceFeatures:
    n = desc.shape[0]
    return PlaceFeatures(uv=np.zeros((n, 2), np.float32), descriptors=desc,
                         points_rect=np.zeros((n, 3), np.float32))


def _reference(q: np.ndarray, t: np.ndarray, ratio: float) -> list[tuple[int, int, float]]:
    d = hamming(q, t)
    out = []
    for i, row in enumerate(d):
        order = np.argsort(row, kind="stable")
        best, second = int(row[order[0]]), int(row[order[1]])
        if best < ratio * second and best < 64:
            out.append((i, int(order[0]), float(best)))
    return out


@pytest.mark.parametrize("ratio", [0.8, 0.6])
def test_matches_agree_with_brute_force(ratio: float) -> None:
    rng = np.random.default_rng(3)
    train = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    # queries: noisy copies of some train rows (a few bits flipped), plus unrelated ones
    src = rng.integers(0, 300, 200)
    noisy = train[src].copy()
    flips = rng.integers(0, 256, noisy.shape, dtype=np.uint8) & (
        rng.random(noisy.shape) < 0.08).astype(np.uint8) * 0xFF
    noisy ^= flips
    query = np.concatenate([noisy, rng.integers(0, 256, (100, 32), dtype=np.uint8)])
    got = QueryMatcher(_place(query), ratio).matches(_place(train))
    want = _reference(query, train, ratio)
    assert got == want
    assert len(got) > 100  # the noisy copies find their rows
    assert all(t == int(src[q]) for q, t, _ in got if q < 200)


def test_ties_and_small_places() -> None:
    rng = np.random.default_rng(4)
    row = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    m = QueryMatcher(_place(row))
    assert m.matches(_place(np.concatenate([row, row]))) == []  # equal best two: ambiguous
    assert m.matches(_place(row)) == []  # one descriptor: no second to compare with
    far = row ^ np.uint8(0xFF)
    assert m.matches(_place(np.concatenate([row, far]))) == [(0, 0, 0.0)]
    assert QueryMatcher(_place(np.zeros((0, 32), np.uint8))).matches(_place(row)) == []
