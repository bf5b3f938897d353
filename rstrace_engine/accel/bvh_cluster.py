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
it (docs/bench-scale-bpy.md), and it is the same tree on any thread count. How each pair
opens is decided where its item is made, reading the triangles' boxes in mesh order; the
leaves are then opened in a walk (its subtrees on every thread), and only a split pair
reads its boxes again and takes a node row (packed after the item tree's, in leaf order):
at 4M triangles, fresh pages and random reads were most of what the opening cost.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from ..cancel import Cancelled
from .bvh_bins import CHEAP_ALL, _add_centroid, _box_area, _empty6, _half_area
from .bvh_build import NEVER_STOP, SAH_BINS, SAH_TRAVERSAL_COST, build_flat_boxes

#: How an item is opened (:func:`pair_items`' ``how``): one leaf of its triangles (one, or
#: both in the mesh's order), or an inner node over two leaves of one, the item's first
#: triangle first or second.
OPEN_LEAF, OPEN_SPLIT, OPEN_SPLIT_SWAPPED = 0, 1, 2


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _opening(pb, i, area, trav_cost):
    """How the item of triangles ``i``, ``i + 1`` (box half area ``area``) is opened: the
    SAH rule the triangle build applies to a node of two primitives
    (:func:`.bvh_build.build_subtree`): split on the first axis their centroids spread on
    (the bins' first candidate: every spread axis gives the same two sides, the same
    cost), the lower centroid first, unless one leaf of both costs no more."""
    axis = -1
    swapped = False
    for q in range(3):
        ca = np.float64(pb[i, q]) + np.float64(pb[i, 3 + q])
        cb = np.float64(pb[i + 1, q]) + np.float64(pb[i + 1, 3 + q])
        if ca != cb:
            axis = q
            swapped = cb < ca
            break
    if axis < 0:
        return OPEN_LEAF
    if swapped:  # (the lower centroid's area first, as the bins add them)
        split_cost = trav_cost + (_box_area(pb, i + 1) + _box_area(pb, i)) / max(area, 1e-300)
    else:
        split_cost = trav_cost + (_box_area(pb, i) + _box_area(pb, i + 1)) / max(area, 1e-300)
    if 2 <= split_cost:
        return OPEN_LEAF
    return OPEN_SPLIT_SWAPPED if swapped else OPEN_SPLIT


#: Pairs of triangles per chunk of :func:`pair_items`' items (each chunk its own bounds).
PAIR_CHUNK = 8192


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def pair_items(verts, tris, pb, trav_cost):
    """Items of the paired build: ``(starts (P + 1,) int32, boxes (P, 6), how (P,) int8,
    root (12,))``, item ``k`` the triangles ``starts[k]:starts[k + 1]`` (one, or two
    consecutive ones with two vertices in common, by position), its box the union of
    theirs (``pb``'s dtype), ``how`` the way :func:`open_items` opens it
    (:data:`OPEN_LEAF` ...: decided here, in the mesh's order, where the triangles' boxes
    are read in order), ``root`` the items' box and centroid bounds, what
    :func:`.bvh_build._range_bounds` finds over ``boxes`` (minima and maxima per chunk of
    :data:`PAIR_CHUNK` pairs, combined in chunk order: the same values; the item build's
    root needs no pass of its own, session 38)."""
    m = tris.shape[0]
    half = (m + 1) // 2
    n_chunks = (half + PAIR_CHUNK - 1) // PAIR_CHUNK
    # (session 39: the sizes int8 and no (half,) int64 prefix sum, each chunk's first item
    # from the chunks' counts: ~30 MB less fresh memory at 4M triangles)
    size = np.empty(half, np.int8)
    first = np.empty(n_chunks + 1, np.int64)  # the first item of each chunk of pairs
    for cc in prange(n_chunks):
        c = np.int64(cc)  # (a prange index may be unsigned: keep index sums integer)
        cnt = 0
        for h in range(c * PAIR_CHUNK, min(half, (c + 1) * PAIR_CHUNK)):
            i = 2 * h
            s = 1  # one item of two, or (the last triangle alone) one of one
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
                s = 1 if shared >= 2 else 2  # one item of two, or two items of one
            size[h] = s
            cnt += s
        first[c + 1] = cnt
    first[0] = 0
    for c in range(n_chunks):
        first[c + 1] += first[c]
    n_items = first[n_chunks]
    starts = np.empty(n_items + 1, np.int32)  # (triangle ids: perm's int32)
    starts[n_items] = m
    boxes = np.empty((n_items, 6), pb.dtype)
    how = np.empty(n_items, np.int8)  # (every item's written below: no zero fill)
    part = np.empty((n_chunks, 12))
    for cc in prange(n_chunks):
        c = np.int64(cc)
        _empty6(part[c, 0:6])
        _empty6(part[c, 6:12])
        k = first[c]
        for h in range(c * PAIR_CHUNK, min(half, (c + 1) * PAIR_CHUNK)):
            i = 2 * h
            if size[h] == 1 and i + 1 < m:  # one item of two triangles
                starts[k] = i
                for q in range(3):
                    boxes[k, q] = min(pb[i, q], pb[i + 1, q])
                    boxes[k, 3 + q] = max(pb[i, 3 + q], pb[i + 1, 3 + q])
                how[k] = _opening(pb, i, _box_area(boxes, k), trav_cost)
            else:
                for j in range(size[h]):
                    starts[k + j] = i + j
                    how[k + j] = OPEN_LEAF
                    for q in range(6):
                        boxes[k + j, q] = pb[i + j, q]
            for j in range(k, k + size[h]):  # (its items: their bounds)
                for q in range(3):
                    part[c, q] = min(part[c, q], np.float64(boxes[j, q]))
                    part[c, 3 + q] = max(part[c, 3 + q], np.float64(boxes[j, 3 + q]))
                _add_centroid(boxes, j, part[c, 6:12])
            k += size[h]
    root = np.empty(12)
    _empty6(root[0:6])
    _empty6(root[6:12])
    for c in range(n_chunks):
        for q in range(3):
            root[q] = min(root[q], part[c, q])
            root[3 + q] = max(root[3 + q], part[c, 3 + q])
            root[6 + q] = min(root[6 + q], part[c, 6 + q])
            root[9 + q] = max(root[9 + q], part[c, 9 + q])
    return starts, boxes, how, root


@njit(cache=True, nogil=True, error_model="numpy")
def item_leaves(starts, iperm, how, rows, nodes):
    """Where each item leaf's triangles and node go, written into ``rows``, ``nodes`` (P,)
    int32 (returned): for the item at ``position`` of the item tree's leaf order
    (``iperm``), ``rows`` the first of its rows of the triangle order, after those of the
    items before it; ``nodes`` the number of split items (``how`` non-zero: each takes a
    node row, :func:`open_items`) before it. (One thread: a prefix sum in chunks on two
    threads, each chunk read twice, took as long, session 38. :func:`build_paired` passes
    the item boxes' memory, dead once the item tree is built: no fresh pages, session
    39.)"""
    n = iperm.shape[0]
    row, k = 0, 0
    for pos in range(n):
        rows[pos], nodes[pos] = row, k
        item = iperm[pos]
        row += starts[item + 1] - starts[item]
        k += how[item] != 0
    return rows, nodes


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _open_leaf(pb, starts, how, iperm, rows, nodes, region0, trav_cost, root_area, bounds,
               child, perm, parent, slot, code):
    """Item leaf ``code`` (``~child[parent, slot]``) opened (:func:`open_items`); returns
    its SAH less the item leaf's."""
    pos = code >> 3
    k = iperm[pos]
    row = np.int64(rows[pos])
    a, cnt = starts[k], starts[k + 1] - starts[k]
    if cnt == 1:  # the item's leaf is the triangle's
        perm[row] = a
        child[parent, slot] = ~((row << 3) | 1)
        return 0.0
    area = _half_area(np.float64(bounds[parent, 6 * slot]),
                      np.float64(bounds[parent, 6 * slot + 1]),
                      np.float64(bounds[parent, 6 * slot + 2]),
                      np.float64(bounds[parent, 6 * slot + 3]),
                      np.float64(bounds[parent, 6 * slot + 4]),
                      np.float64(bounds[parent, 6 * slot + 5]))
    if how[k] == OPEN_LEAF:  # one leaf of both, in the mesh's order
        perm[row], perm[row + 1] = a, a + 1
        child[parent, slot] = ~((row << 3) | 2)
        return area / root_area
    b = a + 1
    if how[k] == OPEN_SPLIT_SWAPPED:
        a, b = b, a
    node = region0 + np.int64(nodes[pos])
    child[parent, slot] = node
    perm[row], perm[row + 1] = a, b
    for q in range(6):
        bounds[node, q] = pb[a, q]
        bounds[node, 6 + q] = pb[b, q]
    child[node, 0] = ~((row << 3) | 1)
    child[node, 1] = ~(((row + 1) << 3) | 1)
    return (trav_cost * area + _box_area(pb, a) + _box_area(pb, b)) / root_area \
        - area / root_area


#: Subtrees :func:`open_items` aims to share among its threads (found within
#: :data:`OPEN_TOP_LEVELS` levels of the root).
OPEN_TASKS = 128
OPEN_TOP_LEVELS = 24


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def open_items(pb, starts, how, iperm, rows, nodes, region0, trav_cost, root_area, bounds,
               child, perm, ntask=OPEN_TASKS):
    """Each item leaf of the item tree (``child``, from its root) opened: its triangles
    listed in ``perm`` from row ``rows[position]`` (:func:`item_leaves`); an item of two
    becomes a leaf of both, or an inner node over two leaves of one, as ``how`` says
    (:func:`pair_items`: the SAH rule of a two-primitive node,
    :func:`.bvh_build.build_subtree`), its inner node row ``region0 + nodes[position]``
    (the split items' rows in leaf order; only those items read their triangles' boxes).
    The levels nearest the root are walked one at a time until one holds ``ntask`` inner
    nodes (or :data:`OPEN_TOP_LEVELS` are walked), the subtrees under them on every
    thread (one a task). Returns the opened items' SAH less the SAH of the leaves they
    replaced (summed per subtree, then in the subtrees' order: the same on any thread
    count; not main's serial walk's order, so the last bits of the SAH cost may differ
    from session 37's, the tree does not)."""
    cap = 2 * ntask + 2
    lv = np.empty(cap, np.int64)
    nx = np.empty(cap, np.int64)
    lv[0] = 0
    n_lv = 1
    dsah = 0.0
    for _ in range(OPEN_TOP_LEVELS):
        if n_lv == 0 or n_lv >= ntask:
            break
        n_nx = 0
        for e in range(n_lv):
            parent = lv[e]
            for slot in range(2):
                c = child[parent, slot]
                if c >= 0:
                    nx[n_nx] = c
                    n_nx += 1
                elif (~np.int64(c) & 7) != 0:  # (not the empty child of a one-leaf root)
                    dsah += _open_leaf(pb, starts, how, iperm, rows, nodes, region0,
                                       trav_cost, root_area, bounds, child, perm, parent,
                                       slot, ~np.int64(c))
        lv, nx = nx, lv
        n_lv = n_nx
    part = np.zeros(n_lv)
    for t in prange(n_lv):
        stack = np.empty(256, np.int64)
        stack[0] = lv[t]
        sp = 1
        d = 0.0
        while sp > 0:
            sp -= 1
            parent = stack[sp]
            for slot in range(2):
                c = child[parent, slot]
                if c >= 0:
                    stack[sp] = c
                    sp += 1
                elif (~np.int64(c) & 7) != 0:
                    d += _open_leaf(pb, starts, how, iperm, rows, nodes, region0, trav_cost,
                                    root_area, bounds, child, perm, parent, slot,
                                    ~np.int64(c))
        part[t] = d
    for t in range(n_lv):
        dsah += part[t]
    return dsah


def item_scratch(ib: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two (P,) int32 arrays in the memory of the item boxes ``ib`` (P, 6) (float32 or
    float64, C-contiguous: 24 or 48 bytes an item, 8 needed), for :func:`item_leaves`."""
    if not ib.flags.c_contiguous:  # (reshape would copy: fresh memory, not ``ib``'s)
        raise ValueError("item_scratch: the item boxes must be C-contiguous")
    n = len(ib)
    flat = ib.reshape(-1).view(np.int32)
    return flat[:n], flat[n:2 * n]


def build_paired(verts: np.ndarray, tris: np.ndarray, pb: np.ndarray, nbins: int = SAH_BINS,
                 trav_cost: float = SAH_TRAVERSAL_COST, grain: int | None = None,
                 stop: np.ndarray = NEVER_STOP):
    """The binary tree of the triangles ``verts[tris]`` of boxes ``pb`` (m, 6), built over
    their quads (module docstring): ``bounds, child, perm, sah`` as
    ``build_flat_boxes(packed=False)`` returns them (the root row 0; rows no child index
    reaches unset)."""
    m = len(tris)
    starts, ib, how, root_bounds = pair_items(verts, tris, pb, trav_cost)
    n_items = len(ib)
    # (the item tree's arrays with a row per split item after them: the opened items'
    # nodes)
    bounds, child, iperm, sah_i = build_flat_boxes(
        ib, 1, nbins, trav_cost, grain, stop, packed=False,
        spare=max(int(np.count_nonzero(how)), 1), cheap_max=CHEAP_ALL, root=root_bounds)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    region0 = max(n_items, 2)
    # (the item boxes ``ib`` (P, 6) are dead once the item tree is built -- reordered, not
    # returned: their memory, already touched, takes the item leaves' rows and nodes)
    rows, nodes = item_leaves(starts, iperm, how, *item_scratch(ib))
    # the root's box: the union of its two children's (no kernel called from Python here:
    # each would be one more for the F12's kernel pre-load, addon/kernels.py)
    root = bounds[0].astype(np.float64)
    lo, hi = np.minimum(root[0:3], root[6:9]), np.maximum(root[3:6], root[9:12])
    dx, dy, dz = (float(x) for x in hi - lo)
    root_area = max(dx * dy + dy * dz + dz * dx, 1e-300)
    perm = np.empty(m, np.int32)
    with numba.parallel_chunksize(1):  # (subtrees differ in size: threads take them in turn)
        dsah = open_items(pb, starts, how, iperm, rows, nodes, region0, trav_cost, root_area,
                          bounds, child, perm)
    return bounds, child, perm, float(sah_i + dsah)
