"""Mesh BVHs: a mesh's triangles to the 4-wide layout the traversal reads (:mod:`.bvh`).

The binary tree (:func:`.bvh_build.build_flat`) is collapsed into 4-wide nodes
(:func:`collapse4`) whose boxes are widened outward by an ulp (:func:`pad_outward`) and
stored in float32, rounded outward; the leaves name triangles (global triangle ids in leaf
order), whose vertex indices and vertices the traversal reads from the scene's own
arrays. Meshes of fewer than :data:`.bvh_build.PARALLEL_MIN` triangles go through numpy and
one thread, with no parallel region to start; larger ones through parallel kernels that
read the triangles through their vertex indices (:func:`build_mesh_bvh_indexed`: no copy
of the mesh's triangles in mesh order) and build the tree over the mesh's quads, two
triangles that share an edge one item (:mod:`.bvh_cluster`).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..cancel import Cancelled
from .bvh_bins import _half_area
from .bvh_build import (
    DEPTH_CAP,
    MAX_LEAF,
    NEVER_STOP,
    PARALLEL_MIN,
    build_flat,
    build_flat_boxes,
    subtree_grain,
)
from .bvh_cluster import build_paired
from .content_hash import ContentHash


class FlatBVH(NamedTuple):
    """A flattened 4-wide BVH (layout: :mod:`.bvh`)."""

    bounds: np.ndarray  # (N, 24) child boxes (SoA over 4 lanes): float32 for a mesh's
    # (rounded outward, :func:`collapse4`), float64 for the top level's
    child: np.ndarray  # (N, 4) int32, inner node index or ~(start << 3 | count)
    perm: np.ndarray  # (n,) int32, primitive ids in leaf order


class MeshBVH(NamedTuple):
    """The bottom-level BVH of one mesh, in object space."""

    bvh: FlatBVH
    tri: np.ndarray  # (m,) int32, triangle index *within the mesh*, leaf order
    sah_cost: float
    build_s: float



# ----------------------------------------------------------------------------- 4-wide


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


#: binary nodes from which :func:`flatten` collapses on all threads (a mesh of
#: :data:`.bvh_build.PARALLEL_MIN` triangles has about half as many: two a quad), and into
#: how many subtrees (:func:`collapse_tasks`: enough that two threads end together, few
#: enough that the nodes above them, made on one thread, stay a few hundred)
COLLAPSE_PARALLEL_MIN = PARALLEL_MIN // 2
COLLAPSE_TASKS = 128

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
    tree, row for row, on both: :func:`collapse4_parallel`.
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
    parent's lane points at them, for :func:`collapse4_parallel`'s threads."""
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
    (then nothing made is of use: :func:`flatten` runs :func:`collapse4`)."""
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


def flatten(b64: np.ndarray, child: np.ndarray, perm: np.ndarray,
            dtype=np.float64, tasks: int | None = None) -> FlatBVH:
    """Binary build output (packed, or the builder's unpacked arrays:
    ``build_flat_boxes(packed=False)``) -> the traversal layout (4-wide), its boxes
    padded (:func:`pad_outward`, as they are read: ``b64`` is not changed) and ``dtype``
    (float32: rounded outward, :func:`collapse4`). The nodes are views of arrays sized for
    the binary arrays (a few times the rows used): the scene's concatenation
    (:func:`.bvh.concat_meshes`) copies them, and the arrays go with the built tree.

    The collapse runs on all threads (:func:`collapse4_parallel`: the same tree, with a few
    rows no child reaches) for a
    tree of :data:`COLLAPSE_PARALLEL_MIN` binary nodes or more when numba has more than
    one; ``tasks`` (tests) sets the number of its subtrees instead (0: one thread)."""
    b4 = np.empty((len(child), 24), dtype)
    if tasks is None:
        tasks = (COLLAPSE_TASKS if len(child) >= COLLAPSE_PARALLEL_MIN
                 and numba.get_num_threads() > 1 else 0)
    if tasks <= 0:
        b4, c4, m = collapse4(b64, child, b4, True)
    else:
        task_bn, n_top = collapse_tasks(b64, child, True, tasks)
        with numba.parallel_chunksize(1):  # (subtrees differ in size: threads take turns)
            b4, c4, m = collapse4_parallel(b64, child, b4, True, task_bn, n_top)
        if m < 0:  # a subtree outgrew its room (none in the meshes measured)
            b4, c4, m = collapse4(b64, child, b4, True)
    return FlatBVH(b4[:m], c4[:m], perm)


# ----------------------------------------------------------------------------- meshes


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def gather_triangles_into(verts, tris, order, out, row0):
    """``out[row0 + i] =`` the vertices of triangle ``tris[order[i]]`` (9 float64), in
    parallel (written straight into a larger array where that is where they are kept)."""
    for i in prange(order.shape[0]):
        t = order[i]
        for c in range(3):
            for q in range(3):
                out[row0 + i, 3 * c + q] = verts[tris[t, c], q]


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def indexed_boxes(verts, tris):
    """Boxes (m, 6) float32 (lo, hi) of triangles ``verts[tris]``, rounded outward
    (:func:`_put_outward`: each contains its float64 box, and equals it where the vertices
    are float32 values, as Blender's are), without gathering their vertices first."""
    m = tris.shape[0]
    pb = np.empty((m, 6), np.float32)
    bits = pb.reshape(-1).view(np.int32)
    for i in prange(m):
        ia, ib, ic = tris[i, 0], tris[i, 1], tris[i, 2]
        for q in range(3):
            a, b, c = verts[ia, q], verts[ib, q], verts[ic, q]
            _put_outward(pb, bits, i, q, min(a, min(b, c)), 3)
            _put_outward(pb, bits, i, 3 + q, max(a, max(b, c)), 3)
    return pb


def outward32(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Primitive boxes (n, 6) float32 of float64 bounds ``lo``, ``hi`` (n, 3), rounded
    outward as :func:`indexed_boxes` rounds them (numpy: the bits are the same)."""
    pb = np.empty((len(lo), 6), np.float32)
    for q, (x, toward) in enumerate(((lo, -np.inf), (hi, np.inf))):
        f = x.astype(np.float32)
        moved = f > x if toward < 0 else f < x
        np.nextafter(f, np.float32(toward), out=f, where=moved)
        pb[:, 3 * q:3 * q + 3] = f
    return pb


def mesh_range(sa, mesh: int) -> tuple[int, int]:
    """Mesh ``mesh``'s triangles: ``sa.tris[start:end]``."""
    return int(sa.mesh_tri_start[mesh]), int(sa.mesh_tri_start[mesh + 1])


def mesh_triangles(sa, mesh: int) -> np.ndarray:
    """Object-space vertices of mesh ``mesh``'s triangles: (m, 3, 3) float64."""
    s, e = mesh_range(sa, mesh)
    if e - s < PARALLEL_MIN:
        return sa.verts[sa.tris[s:e]]
    return gather_triangles(sa.verts, sa.tris, np.arange(s, e, dtype=np.int32)).reshape(-1, 3, 3)


def gather_triangles(verts: np.ndarray, tris: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Vertices of triangles ``tris[order]`` in that order: (len(order), 9) float64."""
    out = np.empty((len(order), 9))
    gather_triangles_into(verts, tris, order, out, 0)
    return out


#: Bytes hashed between two looks at the stop flag (:func:`mesh_key`).
KEY_CHUNK = 1 << 24


def _hash_chunks(h, a: np.ndarray, stop: np.ndarray, less: int = 0) -> None:
    """Feed ``a`` (``a - less`` where ``less``: an int32 array, each chunk taken from it
    into one reused buffer, not a whole copy) to ``h`` in :data:`KEY_CHUNK`-byte chunks."""
    raw = np.ascontiguousarray(a).reshape(-1)
    step = max(KEY_CHUNK // raw.itemsize, 1)
    buf = np.empty(min(step, len(raw)), raw.dtype) if less else None
    for start in range(0, len(raw), step):
        if stop[0]:
            raise Cancelled("BVH build cancelled")
        part = raw[start:start + step]
        if less:
            part = np.subtract(part, raw.dtype.type(less), out=buf[:len(part)])
        h.update(part)


def mesh_key(verts: np.ndarray, tris: np.ndarray, stop: np.ndarray = NEVER_STOP) -> bytes:
    """Content hash of a mesh's triangles ``verts[tris]`` (verts (V, 3) float64, tris
    (m, 3) int32 indices into them), exactly: the vertices ``tris`` spans (the range from
    its least to its largest index) and ``tris`` relative to that range, so the key does
    not depend on where the mesh lies in the scene's concatenation. Equal keys mean equal
    triangle vertices, and the same tree (the build is deterministic). The stop flag is
    looked at every :data:`KEY_CHUNK` bytes (:class:`~rstrace_engine.cancel.Cancelled`).
    The hash is :class:`~.content_hash.ContentHash` (NH under a per-process random key, then
    SHA-256: equal keys of different meshes with probability below 2^-128; 4-5x faster than
    SHA-256 alone); keys live only in the process (the NH key is drawn per process)."""
    h = ContentHash()
    if len(tris) == 0:
        return h.digest()[:16]
    lo, hi = int(tris.min()), int(tris.max())
    h.update(np.array([len(tris), hi + 1 - lo], np.int64).tobytes())
    _hash_chunks(h, np.ascontiguousarray(verts[lo:hi + 1], np.float64), stop)
    _hash_chunks(h, tris, stop, lo)
    return h.digest()[:16]


def build_mesh_bvh(tv: np.ndarray, grain: int | None = None,
                   stop: np.ndarray = NEVER_STOP) -> MeshBVH:
    """Bottom-level BVH of one mesh from its triangle vertices (m, 3, 3) float64
    (``grain``, ``stop``: :func:`build_flat`). The tree holds no vertices: its leaves
    name triangles (``tri``), whose vertices the traversal reads through the scene's
    vertex indices (:class:`.bvh.SceneBVH`)."""
    flat9 = np.ascontiguousarray(tv, dtype=np.float64).reshape(-1, 9)
    m = len(flat9)
    if m >= PARALLEL_MIN:  # the parallel kernels, through indices of the rows' vertices
        return build_mesh_bvh_indexed(flat9.reshape(-1, 3),
                                      np.arange(3 * m, dtype=np.int32).reshape(m, 3), grain,
                                      stop)
    # (numpy and one thread: no parallel region to start)
    t0 = time.perf_counter()
    t3 = flat9.reshape(-1, 3, 3)
    # the float32 boxes' values, held as float64: the builder reads every box as float64,
    # so the tree is the float32 boxes' bit for bit, and it is built by the signature the
    # scene's top level and the shafts build with (below PARALLEL_MIN triangles: 3 MB of
    # boxes and 6 MB of binary nodes at most; the float32 build's kernels are not compiled
    # for small scenes: ~15 s of a cold start, docs/first-render.md, session 33)
    pb = outward32(t3.min(axis=1), t3.max(axis=1)).astype(np.float64)
    flat, sah = _four_wide(_binary(pb, grain, stop), stop)
    return MeshBVH(flat, flat.perm, float(sah), time.perf_counter() - t0)


def build_mesh_bvh_indexed(verts: np.ndarray, tris: np.ndarray, grain: int | None = None,
                           stop: np.ndarray = NEVER_STOP) -> MeshBVH:
    """:func:`build_mesh_bvh` of the triangles ``verts[tris]`` (verts (V, 3) float64, tris
    (m, 3) int32), the same tree, without the (m, 9) copy of their vertices in mesh order
    (a large mesh's boxes are gathered through ``tris``)."""
    if len(tris) < PARALLEL_MIN:
        return build_mesh_bvh(verts[tris], grain, stop)
    t0 = time.perf_counter()
    # (the primitive boxes are gone before the 4-wide tree is made: a lower peak)
    flat, sah = _four_wide(_binary_paired(verts, tris, indexed_boxes(verts, tris), grain,
                                          stop), stop)
    return MeshBVH(flat, flat.perm, float(sah), time.perf_counter() - t0)


def _binary(pb: np.ndarray, grain, stop):
    """The binary tree over primitive boxes ``pb`` (n, 6), which it reorders (the caller
    drops them after: they are not needed for the 4-wide tree, :func:`_four_wide`)."""
    out = build_flat_boxes(pb, grain=grain, stop=stop, packed=False)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    return out


def _binary_paired(verts, tris, pb, grain, stop):
    """:func:`_binary` of a large mesh, built over its quads (:mod:`.bvh_cluster`); the
    item build's ``grain`` (items per subtree) is the triangle build's, so a mesh past
    :data:`.bvh_build.PARALLEL_MIN` triangles runs the parallel phases."""
    out = build_paired(verts, tris, pb, grain=subtree_grain(len(tris)) if grain is None
                       else grain, stop=stop)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    return out


def _four_wide(binary, stop) -> tuple[FlatBVH, float]:
    """The 4-wide tree of :func:`_binary`'s output, its boxes in float32 rounded outward
    (:func:`collapse4`), and its SAH cost."""
    b64, child, perm, sah = binary
    flat = flatten(b64, child, perm, np.float32)
    if stop[0]:
        raise Cancelled("BVH build cancelled")
    return flat, sah


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


# ----------------------------------------------------------------------------- leaves

#: A mesh leaf's code is ``~(start << 3 | kind)`` (layout: :mod:`.bvh`). Kinds 1 to
#: LEAF_LISTED: that many triangles, listed in leaf order at ``tri[start:start + kind]``;
#: the others name their triangles directly, with no list entry: LEAF_ONE triangle
#: ``start``, LEAF_PAIR ``start`` then ``start + 1``, LEAF_PAIR_DOWN ``start + 1`` then
#: ``start`` (most leaves of a triangulated surface: a quad's two triangles are neighbours
#: in the host's order). Kind 0 (code ``~0``) is the empty leaf.
LEAF_LISTED = 4
LEAF_ONE, LEAF_PAIR, LEAF_PAIR_DOWN = 5, 6, 7
assert MAX_LEAF <= LEAF_LISTED  # (a leaf of more would be read as a direct one)


@njit(cache=True, nogil=True, inline="always")
def leaf_size(kind):
    """Triangles in a mesh leaf of ``kind`` (``code & 7``)."""
    if kind <= LEAF_LISTED:
        return kind
    return 1 if kind == LEAF_ONE else 2


@njit(cache=True, nogil=True, inline="always")
def leaf_triangle(tri, start, kind, i):
    """Triangle ``i`` (in leaf order) of the mesh leaf ``~(start << 3 | kind)``."""
    if kind <= LEAF_LISTED:
        return tri[start + i]
    if kind == LEAF_PAIR_DOWN:
        return start + 1 - i
    return start + i


@njit(cache=True, nogil=True, error_model="numpy")
def direct_leaves(child, perm, out_child, out_tri):
    """A built mesh tree's leaves (``child`` codes ``~(start << 3 | count)`` over ``perm``,
    the triangles in leaf order) as the traversal reads them: a leaf of one triangle, or
    of two neighbours in either order, names them (LEAF_ONE, LEAF_PAIR, LEAF_PAIR_DOWN);
    the others list theirs in ``out_tri``, in leaf order. Writes ``out_child`` (same
    shape) and returns the number of ``out_tri`` entries used."""
    n = 0
    for i in range(child.shape[0]):
        for j in range(4):
            c = child[i, j]
            if c >= 0 or c == -1:
                out_child[i, j] = c
                continue
            code = ~c
            s, k = code >> 3, code & 7
            a = perm[s]
            if k == 1:
                out_child[i, j] = ~((a << 3) | LEAF_ONE)
            elif k == 2 and perm[s + 1] == a + 1:
                out_child[i, j] = ~((a << 3) | LEAF_PAIR)
            elif k == 2 and perm[s + 1] == a - 1:
                out_child[i, j] = ~(((a - 1) << 3) | LEAF_PAIR_DOWN)
            else:
                out_child[i, j] = ~((n << 3) | k)
                for q in range(k):
                    out_tri[n + q] = perm[s + q]
                n += k
    return n


def leaf_order(child: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Every triangle of a mesh tree in :func:`direct_leaves`' form, leaf by leaf (nodes
    in order, lanes in order), each leaf's in its order: (m,) int64 (tests, checks)."""
    out = []
    for c in child[child < -1]:
        code = ~int(c)
        s, k = code >> 3, code & 7
        if k <= LEAF_LISTED:
            out.extend(int(x) for x in tri[s:s + k])
        elif k == LEAF_ONE:
            out.append(s)
        else:
            out.extend([s, s + 1] if k == LEAF_PAIR else [s + 1, s])
    return np.array(out, np.int64)


@njit(cache=True, nogil=True, error_model="numpy")
def place_child(src, dst, row0, dn, dl, dt):
    """``dst[row0:row0 + len(src)]`` = child codes ``src`` (N, 4) int32 moved by ``dn``
    nodes, ``dl`` listed entries and ``dt`` triangles (an inner node ``c >= 0`` becomes
    ``c + dn``; a leaf ``~(start << 3 | kind)`` starts ``dl`` later when it lists its
    triangles, ``dt`` later when it names them; the empty leaf ``~0`` stays)."""
    for i in range(src.shape[0]):
        for j in range(4):
            c = src[i, j]
            if c >= 0:
                c += dn
            elif c != -1:
                code = ~c
                c = ~(code + ((dl if (code & 7) <= LEAF_LISTED else dt) << 3))
            dst[row0 + i, j] = c


@njit(cache=True, nogil=True, error_model="numpy")
def place_tri(src, dst, row0, dt):
    """``dst[row0:row0 + len(src)] = src + dt`` (triangle ids moved to a mesh's place)."""
    for i in range(src.shape[0]):
        dst[row0 + i] = src[i] + dt


def build_top(inst_aabb: np.ndarray) -> FlatBVH:
    """Top-level BVH over instance world boxes (I, 2, 3) float64, padded by
    :data:`~.tolerances.INSTANCE_BOX_PAD_REL` of their magnitude (the world->object transform
    of a ray rounds)."""
    lo = inst_aabb[:, 0]
    hi = inst_aabb[:, 1]
    mag = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))
    pad = (tol.INSTANCE_BOX_PAD_REL * (mag + np.linalg.norm(hi - lo, axis=1)))[:, None]
    b64, child, perm, _ = build_flat(lo - pad, hi + pad, 1)
    return flatten(b64, child, perm)
