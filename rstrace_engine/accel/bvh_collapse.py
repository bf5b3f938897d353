"""The collapse of a mesh's binary BVH into the 4-wide tree the traversal reads (split from
:mod:`.bvh_mesh` in session 40; its names are still :mod:`.bvh_mesh`'s too).

:func:`collapse4` makes it on one thread, its boxes widened outward by an ulp (as
:func:`pad_outward` widens them) and stored in float32 rounded outward
(:func:`_put_outward`). :func:`collapse4_parallel` makes the same tree, walked from the root
(the same boxes bit for bit, lanes and leaves), on every thread (issue 26), in other rows:
the 4-wide nodes are opened breadth first from the root until enough subtrees are pending
(:func:`collapse_tasks`); each is given a room of rows (:func:`_room`, from its inner binary
nodes: :func:`_inner_count`), the nodes above them made on one thread in the first rows,
then the subtrees on every thread; unused rows are empty nodes no child reaches.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .bvh_bins import _half_area
from .bvh_build import DEPTH_CAP, PARALLEL_MIN


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _padded(cbits, j, pad):
    """Row ``j`` of the (4, 6) float64 boxes whose int64 view is ``cbits``, widened by one
    ulp on every side when ``pad`` (what :func:`pad_outward` does to a binary box)."""
    if pad:
        for q in range(3):
            cbits[6 * j + q] = _step_down(cbits[6 * j + q])
            cbits[6 * j + 3 + q] = _step_up(cbits[6 * j + 3 + q])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lanes(b2, c2, bn, cb, cc, cbits, pad):
    """The (up to) four lanes of the 4-wide node made of binary node ``bn``: its two
    children, the inner child of largest surface area opened until there are four. Fills
    ``cb`` (4, 6) float64 boxes (padded as :func:`collapse4` reads them: ``cbits`` is its
    int64 view) and ``cc`` (4,) binary child codes; returns the number of lanes used."""
    cnt = 0
    for j in range(2):
        if b2[bn, 6 * j] <= b2[bn, 6 * j + 3]:  # drop the empty child of a 1-leaf root
            for q in range(6):
                cb[cnt, q] = np.float64(b2[bn, 6 * j + q])
            _padded(cbits, cnt, pad)
            cc[cnt] = c2[bn, j]
            cnt += 1
    while cnt < 4:
        pick = -1
        best = -1.0
        for j in range(cnt):
            if cc[j] >= 0:
                area = _half_area(cb[j, 0], cb[j, 1], cb[j, 2], cb[j, 3], cb[j, 4], cb[j, 5])
                if area > best:
                    best, pick = area, j
        if pick < 0:
            break
        inner = cc[pick]
        for q in range(6):
            cb[pick, q] = np.float64(b2[inner, q])
            cb[cnt, q] = np.float64(b2[inner, 6 + q])
        _padded(cbits, pick, pad)
        cc[pick] = c2[inner, 0]
        _padded(cbits, cnt, pad)
        cc[cnt] = c2[inner, 1]
        cnt += 1
    return cnt


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _put_node(b4, bits, c4, k, cb, cc, cnt):
    """Row ``k`` of the 4-wide tree: the lanes :func:`_lanes` made (boxes rounded outward
    where ``b4`` is float32); an unused lane gets an inverted box and the empty leaf."""
    for j in range(4):
        if j < cnt:
            for q in range(6):
                _put_outward(b4, bits, k, 4 * q + j, cb[j, q])
            c4[k, j] = cc[j]
        else:
            for q in range(3):
                b4[k, 4 * q + j] = np.inf
                b4[k, 12 + 4 * q + j] = -np.inf
            c4[k, j] = -1  # ~0: a leaf of no triangles


#: the depth-first stack of a collapse: a 4-wide node opens up to 3 binary nodes and
#: pushes its (<= 4) inner children, so the stack holds at most 3 entries per binary level
_TODO_ROWS = 3 * (DEPTH_CAP + 40) + 4


@njit(cache=True, nogil=True, error_model="numpy")
def collapse4(b2, c2, b4, pad):
    """Binary BVH (child boxes (N, 12) float64, children (N, 2) int32) -> 4-wide BVH.

    Each 4-wide node takes its binary node's two children and repeatedly opens the inner
    child of largest surface area until it has four. Writes ``bounds`` into ``b4`` (N, 24)
    (SoA over the four lanes: lo x, lo y, lo z, hi x, hi y, hi z, four values each),
    float64 as they are, or float32 rounded *outward* (:func:`_put_outward`: every float32
    box contains its float64 one), and returns it with ``child (N, 4) int32`` and the
    number ``M`` of nodes (rows) used; an unused lane has an inverted box and the empty
    leaf ``~0``. The nodes are numbered depth first, whatever the binary numbering, from
    binary node 0 (rows no child reaches are never read: the builder's unpacked arrays
    serve). ``pad``: every binary box is read widened as :func:`pad_outward` widens it
    (the same bits, without a pass over ``b2`` or a change to it). One thread; the same
    tree on all threads: :func:`.bvh_collapse.collapse4_parallel`.
    """
    c4 = np.empty((c2.shape[0], 4), np.int32)
    no = np.empty(0, np.int64)
    m = _collapse_from(b2, c2, b4, c4, 0, 0, pad, no, no, no, c2.shape[0] + 1)
    return b4, c4, m


@njit(cache=True, nogil=True, error_model="numpy")
def _collapse_from(b2, c2, b4, c4, root, k0, pad, task_bn, task_size, task_row, limit,
                   task_k0=0):
    """:func:`collapse4`'s depth-first walk from binary node ``root``, numbered from row
    ``k0``; returns the row after the last, or -1 (rows written up to ``limit`` only)
    when it would need row ``limit``. A binary node listed in ``task_bn`` (sorted) is not
    opened: ``task_size`` rows are reserved for its subtree, in turn from row ``task_k0``
    (``task_row``, set here; the row after the last reserved is then returned), and its
    parent's lane points at them, for the threads of
    :func:`.bvh_collapse.collapse4_parallel`."""
    todo = np.empty((_TODO_ROWS, 3), np.int64)  # binary node, parent, lane
    bits = b4.reshape(-1).view(np.int32)  # (float32 b4: the bits of each bound)
    cb = np.empty((4, 6))
    cc = np.empty(4, np.int64)
    cbits = cb.reshape(-1).view(np.int64)
    todo[0, 0], todo[0, 1], todo[0, 2] = root, -1, 0
    sp = 1
    m = k0
    mt = task_k0
    while sp > 0:
        sp -= 1
        bn, parent, lane = todo[sp, 0], todo[sp, 1], todo[sp, 2]
        if len(task_bn):
            t = np.searchsorted(task_bn, bn)
            if t < len(task_bn) and task_bn[t] == bn:
                task_row[t] = mt
                if parent >= 0:
                    c4[parent, lane] = mt
                mt += task_size[t]
                continue
        k = m
        if k >= limit:
            return -1
        if parent >= 0:
            c4[parent, lane] = k
        m += 1
        cnt = _lanes(b2, c2, bn, cb, cc, cbits, pad)
        _put_node(b4, bits, c4, k, cb, cc, cnt)
        for j in range(cnt - 1, -1, -1):  # lane 0 is numbered first
            if cc[j] >= 0:
                todo[sp, 0], todo[sp, 1], todo[sp, 2] = cc[j], k, j
                sp += 1
    return mt if len(task_bn) else m


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _put_outward(b4, bits, k, col, x, n_lo=12):
    """``b4[k, col] = x`` (a lo bound in columns 0..11, a hi one in 12..23), rounded
    outward where ``b4`` is float32: a lo that the cast (to nearest) moved up steps one
    float32 down, a hi moved down steps up (``np.nextafter`` toward -inf / +inf, on the
    bits ``bits``, ``b4``'s int32 view). A float64 ``b4`` takes ``x`` exactly (the
    branches never run). Infinite bounds stay infinite; a finite bound beyond float32's
    range becomes the largest finite float32 on the inner side, an infinity outside."""
    b4[k, col] = x
    f = b4[k, col]
    i = b4.shape[1] * k + col
    if col < n_lo:
        if f > x:
            bits[i] = _step_down32(bits[i])
    elif f < x:
        bits[i] = _step_up32(bits[i])


@njit(cache=True, nogil=True, error_model="numpy")
def pad_outward(b64):
    """Child boxes (N, 12) float64 widened by one ulp on every side, in place (returned).

    A ray with a zero direction component has a huge finite reciprocal (``bvh._inv_dir``);
    if its origin lay exactly on a box face, ``(face - o) * inv`` would be 0 instead of
    +-inf and the slab would wrongly shrink to ``t = 0``. With the faces one ulp outside the
    geometry, an origin on a face is outside the geometry, so culling it is right. The
    inverted (+inf, -inf) box of an empty child stays as is. (``np.nextafter`` toward -inf
    / +inf, done on the bits: a finite float's neighbour is its bit pattern +-1.)
    """
    bits = b64.reshape(-1).view(np.int64)
    for i in range(b64.shape[0]):
        for s in range(2):
            for q in range(3):
                j = 12 * i + 6 * s + q
                bits[j] = _step_down(bits[j])
                bits[j + 3] = _step_up(bits[j + 3])
    return b64


#: bit patterns of IEEE doubles
_SIGN = np.int64(-0x8000000000000000)
_EXP_ALL = np.int64(0x7FF0000000000000)


@njit(cache=True, nogil=True, inline="always")
def _step_down(x):
    """The bits of ``nextafter(f, -inf)`` for the double ``f`` of bits ``x`` (inf and NaN
    as they are)."""
    if (x & _EXP_ALL) == _EXP_ALL:  # inf, nan
        return x
    if x == 0 or x == _SIGN:  # +-0 -> the smallest negative subnormal
        return _SIGN | 1
    return x - 1 if x > 0 else x + 1


@njit(cache=True, nogil=True, inline="always")
def _step_up(x):
    """The bits of ``nextafter(f, +inf)`` (inf and NaN as they are)."""
    if (x & _EXP_ALL) == _EXP_ALL:
        return x
    if x == 0 or x == _SIGN:
        return np.int64(1)
    return x + 1 if x > 0 else x - 1


_SIGN32 = np.int32(-0x80000000)


@njit(cache=True, nogil=True, inline="always")
def _step_down32(x):
    """The bits of ``nextafter(f, -inf)`` for the float32 ``f`` of bits ``x``, where ``f``
    is above some double (so not -inf or NaN; +inf steps to the largest finite)."""
    if x == 0 or x == _SIGN32:
        return _SIGN32 | np.int32(1)
    return x - np.int32(1) if x > 0 else x + np.int32(1)


@njit(cache=True, nogil=True, inline="always")
def _step_up32(x):
    """The bits of ``nextafter(f, +inf)``, where ``f`` is below some double."""
    if x == 0 or x == _SIGN32:
        return np.int32(1)
    return x + np.int32(1) if x > 0 else x - np.int32(1)


#: binary nodes from which :func:`.bvh_mesh.flatten` collapses on all threads (a mesh of
#: :data:`.bvh_build.PARALLEL_MIN` triangles has about half as many: two a quad), and into
#: how many subtrees (:func:`collapse_tasks`: enough that two threads end together, few
#: enough that the nodes above them, made on one thread, stay a few hundred)
COLLAPSE_PARALLEL_MIN = PARALLEL_MIN // 2
COLLAPSE_TASKS = 128


@njit(cache=True, nogil=True, error_model="numpy")
def collapse_tasks(b2, c2, pad, want):
    """The binary roots of (about) ``want`` disjoint 4-wide subtrees that, with the nodes
    above them, make :func:`collapse4`'s tree: the 4-wide nodes opened breadth first from
    the root until ``want`` are pending (sorted; fewer when the tree has fewer), and the
    number of nodes above them."""
    q = np.empty(8 * want + 8, np.int64)
    cb = np.empty((4, 6))
    cc = np.empty(4, np.int64)
    cbits = cb.reshape(-1).view(np.int64)
    q[0] = 0
    head, tail = 0, 1
    while head < tail and tail - head < want and tail + 4 <= len(q):
        cnt = _lanes(b2, c2, q[head], cb, cc, cbits, pad)
        head += 1
        for j in range(cnt):
            if cc[j] >= 0:
                q[tail] = cc[j]
                tail += 1
    return np.sort(q[head:tail]), head


@njit(cache=True, nogil=True, error_model="numpy")
def _inner_count(c2, root):
    """The number of inner binary nodes in ``root``'s subtree: at least the number of
    4-wide nodes :func:`collapse4` makes of it (each opens one or more), read off the
    child codes alone (8 bytes a node, not the boxes' 96)."""
    stack = np.empty(_TODO_ROWS, np.int64)
    stack[0] = root
    sp = 1
    n = 0
    while sp > 0:
        sp -= 1
        bn = stack[sp]
        n += 1
        for j in range(2):
            if c2[bn, j] >= 0:
                stack[sp] = c2[bn, j]
                sp += 1
    return n


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def collapse4_parallel(b2, c2, b4, pad, task_bn, n_top):
    """:func:`collapse4` on all threads: the ``n_top`` nodes above the subtrees under
    ``task_bn`` (:func:`collapse_tasks`) are made on one thread (rows 0 to ``n_top``: a
    few pages), each subtree given :func:`_room` rows after them; then the subtrees, one
    task each (run under ``numba.parallel_chunksize(1)``: they differ in size). A
    subtree that outgrew its room is made again after the others' rooms, in a room as
    large as its inner binary nodes (always enough), again in parallel. The same tree
    (boxes, lanes, leaves), in other rows: the nodes above the subtrees first, each
    subtree's in :func:`collapse4`'s order; the rooms' unused rows no child reaches,
    each an empty node (inverted boxes, empty leaves; written, so that the arrays are
    the same bytes on every run). Returns ``M = -1`` when the rows would not fit ``b4``
    (then nothing made is of use: :func:`.bvh_mesh.flatten` runs :func:`collapse4`)."""
    n = len(task_bn)
    inner = np.empty(n, np.int64)
    room = np.empty(n, np.int64)
    for t in prange(n):
        inner[t] = _inner_count(c2, task_bn[t])
        # (the root's subtree has no parent row to point at a second room)
        room[t] = _room(inner[t]) if n_top > 0 else inner[t]
    c4 = np.empty((c2.shape[0], 4), np.int32)
    row = np.empty(n, np.int64)
    end = _collapse_from(b2, c2, b4, c4, 0, 0, pad, task_bn, room, row, n_top, n_top)
    if end < 0:  # (not collapse_tasks' n_top)
        return b4, c4, -1
    got = _subtrees(b2, c2, b4, c4, pad, task_bn, row, room)
    redo = np.flatnonzero(got < 0)
    if len(redo) == 0:
        return b4, c4, end
    row2 = np.empty(len(redo), np.int64)
    for i in range(len(redo)):  # a second room each, after the others', and its parent
        t = redo[i]  # lane pointed at it
        row2[i] = end
        end += inner[t]
        for k in range(n_top):
            for j in range(4):
                if c4[k, j] == row[t]:
                    c4[k, j] = end - inner[t]
    if end > c4.shape[0]:
        return b4, c4, -1
    _subtrees(b2, c2, b4, c4, pad, task_bn[redo], row2, inner[redo])
    return b4, c4, end


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _subtrees(b2, c2, b4, c4, pad, task_bn, row, room):
    """:func:`collapse4_parallel`'s subtrees, each in its room (from ``row``), its unused
    rows (all of them when it did not fit) made empty nodes; the rows after each made,
    -1 where it did not fit."""
    n = len(task_bn)
    got = np.empty(n, np.int64)
    no = np.empty(0, np.int64)
    for t in prange(n):
        stop = row[t] + room[t]
        got[t] = _collapse_from(b2, c2, b4, c4, task_bn[t], row[t], pad, no, no, no, stop)
        for k in range(got[t] if got[t] >= 0 else row[t], stop):
            for j in range(4):
                for q in range(3):
                    b4[k, 4 * q + j] = np.inf
                    b4[k, 12 + 4 * q + j] = -np.inf
                c4[k, j] = -1
    return got


@njit(cache=True, nogil=True, inline="always")
def _room(inner):
    """Rows first given to a subtree of ``inner`` inner binary nodes: each 4-wide node
    opens one to three of them, about two in a mesh's tree (4M triangles, session 40:
    2.02 in the median subtree, 1.76 to 2.26), so 0.56 of them (the few subtrees
    past it are made again: :func:`collapse4_parallel`)."""
    return min(inner, inner // 2 + inner // 16 + 16)
