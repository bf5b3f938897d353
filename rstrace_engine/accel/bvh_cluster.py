"""A large mesh's binary BVH over its quads (:func:`build_paired`).

A triangulated surface lists a quad's two triangles one after the other (Blender's loop
triangles, a subdivided or scanned mesh): triangles ``2i`` and ``2i + 1`` that share an
edge. The binned SAH build (:mod:`.bvh_build`) puts nine in ten of them in one leaf of
two anyway, after binning both of them on every level from the root down. Here such a
pair is one item of the SAH build (a triangle whose neighbour in the list is no edge
neighbour is an item alone): half the items on every level and one level fewer. Each
item's leaf is then opened by the SAH rule the build applies to a node of two
primitives: one leaf of both, or an inner node over two leaves of one, split on the first
axis their centroids spread on. The tree differs from the whole-mesh SAH build's where a
pair would have been split higher up; its SAH cost is within a few tenths of a percent of
it (docs/bench-scale-bpy.md), and it is the same tree on any thread count.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..cancel import Cancelled
from .bvh_build import (
    NEVER_STOP,
    SAH_BINS,
    SAH_TRAVERSAL_COST,
    _half_area,
    build_flat_boxes,
)


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def pair_items(verts, tris, pb):
    """Items of the paired build: ``(starts (P + 1,) int64, boxes (P, 6))``, item ``k``
    the triangles ``starts[k]:starts[k + 1]`` (one, or two consecutive ones with two
    vertices in common, by position), its box the union of theirs (``pb``'s dtype)."""
    m = tris.shape[0]
    half = (m + 1) // 2
    size = np.empty(half, np.int64)
    for h in prange(half):
        i = 2 * h
        size[h] = 2  # two items of one, or one of two
        if i + 1 < m:
            shared = 0
            for a in range(3):
                va = tris[i, a]
                for b in range(3):
                    vb = tris[i + 1, b]
                    if (verts[va, 0] == verts[vb, 0] and verts[va, 1] == verts[vb, 1]
                            and verts[va, 2] == verts[vb, 2]):
                        shared += 1
                        break
            size[h] = 1 if shared >= 2 else 2
        else:
            size[h] = 1
    first = np.empty(half + 1, np.int64)  # the first item of each pair of triangles
    first[0] = 0
    for h in range(half):
        first[h + 1] = first[h] + size[h]
    n_items = first[half]
    starts = np.empty(n_items + 1, np.int64)
    starts[n_items] = m
    boxes = np.empty((n_items, 6), pb.dtype)
    for h in prange(half):
        i, k = 2 * h, first[h]
        if size[h] == 1 and i + 1 < m:  # one item of two triangles
            starts[k] = i
            for q in range(3):
                boxes[k, q] = min(pb[i, q], pb[i + 1, q])
                boxes[k, 3 + q] = max(pb[i, 3 + q], pb[i + 1, 3 + q])
        else:
            for j in range(size[h]):
                starts[k + j] = i + j
                for q in range(6):
                    boxes[k + j, q] = pb[i + j, q]
    return starts, boxes


@njit(cache=True, nogil=True, error_model="numpy")
def item_leaves(child, n_items):
    """The item tree's leaves, walked from the root: ``(P, 3) int64`` rows ``parent, slot,
    position`` (the leaf ``~(position << 3 | 1)`` holds the item at ``position`` of the
    tree's leaf order)."""
    out = np.empty((n_items, 3), np.int64)
    stack = np.empty(256, np.int64)
    stack[0] = 0
    sp = 1
    k = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for s in range(2):
            c = child[node, s]
            if c >= 0:
                stack[sp] = c
                sp += 1
            else:
                code = ~np.int64(c)
                if (code & 7) == 0:  # the empty child of a one-leaf root
                    continue
                out[k, 0], out[k, 1], out[k, 2] = node, s, code >> 3
                k += 1
    return out[:k]


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def open_items(pb, starts, iperm, rows, leaves, region0, trav_cost, root_area, bounds,
               child, perm):
    """Each item leaf ``leaves[i]`` (:func:`item_leaves`) opened, one thread per leaf: its
    triangles listed in ``perm`` from row ``rows[position]``; an item of two becomes a
    leaf of both, or an inner node over two leaves of
    one, by the SAH rule of a two-primitive node (:func:`.bvh_build.build_subtree`); the
    inner node of the item at ``position`` is row ``region0 + position``.
    Returns each opened item's SAH less the SAH of the leaf it replaced (P,)."""
    nl = leaves.shape[0]
    dsah = np.zeros(nl)
    for i in prange(nl):
        parent, slot, pos = leaves[i, 0], leaves[i, 1], leaves[i, 2]
        k = iperm[pos]
        a, cnt, row = starts[k], starts[k + 1] - starts[k], rows[pos]
        area = _half_area(np.float64(bounds[parent, 6 * slot]),
                          np.float64(bounds[parent, 6 * slot + 1]),
                          np.float64(bounds[parent, 6 * slot + 2]),
                          np.float64(bounds[parent, 6 * slot + 3]),
                          np.float64(bounds[parent, 6 * slot + 4]),
                          np.float64(bounds[parent, 6 * slot + 5]))
        if cnt == 1:  # the item's leaf is the triangle's
            perm[row] = a
            child[parent, slot] = ~((row << 3) | 1)
            continue
        b = a + 1
        # the first axis the two centroids spread on (the bins' first candidate: every
        # spread axis gives the same two sides, the same cost)
        axis = -1
        for q in range(3):
            ca = np.float64(pb[a, q]) + np.float64(pb[a, 3 + q])
            cb = np.float64(pb[b, q]) + np.float64(pb[b, 3 + q])
            if ca != cb:
                axis = q
                if cb < ca:
                    a, b = b, a
                break
        aa = _half_area(np.float64(pb[a, 0]), np.float64(pb[a, 1]), np.float64(pb[a, 2]),
                        np.float64(pb[a, 3]), np.float64(pb[a, 4]), np.float64(pb[a, 5]))
        ab = _half_area(np.float64(pb[b, 0]), np.float64(pb[b, 1]), np.float64(pb[b, 2]),
                        np.float64(pb[b, 3]), np.float64(pb[b, 4]), np.float64(pb[b, 5]))
        split_cost = trav_cost + (aa + ab) / max(area, 1e-300) if axis >= 0 else np.inf
        if 2 <= split_cost:  # one leaf of both, in the mesh's order
            perm[row], perm[row + 1] = starts[k], starts[k] + 1
            child[parent, slot] = ~((row << 3) | 2)
            dsah[i] = area / root_area
            continue
        node = region0 + pos  # (one row per item: the rows touched stay few)
        child[parent, slot] = node
        perm[row], perm[row + 1] = a, b
        for q in range(6):
            bounds[node, q] = pb[a, q]
            bounds[node, 6 + q] = pb[b, q]
        child[node, 0] = ~((row << 3) | 1)
        child[node, 1] = ~(((row + 1) << 3) | 1)
        dsah[i] = (trav_cost * area + aa + ab) / root_area - area / root_area
    return dsah


def build_paired(verts: np.ndarray, tris: np.ndarray, pb: np.ndarray, nbins: int = SAH_BINS,
                 trav_cost: float = SAH_TRAVERSAL_COST, grain: int | None = None,
                 stop: np.ndarray = NEVER_STOP):
    """The binary tree of the triangles ``verts[tris]`` of boxes ``pb`` (m, 6), built over
    their quads (module docstring): ``bounds, child, perm, sah`` as
    ``build_flat_boxes(packed=False)`` returns them (the root row 0; rows no child index
    reaches unset)."""
    m = len(tris)
    starts, ib = pair_items(verts, tris, pb)
    n_items = len(ib)
    # (the item tree's arrays with a row per item after them: the opened items' nodes)
    bounds, child, iperm, sah_i = build_flat_boxes(ib, 1, nbins, trav_cost, grain, stop,
                                                   packed=False, spare=n_items)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    region0 = max(n_items, 2)
    leaves = item_leaves(child, n_items)
    rows = np.zeros(n_items, np.int64)  # each item's first row of perm, in leaf order
    np.cumsum(np.diff(starts)[iperm][:-1], out=rows[1:])
    # the root's box: the union of its two children's (no kernel called from Python here:
    # each would be one more for the F12's kernel pre-load, addon/kernels.py)
    root = bounds[0].astype(np.float64)
    lo, hi = np.minimum(root[0:3], root[6:9]), np.maximum(root[3:6], root[9:12])
    dx, dy, dz = (float(x) for x in hi - lo)
    root_area = max(dx * dy + dy * dz + dz * dx, 1e-300)
    perm = np.empty(m, np.int32)
    dsah = open_items(pb, starts, iperm, rows, leaves, region0, trav_cost, root_area, bounds,
                      child, perm)
    return bounds, child, perm, float(sah_i + dsah.sum())
