"""The binned-SAH steps of one node of :mod:`.bvh_build`: bins cleared, filled and swept,
the partition, the split of two primitives without bins.

All of them are inlined into the builder's kernels (``inline="always"``): none is a kernel
of its own. Boxes are rows ``(lo x, lo y, lo z, hi x, hi y, hi z)`` of float32 or float64,
read as float64 before any arithmetic. The "centroid bounds" ``cmin``, ``cmax`` a node's
bins are laid over are its centroids' at the root and under an object-median split, and
its box under an SAH split (session 37; :mod:`.bvh_build`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Nodes of at most this many primitives (most of the build's work: its subtrees') are
#: split more cheaply (session 36, docs/bench-scale.md): with at most :data:`CHEAP_BINS`
#: bins per axis, binned only on the axes whose centroid extent is at least
#: :data:`CHEAP_AXIS_FRAC` of the longest one's (:func:`_node_bins`). The rule depends on
#: the node alone, so both phases of the build apply it alike (the same tree on any grain).
CHEAP_MAX = 4096
CHEAP_BINS = 16
CHEAP_AXIS_FRAC = 0.5
#: ``cheap_max`` of a large mesh's item build (:mod:`.bvh_cluster`): the cheap rule on
#: every node, the top levels' too (session 37, docs/bench-scale.md: top levels about a
#: fifth less CPU, SAH cost no higher on Suzanne 1M / 4M; not the triangle build's: +0.9%
#: on a 30k lumpy sphere).
CHEAP_ALL = 1 << 62


@njit(cache=True, nogil=True, inline="always")
def _half_area(b0, b1, b2, b3, b4, b5):
    dx, dy, dz = b3 - b0, b4 - b1, b5 - b2
    if dx < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _clear_axis(bin_n, bin_b, k, nbins):
    """Empty bins ``0 .. nbins - 1`` of axis ``k`` (scalar stores: a slice per bin cost
    more than the stores)."""
    for b in range(nbins):
        bin_n[k, b] = 0
        for q in range(3):
            bin_b[k, b, q] = np.inf
            bin_b[k, b, 3 + q] = -np.inf


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _clear_bins(bin_n, bin_b, nbins):
    """Empty bins ``0 .. nbins - 1`` of the three axes."""
    for k in range(3):
        _clear_axis(bin_n, bin_b, k, nbins)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _node_bins(count, nbins, cmin, cmax, bmin, bmax, cheap_max):
    """How a node of ``count`` primitives with centroid bounds ``cmin``, ``cmax`` (3,) is
    binned (the cheap rule up to ``cheap_max`` primitives: :data:`CHEAP_MAX`, or
    :data:`CHEAP_ALL` in a large mesh's item build, :mod:`.bvh_cluster`): returns its
    bins per axis (at most ``nbins``, and at most its primitives), and
    sets ``bmin``, ``bmax`` (3,) to the bounds the bins are laid over: ``cmin``, ``cmax``
    with each axis left out made flat (a flat axis is neither binned nor swept:
    :func:`_bin_range`, :func:`_best_split`)."""
    emax = max(cmax[0] - cmin[0], max(cmax[1] - cmin[1], cmax[2] - cmin[2]))
    cheap = count <= cheap_max
    for q in range(3):
        bmin[q] = cmin[q]
        bmax[q] = cmax[q]
        if cheap and cmax[q] - cmin[q] < CHEAP_AXIS_FRAC * emax:
            bmax[q] = cmin[q]
    if cheap:
        return min(nbins, CHEAP_BINS, max(count, 2))
    return min(nbins, max(count, 2))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _clear_axes(bin_n, bin_b, nbins, bmin, bmax):
    """:func:`_clear_bins` of the axes binned over ``bmin``, ``bmax`` only (those of
    positive extent: the others are never read)."""
    for k in range(3):
        if bmax[k] > bmin[k]:
            _clear_axis(bin_n, bin_b, k, nbins)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _empty6(a):
    """``a`` (6,) the empty box: (+inf, +inf, +inf, -inf, -inf, -inf)."""
    for q in range(3):
        a[q] = np.inf
        a[3 + q] = -np.inf


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bin_scale(cmin_k, cmax_k, nbins):
    """The factor a centroid's offset from ``cmin_k`` is multiplied by to give its bin
    (:func:`_bin_at`; 0: the axis is flat, not binned)."""
    ext = cmax_k - cmin_k
    return nbins / ext if ext > 0.0 else 0.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bin_at(c, cmin_k, scale, nbins):
    """The bin of centroid coordinate ``c`` (``scale``: :func:`_bin_scale`), clamped."""
    b = int((c - cmin_k) * scale)
    return min(max(b, 0), nbins - 1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _grow(bin_b, k, b, x0, y0, z0, x1, y1, z1):
    bin_b[k, b, 0] = min(bin_b[k, b, 0], x0)
    bin_b[k, b, 1] = min(bin_b[k, b, 1], y0)
    bin_b[k, b, 2] = min(bin_b[k, b, 2], z0)
    bin_b[k, b, 3] = max(bin_b[k, b, 3], x1)
    bin_b[k, b, 4] = max(bin_b[k, b, 4], y1)
    bin_b[k, b, 5] = max(bin_b[k, b, 5], z1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bin_range(pb, start, end, cmin, cmax, nbins, bin_n, bin_b):
    """Add primitives ``pb[start:end]`` to the bins (counts, boxes) of all three axes
    (an axis whose centroids do not spread is left out)."""
    s0 = _bin_scale(cmin[0], cmax[0], nbins)
    s1 = _bin_scale(cmin[1], cmax[1], nbins)
    s2 = _bin_scale(cmin[2], cmax[2], nbins)
    c0, c1, c2 = cmin[0], cmin[1], cmin[2]
    for j in range(start, end):
        x0, y0, z0 = np.float64(pb[j, 0]), np.float64(pb[j, 1]), np.float64(pb[j, 2])
        x1, y1, z1 = np.float64(pb[j, 3]), np.float64(pb[j, 4]), np.float64(pb[j, 5])
        if s0 > 0.0:
            b = _bin_at(0.5 * (x0 + x1), c0, s0, nbins)
            bin_n[0, b] += 1
            _grow(bin_b, 0, b, x0, y0, z0, x1, y1, z1)
        if s1 > 0.0:
            b = _bin_at(0.5 * (y0 + y1), c1, s1, nbins)
            bin_n[1, b] += 1
            _grow(bin_b, 1, b, x0, y0, z0, x1, y1, z1)
        if s2 > 0.0:
            b = _bin_at(0.5 * (z0 + z1), c2, s2, nbins)
            bin_n[2, b] += 1
            _grow(bin_b, 2, b, x0, y0, z0, x1, y1, z1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _best_split(cmin, cmax, nbins, bin_n, bin_b, right_a, right_n):
    """The best split of filled bins: ``(cost, axis, bin)``, between bins ``bin`` and
    ``bin + 1`` (axis -1: none; ``cost`` unnormalised)."""
    best_cost = np.inf
    best_axis = -1
    best_bin = -1
    for k in range(3):
        if cmax[k] - cmin[k] <= 0.0:
            continue
        # sweep from the right: area and count of bins b.. nbins-1
        r0 = r1 = r2 = np.inf
        r3 = r4 = r5 = -np.inf
        cnt = 0
        for b in range(nbins - 1, 0, -1):
            cnt += bin_n[k, b]
            r0 = min(r0, bin_b[k, b, 0])
            r1 = min(r1, bin_b[k, b, 1])
            r2 = min(r2, bin_b[k, b, 2])
            r3 = max(r3, bin_b[k, b, 3])
            r4 = max(r4, bin_b[k, b, 4])
            r5 = max(r5, bin_b[k, b, 5])
            right_n[b] = cnt
            right_a[b] = _half_area(r0, r1, r2, r3, r4, r5)
        l0 = l1 = l2 = np.inf
        l3 = l4 = l5 = -np.inf
        cnt = 0
        for b in range(nbins - 1):  # split between bin b and b + 1
            cnt += bin_n[k, b]
            l0 = min(l0, bin_b[k, b, 0])
            l1 = min(l1, bin_b[k, b, 1])
            l2 = min(l2, bin_b[k, b, 2])
            l3 = max(l3, bin_b[k, b, 3])
            l4 = max(l4, bin_b[k, b, 4])
            l5 = max(l5, bin_b[k, b, 5])
            nr = right_n[b + 1]
            if cnt == 0 or nr == 0:
                continue
            cost = _half_area(l0, l1, l2, l3, l4, l5) * cnt + right_a[b + 1] * nr
            if cost < best_cost:
                best_cost, best_axis, best_bin = cost, k, b
    return best_cost, best_axis, best_bin


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bins_box(bin_b, k, b0, b1, box):
    """Union of the boxes of bins ``b0 .. b1 - 1`` of axis ``k``: the box of their
    primitives."""
    _empty6(box)
    for b in range(b0, b1):
        for q in range(3):
            box[q] = min(box[q], bin_b[k, b, q])
            box[3 + q] = max(box[3 + q], bin_b[k, b, 3 + q])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_centroid(pb, j, cb):
    for q in range(3):
        c = 0.5 * (np.float64(pb[j, q]) + np.float64(pb[j, 3 + q]))
        cb[q] = min(cb[q], c)
        cb[3 + q] = max(cb[3 + q], c)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _swap(pb, perm, i, j):
    perm[i], perm[j] = perm[j], perm[i]
    for q in range(6):
        pb[i, q], pb[j, q] = pb[j, q], pb[i, q]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _partition(pb, perm, start, end, k, cmin_k, ext, nbins, split_bin):
    """Reorder ``pb`` / ``perm[start:end]``: primitives whose centroid falls in bins up to
    ``split_bin`` on axis ``k`` first. Returns where the others start. (No centroid
    bounds are gathered: the two sides' bins are laid over their boxes, which the bins
    give, :mod:`.bvh_build`.)"""
    scale = nbins / ext
    i, j = start, end - 1
    while i <= j:
        if _bin_at(0.5 * (np.float64(pb[i, k]) + np.float64(pb[i, 3 + k])), cmin_k, scale,
                   nbins) <= split_bin:
            i += 1
        else:
            _swap(pb, perm, i, j)
            j -= 1
    return i


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box_area(pb, i):
    """The half area of box row ``i`` of ``pb`` (float32 or float64), in float64."""
    return _half_area(np.float64(pb[i, 0]), np.float64(pb[i, 1]), np.float64(pb[i, 2]),
                      np.float64(pb[i, 3]), np.float64(pb[i, 4]), np.float64(pb[i, 5]))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bin_split(pb, start, end, nbins, cmin, cmax, bmin, bmax, cheap_max, bin_n, bin_b,
               right_a, right_n):
    """One node's bin-and-split step: primitives ``start .. end - 1`` of ``pb`` (centroid
    bounds ``cmin``, ``cmax``) binned as :func:`_node_bins` says, over ``bmin``, ``bmax``
    (set here), and the best split of the bins: ``(nb, cost, axis, bin)`` (the bins per
    axis, then :func:`_best_split`'s)."""
    nb = _node_bins(end - start, nbins, cmin, cmax, bmin, bmax, cheap_max)
    _clear_axes(bin_n, bin_b, nb, bmin, bmax)
    _bin_range(pb, start, end, bmin, bmax, nb, bin_n, bin_b)
    cost, axis, sbin = _best_split(bmin, bmax, nb, bin_n, bin_b, right_a, right_n)
    return nb, cost, axis, sbin


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _centroid(pb, j, k):
    return 0.5 * (np.float64(pb[j, k]) + np.float64(pb[j, 3 + k]))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _two_split(pb, start, cmin, cmax):
    """:func:`_best_split` of the two primitives ``start``, ``start + 1`` (centroid bounds
    ``cmin``, ``cmax``) without bins, the same numbers: each is a bin of its own on every
    axis their centroids spread on, so every such axis costs the sum of their areas and
    the first one wins (``(cost, axis, 0)``; axis -1: none)."""
    for k in range(3):
        if cmax[k] - cmin[k] > 0.0:
            a, b = _box_area(pb, start), _box_area(pb, start + 1)
            lo = _centroid(pb, start, k) <= _centroid(pb, start + 1, k)
            return (a if lo else b) + (b if lo else a), k, 0
    return np.inf, -1, -1
