"""Scan conversion of triangles into the tiles of the visibility field's subfields
(:mod:`.visibility_field`): the build kernels over flat arrays.

For each direction ``k`` (frame ``e1, e2, w`` and tile grid in ``frame[k]``, ``grid[k]``) a
triangle's vertices are projected to ``(u, v)`` and depth ``z = x . w``; every tile row its
projection meets gets the span of the triangle within that row (vertices inside plus edge
crossings of the row's two lines, :func:`_slab_span`), all grown by ``pad`` so the lists are
conservative; each entry also records the 8 x 8 sub-tiles (:data:`SUB`) the triangle covers
within its tile. Two passes: count, then fill at prefix-summed cursors (static), or the same
with version stamps for the dynamic lists (see :func:`raster_dir`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Each tile is split into SUB x SUB sub-tiles (one bit each in an entry's mask).
SUB = 8
#: Rasterise in parallel from this many (direction, triangle) pairs on.
PARALLEL_RASTER_MIN = 2_000_000
#: Raster modes (:func:`raster_dir`).
COUNT, FILL, DYN_COUNT, DYN_FILL = 0, 1, 2, 3


@njit(cache=True, nogil=True, error_model="numpy")
def world_triangles(tv, ref_inst, ref_prim, xform, sel):
    """World-space vertices (len(sel), 9) float64 of the references ``sel``."""
    out = np.empty((sel.shape[0], 9))
    for q in range(sel.shape[0]):
        r = sel[q]
        i, p = ref_inst[r], ref_prim[r]
        for c in range(3):
            x, y, z = tv[p, 3 * c], tv[p, 3 * c + 1], tv[p, 3 * c + 2]
            for a in range(3):
                out[q, 3 * c + a] = (xform[i, a, 0] * x + xform[i, a, 1] * y
                                     + xform[i, a, 2] * z + xform[i, a, 3])
    return out


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _down32(x):
    """float32 not above ``x``."""
    y = np.float32(x)
    if y > x:
        y = np.nextafter(y, np.float32(-np.inf))
    return y


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _up32(x):
    """float32 not below ``x``."""
    y = np.float32(x)
    if y < x:
        y = np.nextafter(y, np.float32(np.inf))
    return y


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _slab_span(u0, v0, u1, v1, u2, v2, ya, yb):
    """Smallest and largest ``u`` of triangle (u_i, v_i) within the slab ``ya <= v <= yb``
    (vertices inside plus edge crossings of the slab's two lines); (inf, -inf) if none."""
    lo, hi = np.inf, -np.inf
    for c in range(3):
        pu = u0 if c == 0 else (u1 if c == 1 else u2)
        pv = v0 if c == 0 else (v1 if c == 1 else v2)
        qu = u1 if c == 0 else (u2 if c == 1 else u0)
        qv = v1 if c == 0 else (v2 if c == 1 else v0)
        if ya <= pv <= yb:
            lo, hi = min(lo, pu), max(hi, pu)
        for s in range(2):
            y = ya if s == 0 else yb
            if (pv - y) * (qv - y) < 0.0:
                x = pu + (y - pv) * (qu - pu) / (qv - pv)
                lo, hi = min(lo, x), max(hi, x)
    return lo, hi


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def cell(x, x0, inv, n):
    """Tile coordinate of ``x`` on an axis starting at ``x0`` with ``n`` tiles, clamped."""
    c = np.floor((x - x0) * inv)
    if c < 0.0:
        return 0
    if c > n - 1:
        return n - 1
    return int(c)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def row_bits(lo, hi, x0, inv, row):
    """Mask bits of sub-tile row ``row`` for the u-interval ``[lo, hi]`` (tile starts at
    ``x0``, ``inv`` sub-tiles per unit)."""
    a = cell(lo, x0, inv, SUB)
    b = cell(hi, x0, inv, SUB)
    return ((1 << (b + 1)) - (1 << a)) << (SUB * row)


@njit(cache=True, nogil=True, error_model="numpy")
def raster_dir(k, frame, grid, n, pad, wv, refs, mode, counts, starts, out_ref, out_zmin,
                out_zmax, out_mask, stamp, gv, dir_total):
    """Scan-convert world triangles ``wv`` (m, 9) (references ``refs``) into subfield ``k``.

    ``mode``: 0 count into ``counts``; 1 fill at the cursors ``starts`` (advanced);
    2 dynamic count (tiles first touched get ``stamp = -gv`` and a zero count; per-direction
    totals in ``dir_total``); 3 dynamic fill (``starts`` are assigned from ``dir_total``,
    which holds the direction's first entry, and ``stamp`` becomes ``gv``).
    """
    nn = n * n
    e1x, e1y, e1z = frame[k, 0], frame[k, 1], frame[k, 2]
    e2x, e2y, e2z = frame[k, 3], frame[k, 4], frame[k, 5]
    wx, wy, wz = frame[k, 6], frame[k, 7], frame[k, 8]
    gu, gv0, iu, iv = grid[k, 0], grid[k, 1], grid[k, 2], grid[k, 3]
    for q in range(wv.shape[0]):
        u0 = wv[q, 0] * e1x + wv[q, 1] * e1y + wv[q, 2] * e1z
        u1 = wv[q, 3] * e1x + wv[q, 4] * e1y + wv[q, 5] * e1z
        u2 = wv[q, 6] * e1x + wv[q, 7] * e1y + wv[q, 8] * e1z
        v0 = wv[q, 0] * e2x + wv[q, 1] * e2y + wv[q, 2] * e2z
        v1 = wv[q, 3] * e2x + wv[q, 4] * e2y + wv[q, 5] * e2z
        v2 = wv[q, 6] * e2x + wv[q, 7] * e2y + wv[q, 8] * e2z
        z0 = wv[q, 0] * wx + wv[q, 1] * wy + wv[q, 2] * wz
        z1 = wv[q, 3] * wx + wv[q, 4] * wy + wv[q, 5] * wz
        z2 = wv[q, 6] * wx + wv[q, 7] * wy + wv[q, 8] * wz
        zlo, zhi = min(z0, z1, z2) - pad, max(z0, z1, z2) + pad
        r0 = cell(min(v0, v1, v2) - pad, gv0, iv, n)
        r1 = cell(max(v0, v1, v2) + pad, gv0, iv, n)
        for r in range(r0, r1 + 1):
            ya = gv0 + r / iv - pad  # row r, grown by pad (as the query computes it)
            yb = gv0 + (r + 1) / iv + pad
            lo, hi = _slab_span(u0, v0, u1, v1, u2, v2, ya, yb)
            if lo > hi:
                continue
            c0 = cell(lo - pad, gu, iu, n)
            c1 = cell(hi + pad, gu, iu, n)
            for c in range(c0, c1 + 1):
                t = k * nn + r * n + c
                if mode == COUNT:
                    counts[t] += 1
                    continue
                if mode == DYN_COUNT:
                    if stamp[t] != -gv:
                        stamp[t] = -gv
                        counts[t] = 0
                    counts[t] += 1
                    dir_total[k] += 1
                    continue
                if mode == DYN_FILL:
                    if stamp[t] == -gv:
                        stamp[t] = gv
                        starts[t] = dir_total[k]
                        dir_total[k] += counts[t]
                        counts[t] = 0
                    e = starts[t] + counts[t]
                    counts[t] += 1
                else:
                    e = starts[t]
                    starts[t] += 1
                out_ref[e] = refs[q]
                out_zmin[e] = _down32(zlo)
                out_zmax[e] = _up32(zhi)
                # the sub-tiles of tile (r, c) the triangle covers (padded spans)
                tu0, tv0 = gu + c / iu, gv0 + r / iv
                su, sv = SUB * iu, SUB * iv
                m = 0
                for sr in range(SUB):
                    lo2, hi2 = _slab_span(u0, v0, u1, v1, u2, v2, tv0 + sr / sv - pad,
                                          tv0 + (sr + 1) / sv + pad)
                    if lo2 <= hi2:
                        m |= row_bits(lo2 - pad, hi2 + pad, tu0, su, sr)
                out_mask[e] = m


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def raster_parallel(frame, grid, n, pad, wv, refs, mode, counts, starts, out_ref, out_zmin,
                     out_zmax, out_mask, stamp, gv, dir_total):
    """:func:`raster_dir` for every direction, in parallel (a direction owns its tiles)."""
    for k in prange(frame.shape[0]):
        raster_dir(k, frame, grid, n, pad, wv, refs, mode, counts, starts, out_ref, out_zmin,
                    out_zmax, out_mask, stamp, gv, dir_total)


@njit(cache=True, nogil=True, error_model="numpy")
def raster_serial(frame, grid, n, pad, wv, refs, mode, counts, starts, out_ref, out_zmin,
                   out_zmax, out_mask, stamp, gv, dir_total):
    """:func:`raster_dir` for every direction on this thread (small dynamic updates: a
    parallel launch costs more than the work on a busy machine)."""
    for k in range(frame.shape[0]):
        raster_dir(k, frame, grid, n, pad, wv, refs, mode, counts, starts, out_ref, out_zmin,
                    out_zmax, out_mask, stamp, gv, dir_total)


def raster(*args) -> None:
    """Run the rasteriser, in parallel when the work (directions x triangles) is large."""
    frame, wv = args[0], args[4]
    if frame.shape[0] * wv.shape[0] >= PARALLEL_RASTER_MIN:
        raster_parallel(*args)
    else:
        raster_serial(*args)


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def order_tiles(start, ref, zmin, zmax, mask):
    """Sort each tile's entries by zmin; turn ``zmax`` into its running maximum (pmax)."""
    for t in prange(start.shape[0] - 1):
        s, e = start[t], start[t + 1]
        if e - s > 1:
            order = np.argsort(zmin[s:e], kind="mergesort") + s
            r, a, b, m = ref[order], zmin[order], zmax[order], mask[order]
            ref[s:e], zmin[s:e], zmax[s:e], mask[s:e] = r, a, b, m
        m = np.float32(-np.inf)
        for x in range(s, e):
            m = max(m, zmax[x])
            zmax[x] = m
