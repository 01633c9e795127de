"""Numba kernels of sea3d's semi-global matcher (private; see :mod:`sea3d.stereo.sgm`).

Layout: every pixel ``p = y * W + x`` searches a band of disparities ``d = lo[p] + k``,
``k < 16 * nch[p]``: whole chunks of 16 candidates, so that each chunk is one step of the
16-lane vector kernels of :mod:`sea3d.stereo._simd`. Costs (uint8) and summed path costs
(int16) are packed: pixel ``p``'s band starts at ``offs[p]`` (:func:`band_offsets`). A full
search is ``lo = 0`` with the range rounded up to chunks; the coarse-to-fine levels give most
pixels one chunk around the coarser answer and pixels at depth steps up to three. Candidates
outside the right image or the range get :data:`INVALID_COST`, which no real match reaches,
and are never selected.

The path recursion is Hirschmüller's (PAMI 2008, eq. 13) with the path minimum subtracted::

    L_r(p, d) = C(p, d) + min(L_r(q, d), L_r(q, d-1) + P1, L_r(q, d+1) + P1,
                              min_k L_r(q, k) + P2(p, q)) - min_k L_r(q, k)

with ``q = p - r``; ``L_r(q, d)`` is infinite where ``d`` lies outside ``q``'s band. P2 is adapted
to the guide image: ``P2(p, q) = max(P1 + 1, P2 * tau / (tau + |I(p) - I(q)|))``. Every path
value is at most ``INVALID_COST + P2``, so 16 paths of them fit int16 for ``P2 <= 1500``.

Scanlines are walked in lockstep groups (:func:`sweep`): a group of neighbouring lines advances
one pixel at a time, so the pixels processed back to back are independent and the CPU overlaps
them; each group keeps one padded state slot per line and shifts with the path direction, so
groups never depend on each other and run on any thread without synchronisation.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from sea3d.stereo._simd import (
    LANES,
    argmin16,
    census16,
    census_cost16,
    load_at,
    min_outside16,
    path_step16_add,
    path_step16_set,
    right_scatter16,
    select16,
    window_sums16,
)

INVALID_COST = 255
"""Matching cost of candidates that lie outside the right image or the disparity range."""
_INF = 8000  # out-of-band path cost: above any real one (<= 255 + 1500), small enough for int16
_BIG = 32767  # "no candidate" in the selection


@njit(parallel=True, cache=True)
def census_transform(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census signature of each pixel: one bit per window neighbour darker than the centre.

    ``img`` (H, W) float32; window (2*half_h+1) x (2*half_w+1) <= 65 pixels; borders replicate.
    Returns (H, W) uint64: the first 32 neighbours (rows first, then columns; the centre left
    out) in the low word, the first of them in its highest bit, the others in the high word;
    the bit order is the same for both images, which is all the Hamming distance needs. Each
    output row copies its window rows once into padded rows (the ends replicated), and
    :func:`census16` forms the bits of 16 pixels at a time in registers, reading every
    neighbour from a contiguous slice (measured on a presmoothed 640x360 frame of the
    simulated dive, one thread: 1.17 ms against 1.72 ms with the bits formed a neighbour at a
    time over the whole row, the same bits).
    """
    h, w = img.shape
    n_rows = 2 * half_h + 1
    n_cols = 2 * half_w + 1
    stride = w + 2 * half_w + LANES  # room for the last block's reads
    n_blocks = (w + LANES - 1) // LANES
    out = np.empty((h, w), np.uint64)
    for y in prange(h):
        rows = np.empty(n_rows * stride, np.float32)
        for r in range(n_rows):
            row = img[min(max(y + r - half_h, 0), h - 1)]
            b = r * stride
            rows[b + half_w:b + half_w + w] = row
            for x in range(half_w):
                rows[b + x] = row[0]
            for x in range(half_w + w, stride):
                rows[b + x] = row[w - 1]
        lo32 = np.empty(n_blocks * LANES, np.uint32)
        hi32 = np.empty(n_blocks * LANES, np.uint32)
        for k in range(n_blocks):
            census16(rows, stride, n_rows, n_cols, k * LANES, lo32, hi32)
        for x in range(w):
            out[y, x] = (np.uint64(hi32[x]) << np.uint64(32)) | np.uint64(lo32[x])
    return out


def band_offsets(nch: np.ndarray) -> np.ndarray:
    """Start of each pixel's band in the packed volumes: (H*W + 1,) int64 prefix sums of
    ``16 * nch``."""
    flat = nch.ravel()
    n0 = int(flat[0]) if flat.size else 0
    if flat.size and int(flat.min()) == n0 == int(flat.max()):
        # one band width everywhere (a full search, or a band search on smooth depth): the
        # prefix sums are a ramp (measured at 640x360, one chunk: 0.27 ms against 1.1 ms)
        return np.arange(flat.size + 1, dtype=np.int64) * np.int64(LANES * n0)
    offs = np.zeros(flat.size + 1, np.int64)
    np.cumsum(flat.astype(np.int64) * LANES, out=offs[1:])
    return offs


@njit(parallel=True, cache=True)
def band_costs(
    census_l: np.ndarray, census_r: np.ndarray, lo: np.ndarray, nch: np.ndarray,
    offs: np.ndarray, num_disp: int,
) -> np.ndarray:
    """Hamming distance of census signatures over each pixel's band.

    Returns the packed volume (offs[-1],) uint8: ``cost[offs[p] + k]`` matches left ``x`` with
    right ``x - lo - k``; candidates with ``lo + k > x`` or ``lo + k >= num_disp`` get
    :data:`INVALID_COST`. Bands must satisfy ``lo + 16 * nch - 1 <= x`` wherever
    ``x >= 16 * nch - 1``, and ``lo = 0`` elsewhere.
    """
    h, w = census_l.shape
    lof = lo.reshape(-1)
    ncf = nch.reshape(-1)
    k_max = int(nch.max()) * LANES
    cost = np.empty(offs[-1], np.uint8)
    # the right rows reversed, so each band reads increasing addresses; padded at the end
    stride = w + k_max
    rev = np.zeros(h * stride, np.uint64)
    for y in prange(h):
        for j in range(w):
            rev[y * stride + j] = census_r[y, w - 1 - j]
    for y in prange(h):
        row = y * stride + w - 1
        for x in range(w):
            p = y * w + x
            lo_p = load_at(lof, p)
            kp = load_at(ncf, p) * LANES
            cb = load_at(offs, p)
            cl = census_l[y, x]
            start = row - x + lo_p
            census_cost16(rev, start, cl, cost, cb)
            for c in range(LANES, kp, LANES):
                census_cost16(rev, start + c, cl, cost, cb + c)
            top = min(x, num_disp - 1) - lo_p  # last valid k
            if top < kp - 1:
                for k in range(max(top + 1, 0), kp):
                    cost[cb + k] = INVALID_COST
    return cost


@njit(cache=True)
def _sweep_block(
    cf: np.ndarray, lof: np.ndarray, ncf: np.ndarray, offs: np.ndarray, k_max: int,
    gf: np.ndarray, tf: np.ndarray, p1: int, p2_lut: np.ndarray, p0: int, so: int, si: int,
    n_outer: int, n_inner: int, s: int, b0: int, nb: int, accumulate: bool,
) -> None:
    pad = k_max + 2
    ll = 3 * k_max + 4
    # two padded state rows per line (previous and current step); entries outside the band
    # written last into a row hold _INF
    state = np.full(2 * nb * ll, _INF, np.int16)
    extent = np.zeros(2 * nb, np.int64)  # candidates written into each row
    mins = np.zeros(nb, np.int64)
    alive = np.zeros(nb, np.bool_)
    back = so + s * si  # pixel index step back to the predecessor
    for o in range(n_outer):
        i_first = b0 + s * o
        # the slots of this step that lie inside the image
        j0 = min(max(0, -i_first), nb)
        j1 = max(min(nb, n_inner - i_first), j0)
        if s != 0:
            for j in range(0, j0):
                alive[j] = False
            for j in range(j1, nb):
                alive[j] = False
        par = o & 1
        rd = (1 - par) * nb * ll + pad
        wr = par * nb * ll + pad
        p_row = p0 + o * so + i_first * si
        for j in range(j0, j1):
            p = p_row + j * si
            cb = load_at(offs, p)
            kp = load_at(ncf, p) * LANES
            sw = wr + j * ll
            if not alive[j]:
                # path start: L = C
                m = _INF
                for k in range(kp):
                    v = np.int16(cf[cb + k])
                    state[sw + k] = v
                    if accumulate:
                        tf[cb + k] += v
                    else:
                        tf[cb + k] = v
                    m = min(m, int(v))
                alive[j] = True
            else:
                q = p - back
                off = min(max(load_at(lof, p) - load_at(lof, q), -k_max - 1), k_max + 1)
                pe = load_at(p2_lut, abs(np.int32(load_at(gf, p)) - np.int32(load_at(gf, q))))
                mq = mins[j]
                # the predecessor's entries, read ``off`` entries along when the band moved
                ip = rd + j * ll + off - 1
                if kp == LANES:  # most pixels of a band search: one vector step
                    if accumulate:
                        m = path_step16_add(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
                    else:
                        m = path_step16_set(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
                elif accumulate:
                    m = path_step16_add(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
                    for c in range(LANES, kp, LANES):
                        m = min(m, path_step16_add(state, ip + c, cf, cb + c, sw + c, tf,
                                                   cb + c, p1, mq + pe, mq))
                else:
                    m = path_step16_set(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
                    for c in range(LANES, kp, LANES):
                        m = min(m, path_step16_set(state, ip + c, cf, cb + c, sw + c, tf,
                                                   cb + c, p1, mq + pe, mq))
            mins[j] = m
            e = par * nb + j
            if extent[e] > kp:  # a wider band was here two steps ago
                for k in range(kp, extent[e]):
                    state[sw + k] = _INF
            extent[e] = kp


@njit(cache=True)
def _sweep_block1(
    cf: np.ndarray, lof: np.ndarray, gf: np.ndarray, tf: np.ndarray, p1: int,
    p2_lut: np.ndarray, p0: int, so: int, si: int, n_outer: int, n_inner: int, s: int, b0: int,
    nb: int, accumulate: bool,
) -> None:
    """:func:`_sweep_block` where every pixel's band is one chunk (``offs[p] = 16 p``): no
    per-pixel band widths to read, no chunk loop and no stale entries to clear."""
    k_max = LANES
    pad = k_max + 2
    ll = 3 * k_max + 4
    state = np.full(2 * nb * ll, _INF, np.int16)
    mins = np.zeros(nb, np.int64)
    alive = np.zeros(nb, np.bool_)
    back = so + s * si
    for o in range(n_outer):
        i_first = b0 + s * o
        j0 = min(max(0, -i_first), nb)
        j1 = max(min(nb, n_inner - i_first), j0)
        if s != 0:
            for j in range(0, j0):
                alive[j] = False
            for j in range(j1, nb):
                alive[j] = False
        par = o & 1
        rd = (1 - par) * nb * ll + pad
        wr = par * nb * ll + pad
        p_row = p0 + o * so + i_first * si
        for j in range(j0, j1):
            p = p_row + j * si
            cb = p * LANES
            sw = wr + j * ll
            if not alive[j]:
                m = _INF
                for k in range(LANES):
                    v = np.int16(cf[cb + k])
                    state[sw + k] = v
                    if accumulate:
                        tf[cb + k] += v
                    else:
                        tf[cb + k] = v
                    m = min(m, int(v))
                alive[j] = True
            else:
                q = p - back
                off = min(max(load_at(lof, p) - load_at(lof, q), -k_max - 1), k_max + 1)
                pe = load_at(p2_lut, abs(np.int32(load_at(gf, p)) - np.int32(load_at(gf, q))))
                mq = mins[j]
                ip = rd + j * ll + off - 1
                if accumulate:
                    m = path_step16_add(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
                else:
                    m = path_step16_set(state, ip, cf, cb, sw, tf, cb, p1, mq + pe, mq)
            mins[j] = m


@njit(parallel=True, cache=True)
def sweep(
    cf: np.ndarray, lof: np.ndarray, ncf: np.ndarray, offs: np.ndarray, gf: np.ndarray,
    tf: np.ndarray, p1: int, p2_lut: np.ndarray, p0: int, so: int, si: int, n_outer: int,
    n_inner: int, s: int, group: int, accumulate: bool,
) -> None:
    """Aggregate one path direction over the whole image; adds into (or sets) ``tf``.

    The scanlines are indexed by ``i`` in ``[0, n_inner)`` and advance by ``o`` in
    ``[0, n_outer)``: pixel ``(o, i)`` is ``p0 + o * so + i * si`` and its predecessor on the
    path is ``(o - 1, i - s)``. Lines are processed in groups of ``group`` neighbours that
    shift by ``s`` per step, so each group holds whole paths. ``cf`` (uint8) and ``tf`` (int16)
    are the packed cost and total volumes (``offs``), ``lof``/``ncf`` the flat band starts and
    chunk counts, ``gf`` the flat uint8 guide image, ``p2_lut[|dI|]`` the edge-adapted P2.
    """
    k_max = int(ncf.max()) * LANES
    span = abs(s) * (n_outer - 1)
    n_groups = (n_inner + span + group - 1) // group
    base = -span if s > 0 else 0
    if k_max == LANES:  # one chunk everywhere (a band search on smooth depth)
        for g in prange(n_groups):
            _sweep_block1(cf, lof, gf, tf, p1, p2_lut, p0, so, si, n_outer, n_inner, s,
                          base + g * group, group, accumulate)
        return
    for g in prange(n_groups):
        _sweep_block(cf, lof, ncf, offs, k_max, gf, tf, p1, p2_lut, p0, so, si, n_outer,
                     n_inner, s, base + g * group, group, accumulate)


def p2_table(p1: int, p2: int, tau: float) -> np.ndarray:
    """Edge-adapted P2 for every intensity step 0..255: ``max(P1 + 1, P2 * tau / (tau + dI))``,
    (256,) int32."""
    diff = np.arange(256, dtype=np.float64)
    return np.maximum(np.floor(p2 * tau / (tau + diff)), p1 + 1).astype(np.int32)


def path_sweeps(h: int, w: int, dy: int, dx: int) -> list[tuple[int, int, int, int, int, int]]:
    """The :func:`sweep` arguments ``(p0, so, si, n_outer, n_inner, s)`` that walk direction
    ``(dy, dx)`` (``dy >= 0``) forward and backward over an ``h x w`` image."""
    if dy == 0:
        # horizontal: lines are rows (inner index y), advancing along x
        step = 1 if dx > 0 else -1
        return [(0 if step > 0 else w - 1, step, w, w, h, 0),
                (w - 1 if step > 0 else 0, -step, w, w, h, 0)]
    out = []
    for r in range(dy):  # rows dy apart form separate paths
        n_outer = (h - r + dy - 1) // dy
        out.append((r * w, dy * w, 1, n_outer, w, dx))
        out.append(((h - 1 - r) * w, -dy * w, 1, n_outer, w, -dx))
    return out


@njit(parallel=True, cache=True)
def select_disparity(
    total: np.ndarray,
    lo: np.ndarray,
    nch: np.ndarray,
    offs: np.ndarray,
    none: np.ndarray,
    num_disp: int,
    uniqueness: float,
    lr_max_diff: int,
    subpixel: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all with subpixel refinement, uniqueness and left-right check.

    ``subpixel``: 0 none, 1 parabola, 2 equiangular. ``uniqueness`` is the minimum relative
    margin ``(second - best) / best`` of the best cost over the best cost outside ``best +- 1``.
    ``lr_max_diff < 0`` disables the left-right check. The right view's disparity is the
    winner-take-all along the same aggregated volume's diagonals. Pixels without a valid
    candidate (or flagged in ``none``) and winners within a pixel of the right image's left edge
    where the band reaches that edge are invalid: their true match may lie outside the image.

    Returns disparity (H, W) float32 (NaN invalid) and confidence (H, W) float32 in [0, 1]:
    ``1 - best / second`` (0 where invalid).
    """
    h, w = lo.shape
    k_max = int(nch.max()) * LANES
    disp = np.empty((h, w), np.float32)
    conf = np.zeros((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in prange(h):
        # right-view winners, stored k_max entries along so candidates off the image fit
        rbest = np.full(w + k_max + LANES, _BIG, np.int16)
        rdisp = np.full(w + k_max + LANES, -1, np.int16)
        dint = np.full(w, -1, np.int32)
        for x in range(w):
            lo_p = lo[y, x]
            kp = nch[y, x] * LANES
            n_valid = min(kp, num_disp - lo_p, x - lo_p + 1)
            cb = offs[y * w + x]
            if n_valid <= 0 or none[y, x]:
                disp[y, x] = nan
                continue
            if kp == LANES:  # one chunk: one fused vector step
                r = select16(total, cb, n_valid, rbest, rdisp, k_max + x - lo_p - (LANES - 1),
                             lo_p)
                best = r % 32768
                second = (r // 32768) % 32768
                kb = r // (32768 * 32768)
            else:
                best = _BIG
                kb = 0
                for c in range(0, kp, LANES):
                    nv = n_valid - c
                    if nv <= 0:
                        break
                    r = argmin16(total, cb + c, nv)
                    if r // 32 < best:
                        best = r // 32
                        kb = c + r % 32
                    right_scatter16(rbest, rdisp, k_max + x - lo_p - c - (LANES - 1), total,
                                    cb + c, nv, lo_p + c)
                second = _BIG
                for c in range(0, kp, LANES):
                    nv = n_valid - c
                    if nv <= 0:
                        break
                    second = min(second,
                                 min_outside16(total, cb + c, nv, kb - 1 - c, kb + 1 - c))
            # a winner against the right image's left edge, with the band reaching it: the
            # true match may lie outside the right image
            if lo_p + n_valid - 1 == x and lo_p + kb >= x - 1:
                disp[y, x] = nan
                continue
            if second < _BIG and (second - best) < uniqueness * best:
                disp[y, x] = nan
                continue
            dint[x] = lo_p + kb
            # > 0 on every matched pixel: confidence 0 marks filled ones
            conf[y, x] = 1.0 if second >= _BIG else max(1.0 - best / max(second, 1), 1e-6)
            delta = 0.0
            if subpixel > 0 and 0 < kb < n_valid - 1:
                cm = float(total[cb + kb - 1])
                c0 = float(best)
                cp = float(total[cb + kb + 1])
                if subpixel == 1:
                    den = cm - 2.0 * c0 + cp
                    if den > 0:
                        delta = 0.5 * (cm - cp) / den
                else:
                    den = (cm - c0) if cm > cp else (cp - c0)
                    if den > 0:
                        delta = 0.5 * (cm - cp) / den
                delta = min(max(delta, -0.5), 0.5)
            disp[y, x] = np.float32(lo_p + kb + delta)
        if lr_max_diff >= 0:
            for x in range(w):
                d = dint[x]
                if d < 0:
                    continue
                if abs(rdisp[k_max + x - d] - d) > lr_max_diff:
                    disp[y, x] = nan
                    conf[y, x] = 0.0
    return disp, conf


@njit(parallel=True, cache=True)
def band_from_coarse(
    coarse: np.ndarray,
    h: int,
    w: int,
    num_disp: int,
    max_chunks: int,
    margin: int,
    radius: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel search bands at a level from the disparity one level coarser (half size).

    Invalid (NaN) coarse pixels take the range spanned by their nearest valid neighbours in the
    row (occlusions lie between a foreground and a background disparity). Each fine pixel's
    natural band is ``[2 * min - margin, 2 * max + margin]`` over a ``(2*radius+1)^2`` coarse
    window. It gets the fewest chunks of 16 that hold it (at most ``max_chunks``), centred on
    it, or, where it is wider still, centred on the coarse value at the pixel's own position;
    the band is then moved inside ``[0, min(num_disp, x + 1))``. Pixels whose natural band lies
    wholly beyond the right image's left edge are flagged in ``none`` (no candidate).

    Returns ``lo`` (h, w) int32, ``nch`` (h, w) int32 chunks, ``none`` (h, w) bool.
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
    # window minimum and maximum on the coarse grid, separably (rows, then columns)
    rmin = np.empty((hc, wc), np.float32)
    rmax = np.empty((hc, wc), np.float32)
    for yc in prange(hc):
        for xc in range(wc):
            mn = cmin[yc, xc]
            mx = cmax[yc, xc]
            for xx in range(max(xc - radius, 0), min(xc + radius + 1, wc)):
                mn = min(mn, cmin[yc, xx])
                mx = max(mx, cmax[yc, xx])
            rmin[yc, xc] = mn
            rmax[yc, xc] = mx
    wmin = np.empty((hc, wc), np.float32)
    wmax = np.empty((hc, wc), np.float32)
    for yc in prange(hc):
        for xc in range(wc):
            mn = rmin[yc, xc]
            mx = rmax[yc, xc]
            for yy in range(max(yc - radius, 0), min(yc + radius + 1, hc)):
                mn = min(mn, rmin[yy, xc])
                mx = max(mx, rmax[yy, xc])
            wmin[yc, xc] = mn
            wmax[yc, xc] = mx
    # each coarse cell's band start and width (its 2x2 fine pixels share them)
    c_start = np.empty((hc, wc), np.int32)
    c_low = np.empty((hc, wc), np.int32)
    c_n = np.empty((hc, wc), np.int32)
    for yc in prange(hc):
        for xc in range(wc):
            a = int(np.floor(2.0 * wmin[yc, xc])) - margin
            b = int(np.ceil(2.0 * wmax[yc, xc])) + margin
            width = b - a + 1
            n = min((width + LANES - 1) // LANES, max_chunks)
            kp = n * LANES
            if width <= kp:
                c_start[yc, xc] = a - (kp - width) // 2
            else:
                c_start[yc, xc] = int(np.round(cmin[yc, xc] + cmax[yc, xc])) - kp // 2
            c_low[yc, xc] = max(a, 0)
            c_n[yc, xc] = n
    lo = np.empty((h, w), np.int32)
    nch = np.empty((h, w), np.int32)
    none = np.zeros((h, w), np.bool_)
    for y in prange(h):
        yc = min(y // 2, hc - 1)
        for x in range(w):
            xc = min(x // 2, wc - 1)
            n = c_n[yc, xc]
            top = min(num_disp - 1, x)  # largest disparity with a match inside the right image
            if c_low[yc, xc] > top:
                none[y, x] = True
            lo[y, x] = max(min(c_start[yc, xc], top - n * LANES + 1), 0)
            nch[y, x] = n
    return lo, nch, none


@njit(parallel=True, cache=True)
def valid_and_zeroed(disp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The validity mask of ``disp`` (1 where finite, float32) and ``disp`` with 0 where not
    finite: one pass instead of numpy's four."""
    h, w = disp.shape
    v = np.empty((h, w), np.float32)
    d = np.empty((h, w), np.float32)
    for y in prange(h):
        for x in range(w):
            e = disp[y, x]
            if e - e == 0:
                v[y, x] = 1.0
                d[y, x] = e
            else:
                v[y, x] = 0.0
                d[y, x] = 0.0
    return v, d


@njit(parallel=True, cache=True)
def slope_from_sums(s1: np.ndarray, sj: np.ndarray, sjj: np.ndarray, sd: np.ndarray,
                    sjd: np.ndarray) -> np.ndarray:
    """Least-squares slope ``(s1 sjd - sj sd) / (s1 sjj - sj^2)`` from the window sums (NaN
    where the determinant is at most 1e-3), float32 operation by operation as numpy does them
    (one pass instead of seven)."""
    h, w = s1.shape
    out = np.empty((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in prange(h):
        for x in range(w):
            a = s1[y, x]
            b = sj[y, x]
            den = np.float32(a * sjj[y, x]) - np.float32(b * b)
            if den > np.float32(1e-3):
                num = np.float32(a * sjd[y, x]) - np.float32(b * sd[y, x])
                out[y, x] = num / den
            else:
                out[y, x] = nan
    return out


@njit(parallel=True, cache=True)
def _padded_rows(img: np.ndarray, stride: int) -> np.ndarray:
    """``img`` (H, W) as flat rows of ``stride >= W`` entries, each row's last value repeated."""
    h, w = img.shape
    out = np.empty(h * stride, np.float32)
    for y in prange(h):
        for x in range(w):
            out[y * stride + x] = img[y, x]
        for x in range(w, stride):
            out[y * stride + x] = img[y, w - 1]
    return out


@njit(parallel=True, cache=True)
def refine_subpixel(
    left: np.ndarray,
    right: np.ndarray,
    disp: np.ndarray,
    grad_y: np.ndarray,
    half_h: int,
    half_w: int,
    iterations: int,
    max_step: float,
    inv_gamma: float,
    row_step: int,
) -> np.ndarray:
    """Refine disparities by direct image alignment, removing the cost-curve fit's bias.

    For each valid pixel, the window ``(2*half_h+1) x (2*half_w+1)`` (``half_w <= 7``) of the
    left image is modelled as ``L(x, y) = a * R(x - d - gy (y - y0)) + b``: gain ``a`` and offset
    ``b`` absorb brightness changes between the views, the vertical disparity slope ``gy``
    (from the current map, ``grad_y``) lets the window follow surfaces that recede upwards, and
    ``R`` is interpolated linearly along the row; every ``row_step``-th window row is read.
    Window pixels are weighted by their likeness to the centre, Tukey's biweight
    ``(1 - t^2)^2`` of ``t = (L - L0) * inv_gamma`` (0 for ``|t| >= 1``; ``inv_gamma = 0``
    weighs all alike), so windows straddling an edge lean on the centre's side. Starting from
    ``a = 1, b = 0``, ``a``, ``b`` and ``d`` are updated by ``iterations`` Gauss-Newton steps
    (:func:`window_sums16` forms the normal equations, 16 lanes per window row). Updates that
    move ``d`` by more than ``max_step`` pixels, windows leaving the image, or texture-less
    windows keep the input.

    ``left``, ``right`` (H, W) float32 images; ``disp`` (H, W) float32, NaN invalid;
    ``grad_y`` (H, W) float32 px/px (NaN treated as 0). Returns a new map.
    """
    h, w = left.shape
    stride = w + 2 * LANES
    lp = _padded_rows(left, stride)
    rp = _padded_rows(right, stride)
    out = disp.copy()
    n_px = np.float32((2 * (half_h // row_step) + 1) * (2 * half_w + 1))
    for y in prange(half_h, h - half_h):
        sums = np.empty(9, np.float32)
        for x in range(half_w, w - half_w):
            d0 = disp[y, x]
            if d0 != d0:
                continue
            gy = grad_y[y, x]
            if gy != gy or abs(gy) > 0.5:
                gy = np.float32(0.0)
            d = np.float32(d0)
            a = np.float32(1.0)
            b = np.float32(0.0)
            ok = True
            for _ in range(iterations):
                reach = half_w + 1.0 + abs(gy) * half_h
                if x - d - reach < 0.0 or x - d + reach > w - 1.001:
                    ok = False
                    break
                window_sums16(lp, rp, stride, x, y, d, gy, half_h, half_w, a, b, left[y, x],
                              inv_gamma, row_step, sums, 0)
                h00 = sums[0]
                h01 = sums[1]
                h02 = -sums[2]
                h11 = sums[3]
                h12 = -sums[4]
                h22 = sums[5]
                g0 = sums[6]
                g1 = sums[7]
                g2 = -sums[8]
                c0 = h11 * h22 - h12 * h12
                c1 = h01 * h22 - h12 * h02
                c2 = h01 * h12 - h11 * h02
                det = h00 * c0 - h01 * c1 + h02 * c2
                if abs(det) < 1e-6 * h11 * h11 * h11 or h22 < 1e-3 * h11 or h11 < 0.1 * n_px:
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
