"""Place recognition without downloaded weights, and geometric verification of loop candidates.

- :class:`Vocabulary`: a tree of binary words (k-majority clustering of ORB descriptors, as in
  DBoW2: Galvez-Lopez and Tardos, T-RO 2012) trained on the dive's own first keyframes, with
  inverse-document-frequency weights.
- :class:`KeyframeDatabase`: an inverted index of the keyframes' bag-of-words vectors; the score
  of two L1-normalised vectors is ``sum_w min(a_w, b_w)`` (DBoW2's L1 score, in [0, 1]).
- :func:`verify_loop`: ORB matches between the query and a candidate, PnP RANSAC of the
  candidate's 3D points (exact, from its refraction-corrected depth) against the query's pixels,
  then a 3D-3D check of the inliers that have depth in both; the loop carries the covariance of
  its PnP fit, so a closure whose inliers crowd into a corner of the image (a fit that trades
  rotation for translation) weighs less in the pose graph than one spread over the view.
"""

from __future__ import annotations

import logging
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.odometry._hamming_kernel import ratio_matches

_NO_DIST = np.zeros(4)  # rectified, virtual-pinhole consistent pixels: no distortion

__all__ = [
    "KeyframeDatabase",
    "LoopCandidate",
    "PlaceFeatures",
    "QueryMatcher",
    "Vocabulary",
    "confirm_loop",
    "pnp_covariance",
    "verify_loop",
]

log = logging.getLogger(__name__)
U8 = NDArray[np.uint8]

_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def hamming(a: U8, b: U8) -> NDArray[np.int32]:
    """Hamming distances ``(N, M)`` between binary descriptors ``a (N, 32)`` and ``b (M, 32)``."""
    x = np.bitwise_xor(a[:, None, :], b[None, :, :])
    return _POPCOUNT[x].sum(axis=2, dtype=np.int32)


@dataclass(frozen=True, kw_only=True, eq=False)
class PlaceFeatures:
    """What a keyframe keeps for place recognition and verification.

    Attributes:
        uv: (N, 2) float32 rectified left pixels of its ORB features (virtual-pinhole consistent
            where a depth is known: see :mod:`sea3d.odometry.stereo_geometry`).
        descriptors: (N, 32) uint8 ORB descriptors.
        points_rect: (N, 3) float32 exact 3D points in ``rect_left``, NaN where no depth.
    """

    uv: NDArray[np.float32]
    descriptors: U8
    points_rect: NDArray[np.float32]

    @property
    def nbytes(self) -> int:
        """Memory held, bytes."""
        return int(self.uv.nbytes + self.descriptors.nbytes + self.points_rect.nbytes)


class Vocabulary:
    """A vocabulary tree of binary words.

    Args:
        centres: per level ``l`` an array ``(k ** (l + 1), 32)`` uint8; the children of node
            ``i`` of level ``l - 1`` are ``i * k ... i * k + k - 1`` of level ``l``.
        idf: ``(k ** depth,)`` inverse document frequency of each word.
        branching: ``k``.
    """

    def __init__(self, centres: list[U8], idf: NDArray[np.float32], branching: int) -> None:
        self.centres = centres
        self.idf = idf
        self.branching = branching

    @property
    def words(self) -> int:
        """Number of words (leaves)."""
        return int(self.centres[-1].shape[0])

    @classmethod
    def train(
        cls,
        descriptors: U8,
        documents: Sequence[NDArray[np.integer[Any]]],
        *,
        branching: int = 10,
        depth: int = 3,
        iterations: int = 6,
        seed: int = 0,
    ) -> Vocabulary:
        """Train on ``descriptors (N, 32)``; ``documents`` lists each training keyframe's rows
        (for the inverse document frequencies)."""
        rng = np.random.default_rng(seed)
        k = branching
        centres: list[U8] = []
        assign = np.zeros(descriptors.shape[0], dtype=np.int64)
        for _level in range(depth):
            n_nodes = int(assign.max()) + 1 if centres else 1
            level_centres = np.zeros((n_nodes * k, descriptors.shape[1]), dtype=np.uint8)
            new_assign = np.zeros_like(assign)
            for node in range(n_nodes):
                rows = np.flatnonzero(assign == node)
                c = _kmajority(descriptors[rows], k, iterations, rng)
                level_centres[node * k : node * k + k] = c
                if rows.size:
                    new_assign[rows] = node * k + np.argmin(hamming(descriptors[rows], c), axis=1)
            centres.append(level_centres)
            assign = new_assign
        vocab = cls(centres, np.zeros(centres[-1].shape[0], np.float32), k)
        df = np.zeros(vocab.words, dtype=np.float64)
        for doc in documents:
            df[np.unique(assign[doc])] += 1
        n_docs = max(len(documents), 1)
        vocab.idf = np.log(n_docs / np.maximum(df, 1.0)).astype(np.float32) + np.float32(1e-3)
        return vocab

    def quantise(self, descriptors: U8) -> NDArray[np.int64]:
        """Word id of each descriptor ``(N, 32)``."""
        idx = np.zeros(descriptors.shape[0], dtype=np.int64)
        k = self.branching
        for level in self.centres:
            cand = idx[:, None] * k + np.arange(k)[None, :]
            c = level[cand]  # (N, k, 32)
            x = np.bitwise_xor(descriptors[:, None, :], c)
            d = _POPCOUNT[x].sum(axis=2, dtype=np.int32)
            idx = cand[np.arange(idx.size), np.argmin(d, axis=1)]
        return idx

    def bow(self, descriptors: U8) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """L1-normalised tf-idf vector as sorted ``(word ids, weights)``."""
        if descriptors.shape[0] == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        words, counts = np.unique(self.quantise(descriptors), return_counts=True)
        w = counts.astype(np.float32) * self.idf[words]
        total = float(w.sum())
        return words, (w / total if total > 0 else w).astype(np.float32)


def _kmajority(desc: U8, k: int, iterations: int, rng: np.random.Generator) -> U8:
    """k-majority clustering of binary descriptors (k-means with Hamming distance and bitwise
    majority centres), seeded k-means++ style."""
    n = desc.shape[0]
    if n == 0:
        return np.zeros((k, 32), dtype=np.uint8)
    if n <= k:
        out = np.zeros((k, desc.shape[1]), dtype=np.uint8)
        out[:n] = desc
        out[n:] = desc[0]
        return out
    first = int(rng.integers(n))
    chosen = [first]
    dmin = hamming(desc, desc[[first]])[:, 0].astype(np.float64)
    for _ in range(1, k):
        p = dmin**2
        s = p.sum()
        nxt = int(rng.choice(n, p=p / s)) if s > 0 else int(rng.integers(n))
        chosen.append(nxt)
        dmin = np.minimum(dmin, hamming(desc, desc[[nxt]])[:, 0])
    centres = desc[chosen].copy()
    bits = np.unpackbits(desc, axis=1)
    for _ in range(iterations):
        lab = np.argmin(hamming(desc, centres), axis=1)
        for c in range(k):
            members = bits[lab == c]
            if members.shape[0]:
                centres[c] = np.packbits(members.mean(axis=0) > 0.5)
    return centres


class KeyframeDatabase:
    """Inverted index of keyframe bag-of-words vectors."""

    def __init__(self, words: int) -> None:
        self._kf: list[array[int]] = [array("q") for _ in range(words)]
        self._w: list[array[float]] = [array("f") for _ in range(words)]
        self.size = 0

    def add(self, kf: int, bow: tuple[NDArray[np.int64], NDArray[np.float32]]) -> None:
        """Index keyframe ``kf``."""
        for word, weight in zip(bow[0].tolist(), bow[1].tolist(), strict=True):
            self._kf[word].append(kf)
            self._w[word].append(weight)
        self.size += 1

    def query(
        self, bow: tuple[NDArray[np.int64], NDArray[np.float32]], n_keyframes: int
    ) -> NDArray[np.float64]:
        """Scores ``(n_keyframes,)`` of every indexed keyframe against ``bow`` (0 when absent)."""
        score = np.zeros(n_keyframes, dtype=np.float64)
        ids, ws = [], []
        for word, weight in zip(bow[0].tolist(), bow[1].tolist(), strict=True):
            if self._kf[word]:
                kf = np.frombuffer(self._kf[word], dtype=np.int64)
                w = np.frombuffer(self._w[word], dtype=np.float32)
                ids.append(kf)
                ws.append(np.minimum(w, weight))
        if ids:
            kf_all = np.concatenate(ids)
            keep = kf_all < n_keyframes
            score += np.bincount(
                kf_all[keep],
                weights=np.concatenate(ws)[keep].astype(np.float64),
                minlength=n_keyframes,
            )[:n_keyframes]
        return score


@dataclass(frozen=True, kw_only=True, eq=False)
class LoopCandidate:
    """A verified loop.

    Attributes:
        candidate: the earlier keyframe's id.
        T_cand_query: 4x4, maps the query's ``rect_left`` points into the candidate's.
        inliers: PnP inliers.
        consistent_3d: inliers whose two 3D points agree after the transform.
        covariance: (6, 6) covariance of ``T_cand_query`` as ``T_cand_query @ Exp(xi)``,
            ``xi = (rotation rad, translation m)`` in the query's ``rect_left`` (gtsam's Pose3
            tangent, as a pose graph edge wants it); None when not known.
    """

    candidate: int
    T_cand_query: F64
    inliers: int
    consistent_3d: int
    covariance: F64 | None = None


def _skew(x: F64) -> F64:
    """``(N, 3)`` vectors to ``(N, 3, 3)`` cross-product matrices."""
    S = np.zeros((x.shape[0], 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -x[:, 2], x[:, 1], -x[:, 0]
    return S - S.transpose(0, 2, 1)


def _pinhole(X: F64, K: F64) -> tuple[F64, F64]:
    """Pinhole projections ``(N, 2)`` of points ``X (N, 3)`` and their Jacobians ``(N, 2, 3)``."""
    x, y, z = X.T
    fx, fy = float(K[0, 0]), float(K[1, 1])
    Jp = np.zeros((X.shape[0], 2, 3))
    Jp[:, 0, 0], Jp[:, 0, 2] = fx / z, -fx * x / z**2
    Jp[:, 1, 1], Jp[:, 1, 2] = fy / z, -fy * y / z**2
    return np.stack([fx * x / z + K[0, 2], fy * y / z + K[1, 2]], axis=1), Jp


def pnp_covariance(points_query: F64, uv: F64, K: F64) -> F64 | None:
    """Covariance of a PnP pose from its inliers' reprojection residuals (Gauss-Newton).

    With ``J (2N, 6)`` the Jacobian of the pinhole projections of ``points_query`` with respect
    to the perturbation ``xi`` of :class:`LoopCandidate` (the query's points move as
    ``Exp(-xi) @ p``: ``dp/dxi = [[p]_x, -I]``) and ``r`` the residuals, the covariance is
    ``s^2 (J^T J)^-1`` with ``s^2 = |r|^2 / (2N - 6)`` (Hartley and Zisserman, 2nd ed., 5.2.3).
    The weak directions of a poorly spread fit (rotation traded for translation) come out as
    large deviations.

    Args:
        points_query: (N, 3) inlier points in the query's ``rect_left`` after the fit, metres.
        uv: (N, 2) their measured query pixels (virtual pinhole).
        K: (3, 3) virtual-pinhole intrinsics.

    Returns:
        (6, 6) covariance, or None when the fit has fewer than 4 points or is degenerate.
    """
    n = points_query.shape[0]
    if n < 4 or not (points_query[:, 2] > 0).all():
        return None
    proj, Jp = _pinhole(points_query, K)
    dp = np.concatenate([_skew(points_query), -np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)
    J = (Jp @ dp).reshape(2 * n, 6)
    H = J.T @ J
    if not np.isfinite(H).all() or np.linalg.cond(H) > 1e12:
        return None
    s2 = float(np.sum((proj - uv) ** 2)) / (2 * n - 6)
    return s2 * np.linalg.inv(H)


class QueryMatcher:
    """The ratio-test matches of one query's ORB descriptors against places, each place (by a
    key the caller gives, a keyframe id) matched once however many candidates' local maps it
    is part of.

    Args:
        query: the query keyframe's features.
        ratio: Lowe's ratio of the best to the second-best Hamming distance.
    """

    def __init__(self, query: PlaceFeatures, ratio: float = 0.8) -> None:
        self.query = query
        self.ratio = ratio
        self._words = _as_words(query.descriptors)
        self._cache: dict[int, list[tuple[int, int, float]]] = {}

    def matches(self, place: PlaceFeatures, key: int | None = None
                ) -> list[tuple[int, int, float]]:
        """``(query index, place index, distance)`` of the query features whose best match
        in ``place`` passes the ratio test (and is under 64 bits)."""
        if key is not None and key in self._cache:
            return self._cache[key]
        out: list[tuple[int, int, float]] = []
        if place.descriptors.shape[0] >= 2 and self._words.shape[0]:
            qi, ti, dist = ratio_matches(self._words, _as_words(place.descriptors),
                                         self.ratio, 64)
            out = list(zip(qi.tolist(), ti.tolist(), dist.astype(float).tolist(), strict=True))
        if key is not None:
            self._cache[key] = out
        return out


def _as_words(descriptors: U8) -> NDArray[np.uint64]:
    """``(N, 32)`` uint8 descriptors as ``(N, 4)`` 64-bit words (the same bits)."""
    return np.ascontiguousarray(descriptors, dtype=np.uint8).view(np.uint64)


def _match_places(
    query: PlaceFeatures, places: list[PlaceFeatures], ratio: float,
    matcher: QueryMatcher | None = None, keys: Sequence[int] | None = None,
) -> tuple[NDArray[np.int64], F64]:
    """Query feature indices and the 3D points (in the first place's frame) they match: the
    ratio test within each place, then each query feature's best match over the places."""
    if matcher is None or matcher.query is not query:
        matcher, keys = QueryMatcher(query, ratio), None
    best: dict[int, tuple[float, NDArray[np.float32]]] = {}
    for i, place in enumerate(places):
        for q, t, dist in matcher.matches(place, None if keys is None else keys[i]):
            if q not in best or dist < best[q][0]:
                best[q] = (dist, place.points_rect[t])
    q_idx = np.asarray(sorted(best), dtype=np.int64)
    points = (np.asarray([best[q][1] for q in q_idx.tolist()], dtype=np.float64)
              if q_idx.size else np.zeros((0, 3)))
    return q_idx, points


def verify_loop(
    query: PlaceFeatures,
    cand: PlaceFeatures,
    cand_id: int,
    K: F64,
    *,
    min_inliers: int,
    threshold_px: float = 2.0,
    ratio: float = 0.8,
    local_map: list[PlaceFeatures] | None = None,
    min_spread: float = 0.0,
    matcher: QueryMatcher | None = None,
    place_keys: Sequence[int] | None = None,
) -> LoopCandidate | None:
    """Geometric verification of a loop candidate.

    The candidate's 3D points and the query's pixels give ``T_query_cand`` by PnP RANSAC; the
    loop is kept when at least ``min_inliers`` inliers remain and most inliers with depth in both
    keyframes agree in 3D (within 3 cm plus 3 % of their depth).

    ``local_map``: the candidate's neighbouring keyframes' features with their points moved into
    the candidate's frame (by the odometry between them): the query is matched against each
    place apart (the ratio test within one place) and each query feature keeps its best match,
    so the inliers cover the part of the view that the candidate alone missed, as ORB-SLAM
    verifies a loop against the candidate's covisible map rather than one keyframe.

    ``matcher`` and ``place_keys`` (one key per place: the candidate, then ``local_map``):
    reuse the query's matches against places already matched for another candidate.

    ``min_spread``: the PnP inliers must span at least this fraction of the view's width and of
    its height (a pose fitted to a small patch of the view is not determined).

    Before PnP RANSAC, the matches with depth in both keyframes must agree on one rigid motion
    for at least half of ``min_inliers`` of them (a batched 3-pair RANSAC): most candidates are
    places that only look alike, and this refuses them for a fraction of PnP's cost.

    Returns:
        A :class:`LoopCandidate`, or None when the geometry does not hold.
    """
    if query.descriptors.shape[0] < min_inliers or cand.descriptors.shape[0] < min_inliers:
        return None
    places = [cand, *(local_map or [])]
    q_idx, points = _match_places(query, places, ratio, matcher, place_keys)
    if len(q_idx) < min_inliers:
        return None
    P = points
    ok = np.isfinite(P).all(axis=1)
    if ok.sum() < min_inliers:
        return None
    q_idx, P = q_idx[ok], P[ok]
    uv = query.uv[q_idx].astype(np.float64)
    Pq_m = query.points_rect[q_idx].astype(np.float64)
    has3 = np.isfinite(Pq_m).all(axis=1)
    if has3.sum() >= min_inliers:
        # a cheap first look: most pairs with depth in both keyframes must agree on one rigid
        # motion; a place that only looks alike rarely gives even half the inliers needed
        tol3 = 2 * (0.03 + 0.03 * np.abs(Pq_m[has3, 2]))
        if _consensus_3d(Pq_m[has3], P[has3], tol3) < min_inliers // 2:
            return None
    try:
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            P,
            uv,
            K,
            _NO_DIST,
            iterationsCount=200,
            reprojectionError=threshold_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_AP3P,
        )
    except cv2.error:
        return None
    if not found or inl is None or len(inl) < min_inliers:
        return None
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(P[inl], uv[inl], K, _NO_DIST, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T_qc = np.eye(4)
    T_qc[:3, :3] = R
    T_qc[:3, 3] = tvec.ravel()
    proj, _ = cv2.projectPoints(P, rvec, tvec, K, _NO_DIST)
    err = np.linalg.norm(proj.reshape(-1, 2) - uv, axis=1)
    inl = np.flatnonzero(err < threshold_px)
    if inl.size < min_inliers:
        return None
    spread = np.ptp(uv[inl], axis=0) / (2.0 * K[[0, 1], [2, 2]])
    if float(spread.min()) < min_spread:
        log.debug("loop candidate %d: inliers span %.0f %% x %.0f %% of the view (< %.0f %%)",
                  cand_id, 100 * spread[0], 100 * spread[1], 100 * min_spread)
        return None
    Pq = query.points_rect[q_idx[inl]].astype(np.float64)
    both = np.isfinite(Pq).all(axis=1)
    moved = P[inl] @ R.T + T_qc[:3, 3]
    gap = np.linalg.norm(moved - Pq, axis=1)
    tol = 0.03 + 0.03 * np.abs(Pq[:, 2])
    consistent = int(np.count_nonzero(both & (gap < tol)))
    if both.sum() >= min_inliers // 2 and consistent < 0.6 * both.sum():
        return None
    T_cq = np.eye(4)
    T_cq[:3, :3] = R.T
    T_cq[:3, 3] = -R.T @ T_qc[:3, 3]
    return LoopCandidate(
        candidate=cand_id,
        T_cand_query=T_cq,
        inliers=int(inl.size),
        consistent_3d=consistent,
        covariance=pnp_covariance(moved, uv[inl], K),
    )


def _consensus_3d(points_a: F64, points_b: F64, tol_m: F64, hypotheses: int = 300) -> int:
    """The largest number of pairs ``(a_i, b_i)`` that one rigid motion ``b ~ R a + t`` brings
    within ``tol_m (N,)`` of each other, by RANSAC over 3-pair samples (Kabsch, batched)."""
    n = points_a.shape[0]
    if n < 3:
        return 0
    rng = np.random.default_rng(0)
    idx = rng.integers(0, n, (2 * hypotheses, 3))
    distinct = (idx[:, 0] != idx[:, 1]) & (idx[:, 1] != idx[:, 2]) & (idx[:, 0] != idx[:, 2])
    idx = idx[distinct][:hypotheses]
    hypotheses = idx.shape[0]
    A, B = points_a[idx], points_b[idx]  # (h, 3, 3)
    ma, mb = A.mean(axis=1, keepdims=True), B.mean(axis=1, keepdims=True)
    H = (A - ma).transpose(0, 2, 1) @ (B - mb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.transpose(0, 2, 1) @ U.transpose(0, 2, 1)))
    D = np.broadcast_to(np.eye(3), (hypotheses, 3, 3)).copy()
    D[:, 2, 2] = d
    R = Vt.transpose(0, 2, 1) @ D @ U.transpose(0, 2, 1)
    t = mb[:, 0, :] - (R @ ma.transpose(0, 2, 1))[:, :, 0]
    moved = np.einsum("hij,nj->hni", R, points_a) + t[:, None, :]
    inliers = (np.linalg.norm(moved - points_b[None], axis=2) < tol_m[None]).sum(axis=1)
    return int(inliers.max())


def confirm_loop(
    loop: LoopCandidate,
    views: Sequence[tuple[PlaceFeatures | None, F64]],
    cand: PlaceFeatures,
    local_map: list[PlaceFeatures],
    K: F64,
    graph: Any,
    *,
    min_inliers: int,
    min_spread: float,
    max_chi2: float,
) -> tuple[bool, float]:
    """A loop seen again from other views of the query's (its previous keyframes): each is
    verified against the same candidate and local map (:func:`verify_loop`), and the loop is
    confirmed by the first whose relative pose agrees with the loop's, ``T_cand_query @
    T_query_view`` against it under both loops' covariances (``graph.loops_agree``, a
    :class:`~sea3d.odometry.posegraph.PoseGraph`): chi-square at most ``max_chi2``.

    Args:
        loop: the verified loop (from the query).
        views: per other view, its place (None: none) and ``T_query_view`` (4x4, the odometry
            between the two).
        cand: the candidate's place.
        local_map: the candidate's local map, as the loop was verified against.
        K: (3, 3) rectified intrinsics.
        graph: the pose graph (its loop covariances and ``loops_agree``).
        min_inliers: as for :func:`verify_loop`.
        min_spread: as for :func:`verify_loop`.
        max_chi2: the largest squared distance that agrees.

    Returns:
        ``(confirmed, chi2)``: the chi-square of the confirming view, or the smallest of those
        that verified (inf when none did).
    """
    best = float("inf")
    for place, T_query_view in views:
        if place is None:
            continue
        other = verify_loop(place, cand, loop.candidate, K, min_inliers=min_inliers,
                            local_map=local_map, min_spread=min_spread)
        if other is None:
            continue
        chi2 = float(graph.loops_agree(loop.T_cand_query, loop.covariance, T_query_view,
                                       other.T_cand_query, other.covariance))
        if chi2 <= max_chi2:
            return True, chi2
        best = min(best, chi2)
    return False, best
