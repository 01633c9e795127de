"""Numba kernels of sea3d's semi-global matcher (private; see :mod:`sea3d.stereo.sgm`).

Layout: every per-pixel disparity search is a *band* ``d = lo[y, x] + k`` for
``k in range(n[y, x])``; costs and aggregated costs are stored as ``(H, W, K)`` arrays with
``K = max(n)``. A full search is the band ``lo = 0``, ``n = D``; the coarse-to-fine search narrows
the band around the disparity found one pyramid level up, so memory and time scale with the band
width, not the disparity range.

The path recursion is Hirschmüller's (PAMI 2008, eq. 13) with the path minimum subtracted::

    L_r(p, d) = C(p, d) + min(L_r(q, d), L_r(q, d-1) + P1, L_r(q, d+1) + P1,
                              min_k L_r(q, k) + P2(p, q)) - min_k L_r(q, k)

with ``q = p - r``; ``L_r(q, d)`` is infinite where ``d`` lies outside ``q``'s band. P2 is adapted
to the guide image: ``P2(p, q) = max(P1 + 1, P2 * tau / (tau + |I(p) - I(q)|))``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_INF = 1 << 20

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_U1 = np.uint64(1)
_U2 = np.uint64(2)
_U4 = np.uint64(4)
_U56 = np.uint64(56)


@njit(cache=True, inline="always")
def _popcount64(x: np.uint64) -> int:
    x = x - ((x >> _U1) & _M1)
    x = (x & _M2) + ((x >> _U2) & _M2)
    x = (x + (x >> _U4)) & _M4
    return int((x * _H01) >> _U56)


@njit(parallel=True, cache=True)
def census_transform(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census signature of each pixel: one bit per window neighbour darker than the centre.

    ``img`` (H, W) float32; window (2*half_h+1) x (2*half_w+1) <= 65 pixels; borders replicate.
    Returns (H, W) uint64. Loops run over whole rows per window offset so that they vectorise.
    """
    h, w = img.shape
    out = np.empty((h, w), np.uint64)
    x0 = min(half_w, w)
    x1 = max(w - half_w, x0)
    for y in prange(h):
        sig = np.zeros(w, np.uint64)
        row = img[y]
        for dy in range(-half_h, half_h + 1):
            nb = img[min(max(y + dy, 0), h - 1)]
            for dx in range(-half_w, half_w + 1):
                if dy == 0 and dx == 0:
                    continue
                for x in range(x0, x1):
                    bit = np.uint64(1) if nb[x + dx] < row[x] else np.uint64(0)
                    sig[x] = (sig[x] << _U1) | bit
                for x in range(0, x0):
                    xx = min(max(x + dx, 0), w - 1)
                    bit = np.uint64(1) if nb[xx] < row[x] else np.uint64(0)
                    sig[x] = (sig[x] << _U1) | bit
                for x in range(x1, w):
                    xx = min(max(x + dx, 0), w - 1)
                    bit = np.uint64(1) if nb[xx] < row[x] else np.uint64(0)
                    sig[x] = (sig[x] << _U1) | bit
        for x in range(w):
            out[y, x] = sig[x]
    return out


@njit(parallel=True, cache=True)
def band_costs(
    census_l: np.ndarray, census_r: np.ndarray, lo: np.ndarray, n: np.ndarray, k_max: int
) -> np.ndarray:
    """Hamming distance of census signatures over each pixel's band.

    Returns (H, W, k_max) uint8; ``cost[y, x, k]`` matches left ``x`` with right ``x - lo - k``.
    Bands never reach past the right image's left edge (``lo + n - 1 <= x``).
    """
    h, w = census_l.shape
    cost = np.empty((h, w, k_max), np.uint8)
    for y in prange(h):
        for x in range(w):
            cl = census_l[y, x]
            base = x - lo[y, x]
            for k in range(n[y, x]):
                cost[y, x, k] = _popcount64(cl ^ census_r[y, base - k])
    return cost


@njit(cache=True, inline="always")
def _path_step(
    cost: np.ndarray,
    cb: int,
    lo_p: int,
    n_p: int,
    buf: np.ndarray,
    qb: int,
    lo_q: int,
    n_q: int,
    min_q: int,
    p1: int,
    p2: int,
    pb: int,
    total: np.ndarray,
) -> int:
    """One step of the path recursion.

    The pixel's costs are ``cost[cb:cb + n_p]`` (flat volume, band starting at ``lo_p``); the
    previous pixel's path costs are ``buf[qb:qb + n_q]`` (band at ``lo_q``). Writes the new path
    costs to ``buf[pb:pb + n_p]``, adds them to ``total[cb:cb + n_p]`` and returns their minimum.
    ``buf`` holds three slots of ``K + 2`` entries; the third (at ``2 * (K + 2)``) is scratch.
    Only integer offsets are passed around: array views in this loop would cost reference
    counting per pixel.
    """
    c2 = min_q + p2
    m = _INF
    if lo_p == lo_q and n_p == n_q and n_p >= 2:
        # common case: same band; a straight loop the compiler can vectorise
        v = min(buf[qb], buf[qb + 1] + p1)
        v = min(v, c2)
        v = np.int32(cost[cb]) + v - min_q
        buf[pb] = v
        total[cb] += v
        m = v
        for k in range(1, n_p - 1):
            v = min(buf[qb + k - 1], buf[qb + k + 1]) + p1
            v = min(v, buf[qb + k])
            v = min(v, c2)
            v = np.int32(cost[cb + k]) + v - min_q
            buf[pb + k] = v
            total[cb + k] += v
            m = min(m, v)
        k = n_p - 1
        v = min(buf[qb + k], buf[qb + k - 1] + p1)
        v = min(v, c2)
        v = np.int32(cost[cb + k]) + v - min_q
        buf[pb + k] = v
        total[cb + k] += v
        return min(m, v)
    off = lo_p - lo_q
    sb = buf.shape[0] // 3 * 2
    for k in range(n_p + 2):
        j = k - 1 + off
        if 0 <= j < n_q:
            buf[sb + k] = buf[qb + j]
        else:
            buf[sb + k] = _INF
    for k in range(n_p):
        v = min(buf[sb + k], buf[sb + k + 2]) + p1
        v = min(v, buf[sb + k + 1])
        v = min(v, c2)
        v = np.int32(cost[cb + k]) + v - min_q
        buf[pb + k] = v
        total[cb + k] += v
        m = min(m, v)
    return m


@njit(parallel=True, cache=True)
def aggregate_lines(
    cost: np.ndarray,
    lo: np.ndarray,
    n: np.ndarray,
    guide: np.ndarray,
    p1: int,
    p2_lut: np.ndarray,
    total: np.ndarray,
    starts: np.ndarray,
    dy: int,
    dx: int,
) -> None:
    """Aggregate along the scanlines of direction ``(dy, dx)`` and back; *adds* into ``total``.

    ``cost`` (H, W, K) uint8 and ``total`` (H, W, K) uint16 volumes; ``guide`` (H, W) uint8;
    ``p2_lut[|dI|]`` the edge-adapted P2 for an intensity step ``dI``. ``starts`` (N, 2) int64
    holds the first pixel ``(y, x)`` of every scanline (the pixels whose predecessor
    ``(y - dy, x - dx)`` lies outside the image). Scanlines are independent, so they are shared
    among threads with no synchronisation; each walks forward (path ``+r``) and then backward
    (path ``-r``).
    """
    h, w, kk = cost.shape
    cf = cost.reshape(-1)
    tf = total.reshape(-1)
    lof = lo.reshape(-1)
    nf = n.reshape(-1)
    gf = guide.reshape(-1)
    step = dy * w + dx
    slot = kk + 2
    for i in prange(starts.shape[0]):
        buf = np.empty(3 * slot, np.int32)
        y = np.int64(starts[i, 0])
        x = np.int64(starts[i, 1])
        # count the line's pixels
        length = 1
        while 0 <= y + length * dy < h and 0 <= x + length * dx < w:
            length += 1
        for direction in range(2):
            if direction == 0:
                p = y * w + x
                s = step
            else:
                p = (y + (length - 1) * dy) * w + x + (length - 1) * dx
                s = -step
            cb = p * kk
            m = _INF
            for k in range(nf[p]):
                v = np.int32(cf[cb + k])
                buf[k] = v
                tf[cb + k] += v
                m = min(m, int(v))
            qb = 0
            pb = slot
            for _ in range(length - 1):
                q = p
                p = p + s
                pe = p2_lut[abs(np.int32(gf[p]) - np.int32(gf[q]))]
                m = _path_step(cf, p * kk, lof[p], nf[p], buf, qb, lof[q], nf[q], m, p1, pe, pb,
                               tf)
                qb, pb = pb, qb


def p2_table(p1: int, p2: int, tau: float) -> np.ndarray:
    """Edge-adapted P2 for every intensity step 0..255: ``max(P1 + 1, P2 * tau / (tau + dI))``,
    (256,) int32."""
    diff = np.arange(256, dtype=np.float64)
    return np.maximum(np.floor(p2 * tau / (tau + diff)), p1 + 1).astype(np.int32)


def scanline_starts(h: int, w: int, dy: int, dx: int, n_threads: int) -> np.ndarray:
    """First pixels ``(y, x)`` of the scanlines of direction ``(dy, dx)``, (N, 2) int64,
    interleaved so that the static split of a parallel loop gives every thread a fair share
    of long and short lines."""
    ys, xs = np.mgrid[0:h, 0:w]
    pred_out = (ys - dy < 0) | (ys - dy >= h) | (xs - dx < 0) | (xs - dx >= w)
    starts = np.stack([ys[pred_out], xs[pred_out]], axis=1).astype(np.int64)
    t = max(int(n_threads), 1)
    order = np.argsort(np.arange(len(starts)) % t, kind="stable")
    return np.ascontiguousarray(starts[order])


@njit(parallel=True, cache=True)
def select_disparity(
    total: np.ndarray,
    lo: np.ndarray,
    n: np.ndarray,
    uniqueness: float,
    lr_max_diff: int,
    subpixel: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all with subpixel refinement, uniqueness and left-right check.

    ``subpixel``: 0 none, 1 parabola, 2 equiangular. ``uniqueness`` is the minimum relative
    margin ``(second - best) / best`` of the best cost over the best cost outside ``best +- 1``.
    ``lr_max_diff < 0`` disables the left-right check. The right view's disparity is the
    winner-take-all along the same aggregated volume's diagonals.

    Returns disparity (H, W) float32 (NaN invalid) and confidence (H, W) float32 in [0, 1]:
    ``1 - best / second`` (0 where invalid).
    """
    h, w, _kk = total.shape
    disp = np.empty((h, w), np.float32)
    conf = np.zeros((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in prange(h):
        rbest = np.full(w, _INF, np.int32)
        rdisp = np.full(w, -1, np.int32)
        dint = np.empty(w, np.int32)
        for x in range(w):
            lo_p = lo[y, x]
            np_ = n[y, x]
            best = _INF
            kb = 0
            for k in range(np_):
                s = int(total[y, x, k])
                if s < best:
                    best = s
                    kb = k
                xr = x - lo_p - k
                if s < rbest[xr]:
                    rbest[xr] = s
                    rdisp[xr] = lo_p + k
            second = _INF
            for k in range(np_):
                if k < kb - 1 or k > kb + 1:
                    s = int(total[y, x, k])
                    if s < second:
                        second = s
            dint[x] = lo_p + kb
            if second < _INF and (second - best) < uniqueness * best:
                disp[y, x] = nan
                dint[x] = -1
                continue
            c = 1.0 if second >= _INF else 1.0 - best / max(second, 1)
            conf[y, x] = c
            delta = 0.0
            if subpixel > 0 and 0 < kb < np_ - 1:
                cm = float(total[y, x, kb - 1])
                c0 = float(best)
                cp = float(total[y, x, kb + 1])
                if subpixel == 1:
                    den = cm - 2.0 * c0 + cp
                    if den > 0:
                        delta = 0.5 * (cm - cp) / den
                else:
                    if cm > cp:
                        den = cm - c0
                        if den > 0:
                            delta = 0.5 * (cm - cp) / den
                    else:
                        den = cp - c0
                        if den > 0:
                            delta = 0.5 * (cm - cp) / den
                delta = min(max(delta, -0.5), 0.5)
            disp[y, x] = np.float32(lo_p + kb + delta)
        if lr_max_diff >= 0:
            for x in range(w):
                d = dint[x]
                if d < 0:
                    continue
                xr = x - d
                if abs(rdisp[xr] - d) > lr_max_diff:
                    disp[y, x] = nan
                    conf[y, x] = 0.0
    return disp, conf


@njit(parallel=True, cache=True)
def band_from_coarse(
    coarse: np.ndarray,
    h: int,
    w: int,
    num_disp: int,
    margin: int,
    band_max: int,
    radius: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel search bands at a level from the disparity one level coarser (half size).

    Invalid (NaN) coarse pixels take the range spanned by their nearest valid neighbours in the
    row (occlusions lie between a foreground and a background disparity). Each fine pixel
    searches ``[2 * min - margin, 2 * max + margin]`` over a ``(2*radius+1)^2`` coarse window,
    capped at ``band_max`` disparities around the coarse value at its own position, and never
    past the right image's left edge. Returns ``lo``, ``n`` (h, w) int32.
    """
    hc, wc = coarse.shape
    cmin = np.empty((hc, wc), np.float32)
    cmax = np.empty((hc, wc), np.float32)
    for yc in prange(hc):
        last = -1.0
        for xc in range(wc):
            v = coarse[yc, xc]
            if v == v:
                last = v
                cmin[yc, xc] = v
            else:
                cmin[yc, xc] = last  # left neighbour, -1 if none
        nxt = -1.0
        for xc in range(wc - 1, -1, -1):
            v = coarse[yc, xc]
            if v == v:
                nxt = v
                cmax[yc, xc] = v
            else:
                a = cmin[yc, xc]
                b = nxt
                if a < 0 and b < 0:
                    cmin[yc, xc] = 0.0
                    cmax[yc, xc] = (num_disp - 1) / 2.0
                elif a < 0:
                    cmin[yc, xc] = b
                    cmax[yc, xc] = b
                elif b < 0:
                    cmax[yc, xc] = a
                else:
                    cmin[yc, xc] = min(a, b)
                    cmax[yc, xc] = max(a, b)
    lo = np.empty((h, w), np.int32)
    nn = np.empty((h, w), np.int32)
    for y in prange(h):
        yc = min(y // 2, hc - 1)
        for x in range(w):
            xc = min(x // 2, wc - 1)
            mn = np.float32(1e9)
            mx = np.float32(-1e9)
            for yy in range(max(yc - radius, 0), min(yc + radius + 1, hc)):
                for xx in range(max(xc - radius, 0), min(xc + radius + 1, wc)):
                    mn = min(mn, cmin[yy, xx])
                    mx = max(mx, cmax[yy, xx])
            a = int(np.floor(2.0 * mn)) - margin
            b = int(np.ceil(2.0 * mx)) + margin
            if b - a + 1 > band_max:
                centre = 2.0 * 0.5 * (cmin[yc, xc] + cmax[yc, xc])
                a = int(np.round(centre)) - band_max // 2
                b = a + band_max - 1
            top = min(num_disp - 1, x)
            a = max(a, 0)
            b = min(b, top)
            if a > b:
                a = max(min(a, top), 0)
                b = a
            lo[y, x] = a
            nn[y, x] = b - a + 1
    return lo, nn


@njit(parallel=True, cache=True)
def full_band(h: int, w: int, num_disp: int) -> tuple[np.ndarray, np.ndarray]:
    """The full search ``[0, num_disp)`` cut at the right image's left edge."""
    lo = np.zeros((h, w), np.int32)
    nn = np.empty((h, w), np.int32)
    for y in prange(h):
        for x in range(w):
            nn[y, x] = min(num_disp, x + 1)
    return lo, nn
