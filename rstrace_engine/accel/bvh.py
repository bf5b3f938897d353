"""Two-level bounding volume hierarchy in numba: the default ray accelerator.

* **Bottom level**: one binned-SAH BVH per *mesh*, in object space, built once and shared by
  every instance of the mesh. Meshes are keyed by a content hash of their triangles, so a new
  packing of the scene reuses every mesh whose geometry did not change.
* **Top level**: a BVH over the instances' world bounds, rebuilt on every update (cheap: one
  primitive per instance). At an instance leaf the ray is taken to object space (direction not
  normalised, so distances stay world distances) and the mesh BVH is traversed.

Build and layout (flattened, pbrt/pynndescent style): a binary binned-SAH tree is built
(:func:`build_flat`) and collapsed into a 4-wide tree (:func:`collapse4`) whose nodes hold
the boxes of their four children, so one visit tests four boxes and pushes those hit
farthest first (front-to-back traversal with a small fixed stack).

* ``bounds`` (N, 24) float64, struct-of-arrays over the four lanes: ``lo x[4], lo y[4],
  lo z[4], hi x[4], hi y[4], hi z[4]``: min / max of the vertex coordinates widened by one
  ulp (:func:`pad_outward`; float64 measured ~5% faster than float32 boxes here: no
  conversions in the slab test). An unused lane has an inverted box (``lo = +inf``) and is
  never entered.
* ``child`` (N, 4) int32: ``>= 0`` an inner node; ``< 0`` a leaf ``~(start << 3 | count)``
  over ``count`` (0..7) consecutive primitives in leaf order.

The box test is the conservative slab test of pbrt-v4 (``t_far`` scaled by
:data:`~.tolerances.BOX_TFAR_SCALE`) and the triangle test is watertight (:mod:`.triangle`),
so no ray slips through a shared edge or vertex.
"""

from __future__ import annotations

import hashlib
import logging
import time
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from .triangle import intersect_sheared, ray_shear

log = logging.getLogger(__name__)

#: Most primitives in a leaf (the leaf code keeps the count in 3 bits).
MAX_LEAF = 4
#: SAH bins per axis.
SAH_BINS = 24
#: SAH cost of one node traversal relative to one primitive test.
SAH_TRAVERSAL_COST = 1.0
#: Past this depth the builder splits at the object median (bounds the traversal stack).
DEPTH_CAP = 60
#: Traversal stack entries: a 4-wide visit pushes <= 4 and pops 1, the depth is <= DEPTH_CAP
#: + 31 (median splits below the cap add <= 31 levels).
STACK_SIZE = 3 * (DEPTH_CAP + 31) + 4
#: Rays per parallel work item.
CHUNK = 64
#: Work items a thread takes at a time (dynamic scheduling).
PARALLEL_CHUNKSIZE = 16


class FlatBVH(NamedTuple):
    """A flattened 4-wide BVH (see the module docstring)."""

    bounds: np.ndarray  # (N, 24) float64, child boxes (SoA over 4 lanes)
    child: np.ndarray  # (N, 4) int32, inner node index or ~(start << 3 | count)
    perm: np.ndarray  # (n,) int32, primitive ids in leaf order


class MeshBVH(NamedTuple):
    """The bottom-level BVH of one mesh, in object space."""

    bvh: FlatBVH
    tv: np.ndarray  # (m, 9) float64, triangle vertices (a, b, c) in leaf order
    tri: np.ndarray  # (m,) int32, triangle index *within the mesh*, leaf order
    sah_cost: float
    build_s: float


class SceneBVH(NamedTuple):
    """Everything the traversal kernel reads: both levels, concatenated (what numba takes)."""

    top_bounds: np.ndarray  # (Nt, 24) float64
    top_child: np.ndarray  # (Nt, 4) int32
    top_inst: np.ndarray  # (I,) int32, instance ids in leaf order
    bounds: np.ndarray  # (N, 24) float64, all mesh BVH nodes
    child: np.ndarray  # (N, 4) int32, node and triangle indices already offset
    tv: np.ndarray  # (T, 9) float64, triangle vertices in leaf order
    tri: np.ndarray  # (T,) int32, GLOBAL triangle index (into SceneArrays.tris)
    mesh_root: np.ndarray  # (M,) int32, root node of each mesh
    inst_mesh: np.ndarray  # (I,) int32
    inst_inv: np.ndarray  # (I, 4, 4) float64 world -> object


# ----------------------------------------------------------------------------- build


@njit(cache=True, nogil=True, inline="always")
def _half_area(b0, b1, b2, b3, b4, b5):
    dx, dy, dz = b3 - b0, b4 - b1, b5 - b2
    if dx < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=True, nogil=True, error_model="numpy")
def _range_box(lo, hi, perm, start, end, box):
    for k in range(3):
        box[k] = np.inf
        box[3 + k] = -np.inf
    for j in range(start, end):
        p = perm[j]
        for k in range(3):
            box[k] = min(box[k], lo[p, k])
            box[3 + k] = max(box[3 + k], hi[p, k])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _centroid_bounds(cen, perm, start, end, cmin, cmax):
    """Bounds ``cmin``, ``cmax`` (3,) of the centroids of primitives ``perm[start:end]``."""
    for k in range(3):
        cmin[k] = np.inf
        cmax[k] = -np.inf
    for j in range(start, end):
        p = perm[j]
        for k in range(3):
            cmin[k] = min(cmin[k], cen[p, k])
            cmax[k] = max(cmax[k], cen[p, k])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sah_split(lo, hi, cen, perm, start, end, cmin, cmax, nbins, bin_n, bin_b, right_a,
               right_n):
    """The best binned-SAH split of primitives ``perm[start:end]`` over their centroid
    bounds, on all three axes: ``(cost, axis, bin)``, the split between bins ``bin`` and
    ``bin + 1`` (axis -1: no split; ``cost`` unnormalised). ``bin_n .. right_n``: the
    bins' scratch arrays."""
    best_cost = np.inf
    best_axis = -1
    best_bin = -1
    bin_n[:, :] = 0
    for k in range(3):
        for b in range(nbins):
            bin_b[k, b, 0:3] = np.inf
            bin_b[k, b, 3:6] = -np.inf
    for j in range(start, end):
        p = perm[j]
        for k in range(3):
            ext = cmax[k] - cmin[k]
            if ext <= 0.0:
                continue
            b = int((cen[p, k] - cmin[k]) * (nbins / ext))
            b = min(max(b, 0), nbins - 1)
            bin_n[k, b] += 1
            for q in range(3):
                bin_b[k, b, q] = min(bin_b[k, b, q], lo[p, q])
                bin_b[k, b, 3 + q] = max(bin_b[k, b, 3 + q], hi[p, q])
    rb = np.empty(6)
    lb = np.empty(6)
    for k in range(3):
        if cmax[k] - cmin[k] <= 0.0:
            continue
        # sweep from the right: area and count of bins b.. nbins-1
        rb[0:3] = np.inf
        rb[3:6] = -np.inf
        cnt = 0
        for b in range(nbins - 1, 0, -1):
            cnt += bin_n[k, b]
            for q in range(3):
                rb[q] = min(rb[q], bin_b[k, b, q])
                rb[3 + q] = max(rb[3 + q], bin_b[k, b, 3 + q])
            right_n[b] = cnt
            right_a[b] = _half_area(rb[0], rb[1], rb[2], rb[3], rb[4], rb[5])
        lb[0:3] = np.inf
        lb[3:6] = -np.inf
        cnt = 0
        for b in range(nbins - 1):  # split between bin b and b + 1
            cnt += bin_n[k, b]
            for q in range(3):
                lb[q] = min(lb[q], bin_b[k, b, q])
                lb[3 + q] = max(lb[3 + q], bin_b[k, b, 3 + q])
            nr = right_n[b + 1]
            if cnt == 0 or nr == 0:
                continue
            la = _half_area(lb[0], lb[1], lb[2], lb[3], lb[4], lb[5])
            cost = la * cnt + right_a[b + 1] * nr
            if cost < best_cost:
                best_cost, best_axis, best_bin = cost, k, b
    return best_cost, best_axis, best_bin


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _partition(cen, perm, start, end, k, cmin_k, ext, nbins, split_bin):
    """Reorder ``perm[start:end]``: primitives whose centroid falls in bins up to
    ``split_bin`` on axis ``k`` first. Returns where the others start."""
    i, j = start, end - 1
    while i <= j:
        b = int((cen[perm[i], k] - cmin_k) * (nbins / ext))
        b = min(max(b, 0), nbins - 1)
        if b <= split_bin:
            i += 1
        else:
            perm[i], perm[j] = perm[j], perm[i]
            j -= 1
    return i


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _median_split(cen, perm, start, end, cmin, cmax):
    """Object median along the widest centroid axis: sorts ``perm[start:end]`` along it and
    returns the middle."""
    k = 0
    for q in range(1, 3):
        if cmax[q] - cmin[q] > cmax[k] - cmin[k]:
            k = q
    count = end - start
    if count > 1:
        keys = np.empty(count)
        for j in range(count):
            keys[j] = cen[perm[start + j], k]
        order = np.argsort(keys, kind="mergesort")
        seg = perm[start:end].copy()
        for j in range(count):
            perm[start + j] = seg[order[j]]
    return (start + end) // 2


@njit(cache=True, nogil=True, error_model="numpy")
def build_flat(lo, hi, max_leaf, nbins, trav_cost):
    """Binned-SAH BVH over primitive boxes.

    lo, hi : (n, 3) float64 primitive bounds (n >= 1)
    Returns ``bounds (N, 12) float64, child (N, 2) int32, perm (n,) int32, sah_cost``
    (``sah_cost`` is the SAH estimate of the whole tree in units of one primitive test).
    Depth first from an explicit stack of tasks (a node's primitive range): each becomes a
    leaf, or is split (:func:`_sah_split`, else :func:`_median_split`) into two tasks.
    """
    n = lo.shape[0]
    perm = np.arange(n).astype(np.int32)
    cen = 0.5 * (lo + hi)
    cap = max(n, 2)
    bounds = np.empty((cap, 12))
    child = np.empty((cap, 2), np.int32)
    # pending tasks (DFS): parent node, slot, start, end, depth; plus the task's box
    t_int = np.empty((2 * STACK_SIZE, 5), np.int64)
    t_box = np.empty((2 * STACK_SIZE, 6))
    bin_n = np.zeros((3, nbins), np.int64)
    bin_b = np.empty((3, nbins, 6))
    right_a = np.empty(nbins)
    right_n = np.empty(nbins, np.int64)
    box = np.empty(6)
    lbox = np.empty(6)
    rbox = np.empty(6)
    cmin = np.empty(3)
    cmax = np.empty(3)
    # node 0 is the root; its own box is implicit (the instance / scene box)
    _range_box(lo, hi, perm, 0, n, box)
    root_area = max(_half_area(box[0], box[1], box[2], box[3], box[4], box[5]), 1e-300)
    sah = 0.0
    nn = 1
    sp = 0
    t_int[0, 0], t_int[0, 1], t_int[0, 2], t_int[0, 3], t_int[0, 4] = -1, 0, 0, n, 0
    t_box[0, :] = box
    while sp >= 0:
        parent, slot, start, end, depth = (t_int[sp, 0], t_int[sp, 1], t_int[sp, 2],
                                           t_int[sp, 3], t_int[sp, 4])
        box[:] = t_box[sp]
        sp -= 1
        count = end - start
        area = _half_area(box[0], box[1], box[2], box[3], box[4], box[5])
        _centroid_bounds(cen, perm, start, end, cmin, cmax)
        best_cost, best_axis, best_bin = np.inf, -1, -1
        if count > 1 and depth < DEPTH_CAP:
            best_cost, best_axis, best_bin = _sah_split(lo, hi, cen, perm, start, end, cmin,
                                                        cmax, nbins, bin_n, bin_b, right_a,
                                                        right_n)
        split_cost = trav_cost + best_cost / max(area, 1e-300)
        make_leaf = count <= max_leaf and (count == 1 or count <= split_cost)
        if make_leaf and parent >= 0:
            bounds[parent, 6 * slot:6 * slot + 6] = box
            child[parent, slot] = ~((start << 3) | count)
            sah += count * area / root_area
            continue
        if best_axis >= 0 and not make_leaf:
            mid = _partition(cen, perm, start, end, best_axis, cmin[best_axis],
                             cmax[best_axis] - cmin[best_axis], nbins, best_bin)
        else:
            # no usable SAH split (coincident centroids, depth cap, or a root that is one
            # leaf)
            mid = _median_split(cen, perm, start, end, cmin, cmax)
        # --- allocate the inner node (the root is node 0, already allocated)
        if parent >= 0:
            node = nn
            nn += 1
            bounds[parent, 6 * slot:6 * slot + 6] = box
            child[parent, slot] = node
            sah += trav_cost * area / root_area
        else:
            node = 0
            sah += trav_cost
            if count == 1 or make_leaf:  # the whole mesh is one leaf: child 1 is empty
                bounds[0, 0:6] = box
                child[0, 0] = ~((start << 3) | count)
                bounds[0, 6:9] = np.inf
                bounds[0, 9:12] = -np.inf
                child[0, 1] = ~((start << 3) | 1)
                sah += count * area / root_area
                continue
        _range_box(lo, hi, perm, start, mid, lbox)
        _range_box(lo, hi, perm, mid, end, rbox)
        # push right then left so the left child is processed (and numbered) first
        sp += 1
        t_int[sp, 0], t_int[sp, 1], t_int[sp, 2], t_int[sp, 3], t_int[sp, 4] = (
            node, 1, mid, end, depth + 1)
        t_box[sp, :] = rbox
        sp += 1
        t_int[sp, 0], t_int[sp, 1], t_int[sp, 2], t_int[sp, 3], t_int[sp, 4] = (
            node, 0, start, mid, depth + 1)
        t_box[sp, :] = lbox
    return bounds[:nn].copy(), child[:nn].copy(), perm, sah


@njit(cache=True, nogil=True, error_model="numpy")
def collapse4(b2, c2):
    """Binary BVH (child boxes (N, 12) float64, children (N, 2) int32) -> 4-wide BVH.

    Each 4-wide node takes its binary node's two children and repeatedly opens the inner
    child of largest surface area until it has four. Returns ``bounds (M, 24) float64``
    (SoA over the four lanes: lo x, lo y, lo z, hi x, hi y, hi z, four values each) and
    ``child (M, 4) int32``; an unused lane has an inverted box and the empty leaf ``~0``.
    """
    n2 = c2.shape[0]
    b4 = np.empty((n2, 24))
    c4 = np.empty((n2, 4), np.int32)
    todo = np.empty((4 * n2 + 4, 3), np.int64)  # binary node, 4-wide parent, lane
    cb = np.empty((4, 6))
    cc = np.empty(4, np.int64)
    sp = 0
    todo[0, 0], todo[0, 1], todo[0, 2] = 0, -1, 0
    sp = 1
    m = 0
    while sp > 0:
        sp -= 1
        bn, parent, lane = todo[sp, 0], todo[sp, 1], todo[sp, 2]
        k = m
        m += 1
        if parent >= 0:
            c4[parent, lane] = k
        cnt = 0
        for j in range(2):
            if b2[bn, 6 * j] <= b2[bn, 6 * j + 3]:  # drop the empty child of a 1-leaf root
                cb[cnt, :] = b2[bn, 6 * j:6 * j + 6]
                cc[cnt] = c2[bn, j]
                cnt += 1
        while cnt < 4:
            pick = -1
            best = -1.0
            for j in range(cnt):
                if cc[j] >= 0:
                    area = _half_area(cb[j, 0], cb[j, 1], cb[j, 2], cb[j, 3], cb[j, 4],
                                      cb[j, 5])
                    if area > best:
                        best, pick = area, j
            if pick < 0:
                break
            inner = cc[pick]
            cb[pick, :] = b2[inner, 0:6]
            cc[pick] = c2[inner, 0]
            cb[cnt, :] = b2[inner, 6:12]
            cc[cnt] = c2[inner, 1]
            cnt += 1
        for j in range(4):
            if j < cnt:
                for q in range(6):
                    b4[k, 4 * q + j] = cb[j, q]
                c4[k, j] = cc[j]
            else:
                for q in range(3):
                    b4[k, 4 * q + j] = np.inf
                    b4[k, 12 + 4 * q + j] = -np.inf
                c4[k, j] = -1  # ~0: a leaf of no triangles
        for j in range(cnt - 1, -1, -1):  # lane 0 is numbered first
            if cc[j] >= 0:
                todo[sp, 0], todo[sp, 1], todo[sp, 2] = cc[j], k, j
                sp += 1
    return b4[:m].copy(), c4[:m].copy()


def pad_outward(b64: np.ndarray) -> np.ndarray:
    """Child boxes (N, 12) float64 widened by one ulp on every side.

    A ray with a zero direction component has a huge finite reciprocal (:func:`_inv_dir`);
    if its origin lay exactly on a box face, ``(face - o) * inv`` would be 0 instead of
    +-inf and the slab would wrongly shrink to ``t = 0``. With the faces one ulp outside the
    geometry, an origin on a face is outside the geometry, so culling it is right.
    """
    b = b64.reshape(-1, 2, 2, 3)
    out = np.empty_like(b)
    out[:, :, 0] = np.nextafter(b[:, :, 0], -np.inf)
    out[:, :, 1] = np.nextafter(b[:, :, 1], np.inf)
    bad = ~np.isfinite(b)  # the inverted (+inf, -inf) box of an empty child stays as is
    out[bad] = b[bad]
    return np.ascontiguousarray(out.reshape(-1, 12))


def flatten(b64: np.ndarray, child: np.ndarray, perm: np.ndarray) -> FlatBVH:
    """Binary build output -> the traversal layout (4-wide)."""
    b4, c4 = collapse4(pad_outward(b64), child)
    return FlatBVH(b4, c4, perm)


def mesh_triangles(sa, mesh: int) -> np.ndarray:
    """Object-space vertices of mesh ``mesh``'s triangles: (m, 3, 3) float64."""
    s, e = sa.mesh_tri_start[mesh], sa.mesh_tri_start[mesh + 1]
    return sa.verts[sa.tris[s:e]]


def mesh_key(tv: np.ndarray) -> bytes:
    """Content hash of a mesh's triangle vertices (m, 3, 3) float64."""
    return hashlib.blake2b(np.ascontiguousarray(tv).view(np.uint8), digest_size=16).digest()


def build_mesh_bvh(tv: np.ndarray) -> MeshBVH:
    """Bottom-level BVH of one mesh from its triangle vertices (m, 3, 3) float64."""
    t0 = time.perf_counter()
    lo = np.ascontiguousarray(tv.min(axis=1))
    hi = np.ascontiguousarray(tv.max(axis=1))
    b64, child, perm, sah = build_flat(lo, hi, MAX_LEAF, SAH_BINS, SAH_TRAVERSAL_COST)
    flat = flatten(b64, child, perm)
    return MeshBVH(flat, np.ascontiguousarray(tv[perm].reshape(-1, 9)), perm, float(sah),
                   time.perf_counter() - t0)


def build_top(inst_aabb: np.ndarray) -> FlatBVH:
    """Top-level BVH over instance world boxes (I, 2, 3) float64, padded by
    :data:`~.tolerances.INSTANCE_BOX_PAD_REL` of their magnitude (the world->object transform
    of a ray rounds)."""
    lo = inst_aabb[:, 0]
    hi = inst_aabb[:, 1]
    mag = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))
    pad = (tol.INSTANCE_BOX_PAD_REL * (mag + np.linalg.norm(hi - lo, axis=1)))[:, None]
    b64, child, perm, _ = build_flat(np.ascontiguousarray(lo - pad),
                                     np.ascontiguousarray(hi + pad), 1, SAH_BINS,
                                     SAH_TRAVERSAL_COST)
    return flatten(b64, child, perm)


def concat_meshes(meshes: list[MeshBVH], mesh_tri_start: np.ndarray):
    """Concatenate mesh BVHs: returns ``bounds, child, tv, tri (global), mesh_root``."""
    node_base = np.cumsum([0] + [len(m.bvh.child) for m in meshes])
    tri_base = np.cumsum([0] + [len(m.tri) for m in meshes])
    childs = []
    for m, nb, tb in zip(meshes, node_base[:-1], tri_base[:-1], strict=True):
        c = m.bvh.child.astype(np.int64)
        leaf = c < 0
        code = ~c
        moved = ~(((code >> 3) + tb) << 3 | (code & 7))
        childs.append(np.where(leaf & (c != -1), moved, np.where(leaf, c, c + nb)))
    child = np.concatenate(childs)
    if child.min() < np.iinfo(np.int32).min:
        raise OverflowError("BVH: too many triangles for 32-bit leaf codes")
    tri = np.concatenate([m.tri.astype(np.int64) + mesh_tri_start[k]
                          for k, m in enumerate(meshes)])
    return (np.ascontiguousarray(np.concatenate([m.bvh.bounds for m in meshes])),
            np.ascontiguousarray(child.astype(np.int32)),
            np.ascontiguousarray(np.concatenate([m.tv for m in meshes])),
            np.ascontiguousarray(tri.astype(np.int32)),
            node_base[:-1].astype(np.int32))


# ----------------------------------------------------------------------------- traversal


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def ray_to_object(inv, i, ox, oy, oz, dx, dy, dz):
    """World ray -> object space of instance ``i`` with ``inv`` (I, 4, 4) float64.

    The direction is transformed without normalisation, so a distance ``t`` along the
    object-space ray is the same ``t`` along the world ray.
    """
    # element indexing only: a view (inv[i]) would cost a reference count in the hot loop
    return (inv[i, 0, 0] * ox + inv[i, 0, 1] * oy + inv[i, 0, 2] * oz + inv[i, 0, 3],
            inv[i, 1, 0] * ox + inv[i, 1, 1] * oy + inv[i, 1, 2] * oz + inv[i, 1, 3],
            inv[i, 2, 0] * ox + inv[i, 2, 1] * oy + inv[i, 2, 2] * oz + inv[i, 2, 3],
            inv[i, 0, 0] * dx + inv[i, 0, 1] * dy + inv[i, 0, 2] * dz,
            inv[i, 1, 0] * dx + inv[i, 1, 1] * dy + inv[i, 1, 2] * dz,
            inv[i, 2, 0] * dx + inv[i, 2, 1] * dy + inv[i, 2, 2] * dz)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _inv_dir(x):
    # a zero component gets a huge finite reciprocal: (b - o) * inv stays NaN-free
    if x == 0.0:
        return 1e300
    return 1.0 / x


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _lane(bounds, node, j, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1):
    """Entry distance of the ray into lane ``j`` of a 4-wide node; inf when it misses."""
    tn = max(max((bounds[node, nx + j] - ox) * ix, (bounds[node, ny + j] - oy) * iy),
             max((bounds[node, nz + j] - oz) * iz, t0))
    tf = min(min((bounds[node, 12 - nx + j] - ox) * ix, (bounds[node, 20 - ny + j] - oy) * iy),
             min((bounds[node, 28 - nz + j] - oz) * iz, t1))
    if tn <= tf * tol.BOX_TFAR_SCALE:
        return tn
    return np.inf


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _visit(bounds, child, node, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1, st_node, st_t, sp):
    """Test the four children of ``node``; push those hit, farthest first. Returns ``sp``."""
    ta = _lane(bounds, node, 0, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)
    tb = _lane(bounds, node, 1, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)
    tc = _lane(bounds, node, 2, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)
    td = _lane(bounds, node, 3, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1)
    ca, cb, cc, cd = child[node, 0], child[node, 1], child[node, 2], child[node, 3]
    # sorting network, ascending
    if tb < ta:
        ta, tb, ca, cb = tb, ta, cb, ca
    if td < tc:
        tc, td, cc, cd = td, tc, cd, cc
    if tc < ta:
        ta, tc, ca, cc = tc, ta, cc, ca
    if td < tb:
        tb, td, cb, cd = td, tb, cd, cb
    if tc < tb:
        tb, tc, cb, cc = tc, tb, cc, cb
    if td < np.inf:
        st_node[sp], st_t[sp] = cd, td
        sp += 1
    if tc < np.inf:
        st_node[sp], st_t[sp] = cc, tc
        sp += 1
    if tb < np.inf:
        st_node[sp], st_t[sp] = cb, tb
        sp += 1
    if ta < np.inf:
        st_node[sp], st_t[sp] = ca, ta
        sp += 1
    return sp


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _inv_dir(x):
    # tiny or zero components get a huge finite reciprocal: (b - o) * inv stays NaN-free
    if x >= 0.0:
        return 1e300 if x < 1e-300 else 1.0 / x
    return -1e300 if x > -1e-300 else 1.0 / x


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _near(ix, iy, iz):
    """Offsets of the near planes of each axis in a node's SoA bounds."""
    return 0 if ix >= 0.0 else 12, 4 if iy >= 0.0 else 16, 8 if iz >= 0.0 else 20


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cull(best):
    """Nodes entered beyond this are skipped: ``best`` plus
    :data:`~.tolerances.BVH_CULL_REL` of it (a box entry and a triangle distance round
    differently; a node culled by an ulp lost a hit tying within an ulp, and which of the two
    won then depended on the traversal order, i.e. on the other objects)."""
    return best + abs(best) * tol.BVH_CULL_REL


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _trace_mesh(bounds, child, tv, root, ox, oy, oz, dx, dy, dz, t0, best, anyhit,
                st_node, st_t):
    """Closest (or any) hit in one mesh BVH; the ray is in object space.

    Returns ``(found, t, leaf_index, u, v)`` with ``t <= best``.
    """
    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)
    okx = ox if kx == 0 else (oy if kx == 1 else oz)
    oky = ox if ky == 0 else (oy if ky == 1 else oz)
    okz = ox if kz == 0 else (oy if kz == 1 else oz)
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    found = False
    bp, bu, bv = -1, 0.0, 0.0
    st_node[0], st_t[0] = root, t0  # one _visit call site: it is inlined, keep it small
    sp = 1
    while sp > 0:
        sp -= 1
        if st_t[sp] > _cull(best):
            continue
        c = st_node[sp]
        if c >= 0:
            sp = _visit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, _cull(best),
                        st_node, st_t, sp)
            continue
        code = ~c
        s = code >> 3
        for p in range(s, s + (code & 7)):
            hit, t, u, v = intersect_sheared(
                tv[p, kx], tv[p, ky], tv[p, kz], tv[p, 3 + kx], tv[p, 3 + ky], tv[p, 3 + kz],
                tv[p, 6 + kx], tv[p, 6 + ky], tv[p, 6 + kz], okx, oky, okz, sx, sy, sz, t0,
                best)
            if hit:
                found, best, bp, bu, bv = True, t, p, u, v
                if anyhit:
                    return found, best, bp, bu, bv
    return found, best, bp, bu, bv


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _trace_ray(sb, ox, oy, oz, dx, dy, dz, t0, best, anyhit, only, st_node, st_t, st2_node,
               st2_t):
    """One world ray through both levels (or only instance ``only`` when ``only >= 0``).

    Returns ``(inst, t, leaf_index, u, v)``. Each inlined helper has a single call site (the
    instance range ``q..q_end`` of a top-level leaf, or ``only``, is drained before the next
    pop), which keeps the kernel's compile time reasonable.
    """
    bi, bp, bu, bv = -1, -1, 0.0, 0.0
    bounds, child, top_inst = sb.top_bounds, sb.top_child, sb.top_inst
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx, ny, nz = _near(ix, iy, iz)
    sp = 0
    q, q_end = 0, 0
    if only >= 0:
        q_end = 1
    else:
        st_node[0], st_t[0] = 0, t0
        sp = 1
    while True:
        if q < q_end:
            i = only if only >= 0 else top_inst[q]
            q += 1
            lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, i, ox, oy, oz, dx, dy, dz)
            found, t, p, u, v = _trace_mesh(sb.bounds, sb.child, sb.tv,
                                            sb.mesh_root[sb.inst_mesh[i]], lx, ly, lz,
                                            ex, ey, ez, t0, best, anyhit, st2_node, st2_t)
            # t <= best; an equal distance goes to the highest instance id (the oracle's
            # rule), not to whichever instance the top level happened to visit last
            if found and (t < best or i > bi):
                bi, best, bp, bu, bv = i, t, p, u, v
                if anyhit:
                    break
            continue
        if sp == 0:
            break
        sp -= 1
        if st_t[sp] > _cull(best):
            continue
        c = st_node[sp]
        if c >= 0:
            sp = _visit(bounds, child, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, _cull(best),
                        st_node, st_t, sp)
        else:
            q = (~c) >> 3
            q_end = q + ((~c) & 7)
    return bi, best, bp, bu, bv


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def trace_kernel(sb, o, d, tmin, tmax, only, anyhit, out_t, out_inst, out_prim, out_u, out_v,
                 stop):
    """Closest (``anyhit=False``) or any hit of each ray through a :class:`SceneBVH`.

    o, d : (n, 3) float64; tmin, tmax : (n,) float64; only : (n,) int32, ``>= 0`` restricts
    a ray to that instance. Outputs (n,): t float64 (inf on miss), inst int32, prim int32
    (global triangle), u, v float64; rows that miss are left untouched (callers pre-fill
    them). Work items are :data:`CHUNK` consecutive rays; call it under
    ``numba.parallel_chunksize(PARALLEL_CHUNKSIZE)`` (:func:`trace`) so threads take work
    items dynamically (cost per ray varies a lot across an image).

    stop : (1,) int32, read before every work item: once it is non-zero the remaining
    work items are skipped (their rows left as misses) and the result is incomplete, for
    the caller to discard (:mod:`rstrace_engine.cancel`); zero, every ray is traced.
    """
    n = o.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        if stop[0] != 0:
            continue
        st_node = np.empty(STACK_SIZE, np.int32)
        st_t = np.empty(STACK_SIZE)
        st2_node = np.empty(STACK_SIZE, np.int32)
        st2_t = np.empty(STACK_SIZE)
        for r in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if not tmin[r] <= tmax[r]:
                continue
            bi, t, p, u, v = _trace_ray(sb, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1],
                                        d[r, 2], tmin[r], tmax[r], anyhit, only[r], st_node,
                                        st_t, st2_node, st2_t)
            if bi >= 0:
                out_t[r] = t
                out_inst[r] = bi
                out_prim[r] = sb.tri[p]
                out_u[r] = u
                out_v[r] = v


#: The stop flag of queries nobody cancels.
NEVER_STOP = np.zeros(1, np.int32)


def trace(sb: SceneBVH, o, d, tmin, tmax, only, anyhit: bool, hits,
          stop: np.ndarray = NEVER_STOP) -> None:
    """Run :func:`trace_kernel` with dynamic scheduling into ``hits`` (t, inst, prim, u, v);
    ``stop``: its stop flag (a :class:`~rstrace_engine.cancel.CancelFlag`'s ``array``)."""
    with numba.parallel_chunksize(PARALLEL_CHUNKSIZE):
        trace_kernel(sb, o, d, tmin, tmax, only, anyhit, *hits, stop)
