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
from .bvh_build import (
    MAX_LEAF,
    NEVER_STOP,
    PARALLEL_MIN,
    build_flat,
    build_flat_boxes,
    subtree_grain,
)
from .bvh_cluster import build_paired
from .bvh_collapse import (  # (collapse4, pad_outward: this module's names before session 40)
    COLLAPSE_PARALLEL_MIN,
    COLLAPSE_TASKS,
    _put_outward,
    collapse4,
    collapse4_parallel,
    collapse_tasks,
    pad_outward,  # noqa: F401
)
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


def flatten(b64: np.ndarray, child: np.ndarray, perm: np.ndarray,
            dtype=np.float64, tasks: int | None = None) -> FlatBVH:
    """Binary build output (packed, or the builder's unpacked arrays:
    ``build_flat_boxes(packed=False)``) -> the traversal layout (4-wide), its boxes
    padded (:func:`pad_outward`, as they are read: ``b64`` is not changed) and ``dtype``
    (float32: rounded outward, :func:`collapse4`). The nodes are views of arrays sized for
    the binary arrays (a few times the rows used): the scene's concatenation
    (:func:`.bvh.concat_meshes`) copies them, and the arrays go with the built tree.

    The collapse runs on all threads (:func:`.bvh_collapse.collapse4_parallel`: the same
    tree, with rows no child reaches) for a tree over :data:`.bvh_build.PARALLEL_MIN`
    primitives or more (``perm``: below it a build starts no parallel region, as
    :func:`build_mesh_bvh` and :func:`build_top` promise; ``len(child)`` alone is no node
    count: the builder's unpacked arrays have a row a primitive) and of
    :data:`.bvh_collapse.COLLAPSE_PARALLEL_MIN` binary rows or more, when numba has more
    than one thread; ``tasks`` (tests) sets the number of its subtrees instead (0: one
    thread)."""
    b4 = np.empty((len(child), 24), dtype)
    if tasks is None:
        tasks = (COLLAPSE_TASKS if len(perm) >= PARALLEL_MIN
                 and len(child) >= COLLAPSE_PARALLEL_MIN
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


#: A mesh of fewer than :data:`.bvh_build.PARALLEL_MIN` triangles is built with this SAH
#: cost of a binary node (against one triangle test) and leaves of at most this many
#: triangles (session 42, docs/bench-raycast.md "session 42 (tree)": leaves of 2-3 where
#: the defaults, 1.0 and 4, make 1-2; on the rough frame's rays 3% fewer node visits and
#: leaves entered for 29% more triangles tested, about 2% less closest-hit and shadow CPU;
#: leaves of 4 at 2.0 cost museum's rays 4-9%: its small meshes' 4-triangle leaves doubled
#: the triangles tested). A large mesh's build (:func:`_binary_paired`) keeps the
#: defaults: its build time is issue 26's.
SMALL_TRAV_COST = 2.0
SMALL_MAX_LEAF = 3


def _binary(pb: np.ndarray, grain, stop):
    """The binary tree over primitive boxes ``pb`` (n, 6), which it reorders (the caller
    drops them after: they are not needed for the 4-wide tree, :func:`_four_wide`); with
    :data:`SMALL_TRAV_COST` and :data:`SMALL_MAX_LEAF` (a mesh below
    :data:`.bvh_build.PARALLEL_MIN` triangles)."""
    out = build_flat_boxes(pb, SMALL_MAX_LEAF, trav_cost=SMALL_TRAV_COST, grain=grain,
                           stop=stop, packed=False)
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


# ----------------------------------------------------------------------------- leaves

#: A mesh leaf's code is ``~(start << 3 | kind)`` (layout: :mod:`.bvh`). Kinds 1 to
#: LEAF_LISTED: that many triangles, listed in leaf order at ``tri[start:start + kind]``;
#: the others name their triangles directly, with no list entry: LEAF_ONE triangle
#: ``start``, LEAF_PAIR ``start`` then ``start + 1``, LEAF_PAIR_DOWN ``start + 1`` then
#: ``start`` (most leaves of a triangulated surface: a quad's two triangles are neighbours
#: in the host's order). Kind 0 (code ``~0``) is the empty leaf.
LEAF_LISTED = 4
LEAF_ONE, LEAF_PAIR, LEAF_PAIR_DOWN = 5, 6, 7
# (a leaf of more would be read as a direct one)
assert max(MAX_LEAF, SMALL_MAX_LEAF) <= LEAF_LISTED


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
    the others list theirs in ``out_tri``, in leaf order. Writes ``out_child`` (``child``'s
    shape) and returns the number of ``out_tri`` entries used and of ``out_child`` rows.

    Rows no child reaches (:func:`.bvh_collapse.collapse4_parallel`'s rooms leave them,
    each an empty node: lane 0 the empty leaf ``~0``, which a node's lane 0 never is) are
    dropped, the others renumbered in their order (:func:`used_runs` gives their boxes'
    rows); the root, row 0, is kept whatever it holds."""
    rows = child.shape[0]
    used = 0
    for i in range(rows):
        used += i == 0 or child[i, 0] != -1
    gaps = used < rows
    new = np.empty(rows if gaps else 0, np.int32)  # (old row -> new, where rows drop)
    if gaps:
        r = 0
        for i in range(rows):
            new[i] = r
            r += i == 0 or child[i, 0] != -1
    n = 0
    r = 0
    for i in range(rows):
        if i > 0 and child[i, 0] == -1:
            continue
        for j in range(4):
            c = child[i, j]
            if c >= 0 or c == -1:
                out_child[r, j] = new[c] if gaps and c >= 0 else c
                continue
            code = ~c
            s, k = code >> 3, code & 7
            a = perm[s]
            if k == 1:
                out_child[r, j] = ~((a << 3) | LEAF_ONE)
            elif k == 2 and perm[s + 1] == a + 1:
                out_child[r, j] = ~((a << 3) | LEAF_PAIR)
            elif k == 2 and perm[s + 1] == a - 1:
                out_child[r, j] = ~(((a - 1) << 3) | LEAF_PAIR_DOWN)
            else:
                out_child[r, j] = ~((n << 3) | k)
                for q in range(k):
                    out_tri[n + q] = perm[s + q]
                n += k
        r += 1
    return n, r


def used_runs(child: np.ndarray) -> tuple[tuple[int, int], ...]:
    """The ``(start, stop)`` runs of a built tree's rows that :func:`direct_leaves` keeps,
    in order: ``((0, len(child)),)`` when it keeps every row."""
    live = child[:, 0] != -1
    live[:1] = True
    if live.all():
        return ((0, len(child)),)
    edge = np.flatnonzero(np.diff(live.astype(np.int8), prepend=np.int8(0),
                                  append=np.int8(0)))
    return tuple((int(a), int(b)) for a, b in zip(edge[0::2], edge[1::2], strict=True))


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
