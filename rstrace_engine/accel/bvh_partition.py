"""The stable partition of a binary BVH node (:func:`partition_stable`), for the builder
of :mod:`.bvh_build` (a module of its own: that one is at the size limit)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def partition_stable(pb, perm, start, end, k, cmin_k, ext, nbins, split_bin, lcb, rcb, sc,
                      sperm):
    """:func:`.bvh_build._partition`'s sides, each in its rows' order (stable): a row of the first
    side moves down in place, one of the other goes to the scratch rows ``sc`` /
    ``sperm`` (at least ``end - start`` of them) and back after them. Each row is read
    once, and the sides' centroid bounds are kept in scalars. For a tree whose leaves hold
    one primitive, where the order inside a node decides nothing but a median split's
    ties (:func:`.bvh_build.build_subtree`): no row is read back just after it was written, as the
    swaps of ``_partition`` read them (7-15% less CPU in the subtrees, session 35)."""
    scale = nbins / ext
    l0 = l1 = l2 = r0 = r1 = r2 = np.inf
    l3 = l4 = l5 = r3 = r4 = r5 = -np.inf
    lw = start
    rw = 0
    for i in range(start, end):
        a0, a1, a2, a3, a4, a5 = pb[i, 0], pb[i, 1], pb[i, 2], pb[i, 3], pb[i, 4], pb[i, 5]
        c0 = 0.5 * (np.float64(a0) + np.float64(a3))
        c1 = 0.5 * (np.float64(a1) + np.float64(a4))
        c2 = 0.5 * (np.float64(a2) + np.float64(a5))
        c = c0 if k == 0 else (c1 if k == 1 else c2)
        b = min(max(int((c - cmin_k) * scale), 0), nbins - 1)  # (bvh_build._bin_at)
        if b <= split_bin:
            if lw != i:
                pb[lw, 0], pb[lw, 1], pb[lw, 2] = a0, a1, a2
                pb[lw, 3], pb[lw, 4], pb[lw, 5] = a3, a4, a5
                perm[lw] = perm[i]
            lw += 1
            l0, l1, l2 = min(l0, c0), min(l1, c1), min(l2, c2)
            l3, l4, l5 = max(l3, c0), max(l4, c1), max(l5, c2)
        else:
            sc[rw, 0], sc[rw, 1], sc[rw, 2] = a0, a1, a2
            sc[rw, 3], sc[rw, 4], sc[rw, 5] = a3, a4, a5
            sperm[rw] = perm[i]
            rw += 1
            r0, r1, r2 = min(r0, c0), min(r1, c1), min(r2, c2)
            r3, r4, r5 = max(r3, c0), max(r4, c1), max(r5, c2)
    for t in range(rw):
        for q in range(6):
            pb[lw + t, q] = sc[t, q]
        perm[lw + t] = sperm[t]
    lcb[0], lcb[1], lcb[2], lcb[3], lcb[4], lcb[5] = l0, l1, l2, l3, l4, l5
    rcb[0], rcb[1], rcb[2], rcb[3], rcb[4], rcb[5] = r0, r1, r2, r3, r4, r5
    return lw
