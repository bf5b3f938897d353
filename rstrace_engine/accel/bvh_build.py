"""Building the BVH of :mod:`.bvh`: binned SAH, in parallel, the same tree on any thread count.

A binary binned-SAH tree is built here (:func:`build_flat`); :mod:`.bvh_mesh` builds one per
mesh from its triangles and collapses it into the 4-wide traversal layout.

The binary build runs in two phases over one array of primitive boxes ``pb`` (n, 6)
(``lo x, lo y, lo z, hi x, hi y, hi z``; float64, or float32 for a mesh's:
:func:`.bvh_mesh.indexed_boxes`, whose node boxes are then float32 too -- every value is
read as float64 before any arithmetic, so float32 boxes give the tree float64 boxes of the
same values give), reordered in place together with ``perm`` so that every pass streams
through memory:

1. **Top** (:func:`split_top`): while a node holds more than ``grain`` primitives it is
   split one at a time, its SAH bins filled by all threads (:func:`_bin_chunks`: fixed
   chunks of :data:`BIN_CHUNK` primitives each fill their own bins, then summed in chunk
   order). Counts, minima and maxima do not depend on the order they are combined in, so
   the split is exactly the one a single thread finds.
2. **Subtrees** (:func:`build_subtrees`): the nodes left (at most ``grain`` primitives
   each) are built independently, one thread each, into their own stretch of the node
   arrays, then packed (:func:`pack_nodes`; a mesh BVH is collapsed to 4-wide straight
   from the unpacked arrays, ``build_flat_boxes(packed=False)``).

``grain`` depends only on the primitive count, so the tree (nodes, boxes, leaf order) is the
same whatever the thread count, and it is the tree one sequential build (``grain >= n``)
makes: the tests compare them.

Each node is split at the best of ``SAH_BINS`` bins per axis laid over its bounds -- its
centroid bounds at the root and under an object-median split, **its box** under an SAH
split: the children's boxes are unions of bins, so the partition gathers nothing (session
37, docs/bench-scale.md: up to a tenth less subtree CPU; SAH cost the same on Suzanne,
+0.4% on a 30k lumpy sphere; both phases do it, so the tree is the same on any grain;
a node whose bins over its box hold every centroid in one bin is binned again over its
centroid bounds, :func:`_to_centroid_bounds`) --
or at the object median when no bin boundary separates the centroids or below
:data:`DEPTH_CAP`. A node of at most :data:`.bvh_bins.CHEAP_MAX` primitives gets fewer bins
and only the axes along which its centroids spread at least half as far as along the
longest (:func:`.bvh_bins._node_bins`: about 13% less work in the subtrees for about 0.4%
more SAH cost); a large mesh's item build (:mod:`.bvh_cluster`) applies that rule to every
node (``cheap_max``: :data:`.bvh_bins.CHEAP_ALL`).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from ..cancel import Cancelled
from .bvh_bins import (
    CHEAP_MAX,
    _add_centroid,
    _best_split,
    _bin_range,
    _bin_split,
    _bins_box,
    _box_area,
    _centroid,
    _clear_bins,
    _empty6,
    _half_area,
    _node_bins,
    _partition,
    _swap,
    _two_split,
)

#: Most primitives in a leaf (the leaf code keeps the count in 3 bits).
MAX_LEAF = 4
#: SAH bins per axis.
SAH_BINS = 24
#: SAH cost of one node traversal relative to one primitive test.
SAH_TRAVERSAL_COST = 1.0
#: Past this depth the builder splits at the object median (bounds the traversal stack).
DEPTH_CAP = 60
#: Primitives per chunk of the parallel binning of the top levels.
BIN_CHUNK = 16384
#: The kernels every build runs (``module.function`` under rstrace_engine, for the
#: kernel-cache lists) ...
BUILD_KERNELS = ("accel.bvh_build.split_top", "accel.bvh_build.build_subtree",
                 "accel.bvh_mesh.collapse4",
                 "accel.bvh_mesh.direct_leaves", "accel.bvh_mesh.place_child",
                 "accel.bvh_mesh.place_tri")
#: ... and those only a mesh past :data:`PARALLEL_MIN` triangles (or of several subtrees)
#: runs, compiled by the first such build.
LARGE_BUILD_KERNELS = ("accel.bvh_build._bin_level", "accel.bvh_build._split_level",
                       "accel.bvh_build._bounds_chunks",
                       "accel.bvh_build.build_subtrees", "accel.bvh_build.pack_nodes",
                       "accel.bvh_mesh.indexed_boxes", "accel.bvh_cluster.pair_items",
                       "accel.bvh_cluster.item_leaves", "accel.bvh_cluster.open_items",
                       "accel.bvh_collapse.collapse_tasks",
                       "accel.bvh_collapse.collapse4_parallel")
#: Meshes of fewer triangles are built by one thread, without parallel regions (starting
#: one costs more than it saves there, and very much more when the cores are
#: oversubscribed).
PARALLEL_MIN = 1 << 16
#: Nodes of at most this many primitives are built as one subtree by one thread ...
SUBTREE_MIN = 4096
#: ... or of at most ``n // SUBTREE_SPLIT`` when that is more (a few hundred subtrees).
SUBTREE_SPLIT = 256


#: :func:`split_top`'s ``root`` when the caller has no bounds: found there.
_NO_ROOT = np.empty(0)
#: The stop flag of builds and queries nobody cancels (:mod:`rstrace_engine.cancel`).
NEVER_STOP = np.zeros(1, np.int32)


def subtree_grain(n: int) -> int:
    """Primitives of the largest node built by one thread (depends on ``n`` only; all of
    them below :data:`PARALLEL_MIN`)."""
    return n if n < PARALLEL_MIN else max(SUBTREE_MIN, n // SUBTREE_SPLIT)


@njit(cache=True, nogil=True, error_model="numpy")
def _range_bounds(pb, start, end, box, cb):
    """Box ``box`` and centroid bounds ``cb`` (6,) of primitives ``pb[start:end]``."""
    _empty6(box)
    _empty6(cb)
    for j in range(start, end):
        for q in range(3):
            box[q] = min(box[q], np.float64(pb[j, q]))
            box[3 + q] = max(box[3 + q], np.float64(pb[j, 3 + q]))
        _add_centroid(pb, j, cb)


@njit(cache=True, nogil=True, error_model="numpy")
def _to_centroid_bounds(pb, start, end, cmin, cmax, box, cb):
    """Set ``cmin``, ``cmax`` (3,) to the centroid bounds of ``pb[start:end]`` (``box``,
    ``cb`` (6,): scratch); returns whether they changed: the bounds were a box (below an
    SAH split), whose bins held every centroid in one bin (a long cylinder's full-length
    triangles along its axis), so the node is binned again over its centroids."""
    _range_bounds(pb, start, end, box, cb)
    changed = False
    for q in range(3):
        if cb[q] != cmin[q] or cb[3 + q] != cmax[q]:
            changed = True
        cmin[q] = cb[q]
        cmax[q] = cb[3 + q]
    return changed


@njit(cache=True, nogil=True, error_model="numpy")
def _median_split(pb, perm, start, end, cb, lbox, lcb, rbox, rcb):
    """Object median along the widest centroid axis: sorts ``start:end`` along it (stable)
    and returns the middle; fills both sides' boxes and centroid bounds."""
    k = 0
    for q in range(1, 3):
        if cb[3 + q] - cb[q] > cb[3 + k] - cb[k]:
            k = q
    count = end - start
    if count > 1:
        keys = np.empty(count)
        for j in range(count):
            keys[j] = 0.5 * (np.float64(pb[start + j, k]) + np.float64(pb[start + j, 3 + k]))
        order = np.argsort(keys, kind="mergesort")
        seg = perm[start:end].copy()
        segb = pb[start:end].copy()
        for j in range(count):
            perm[start + j] = seg[order[j]]
            pb[start + j] = segb[order[j]]
    mid = (start + end) // 2
    _range_bounds(pb, start, mid, lbox, lcb)
    _range_bounds(pb, mid, end, rbox, rcb)
    return mid


# ----------------------------------------------------------------------------- phase 1


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _bounds_chunks(pb, box, cb):
    """:func:`_range_bounds` of all of ``pb``, all threads: each chunk of
    :data:`BIN_CHUNK` primitives its own bounds, then combined in chunk order (minima and
    maxima: the same values one thread finds; session 38, the root's bounds were the
    top levels' first serial pass)."""
    n = pb.shape[0]
    nc = (n + BIN_CHUNK - 1) // BIN_CHUNK
    part = np.empty((nc, 12))
    for cc in prange(nc):
        c = np.int64(cc)  # (a prange index may be unsigned: keep index sums integer)
        _range_bounds(pb, c * BIN_CHUNK, min(n, (c + 1) * BIN_CHUNK), part[c, 0:6],
                      part[c, 6:12])
    _empty6(box)
    _empty6(cb)
    for c in range(nc):
        for q in range(3):
            box[q] = min(box[q], part[c, q])
            box[3 + q] = max(box[3 + q], part[c, 3 + q])
            cb[q] = min(cb[q], part[c, 6 + q])
            cb[3 + q] = max(cb[3 + q], part[c, 9 + q])


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _bin_level(pb, chunks, node_c, node_nb, nbins):
    """Bins of every chunk ``(node, start, end)`` of a level, all threads: per chunk
    ``(C, 3, nbins)`` counts and ``(C, 3, nbins, 6)`` boxes (node ``node``'s bins:
    ``node_nb[node]`` per axis over the bounds ``node_c[node]`` (6,), :func:`_node_bins`;
    the bins past them left empty)."""
    nc = chunks.shape[0]
    cn = np.zeros((nc, 3, nbins), np.int64)
    cbx = np.empty((nc, 3, nbins, 6))
    for c in prange(nc):
        e = chunks[c, 0]
        _clear_bins(cn[c], cbx[c], nbins)
        _bin_range(pb, chunks[c, 1], chunks[c, 2], node_c[e, 0:3], node_c[e, 3:6],
                   node_nb[e], cn[c], cbx[c])
    return cn, cbx


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _split_level(pb, perm, ranges, node_c, split, node_nb, out_box, out_c):
    """Split every node of a level, one thread each: node ``e`` (``ranges[e]``: start,
    end) at ``split[e]`` (axis, bin of ``node_nb[e]``; axis -1: the object median).
    Returns the middles;
    ``out_box``, ``out_c`` (E, 2, 6) get the children's boxes and the bounds their bins
    are laid over (an SAH split's boxes are already there, from the bins, and are its
    children's bin bounds too; a median split's: their centroid bounds)."""
    ne = ranges.shape[0]
    mid = np.empty(ne, np.int64)
    for e in prange(ne):
        start, end = ranges[e, 0], ranges[e, 1]
        k = split[e, 0]
        if k >= 0:
            mid[e] = _partition(pb, perm, start, end, k, node_c[e, k],
                                node_c[e, 3 + k] - node_c[e, k], node_nb[e], split[e, 1])
            for s in range(2):  # (the bins of each side: over its box)
                for q in range(6):
                    out_c[e, s, q] = out_box[e, s, q]
        else:
            mid[e] = _median_split(pb, perm, start, end, node_c[e], out_box[e, 0],
                                   out_c[e, 0], out_box[e, 1], out_c[e, 1])
    return mid


@njit(cache=True, nogil=True, error_model="numpy")
def split_top(pb, perm, grain, nbins, trav_cost, bounds, child, stop, cheap_max, root):
    """Phase 1: split nodes of more than ``grain`` primitives, a level at a time (numbered
    from 0 in ``bounds`` (., 12) / ``child`` (., 2), breadth first). ``stop`` (1,) int32
    is read before each level: once non-zero the phase returns unfinished. ``root``
    (12,): the primitives' box and centroid bounds, as :func:`_range_bounds` finds them
    (the caller's, from a pass it makes anyway: :func:`.bvh_cluster.pair_items`), or
    (0,): found here.

    Returns ``(n_top, tasks (T, 5) int64, task_box (T, 12), sah, root_area)``: the nodes
    left for :func:`build_subtrees`, each ``parent, slot, start, end, depth`` with its box
    and centroid bounds (a root task has parent -1: the whole tree is one subtree).
    """
    n = pb.shape[0]
    box = np.empty(6)
    cb = np.empty(6)
    if root.shape[0] == 12:
        box[:] = root[0:6]
        cb[:] = root[6:12]
    elif n > grain:  # (the levels below run parallel regions too; a smaller tree none)
        _bounds_chunks(pb, box, cb)
    else:
        _range_bounds(pb, 0, n, box, cb)
    root_area = max(_half_area(box[0], box[1], box[2], box[3], box[4], box[5]), 1e-300)
    # a level's nodes are disjoint: < n / grain of them are split, and 2 children each
    cap = 2 * (n // max(grain, 1)) + 2
    lv_int = np.empty((cap, 5), np.int64)  # parent, slot, start, end, depth
    lv_box = np.empty((cap, 12))  # box, centroid bounds
    nx_int = np.empty((cap, 5), np.int64)
    nx_box = np.empty((cap, 12))
    tasks = np.empty((n // max(grain, 1) * (DEPTH_CAP + 33) + 2, 5), np.int64)
    task_box = np.empty((tasks.shape[0], 12))
    lv_int[0, 0], lv_int[0, 1], lv_int[0, 2], lv_int[0, 3], lv_int[0, 4] = -1, 0, 0, n, 0
    lv_box[0, 0:6] = box
    lv_box[0, 6:12] = cb
    n_lv, nt, nn = 1, 0, 0
    sah = 0.0
    right_a = np.empty(nbins)
    right_n = np.empty(nbins, np.int64)
    bin_n = np.zeros((3, nbins), np.int64)
    bin_b = np.empty((3, nbins, 6))
    while n_lv > 0 and stop[0] == 0:
        # the nodes small enough are subtrees; the others are split at this level
        ne = 0
        n_chunks = 0
        for e in range(n_lv):
            count = lv_int[e, 3] - lv_int[e, 2]
            if count <= grain:
                tasks[nt] = lv_int[e]
                task_box[nt] = lv_box[e]
                nt += 1
            else:
                lv_int[ne] = lv_int[e]
                lv_box[ne] = lv_box[e]
                ne += 1
                n_chunks += (count + BIN_CHUNK - 1) // BIN_CHUNK
        if ne == 0:
            break
        node_c = np.ascontiguousarray(lv_box[:ne, 6:12])
        node_m = np.empty((ne, 6))  # the bounds each node's bins are laid over
        node_nb = np.empty(ne, np.int64)
        for e in range(ne):
            node_nb[e] = _node_bins(lv_int[e, 3] - lv_int[e, 2], nbins, node_c[e, 0:3],
                                    node_c[e, 3:6], node_m[e, 0:3], node_m[e, 3:6],
                                    cheap_max)
        chunks = np.empty((n_chunks, 3), np.int64)
        c = 0
        for e in range(ne):
            if lv_int[e, 4] >= DEPTH_CAP:
                continue
            for s in range(lv_int[e, 2], lv_int[e, 3], BIN_CHUNK):
                chunks[c, 0], chunks[c, 1], chunks[c, 2] = e, s, min(s + BIN_CHUNK, lv_int[e, 3])
                c += 1
        cn, cbx = _bin_level(pb, chunks[:c], node_m, node_nb, nbins)
        # each node's bins: its chunks' summed in chunk order; its best split
        split = np.full((ne, 2), -1, np.int64)
        out_box = np.empty((ne, 2, 6))
        out_c = np.empty((ne, 2, 6))
        c0 = 0
        for e in range(ne):
            if lv_int[e, 4] >= DEPTH_CAP:
                continue
            c1 = c0
            while c1 < c and chunks[c1, 0] == e:
                c1 += 1
            _clear_bins(bin_n, bin_b, nbins)
            for j in range(c0, c1):
                for k in range(3):
                    for b in range(nbins):
                        bin_n[k, b] += cn[j, k, b]
                        for q in range(3):
                            bin_b[k, b, q] = min(bin_b[k, b, q], cbx[j, k, b, q])
                            bin_b[k, b, 3 + q] = max(bin_b[k, b, 3 + q], cbx[j, k, b, 3 + q])
            c0 = c1
            _, axis, sbin = _best_split(node_m[e, 0:3], node_m[e, 3:6], node_nb[e], bin_n,
                                        bin_b, right_a, right_n)
            start, end = lv_int[e, 2], lv_int[e, 3]
            if axis < 0 and _to_centroid_bounds(pb, start, end, node_c[e, 0:3],
                                                node_c[e, 3:6], box, cb):
                # (as build_subtree: the same bins, one thread)
                node_nb[e], _, axis, sbin = _bin_split(
                    pb, start, end, nbins, node_c[e, 0:3], node_c[e, 3:6], node_m[e, 0:3],
                    node_m[e, 3:6], cheap_max, bin_n, bin_b, right_a, right_n)
            if axis >= 0:
                split[e, 0], split[e, 1] = axis, sbin
                _bins_box(bin_b, axis, 0, sbin + 1, out_box[e, 0])
                _bins_box(bin_b, axis, sbin + 1, node_nb[e], out_box[e, 1])
        ranges = np.ascontiguousarray(lv_int[:ne, 2:4])
        mid = _split_level(pb, perm, ranges, node_c, split, node_nb, out_box, out_c)
        n_nx = 0
        for e in range(ne):
            parent, slot, start, end, depth = (lv_int[e, 0], lv_int[e, 1], lv_int[e, 2],
                                               lv_int[e, 3], lv_int[e, 4])
            node = nn
            nn += 1
            if parent >= 0:
                box[:] = lv_box[e, 0:6]
                for q in range(6):
                    bounds[parent, 6 * slot + q] = box[q]
                child[parent, slot] = node
                sah += trav_cost * _half_area(box[0], box[1], box[2], box[3], box[4],
                                              box[5]) / root_area
            else:
                sah += trav_cost
            for s in range(2):
                nx_int[n_nx, 0], nx_int[n_nx, 1], nx_int[n_nx, 4] = node, s, depth + 1
                nx_int[n_nx, 2] = start if s == 0 else mid[e]
                nx_int[n_nx, 3] = mid[e] if s == 0 else end
                nx_box[n_nx, 0:6] = out_box[e, s]
                nx_box[n_nx, 6:12] = out_c[e, s]
                n_nx += 1
        lv_int, nx_int = nx_int, lv_int
        lv_box, nx_box = nx_box, lv_box
        n_lv = n_nx
    return nn, tasks[:nt].copy(), task_box[:nt].copy(), sah, root_area


# ----------------------------------------------------------------------------- phase 2


@njit(cache=True, nogil=True, error_model="numpy")
def build_subtree(pb, perm, task, tbox, node0, max_leaf, nbins, trav_cost, root_area,
                  bounds, child, cheap_max):
    """One subtree, depth first, its inner nodes numbered from ``node0`` (a root task's
    root is node ``node0`` itself). Returns ``(nodes used, sah)``."""
    t_int = np.empty((2 * (DEPTH_CAP + 40), 5), np.int64)
    t_box = np.empty((2 * (DEPTH_CAP + 40), 12))
    bin_n = np.zeros((3, nbins), np.int64)
    bin_b = np.empty((3, nbins, 6))
    right_a = np.empty(nbins)
    right_n = np.empty(nbins, np.int64)
    box = np.empty(6)
    cb = np.empty(6)
    lbox = np.empty(6)
    rbox = np.empty(6)
    lcb = np.empty(6)
    rcb = np.empty(6)
    cmin = np.empty(3)
    cmax = np.empty(3)
    bmin = np.empty(3)
    bmax = np.empty(3)
    sah = 0.0
    nn = 0
    sp = 0
    for q in range(5):
        t_int[0, q] = task[q]
    for q in range(12):
        t_box[0, q] = tbox[q]
    while sp >= 0:
        parent, slot, start, end, depth = (t_int[sp, 0], t_int[sp, 1], t_int[sp, 2],
                                           t_int[sp, 3], t_int[sp, 4])
        for q in range(3):
            box[q] = t_box[sp, q]
            box[3 + q] = t_box[sp, 3 + q]
            cmin[q] = t_box[sp, 6 + q]
            cmax[q] = t_box[sp, 9 + q]
        sp -= 1
        count = end - start
        area = _half_area(box[0], box[1], box[2], box[3], box[4], box[5])
        best_cost, best_axis, best_bin = np.inf, -1, -1
        nb = 2
        if count == 2 and depth < DEPTH_CAP:
            best_cost, best_axis, best_bin = _two_split(pb, start, cmin, cmax)
        elif count > 1 and depth < DEPTH_CAP:
            nb, best_cost, best_axis, best_bin = _bin_split(
                pb, start, end, nbins, cmin, cmax, bmin, bmax, cheap_max, bin_n, bin_b,
                right_a, right_n)
            if best_axis < 0 and _to_centroid_bounds(pb, start, end, cmin, cmax, lbox, cb):
                nb, best_cost, best_axis, best_bin = _bin_split(
                    pb, start, end, nbins, cmin, cmax, bmin, bmax, cheap_max, bin_n, bin_b,
                    right_a, right_n)
        split_cost = trav_cost + best_cost / max(area, 1e-300)
        make_leaf = count <= max_leaf and (count == 1 or count <= split_cost)
        if make_leaf and parent >= 0:
            for q in range(6):
                bounds[parent, 6 * slot + q] = box[q]
            child[parent, slot] = ~((start << 3) | count)
            sah += count * area / root_area
            continue
        if parent >= 0:
            node = node0 + nn
            nn += 1
            for q in range(6):
                bounds[parent, 6 * slot + q] = box[q]
            child[parent, slot] = node
            sah += trav_cost * area / root_area
        else:
            node = node0
            nn += 1
            sah += trav_cost
            if count == 1 or make_leaf:  # the whole tree is one leaf: child 1 is empty
                for q in range(6):
                    bounds[node, q] = box[q]
                child[node, 0] = ~((start << 3) | count)
                for q in range(3):
                    bounds[node, 6 + q] = np.inf
                    bounds[node, 9 + q] = -np.inf
                child[node, 1] = ~((start << 3) | 1)
                sah += count * area / root_area
                continue
        if best_axis >= 0 and not make_leaf and count == 2:
            # two leaves of one, the lower centroid first (what the bins' partition does)
            if _centroid(pb, start + 1, best_axis) < _centroid(pb, start, best_axis):
                _swap(pb, perm, start, start + 1)
            for s in range(2):
                j = start + s
                for q in range(6):
                    bounds[node, 6 * s + q] = pb[j, q]
                child[node, s] = ~((j << 3) | 1)
                sah += _box_area(pb, j) / root_area
            continue
        if best_axis >= 0 and not make_leaf:
            mid = _partition(pb, perm, start, end, best_axis, cmin[best_axis],
                             cmax[best_axis] - cmin[best_axis], nb, best_bin)
            _bins_box(bin_b, best_axis, 0, best_bin + 1, lbox)
            _bins_box(bin_b, best_axis, best_bin + 1, nb, rbox)
            for q in range(6):  # (the bins of each side: over its box)
                lcb[q] = lbox[q]
                rcb[q] = rbox[q]
        else:
            # no usable SAH split (coincident centroids, depth cap, or a root that is one
            # leaf)
            for q in range(3):
                cb[q] = cmin[q]
                cb[3 + q] = cmax[q]
            mid = _median_split(pb, perm, start, end, cb, lbox, lcb, rbox, rcb)
        # push right then left so the left child is processed (and numbered) first
        sp += 1
        t_int[sp, 0], t_int[sp, 1], t_int[sp, 2], t_int[sp, 3], t_int[sp, 4] = (
            node, 1, mid, end, depth + 1)
        for q in range(6):
            t_box[sp, q] = rbox[q]
            t_box[sp, 6 + q] = rcb[q]
        sp += 1
        t_int[sp, 0], t_int[sp, 1], t_int[sp, 2], t_int[sp, 3], t_int[sp, 4] = (
            node, 0, start, mid, depth + 1)
        for q in range(6):
            t_box[sp, q] = lbox[q]
            t_box[sp, 6 + q] = lcb[q]
    return nn, sah


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def build_subtrees(pb, perm, tasks, task_box, region, max_leaf, nbins, trav_cost, root_area,
                   bounds, child, stop, cheap_max):
    """Phase 2: task ``t`` (:func:`split_top`) built into nodes from ``region[t]``, one
    thread per task. Returns the nodes each used (T,) and their SAH (T,). ``stop`` (1,)
    int32 is read before each task: once non-zero the others are skipped."""
    nt = tasks.shape[0]
    used = np.zeros(nt, np.int64)
    sah = np.zeros(nt)
    for t in prange(nt):
        if stop[0] != 0:
            continue
        used[t], sah[t] = build_subtree(pb, perm, tasks[t], task_box[t], region[t],
                                         max_leaf, nbins, trav_cost, root_area, bounds, child,
                                         cheap_max)
    return used, sah


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def pack_nodes(bounds, child, n_top, region, used):
    """The nodes in use, packed: top nodes, then each task's, inner indices renumbered."""
    nt = region.shape[0]
    start = np.empty(nt + 1, np.int64)
    start[0] = n_top
    for t in range(nt):
        start[t + 1] = start[t] + used[t]
    total = start[nt]
    ob = np.empty((max(total, 1), 12), bounds.dtype)
    oc = np.empty((max(total, 1), 2), np.int32)
    for ii in prange(total):
        i = np.int64(ii)  # (a prange index may be unsigned: keep index sums integer)
        if i < n_top:
            src = i
        else:
            t = np.searchsorted(start, i, side="right") - 1
            src = region[t] + (i - start[t])
        ob[i] = bounds[src]
        for s in range(2):
            c = child[src, s]
            if c >= n_top:
                t = np.searchsorted(region, c, side="right") - 1
                c = c - region[t] + start[t]
            oc[i, s] = c
    return ob[:total], oc[:total]


def build_flat(lo, hi, max_leaf: int = MAX_LEAF, nbins: int = SAH_BINS,
               trav_cost: float = SAH_TRAVERSAL_COST, grain: int | None = None,
               stop: np.ndarray = NEVER_STOP):
    """Binned-SAH BVH over primitive boxes, in parallel (see the module docstring).

    lo, hi : (n, 3) float64 primitive bounds (n >= 1); ``grain``: the largest node built by
    one thread (default :func:`subtree_grain`; ``>= n``: one sequential build, the same
    tree). Returns ``bounds (N, 12) float64, child (N, 2) int32, perm (n,) int32,
    sah_cost`` (the SAH estimate of the whole tree in units of one primitive test); node 0
    is the root, whose own box is implicit. Raises :class:`~rstrace_engine.cancel.Cancelled`
    once ``stop`` (a (1,) int32 flag, read between levels and subtrees) is set.
    """
    pb = np.empty((len(lo), 6))
    pb[:, :3] = lo
    pb[:, 3:] = hi
    return build_flat_boxes(pb, max_leaf, nbins, trav_cost, grain, stop)


def build_flat_boxes(pb, max_leaf: int = MAX_LEAF, nbins: int = SAH_BINS,
                     trav_cost: float = SAH_TRAVERSAL_COST, grain: int | None = None,
                     stop: np.ndarray = NEVER_STOP, packed: bool = True, spare: int = 0,
                     cheap_max: int = CHEAP_MAX, root: np.ndarray | None = None):
    """:func:`build_flat` over ``pb`` (n, 6) float64 or float32 (lo, hi; the node boxes
    take its dtype), which it reorders (leaf order). ``packed=False``: the node arrays as
    built, unpacked (``max(n, 2)`` rows, the root row 0, the rows no child index reaches
    unset: for a walk from the root such as
    :func:`.bvh_mesh.collapse4`, which then needs no :func:`pack_nodes` copy), with
    ``spare`` rows more after them (for the caller's nodes: :mod:`.bvh_cluster`);
    ``cheap_max``: the largest node split by the cheap rule (:func:`.bvh_bins._node_bins`);
    ``root``: ``pb``'s box and centroid bounds (12,) if the caller has them
    (:func:`split_top`)."""
    n = pb.shape[0]
    grain = subtree_grain(n) if grain is None else max(int(grain), 8)
    perm = np.arange(n, dtype=np.int32)
    cap = max(n, 2) + (0 if packed else int(spare))
    bounds = np.empty((cap, 12), pb.dtype)
    child = np.empty((cap, 2), np.int32)
    n_top, tasks, task_box, sah, root_area = split_top(pb, perm, grain, nbins, trav_cost,
                                                       bounds, child, stop, cheap_max,
                                                       _NO_ROOT if root is None else root)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    # task t uses at most (its primitives - 1) nodes (a root task of one primitive: one);
    # with the top nodes that is at most n - 1 in all
    size = tasks[:, 3] - tasks[:, 2] - 1
    size[tasks[:, 0] < 0] = max(n - 1, 1)
    region = n_top + np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.int64)
    if len(tasks) == 1:  # one subtree (a small mesh): no parallel region to start
        used, task_sah = build_subtree(pb, perm, tasks[0], task_box[0], region[0], max_leaf,
                                        nbins, trav_cost, root_area, bounds, child,
                                        cheap_max)
        if not packed:
            return bounds, child, perm, float(sah + task_sah)
        return bounds[:n_top + used].copy(), child[:n_top + used].copy(), perm, float(
            sah + task_sah)
    with numba.parallel_chunksize(1):  # subtrees differ in cost: threads take them in turn
        used, task_sah = build_subtrees(pb, perm, tasks, task_box, region, max_leaf, nbins,
                                        trav_cost, root_area, bounds, child, stop, cheap_max)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    if not packed:
        return bounds, child, perm, float(sah + task_sah.sum())
    b, c = pack_nodes(bounds, child, n_top, region, used)
    return b, c, perm, float(sah + task_sah.sum())
