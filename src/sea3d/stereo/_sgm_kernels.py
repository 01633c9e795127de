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

    Path costs live in ``prev``/``cur`` with one infinite entry on each side of the band, so
    the recursion's ``d - 1`` and ``d + 1`` need no bounds tests; when the band moves between
    neighbours the previous costs are first re-aligned into ``tmp``. (Separate small arrays and
    plain loops measured fastest; walking neighbouring lines in lockstep was slower.)
    """
    h, w = lo.shape
    kk = k_max
    lof = lo.reshape(-1)
    nf = n.reshape(-1)
    gf = guide.reshape(-1)
    for i in prange(starts.shape[0]):
        prev = np.full(kk + 2, _INF, np.int32)
        cur = np.full(kk + 2, _INF, np.int32)
        tmp = np.full(kk + 2, _INF, np.int32)
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
            for k in range(np_):
                v = np.int32(cf[cb + k])
                prev[k + 1] = v
                tf[cb + k] += v
                m = min(m, int(v))
            prev[np_ + 1] = _INF
            for _ in range(length - 1):
                q = p
                p += s
                n_q = np_
                np_ = nf[p]
                off = lof[p] - lof[q]
                pe = p2_lut[abs(np.int32(gf[p]) - np.int32(gf[q]))]
                c2 = m + pe
                if off == 0 and np_ == n_q:
                    src = prev
                else:
                    for k in range(np_ + 2):
                        j = k + off
                        tmp[k] = prev[j] if 1 <= j <= n_q else _INF
                    src = tmp
                cb = offs[p]
                mm = _INF
                for k in range(np_):
                    v = min(src[k], src[k + 2]) + p1
                    v = min(v, src[k + 1])
                    v = min(v, c2)
                    v = np.int32(cf[cb + k]) + v - m
                    cur[k + 1] = v
                    tf[cb + k] += v
                    mm = min(mm, int(v))
                cur[np_ + 1] = _INF
                m = mm
                prev, cur = cur, prev


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
    winner-take-all along the same aggregated volume's diagonals.

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


@njit(parallel=True, cache=True)
def refine_subpixel(
    left: np.ndarray,
    right: np.ndarray,
    disp: np.ndarray,
    half_h: int,
    half_w: int,
    iterations: int,
    max_step: float,
) -> np.ndarray:
    """Refine disparities by direct image alignment, removing the cost-curve fit's bias.

    For each valid pixel, the window ``(2*half_h+1) x (2*half_w+1)`` of the left image is
    modelled as ``L = a * R(x - d) + b`` (gain ``a`` and offset ``b`` absorb brightness
    changes between the views, ``R`` interpolated linearly along the row); ``a``, ``b`` and
    ``d`` are updated by Gauss-Newton ``iterations`` times. Updates that move ``d`` by more
    than ``max_step`` pixels, or degenerate (texture-less) windows, keep the input value.

    ``left``, ``right`` (H, W) float32 images; ``disp`` (H, W) float32, NaN invalid.
    Returns a new (H, W) float32 map.
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
            d = np.float64(d0)
            # initial gain and offset from window statistics
            sl = 0.0
            sll = 0.0
            n = 0
            for yy in range(y - half_h, y + half_h + 1):
                for xx in range(x - half_w, x + half_w + 1):
                    v = left[yy, xx]
                    sl += v
                    sll += v * v
                    n += 1
            ok = True
            a = 1.0
            b = 0.0
            for it in range(iterations + 1):
                # accumulate normal equations for (a, b, d)
                h00 = h01 = h02 = h11 = h12 = h22 = 0.0
                g0 = g1 = g2 = 0.0
                sr = 0.0
                srr = 0.0
                for yy in range(y - half_h, y + half_h + 1):
                    for xx in range(x - half_w, x + half_w + 1):
                        xr = xx - d
                        if xr < 0.0 or xr > w - 1.001:
                            ok = False
                            break
                        i0 = int(xr)
                        f = xr - i0
                        r0 = right[yy, i0]
                        r1 = right[yy, i0 + 1]
                        rv = r0 + f * (r1 - r0)
                        sr += rv
                        srr += rv * rv
                        if it > 0:
                            jd = a * (r1 - r0)  # d/dd of a * R(x - d) is -a R'; r = L - model
                            res = left[yy, xx] - a * rv - b
                            # J = [rv, 1, -jd]; minimise |r - J delta|^2
                            h00 += rv * rv
                            h01 += rv
                            h02 -= rv * jd
                            h11 += 1.0
                            h12 -= jd
                            h22 += jd * jd
                            g0 += rv * res
                            g1 += res
                            g2 -= jd * res
                    if not ok:
                        break
                if not ok:
                    break
                if it == 0:
                    var_l = sll / n - (sl / n) ** 2
                    var_r = srr / n - (sr / n) ** 2
                    if var_l < 1.0 or var_r < 1.0:
                        ok = False
                        break
                    a = np.sqrt(var_l / var_r)
                    b = sl / n - a * sr / n
                    continue
                # solve the 3x3 system by Cramer's rule
                det = (h00 * (h11 * h22 - h12 * h12) - h01 * (h01 * h22 - h12 * h02)
                       + h02 * (h01 * h12 - h11 * h02))
                if abs(det) < 1e-9:
                    ok = False
                    break
                da = (g0 * (h11 * h22 - h12 * h12) - h01 * (g1 * h22 - h12 * g2)
                      + h02 * (g1 * h12 - h11 * g2)) / det
                db = (h00 * (g1 * h22 - g2 * h12) - g0 * (h01 * h22 - h12 * h02)
                      + h02 * (h01 * g2 - g1 * h02)) / det
                dd = (h00 * (h11 * g2 - h12 * g1) - h01 * (h01 * g2 - g1 * h02)
                      + g0 * (h01 * h12 - h11 * h02)) / det
                a += da
                b += db
                d += dd
                if abs(d - d0) > max_step:
                    ok = False
                    break
            if ok:
                out[y, x] = np.float32(d)
    return out
