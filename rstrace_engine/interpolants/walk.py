"""A frame's walk down the linetrees (the kernels of
:meth:`~.cache.InterpolantCache.resolve`): per level, every active ray descends to its leaf
and is interpolated where the leaf holds an interpolant, marked where it holds a fail, or
grouped with the other rays that reached the same empty leaf (a cell to build).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..frame import (
    CLASS_FAIL_SILHOUETTE,
    CLASS_INTERPOLATED,
    CLASS_REBUILT,
    CLASS_TRACED,
)
from .linetree import (
    EMPTY,
    cell_bounds,
    descend_one,
    interpolate16,
)

#: Rays per block of the frame kernels (each block walks its rays in order, so that a ray can
#: reuse the leaf of the ray before it: neighbouring pixels mostly share a cell).
WALK_BLOCK = 4096


@njit(cache=True, nogil=True, parallel=True)
def walk_level(lt, rad16, izlo, izhi, icls, istamp, irebuilt, clock, nodes, inherited, abcd, zp,
          clsp, active, idx, rad, done, pcls, pinterp):
    """One level of a frame's walk down the linetrees, for the active rays among ``idx``
    (ray ids in increasing order): descend to the
    leaf; where it holds an interpolant, the ray is finished: interpolated (quadrilinear) if
    its visible hit is the interpolant's slab crossing (class and depth), else to be traced
    (silhouette). The interpolant's LRU stamp becomes ``clock``; ``pinterp[r]`` the id of the
    interpolant an interpolated ray used, and its class ``CLASS_REBUILT`` if that interpolant
    was rebuilt after an edit.

    A ray from the same start node and inherited code as the ray before it whose line lies
    in that ray's leaf cell takes that leaf without descending: the descent from the start
    follows the prefixes of the leaf's lattice coordinates (scaling by powers of two is
    exact), so it would reach the same leaf with the same inherited code."""
    n = idx.shape[0]
    for b in prange((n + WALK_BLOCK - 1) // WALK_BLOCK):
        pstart = -1
        pinh = 0
        pleaf = 0
        pout = 0
        lo = np.zeros(4)
        hi = np.zeros(4)
        for k in range(b * WALK_BLOCK, min(n, (b + 1) * WALK_BLOCK)):
            r = idx[k]
            if not active[r]:
                continue
            a0 = abcd[r, 0]
            a1 = abcd[r, 1]
            a2 = abcd[r, 2]
            a3 = abcd[r, 3]
            if (nodes[r] == pstart and inherited[r] == pinh and lo[0] <= a0 < hi[0]
                    and lo[1] <= a1 < hi[1] and lo[2] <= a2 < hi[2] and lo[3] <= a3 < hi[3]):
                nd = pleaf
                inh = pout
            else:
                pstart = nodes[r]
                pinh = inherited[r]
                nd, inh = descend_one(lt, pstart, abcd[r], pinh)
                pleaf = nd
                pout = inh
                cell_bounds(lt, nd, lo, hi)
            nodes[r] = nd
            inherited[r] = inh
            q = lt.leaf[nd]
            if q < 0:
                continue
            active[r] = False
            istamp[q] = clock
            if clsp[r] != icls[q] or zp[r] < izlo[q] or zp[r] > izhi[q]:
                pcls[r] = CLASS_FAIL_SILHOUETTE
                continue
            s = float(1 << lt.depth[nd])
            u0 = min(max(a0 * s - lt.coord[nd, 0], 0.0), 1.0)
            u1 = min(max(a1 * s - lt.coord[nd, 1], 0.0), 1.0)
            u2 = min(max(a2 * s - lt.coord[nd, 2], 0.0), 1.0)
            u3 = min(max(a3 * s - lt.coord[nd, 3], 0.0), 1.0)
            interpolate16(rad16, q, rad, r, u0, u1, u2, u3)
            done[r] = True
            pinterp[r] = q
            pcls[r] = CLASS_REBUILT if irebuilt[q] else CLASS_INTERPOLATED


@njit(cache=True, nogil=True)
def group_active(nodes, active, idx, counts, uniq):
    """Leaves of the active rays among ``idx``, in order of appearance, into ``uniq``;
    ``counts[leaf]`` (zero on entry) gets each leaf's ray count. Returns the number of
    leaves."""
    u = 0
    for k in range(idx.shape[0]):
        r = idx[k]
        if active[r]:
            nd = nodes[r]
            if counts[nd] == 0:
                uniq[u] = nd
                u += 1
            counts[nd] += 1
    return u


@njit(cache=True, nogil=True)
def settle(node_cls, nodes, inherited, active, idx, pcls):
    """Rays of leaves that are neither built nor split this level are finished (to be
    traced): ``node_cls`` is their class, 0 for a cell too small to build (it shows the
    class of the failed cell it was split from, if any), 255 for leaves that go on. Only
    the rays among ``idx`` are looked at."""
    for k in range(idx.shape[0]):
        r = idx[k]
        if not active[r]:
            continue
        c = node_cls[nodes[r]]
        if c == 255:
            continue
        active[r] = False
        if c == 0:
            c = -2 - inherited[r] if inherited[r] < EMPTY else CLASS_TRACED
        pcls[r] = c
