"""Two-level bounding volume hierarchy in numba: the default ray accelerator.

* **Bottom level**: one binned-SAH BVH per *mesh*, in object space, built once and shared by
  every instance of the mesh. Meshes are keyed by a content hash of their triangles, so a new
  packing of the scene reuses every mesh whose geometry did not change.
* **Top level**: a BVH over the instances' world bounds, rebuilt on every update (cheap: one
  primitive per instance). At an instance leaf the ray is taken to object space (direction not
  normalised, so distances stay world distances) and the mesh BVH is traversed.

Layout (flattened, pbrt/pynndescent style): binary nodes that hold the boxes of *both*
children, so one visit tests two boxes and descends front to back.

* ``bounds`` (N, 12) float32: child 0 ``lo xyz, hi xyz``, then child 1; rounded outward from
  float64 so a box always contains its geometry.
* ``child`` (N, 2) int32: ``>= 0`` an inner node; ``< 0`` a leaf ``~(start << 3 | count)``
  over ``count`` (1..7) consecutive primitives in leaf order. An empty child has an inverted
  box (``lo = +inf``) and is never entered.

The box test is the conservative slab test of pbrt-v4 (``t_far`` scaled by
:data:`~.tolerances.BOX_TFAR_SCALE`) and the triangle test is watertight (:mod:`.triangle`),
so no ray slips through a shared edge or vertex.
"""

from __future__ import annotations

import hashlib
import logging
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from . import tolerances as tol
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
#: Traversal stack entries (> DEPTH_CAP + 31: median splits below the cap add <= 31).
STACK_SIZE = 96
#: Rays per parallel work item.
CHUNK = 64


class FlatBVH(NamedTuple):
    """A flattened binary BVH (see the module docstring)."""

    bounds: np.ndarray  # (N, 12) float32, child boxes
    child: np.ndarray  # (N, 2) int32, inner node index or ~(start << 3 | count)
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

    top_bounds: np.ndarray  # (Nt, 12) float32
    top_child: np.ndarray  # (Nt, 2) int32
    top_inst: np.ndarray  # (I,) int32, instance ids in leaf order
    bounds: np.ndarray  # (N, 12) float32, all mesh BVH nodes
    child: np.ndarray  # (N, 2) int32, node and triangle indices already offset
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


@njit(cache=True, nogil=True, error_model="numpy")
def build_flat(lo, hi, max_leaf, nbins, trav_cost):
    """Binned-SAH BVH over primitive boxes.

    lo, hi : (n, 3) float64 primitive bounds (n >= 1)
    Returns ``bounds (N, 12) float64, child (N, 2) int32, perm (n,) int32, sah_cost``
    (``sah_cost`` is the SAH estimate of the whole tree in units of one primitive test).
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
        # --- choose a split: binned SAH over centroid bounds, all three axes
        cmin = np.empty(3)
        cmax = np.empty(3)
        for k in range(3):
            cmin[k] = np.inf
            cmax[k] = -np.inf
        for j in range(start, end):
            p = perm[j]
            for k in range(3):
                cmin[k] = min(cmin[k], cen[p, k])
                cmax[k] = max(cmax[k], cen[p, k])
        best_cost = np.inf
        best_axis = -1
        best_bin = -1
        if count > 1 and depth < DEPTH_CAP:
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
            for k in range(3):
                if cmax[k] - cmin[k] <= 0.0:
                    continue
                # sweep from the right: area and count of bins b.. nbins-1
                rb = np.empty(6)
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
                lb = np.empty(6)
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
        split_cost = trav_cost + best_cost / max(area, 1e-300)
        make_leaf = count <= max_leaf and (count == 1 or count <= split_cost)
        if make_leaf and parent >= 0:
            bounds[parent, 6 * slot:6 * slot + 6] = box
            child[parent, slot] = ~((start << 3) | count)
            sah += count * area / root_area
            continue
        # --- partition perm[start:end]
        if best_axis >= 0 and not make_leaf:
            k = best_axis
            ext = cmax[k] - cmin[k]
            i, j = start, end - 1
            while i <= j:
                b = int((cen[perm[i], k] - cmin[k]) * (nbins / ext))
                b = min(max(b, 0), nbins - 1)
                if b <= best_bin:
                    i += 1
                else:
                    perm[i], perm[j] = perm[j], perm[i]
                    j -= 1
            mid = i
        else:
            # no usable SAH split (coincident centroids, depth cap, or a root that is one
            # leaf): object median along the widest centroid axis
            k = 0
            for q in range(1, 3):
                if cmax[q] - cmin[q] > cmax[k] - cmin[k]:
                    k = q
            mid = (start + end) // 2
            if count > 1:
                keys = np.empty(count)
                for j in range(count):
                    keys[j] = cen[perm[start + j], k]
                order = np.argsort(keys, kind="mergesort")
                seg = perm[start:end].copy()
                for j in range(count):
                    perm[start + j] = seg[order[j]]
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


def outward_f32(bounds64: np.ndarray) -> np.ndarray:
    """(N, 12) float64 child boxes -> float32 rounded outward (lo down, hi up)."""
    b = bounds64.reshape(-1, 2, 2, 3)
    lo = b[:, :, 0].astype(np.float32)
    hi = b[:, :, 1].astype(np.float32)
    with np.errstate(invalid="ignore"):
        lo = np.where(lo > b[:, :, 0], np.nextafter(lo, np.float32(-np.inf)), lo)
        hi = np.where(hi < b[:, :, 1], np.nextafter(hi, np.float32(np.inf)), hi)
    return np.ascontiguousarray(np.stack([lo, hi], axis=2).reshape(-1, 12), dtype=np.float32)


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
    flat = FlatBVH(outward_f32(b64), child, perm)
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
    return FlatBVH(outward_f32(b64), child, perm)


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
        childs.append(np.where(leaf, moved, c + nb))
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
    m = inv[i]
    return (m[0, 0] * ox + m[0, 1] * oy + m[0, 2] * oz + m[0, 3],
            m[1, 0] * ox + m[1, 1] * oy + m[1, 2] * oz + m[1, 3],
            m[2, 0] * ox + m[2, 1] * oy + m[2, 2] * oz + m[2, 3],
            m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz,
            m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz,
            m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _inv_dir(x):
    # a zero component gets a huge finite reciprocal: (b - o) * inv stays NaN-free
    if x == 0.0:
        return 1e300
    return 1.0 / x


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _slab(bounds, node, c, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, t1):
    """Entry distance of the ray into child ``c`` of ``node``, NaN when it misses."""
    o = 6 * c
    tn = max(max((bounds[node, o + nx] - ox) * ix, (bounds[node, o + ny] - oy) * iy),
             max((bounds[node, o + nz] - oz) * iz, t0))
    tf = min(min((bounds[node, o + 3 - nx] - ox) * ix,
                 (bounds[node, o + 5 - ny] - oy) * iy),
             min((bounds[node, o + 7 - nz] - oz) * iz, t1))
    if tn <= tf * tol.BOX_TFAR_SCALE:
        return tn
    return np.nan


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
    nx = 0 if ix >= 0.0 else 3
    ny = 1 if iy >= 0.0 else 4
    nz = 2 if iz >= 0.0 else 5
    found = False
    bp, bu, bv = -1, 0.0, 0.0
    sp = 0
    node = root
    while True:
        ta = _slab(bounds, node, 0, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, best)
        tb = _slab(bounds, node, 1, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, best)
        ca, cb = child[node, 0], child[node, 1]
        if tb < ta or ta != ta:  # nearer first; a miss (NaN) last
            ta, tb = tb, ta
            ca, cb = cb, ca
        nxt = -1
        for step in range(2):
            tn = ta if step == 0 else tb
            c = ca if step == 0 else cb
            if not tn <= best:
                continue
            if c < 0:
                code = ~c
                s = code >> 3
                for p in range(s, s + (code & 7)):
                    hit, t, u, v = intersect_sheared(
                        tv[p, kx], tv[p, ky], tv[p, kz], tv[p, 3 + kx], tv[p, 3 + ky],
                        tv[p, 3 + kz], tv[p, 6 + kx], tv[p, 6 + ky], tv[p, 6 + kz],
                        okx, oky, okz, sx, sy, sz, t0, best)
                    if hit:
                        found, best, bp, bu, bv = True, t, p, u, v
                        if anyhit:
                            return found, best, bp, bu, bv
            elif nxt < 0:
                nxt = c
            else:
                st_node[sp] = c
                st_t[sp] = tn
                sp += 1
        if nxt >= 0:
            node = nxt
            continue
        node = -1
        while sp > 0:
            sp -= 1
            if st_t[sp] <= best:
                node = st_node[sp]
                break
        if node < 0:
            break
    return found, best, bp, bu, bv


@njit(cache=True, nogil=True, error_model="numpy")
def _trace_ray(sb, ox, oy, oz, dx, dy, dz, t0, best, anyhit, only, st_node, st_t, st2_node,
               st2_t):
    """One world ray through both levels. Returns ``(inst, t, leaf_index, u, v)``."""
    bi, bp, bu, bv = -1, -1, 0.0, 0.0
    if only >= 0:
        lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, only, ox, oy, oz, dx, dy, dz)
        found, t, p, u, v = _trace_mesh(sb.bounds, sb.child, sb.tv,
                                        sb.mesh_root[sb.inst_mesh[only]], lx, ly, lz,
                                        ex, ey, ez, t0, best, anyhit, st_node, st_t)
        if found:
            return only, t, p, u, v
        return bi, best, bp, bu, bv
    bounds, child = sb.top_bounds, sb.top_child
    ix, iy, iz = _inv_dir(dx), _inv_dir(dy), _inv_dir(dz)
    nx = 0 if ix >= 0.0 else 3
    ny = 1 if iy >= 0.0 else 4
    nz = 2 if iz >= 0.0 else 5
    sp = 0
    node = 0
    while True:
        ta = _slab(bounds, node, 0, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, best)
        tb = _slab(bounds, node, 1, nx, ny, nz, ox, oy, oz, ix, iy, iz, t0, best)
        ca, cb = child[node, 0], child[node, 1]
        if tb < ta or ta != ta:  # nearer first; a miss (NaN) last
            ta, tb = tb, ta
            ca, cb = cb, ca
        nxt = -1
        for step in range(2):
            tn = ta if step == 0 else tb
            c = ca if step == 0 else cb
            if not tn <= best:
                continue
            if c < 0:
                code = ~c
                s = code >> 3
                for q in range(s, s + (code & 7)):
                    i = sb.top_inst[q]
                    lx, ly, lz, ex, ey, ez = ray_to_object(sb.inst_inv, i, ox, oy, oz,
                                                           dx, dy, dz)
                    found, t, p, u, v = _trace_mesh(sb.bounds, sb.child, sb.tv,
                                                    sb.mesh_root[sb.inst_mesh[i]], lx, ly, lz,
                                                    ex, ey, ez, t0, best, anyhit, st2_node,
                                                    st2_t)
                    if found:
                        bi, best, bp, bu, bv = i, t, p, u, v
                        if anyhit:
                            return bi, best, bp, bu, bv
            elif nxt < 0:
                nxt = c
            else:
                st_node[sp] = c
                st_t[sp] = tn
                sp += 1
        if nxt >= 0:
            node = nxt
            continue
        node = -1
        while sp > 0:
            sp -= 1
            if st_t[sp] <= best:
                node = st_node[sp]
                break
        if node < 0:
            break
    return bi, best, bp, bu, bv


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def trace_kernel(sb, o, d, tmin, tmax, only, anyhit, order, out_t, out_inst, out_prim,
                 out_u, out_v):
    """Closest (``anyhit=False``) or any hit of each ray through a :class:`SceneBVH`.

    o, d : (n, 3) float64; tmin, tmax : (n,) float64; only : (n,) int32, ``>= 0`` restricts
    a ray to that instance; order : (nchunks,) int64, a permutation of the CHUNK-ray work
    items (interleaved, to balance the static schedule). Outputs (n,): t float64 (inf on
    miss), inst int32, prim int32 (global triangle), u, v float64; rows that miss are left
    untouched (callers pre-fill them).
    """
    n = o.shape[0]
    for w in prange(order.shape[0]):
        st_node = np.empty(STACK_SIZE, np.int32)
        st_t = np.empty(STACK_SIZE)
        st2_node = np.empty(STACK_SIZE, np.int32)
        st2_t = np.empty(STACK_SIZE)
        c = order[w]
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


def chunk_order(n: int) -> np.ndarray:
    """Work-item order for :func:`trace_kernel`: chunks interleaved in groups of 16, so a
    static split across threads gives every thread parts of every image region."""
    nchunks = (n + CHUNK - 1) // CHUNK
    return np.argsort(np.arange(nchunks) % 16, kind="stable").astype(np.int64)
