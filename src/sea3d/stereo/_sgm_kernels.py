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
_GROUP = 16  # neighbouring scanlines kept together in one thread's share

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
    Returns (H, W) uint64.
    """
    h, w = img.shape
    out = np.empty((h, w), np.uint64)
    for y in prange(h):
        interior_y = half_h <= y < h - half_h
        for x in range(w):
            c = img[y, x]
            sig = np.uint64(0)
            if interior_y and half_w <= x < w - half_w:
                for dy in range(-half_h, half_h + 1):
                    for dx in range(-half_w, half_w + 1):
                        if dy != 0 or dx != 0:
                            sig = (sig << _U1) | np.uint64(img[y + dy, x + dx] < c)
            else:
                for dy in range(-half_h, half_h + 1):
                    yy = min(max(y + dy, 0), h - 1)
                    for dx in range(-half_w, half_w + 1):
                        if dy != 0 or dx != 0:
                            xx = min(max(x + dx, 0), w - 1)
                            sig = (sig << _U1) | np.uint64(img[yy, xx] < c)
            out[y, x] = sig
    return out


@njit(parallel=True, cache=True)
def band_costs(
    census_l: np.ndarray, census_r: np.ndarray, lo: np.ndarray, n: np.ndarray, offs: np.ndarray
) -> np.ndarray:
    """Hamming distance of census signatures over each pixel's band.

    Returns the packed volume (offs[-1],) uint8: ``cost[offs[y*W+x] + k]`` matches left ``x``
    with right ``x - lo - k``. Bands never reach past the right image's left edge
    (``lo + n - 1 <= x``).
    """
    h, w = census_l.shape
    cost = np.empty(offs[-1], np.uint8)
    for y in prange(h):
        for x in range(w):
            cl = census_l[y, x]
            base = x - lo[y, x]
            cb = offs[y * w + x]
            for k in range(n[y, x]):
                cost[cb + k] = _popcount64(cl ^ census_r[y, base - k])
    return cost


def band_offsets(n: np.ndarray) -> np.ndarray:
    """Start of each pixel's band in the packed volumes: (H*W + 1,) int64 prefix sums of n."""
    offs = np.zeros(n.size + 1, np.int64)
    np.cumsum(n.ravel(), out=offs[1:])
    return offs


@njit(parallel=True, cache=True)
def aggregate_lines(
    cf: np.ndarray,
    lo: np.ndarray,
    n: np.ndarray,
    offs: np.ndarray,
    k_max: int,
    guide: np.ndarray,
    p1: int,
    p2_lut: np.ndarray,
    tf: np.ndarray,
    starts: np.ndarray,
    dy: int,
    dx: int,
) -> None:
    """Aggregate along the scanlines of direction ``(dy, dx)`` and back; *adds* into ``tf``.

    ``cf`` (packed, uint8) and ``tf`` (packed, uint16) are the cost and summed volumes with
    pixel ``p = y * W + x``'s band at ``offs[p]`` (:func:`band_offsets`); ``guide`` (H, W) uint8;
    ``p2_lut[|dI|]`` the edge-adapted P2 for an intensity step ``dI``. ``starts`` (N, 2) int64
    holds the first pixel ``(y, x)`` of every scanline (the pixels whose predecessor
    ``(y - dy, x - dx)`` lies outside the image). Scanlines are independent, so they are shared
    among threads with no synchronisation; each is walked forward (path ``+r``), then backward.

    Path costs live in rows of ``bufs`` (previous, current, re-aligned) with one infinite entry
    on each side of the band, so the recursion's ``d - 1`` and ``d + 1`` need no bounds tests;
    when the band moves between neighbours the previous costs are first re-aligned into the
    third row. (Walking neighbouring lines in lockstep for cache locality measured slower.)
    """
    h, w = lo.shape
    kk = k_max
    lof = lo.reshape(-1)
    nf = n.reshape(-1)
    gf = guide.reshape(-1)
    for i in prange(starts.shape[0]):
        bufs = np.full((3, kk + 2), _INF, np.int32)
        y0 = np.int64(starts[i, 0])
        x0 = np.int64(starts[i, 1])
        length = 1
        while 0 <= y0 + length * dy < h and 0 <= x0 + length * dx < w:
            length += 1
        for direction in range(2):
            if direction == 0:
                p = y0 * w + x0
                s = dy * w + dx
            else:
                p = (y0 + (length - 1) * dy) * w + x0 + (length - 1) * dx
                s = -(dy * w + dx)
            np_ = nf[p]
            cb = offs[p]
            m = _INF
            pi = 0
            for k in range(np_):
                v = np.int32(cf[cb + k])
                bufs[0, k + 1] = v
                tf[cb + k] += v
                m = min(m, int(v))
            bufs[0, np_ + 1] = _INF
            for _ in range(length - 1):
                q = p
                p += s
                n_q = np_
                np_ = nf[p]
                off = lof[p] - lof[q]
                pe = p2_lut[abs(np.int32(gf[p]) - np.int32(gf[q]))]
                c2 = m + pe
                ci = 1 - pi
                si = pi
                if off != 0 or np_ != n_q:
                    for k in range(np_ + 2):
                        j = k + off
                        bufs[2, k] = bufs[pi, j] if 1 <= j <= n_q else _INF
                    si = 2
                cb = offs[p]
                mm = _INF
                for k in range(np_):
                    v = min(bufs[si, k], bufs[si, k + 2]) + p1
                    v = min(v, bufs[si, k + 1])
                    v = min(v, c2)
                    v = np.int32(cf[cb + k]) + v - m
                    bufs[ci, k + 1] = v
                    tf[cb + k] += v
                    mm = min(mm, int(v))
                bufs[ci, np_ + 1] = _INF
                m = mm
                pi = ci


def p2_table(p1: int, p2: int, tau: float) -> np.ndarray:
    """Edge-adapted P2 for every intensity step 0..255: ``max(P1 + 1, P2 * tau / (tau + dI))``,
    (256,) int32."""
    diff = np.arange(256, dtype=np.float64)
    return np.maximum(np.floor(p2 * tau / (tau + diff)), p1 + 1).astype(np.int32)


def scanline_starts(h: int, w: int, dy: int, dx: int, n_threads: int) -> np.ndarray:
    """First pixels ``(y, x)`` of the scanlines of direction ``(dy, dx)``, (N, 2) int64.

    Starts are in border order (neighbouring lines next to each other, as
    :func:`aggregate_lines` groups them), with groups dealt round-robin to the threads' shares
    of a static parallel split, so each thread gets long and short lines alike.
    """
    ys, xs = np.mgrid[0:h, 0:w]
    pred_out = (ys - dy < 0) | (ys - dy >= h) | (xs - dx < 0) | (xs - dx >= w)
    sy, sx = ys[pred_out], xs[pred_out]
    # border order: along rows for starts on the top/bottom edge, then along columns
    on_row_edge = (sy - dy < 0) | (sy - dy >= h)
    key = np.where(on_row_edge, sx, w + sy).astype(np.int64)
    order = np.argsort(key, kind="stable")
    starts = np.stack([sy[order], sx[order]], axis=1).astype(np.int64)
    t = max(int(n_threads), 1)
    block = np.arange(len(starts)) // _GROUP
    order = np.argsort(block % t, kind="stable")
    return np.ascontiguousarray(starts[order])


@njit(parallel=True, cache=True)
def select_disparity(
    total: np.ndarray,
    lo: np.ndarray,
    n: np.ndarray,
    offs: np.ndarray,
    uniqueness: float,
    lr_max_diff: int,
    subpixel: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all with subpixel refinement, uniqueness and left-right check.

    ``subpixel``: 0 none, 1 parabola, 2 equiangular. ``uniqueness`` is the minimum relative
    margin ``(second - best) / best`` of the best cost over the best cost outside ``best +- 1``.
    ``lr_max_diff < 0`` disables the left-right check. The right view's disparity is the
    winner-take-all along the same aggregated volume's diagonals. Pixels without candidates
    (``n = 0``) and winners within a pixel of the right image's left edge where the band was
    cut there are invalid: their true match may lie outside the right image.

    Returns disparity (H, W) float32 (NaN invalid) and confidence (H, W) float32 in [0, 1]:
    ``1 - best / second`` (0 where invalid).
    """
    h, w = lo.shape
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
            cb = offs[y * w + x]
            best = _INF
            kb = 0
            for k in range(np_):
                s = int(total[cb + k])
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
                    s = int(total[cb + k])
                    if s < second:
                        second = s
            dint[x] = lo_p + kb
            # no candidate, or a winner against the right image's left edge with the band cut
            # there: the true match may lie outside the right image
            if np_ == 0 or (lo_p + np_ - 1 == x and lo_p + kb >= x - 1):
                disp[y, x] = nan
                dint[x] = -1
                continue
            if second < _INF and (second - best) < uniqueness * best:
                disp[y, x] = nan
                dint[x] = -1
                continue
            c = 1.0 if second >= _INF else 1.0 - best / max(second, 1)
            conf[y, x] = c
            delta = 0.0
            if subpixel > 0 and 0 < kb < np_ - 1:
                cm = float(total[cb + kb - 1])
                c0 = float(best)
                cp = float(total[cb + kb + 1])
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
    past the right image's left edge; pixels whose whole band lies beyond that edge get
    ``n = 0`` (no candidate: invalid). Returns ``lo``, ``n`` (h, w) int32.
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
                # the coarse level puts this pixel's match left of the right image: no search
                lo[y, x] = max(min(a, top), 0)
                nn[y, x] = 0
                continue
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


@njit(parallel=True, cache=True)
def refine_subpixel(
    left: np.ndarray,
    right: np.ndarray,
    disp: np.ndarray,
    grad_x: np.ndarray,
    grad_y: np.ndarray,
    half_h: int,
    half_w: int,
    iterations: int,
    max_step: float,
) -> np.ndarray:
    """Refine disparities by direct image alignment, removing the cost-curve fit's bias.

    For each valid pixel, the window ``(2*half_h+1) x (2*half_w+1)`` of the left image is
    modelled as ``L(x, y) = a * R(x - d - gx (x - x0) - gy (y - y0)) + b``: gain ``a`` and
    offset ``b`` absorb brightness changes between the views, the disparity gradient
    ``(gx, gy)`` (from the current map, ``grad_x``/``grad_y``) lets the window follow slanted
    surfaces, and ``R`` is interpolated linearly along the row. Starting from ``a = 1, b = 0``,
    ``a``, ``b`` and ``d`` are updated by ``iterations`` Gauss-Newton steps. Updates that move
    ``d`` by more than ``max_step`` pixels, windows leaving the image, or texture-less windows
    keep the input value.

    ``left``, ``right`` (H, W) float32 images; ``disp`` (H, W) float32, NaN invalid;
    ``grad_x``, ``grad_y`` (H, W) float32 px/px (NaN treated as 0). Returns a new map.
    """
    h, w = left.shape
    out = disp.copy()
    for y in prange(h):
        if y < half_h or y >= h - half_h:
            continue
        for x in range(half_w, w - half_w):
            d0 = disp[y, x]
            if d0 != d0:
                continue
            gx = grad_x[y, x]
            gy = grad_y[y, x]
            if gx != gx or abs(gx) > 0.5:
                gx = np.float32(0.0)
            if gy != gy or abs(gy) > 0.5:
                gy = np.float32(0.0)
            d = np.float32(d0)
            a = np.float32(1.0)
            b = np.float32(0.0)
            ok = True
            for _ in range(iterations):
                reach = half_w + 1.0 + abs(gx) * half_w + abs(gy) * half_h
                if x - d - reach < 0.0 or x - d + reach > w - 1.001:
                    ok = False
                    break
                h00 = h01 = h02 = h12 = h22 = np.float32(0.0)
                g0 = g1 = g2 = np.float32(0.0)
                for j in range(-half_h, half_h + 1):
                    rrow = right[y + j]
                    lrow = left[y + j]
                    # the row's shift; the horizontal slant only stretches the window slightly,
                    # so the fractional part is shared by the row (cheap, vectorisable)
                    x0 = x - half_w - d - gy * j
                    i0 = int(x0)
                    f = x0 - i0
                    for i in range(2 * half_w + 1):
                        k = i0 + i + int(np.floor(0.5 - gx * (i - half_w)))
                        r0 = rrow[k]
                        grad = rrow[k + 1] - r0
                        rv = r0 + f * grad
                        jd = a * grad
                        res = lrow[x - half_w + i] - a * rv - b
                        h00 += rv * rv
                        h01 += rv
                        h02 -= rv * jd
                        h12 -= jd
                        h22 += jd * jd
                        g0 += rv * res
                        g1 += res
                        g2 -= jd * res
                h11 = np.float32((2 * half_h + 1) * (2 * half_w + 1))
                c0 = h11 * h22 - h12 * h12
                c1 = h01 * h22 - h12 * h02
                c2 = h01 * h12 - h11 * h02
                det = h00 * c0 - h01 * c1 + h02 * c2
                if abs(det) < 1e-6 * h11 * h11 * h11 or h22 < 1e-3 * h11:
                    ok = False
                    break
                da = (g0 * c0 - h01 * (g1 * h22 - h12 * g2) + h02 * (g1 * h12 - h11 * g2)) / det
                db = (h00 * (g1 * h22 - g2 * h12) - g0 * c1 + h02 * (h01 * g2 - g1 * h02)) / det
                dd = (h00 * (h11 * g2 - h12 * g1) - h01 * (h01 * g2 - g1 * h02) + g0 * c2) / det
                a += da
                b += db
                d += dd
                if abs(d - d0) > max_step:
                    ok = False
                    break
            if ok:
                out[y, x] = d
    return out


@njit(parallel=True, cache=True)
def disparity_gradients(disp: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """Disparity slope per pixel (px/px) by central differences over ``r`` pixels, NaN where
    either neighbour is invalid. Returns ``(grad_x, grad_y)`` (H, W) float32."""
    h, w = disp.shape
    gx = np.full((h, w), np.nan, np.float32)
    gy = np.full((h, w), np.nan, np.float32)
    for y in prange(h):
        for x in range(w):
            if r <= x < w - r:
                gx[y, x] = (disp[y, x + r] - disp[y, x - r]) / (2 * r)
            if r <= y < h - r:
                gy[y, x] = (disp[y + r, x] - disp[y - r, x]) / (2 * r)
    return gx, gy


@njit(parallel=True, cache=True)
def invalidate_left_border(disp: np.ndarray, reach: int, tolerance: float) -> None:
    """Invalidate left-border pixels whose neighbourhood says their match is off the image.

    A left pixel ``x`` can only be matched if its disparity is at most ``x``. Near the left
    border the true disparity may exceed ``x``; the search then returns some wrong smaller
    value. Where the smallest valid disparity among the next ``reach`` pixels to the right
    exceeds ``x + tolerance``, pixel ``x`` is set invalid (in place; NaN). Rows are scanned
    from right to left, so that a run of wrong border pixels cannot vouch for itself: each
    pixel is judged against neighbours already judged.
    """
    h, w = disp.shape
    nan = np.float32(np.nan)
    for y in prange(h):
        row_max = np.float32(-1.0)
        for x in range(w):
            v = disp[y, x]
            if v == v and v > row_max:
                row_max = v
        if row_max < 0:
            continue
        start = min(int(row_max) + reach + 1, 4 * w // 5)
        for x in range(start, -1, -1):
            dmin = np.float32(np.inf)
            for xx in range(x + 1, min(x + reach + 1, w)):
                v = disp[y, xx]
                if v == v and v < dmin:
                    dmin = v
            if dmin == np.inf:
                continue
            if dmin > x + tolerance:
                disp[y, x] = nan
