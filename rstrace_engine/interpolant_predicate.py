"""The error predicate of radiance interpolants: surface classes, shafts, per-cell checks.

What a valid cell guarantees (see docs/INTERPOLANTS.md for the argument):

* **Geometry (all meshes, convex or not).** The cell's lines all cross the plane slab
  ``z_lo <= depth <= z_hi`` inside the *slab shaft* ``S'`` (the hexahedron swept by the
  cell's lines between those depths). Every triangle of the object that meets ``S'`` belongs
  to the surface class ``C`` of the 16 corner hits and faces every line of the cell (its
  normal against all 16 corner directions; line directions are affine in ``(a, b, c, d)``,
  so the corners bound them), no boundary edge of the mesh meets ``S'``, and no triangle
  meets the two end rectangles of ``S'``. A winding-number argument then shows that every line
  of the cell crosses the object exactly once inside the slab, entering class ``C``: a pixel
  whose visible hit on the object lies in the slab is that crossing, whatever the viewpoint.
* **Lights.** The 16 corners (and the test lines) agree on every light's state: contributes,
  occluded by the same object, or not facing / outside the cone. For a contributing light, a
  shaft from the slab's box to the light meets no triangle of any other object, and every
  triangle of the object itself inside it faces the light with no boundary edge inside it;
  then no interior point is shadowed (a shadow ray would have to enter the object through a
  triangle facing away from the light). For an occluded light, the shaft meets nothing but
  the object and the named occluder. A light off at every corner must be behind every slab
  triangle (or, if in front of all of them, its shaft must be empty as for a lit light).
* **Reflection / refraction tunnels** (ray-tree nodes below the root): the shaft between the
  padded boxes of the 16 parent points and the 16 node points, and each node's light shafts,
  meet no other object than those the tree names. Secondary hit points of interior lines are
  not bounded exactly (curved mirrors), so this part is conservative only up to the padding
  :data:`~.tolerances.TUNNEL_MARGIN_REL`: tested, not guaranteed.

Triangle queries walk per-mesh binary BVHs built with :func:`.bvh.build_flat` (object space;
a shaft's planes are taken to object space exactly) under a BVH over the instances' world
boxes. Triangles are clipped against a shaft's planes (Sutherland-Hodgman), so the overlap test
is exact up to the planes' outward slack :data:`~.tolerances.SHAFT_SLACK_REL`.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from . import bvh
from . import tolerances as tol
from .frame import CLASS_FAIL_SHADOW, CLASS_FAIL_SILHOUETTE
from .linetree import face_frame, line_points
from .scene import LIGHT_SUN, SceneArrays

log = logging.getLogger(__name__)

#: Predicate outcome of a cell that passed (otherwise a CLASS_FAIL_* code).
VALID = 0
_SIL = CLASS_FAIL_SILHOUETTE
_SHD = CLASS_FAIL_SHADOW
#: Why a cell failed, finer than its pixel class (``check_cells``'s ``detail`` output).
REASONS = ("valid", "corner_miss", "class_change", "light_change", "tree_change", "slab",
           "light_facing", "light_shaft", "self_shadow", "tunnel", "tunnel_light")
(R_VALID, R_MISS, R_CLASS, R_LIGHT, R_TREE, R_SLAB, R_FACING, R_SHAFT, R_SELF, R_TUNNEL,
 R_TUNNEL_LIGHT) = range(len(REASONS))
#: Slab depth margin: half the corners' depth range plus this fraction of the cell's width.
SLAB_WIDTH_MARGIN = 0.25
#: Meshes with more than sqrt(this) triangles are not tested for convexity (the test is
#: quadratic); they count as non-convex, which only adds test lines.
CONVEXITY_TEST_MAX = 4e8
#: Triangles a self query may collect before the cell fails (conservatively).
MAX_CANDIDATES = 4096
#: Most planes a shaft has (6 box planes and 12 edge planes).
MAX_PLANES = 18
_STACK = 128


# ----------------------------------------------------------------------------- topology


class MeshTopology(NamedTuple):
    """Per-triangle surface classes and boundary edges, per-mesh convexity."""

    tri_class: np.ndarray  # (T,) int32 global class id (smooth patch of one material slot)
    tri_boundary: np.ndarray  # (T,) uint8 bit e: edge (v_e, v_e+1) is a boundary edge
    mesh_closed: np.ndarray  # (M,) bool no boundary edge
    mesh_convex: np.ndarray  # (M,) bool closed and convex


@njit(cache=True, nogil=True)
def _find(parent, x):
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit(cache=True, nogil=True)
def _edge_pass(order, key_lo, key_hi, e_tri, e_loc, e_dir, tris_w, normals, uvs, slots,
               parent, boundary, ntol, uvtol):
    """Union smooth manifold edges; mark every other edge as a boundary of its triangles."""
    m = order.shape[0]
    g = 0
    while g < m:
        h = g + 1
        while h < m and key_lo[order[h]] == key_lo[order[g]] \
                and key_hi[order[h]] == key_hi[order[g]]:
            h += 1
        if h - g == 2 and e_dir[order[g]] != e_dir[order[g + 1]]:
            e1 = order[g]
            e2 = order[g + 1]
            t1, t2 = e_tri[e1], e_tri[e2]
            smooth = slots[t1] == slots[t2]
            # corners of the shared edge: in t1 at (l1, l1+1), in t2 reversed
            l1, l2 = e_loc[e1], e_loc[e2]
            for s in range(2):
                c1 = (l1 + s) % 3
                c2 = (l2 + 1 - s) % 3
                for q in range(3):
                    if abs(normals[t1, c1, q] - normals[t2, c2, q]) > ntol:
                        smooth = False
                for q in range(2):
                    if abs(uvs[t1, c1, q] - uvs[t2, c2, q]) > uvtol:
                        smooth = False
            if smooth:
                r1 = _find(parent, t1)
                r2 = _find(parent, t2)
                if r1 != r2:
                    parent[max(r1, r2)] = min(r1, r2)
        else:
            for q in range(g, h):
                e = order[q]
                boundary[e_tri[e]] |= np.uint8(1 << e_loc[e])
        g = h
    for t in range(parent.shape[0]):
        parent[t] = _find(parent, t)


@njit(cache=True, nogil=True)
def _is_convex(verts, tris, lo, hi, tol_abs):
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e1 = verts[b] - verts[a]
        e2 = verts[c] - verts[a]
        n = np.cross(e1, e2)
        ln = math.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
        if ln == 0.0:
            continue
        for v in range(lo, hi):
            s = ((verts[v, 0] - verts[a, 0]) * n[0] + (verts[v, 1] - verts[a, 1]) * n[1]
                 + (verts[v, 2] - verts[a, 2]) * n[2]) / ln
            if s > tol_abs:
                return False
    return True


def mesh_topology(sa: SceneArrays) -> MeshTopology:
    """Surface classes, boundary edges and convexity of every mesh of ``sa``.

    Vertices are welded by exact position per mesh, so a seam of duplicated vertices is
    closed for the boundary test; it still separates classes where normals or uvs jump.
    """
    n_tri = len(sa.tris)
    n_mesh = len(sa.mesh_tri_start) - 1
    tri_mesh = np.repeat(np.arange(n_mesh), np.diff(sa.mesh_tri_start))
    _, weld = np.unique(sa.verts, axis=0, return_inverse=True)
    weld = weld.reshape(-1).astype(np.int64)
    # vertices of different meshes never weld: offset by mesh
    tris_w = weld[sa.tris] + (tri_mesh[:, None].astype(np.int64) * (len(sa.verts) + 1))
    va = tris_w.reshape(-1)
    vb = np.roll(tris_w, -1, axis=1).reshape(-1)
    key_lo = np.minimum(va, vb)
    key_hi = np.maximum(va, vb)
    e_dir = (va < vb).astype(np.int8)
    e_tri = np.repeat(np.arange(n_tri, dtype=np.int64), 3)
    e_loc = np.tile(np.arange(3, dtype=np.int64), n_tri)
    order = np.lexsort((key_hi, key_lo))
    parent = np.arange(n_tri, dtype=np.int64)
    boundary = np.zeros(n_tri, np.uint8)
    _edge_pass(order, key_lo, key_hi, e_tri, e_loc, e_dir, tris_w,
               sa.tri_normals.astype(np.float64), sa.tri_uvs.astype(np.float64),
               sa.tri_slot, parent, boundary, tol.CLASS_NORMAL_TOL, tol.CLASS_UV_TOL)
    closed = np.ones(n_mesh, bool)
    convex = np.zeros(n_mesh, bool)
    for m in range(n_mesh):
        s, e = sa.mesh_tri_start[m], sa.mesh_tri_start[m + 1]
        closed[m] = not np.any(boundary[s:e])
        if closed[m] and (e - s) * (e - s) <= CONVEXITY_TEST_MAX:
            vids = np.unique(sa.tris[s:e])
            v = sa.verts[vids.min():vids.max() + 1]
            diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
            convex[m] = _is_convex(sa.verts, sa.tris[s:e], int(vids.min()), int(vids.max()) + 1,
                                   tol.CONVEX_TOL_REL * diag)
    return MeshTopology(parent.astype(np.int32), boundary, closed, convex)


# ----------------------------------------------------------------------------- query scene


class QueryScene(NamedTuple):
    """What the predicate kernels read: instance and triangle BVHs, topology, lights.

    The BVHs are binary (:func:`.bvh.build_flat`): ``bounds (N, 12)`` float64 holds the boxes
    of both children (``lo xyz, hi xyz`` each), ``child (N, 2)`` an inner node or a leaf
    ``~(start << 3 | count)`` over consecutive primitives in leaf order.
    """

    top_bounds: np.ndarray  # (Nt, 12) float64 instance BVH over world boxes
    top_child: np.ndarray  # (Nt, 2) int32
    top_inst: np.ndarray  # (I,) int32 instance ids in leaf order
    bounds: np.ndarray  # (N, 12) float64 all mesh BVH nodes (object space)
    child: np.ndarray  # (N, 2) int32
    tv: np.ndarray  # (T, 9) float64 triangle vertices in leaf order
    tri: np.ndarray  # (T,) int32 global triangle index
    mesh_root: np.ndarray  # (M,) int32
    inst_mesh: np.ndarray  # (I,) int32
    inst_xform: np.ndarray  # (I, 4, 4) float64
    inst_inv: np.ndarray  # (I, 4, 4) float64
    tri_class: np.ndarray  # (T,) int32 by global triangle
    tri_boundary: np.ndarray  # (T,) uint8 by global triangle
    light_kind: np.ndarray  # (L,) int32
    light_pos: np.ndarray  # (L, 3) float64
    light_dir: np.ndarray  # (L, 3) float64
    scene_center: np.ndarray  # (3,) float64
    extent: float
    slack: float  # absolute outward slack of shaft planes


def _binary_bvh(lo: np.ndarray, hi: np.ndarray, max_leaf: int):
    b, c, perm, _ = bvh.build_flat(np.ascontiguousarray(lo), np.ascontiguousarray(hi),
                                   max_leaf, bvh.SAH_BINS, bvh.SAH_TRAVERSAL_COST)
    return b, c, perm


def query_scene(sa: SceneArrays, topo: MeshTopology) -> QueryScene:
    """Build the predicate's query structures over ``sa`` (binary BVHs of :mod:`.bvh`)."""
    bounds, childs, tvs, tris, roots = [], [], [], [], []
    n_nodes = n_tris = 0
    for m in range(len(sa.mesh_tri_start) - 1):
        tv = bvh.mesh_triangles(sa, m)
        b, c, perm = _binary_bvh(tv.min(axis=1), tv.max(axis=1), bvh.MAX_LEAF)
        c = c.astype(np.int64)
        code = ~c
        c = np.where(c < 0, ~(((code >> 3) + n_tris) << 3 | (code & 7)), c + n_nodes)
        bounds.append(b)
        childs.append(c.astype(np.int32))
        tvs.append(tv[perm].reshape(-1, 9))
        tris.append(perm.astype(np.int64) + sa.mesh_tri_start[m])
        roots.append(n_nodes)
        n_nodes += len(b)
        n_tris += len(perm)
    lo, hi = sa.inst_aabb[:, 0], sa.inst_aabb[:, 1]
    mag = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))
    pad = (tol.INSTANCE_BOX_PAD_REL * (mag + np.linalg.norm(hi - lo, axis=1)))[:, None]
    tb, tc, tperm = _binary_bvh(lo - pad, hi + pad, 1)
    lo_s, hi_s = sa.scene_aabb
    mag = float(sa.scene_extent + np.max(np.abs(sa.scene_aabb)))
    return QueryScene(tb, tc, tperm.astype(np.int32), np.concatenate(bounds),
                      np.concatenate(childs), np.ascontiguousarray(np.concatenate(tvs)),
                      np.concatenate(tris).astype(np.int32), np.array(roots, np.int32),
                      np.ascontiguousarray(sa.inst_mesh, np.int32), sa.inst_xform, sa.inst_inv,
                      topo.tri_class, topo.tri_boundary, sa.light_kind,
                      sa.light_pos.reshape(-1, 3), sa.light_dir.reshape(-1, 3),
                      0.5 * (lo_s + hi_s), float(sa.scene_extent), tol.SHAFT_SLACK_REL * mag)


# ----------------------------------------------------------------------------- shafts


@njit(cache=True, nogil=True)
def hw_shaft(alo, ahi, blo, bhi, slack, pl, bb):
    """Haines-Wallace shaft between boxes A and B: writes planes ``pl`` (>= 18, 4) and the
    joint box ``bb`` (6,); returns the plane count. Inside: ``n . x + d >= 0``; every plane
    is moved outward by ``slack``. Degenerate boxes (a point light) are fine."""
    for k in range(3):
        bb[k] = min(alo[k], blo[k])
        bb[3 + k] = max(ahi[k], bhi[k])
    npl = 0
    for k in range(3):
        pl[npl, 0] = 0.0
        pl[npl, 1] = 0.0
        pl[npl, 2] = 0.0
        pl[npl, k] = 1.0
        pl[npl, 3] = -bb[k] + slack
        npl += 1
        pl[npl, 0] = 0.0
        pl[npl, 1] = 0.0
        pl[npl, 2] = 0.0
        pl[npl, k] = -1.0
        pl[npl, 3] = bb[3 + k] + slack
        npl += 1
    for u in range(3):
        for v in range(u + 1, 3):
            for su in range(2):
                for sv in range(2):
                    au = alo[u] if su == 0 else ahi[u]
                    bu = blo[u] if su == 0 else bhi[u]
                    av = alo[v] if sv == 0 else ahi[v]
                    bv = blo[v] if sv == 0 else bhi[v]
                    a_u = au < bu if su == 0 else au > bu
                    b_u = bu < au if su == 0 else bu > au
                    a_v = av < bv if sv == 0 else av > bv
                    b_v = bv < av if sv == 0 else bv > av
                    if not ((a_u and b_v) or (b_u and a_v)):
                        continue
                    nu = -(bv - av)
                    nv = bu - au
                    ln = math.sqrt(nu * nu + nv * nv)
                    if ln == 0.0:
                        continue
                    nu /= ln
                    nv /= ln
                    cu = 0.25 * (alo[u] + ahi[u] + blo[u] + bhi[u])
                    cv = 0.25 * (alo[v] + ahi[v] + blo[v] + bhi[v])
                    if nu * (cu - au) + nv * (cv - av) < 0.0:
                        nu = -nu
                        nv = -nv
                    pl[npl, 0] = 0.0
                    pl[npl, 1] = 0.0
                    pl[npl, 2] = 0.0
                    pl[npl, u] = nu
                    pl[npl, v] = nv
                    pl[npl, 3] = -(nu * au + nv * av) + slack
                    npl += 1
    return npl


@njit(cache=True, nogil=True)
def _hexa_planes(V, slack, pl):
    """Planes of a hexahedron with box topology (vertex bit0 i, bit1 j, bit2 depth):
    order i-min, i-max, j-min, j-max, z-lo, z-hi, each moved outward by ``slack``."""
    faces = ((0, 2, 4), (1, 5, 3), (0, 4, 1), (2, 3, 6), (0, 1, 2), (4, 6, 5))
    cx = cy = cz = 0.0
    for v in range(8):
        cx += V[v, 0] / 8.0
        cy += V[v, 1] / 8.0
        cz += V[v, 2] / 8.0
    for f in range(6):
        p0, p1, p2 = faces[f]
        e1 = V[p1] - V[p0]
        e2 = V[p2] - V[p0]
        n = np.cross(e1, e2)
        ln = math.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
        if ln > 0.0:
            n /= ln
        d = -(n[0] * V[p0, 0] + n[1] * V[p0, 1] + n[2] * V[p0, 2])
        if n[0] * cx + n[1] * cy + n[2] * cz + d < 0.0:
            n = -n
            d = -d
        pl[f, 0] = n[0]
        pl[f, 1] = n[1]
        pl[f, 2] = n[2]
        pl[f, 3] = d + slack


@njit(cache=True, nogil=True)
def _to_object(xf, inv, pl, npl, bb, plo, bbo):
    """Planes and box of a world shaft in an instance's object space (exact for planes)."""
    for p in range(npl):
        nx, ny, nz = pl[p, 0], pl[p, 1], pl[p, 2]
        plo[p, 0] = xf[0, 0] * nx + xf[1, 0] * ny + xf[2, 0] * nz
        plo[p, 1] = xf[0, 1] * nx + xf[1, 1] * ny + xf[2, 1] * nz
        plo[p, 2] = xf[0, 2] * nx + xf[1, 2] * ny + xf[2, 2] * nz
        plo[p, 3] = nx * xf[0, 3] + ny * xf[1, 3] + nz * xf[2, 3] + pl[p, 3]
    for k in range(3):
        bbo[k] = np.inf
        bbo[3 + k] = -np.inf
    for c in range(8):
        x = bb[3] if c & 1 else bb[0]
        y = bb[4] if c & 2 else bb[1]
        z = bb[5] if c & 4 else bb[2]
        for k in range(3):
            w = inv[k, 0] * x + inv[k, 1] * y + inv[k, 2] * z + inv[k, 3]
            bbo[k] = min(bbo[k], w)
            bbo[3 + k] = max(bbo[3 + k], w)
    # rounding of the transform: grow the box a little
    pad = 1e-12 * (abs(bbo[0]) + abs(bbo[1]) + abs(bbo[2]) + abs(bbo[3]) + abs(bbo[4])
                   + abs(bbo[5]) + (bbo[3] - bbo[0]) + (bbo[4] - bbo[1]) + (bbo[5] - bbo[2]))
    for k in range(3):
        bbo[k] -= pad
        bbo[3 + k] += pad


@njit(cache=True, nogil=True)
def _box_out(pl, npl, bb, bounds, node, c):
    """Child ``c`` of BVH node ``node`` lies outside the shaft (box or some plane)."""
    o = 6 * c
    lx, ly, lz = bounds[node, o], bounds[node, o + 1], bounds[node, o + 2]
    hx, hy, hz = bounds[node, o + 3], bounds[node, o + 4], bounds[node, o + 5]
    if lx > hx or hx < bb[0] or hy < bb[1] or hz < bb[2] or lx > bb[3] or ly > bb[4] \
            or lz > bb[5]:
        return True
    for p in range(npl):
        px = hx if pl[p, 0] > 0.0 else lx
        py = hy if pl[p, 1] > 0.0 else ly
        pz = hz if pl[p, 2] > 0.0 else lz
        if pl[p, 0] * px + pl[p, 1] * py + pl[p, 2] * pz + pl[p, 3] < 0.0:
            return True
    return False


@njit(cache=True, nogil=True)
def clip_polygon(pl, p0, p1, P, n, Q):
    """Clip convex polygon ``P[:n]`` (n >= 3) by planes ``p0 <= p < p1`` of ``pl`` (keep
    ``n . x + d >= 0``); the result is left in ``P``. ``Q`` is scratch of the same size
    (>= n + p1 - p0 rows). Returns the vertex count (0: nothing left)."""
    for p in range(p0, p1):
        if n == 0:
            return 0
        m = 0
        for a in range(n):
            b = a + 1 if a + 1 < n else 0
            da = pl[p, 0] * P[a, 0] + pl[p, 1] * P[a, 1] + pl[p, 2] * P[a, 2] + pl[p, 3]
            db = pl[p, 0] * P[b, 0] + pl[p, 1] * P[b, 1] + pl[p, 2] * P[b, 2] + pl[p, 3]
            if da >= 0.0:
                Q[m, 0] = P[a, 0]
                Q[m, 1] = P[a, 1]
                Q[m, 2] = P[a, 2]
                m += 1
            if (da >= 0.0) != (db >= 0.0):
                s = da / (da - db)
                Q[m, 0] = P[a, 0] + s * (P[b, 0] - P[a, 0])
                Q[m, 1] = P[a, 1] + s * (P[b, 1] - P[a, 1])
                Q[m, 2] = P[a, 2] + s * (P[b, 2] - P[a, 2])
                m += 1
        for a in range(m):
            P[a, 0] = Q[a, 0]
            P[a, 1] = Q[a, 1]
            P[a, 2] = Q[a, 2]
        n = m
    return n


@njit(cache=True, nogil=True)
def segment_in(pl, npl, ax, ay, az, bx, by, bz):
    """Does segment a-b meet the intersection of the half-spaces ``pl[:npl]``?"""
    t0 = 0.0
    t1 = 1.0
    for p in range(npl):
        da = pl[p, 0] * ax + pl[p, 1] * ay + pl[p, 2] * az + pl[p, 3]
        db = pl[p, 0] * bx + pl[p, 1] * by + pl[p, 2] * bz + pl[p, 3]
        if da < 0.0 and db < 0.0:
            return False
        if da < 0.0:
            t0 = max(t0, da / (da - db))
        elif db < 0.0:
            t1 = min(t1, da / (da - db))
        if t0 > t1:
            return False
    return True


@njit(cache=True, nogil=True)
def _load_tri(tv, t, P):
    for v in range(3):
        P[v, 0] = tv[t, 3 * v]
        P[v, 1] = tv[t, 3 * v + 1]
        P[v, 2] = tv[t, 3 * v + 2]


@njit(cache=True, nogil=True)
def _tri_in(tv, t, plo, npl, P, Q):
    _load_tri(tv, t, P)
    return clip_polygon(plo, 0, npl, P, 3, Q) > 0


@njit(cache=True, nogil=True)
def mesh_candidates(qs, m, plo, npl, bbo, out, P, Q):
    """Leaf-order triangles of mesh ``m`` meeting the (object-space) shaft; writes them to
    ``out`` and returns their count, or -1 when ``out`` is too small."""
    stack = np.empty(_STACK, np.int32)
    sp = 0
    stack[0] = qs.mesh_root[m]
    sp = 1
    cnt = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(2):
            if _box_out(plo, npl, bbo, qs.bounds, node, c):
                continue
            ch = qs.child[node, c]
            if ch >= 0:
                if sp >= _STACK:
                    return -1
                stack[sp] = ch
                sp += 1
            else:
                code = ~ch
                start = code >> 3
                for t in range(start, start + (code & 7)):
                    if _tri_in(qs.tv, t, plo, npl, P, Q):
                        if cnt >= out.shape[0]:
                            return -1
                        out[cnt] = t
                        cnt += 1
    return cnt


@njit(cache=True, nogil=True)
def other_geometry(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q):
    """Does a triangle of an instance not in ``named[:n_named]`` meet the world shaft?"""
    stack = np.empty(_STACK, np.int32)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(2):
            if _box_out(pl, npl, bb, qs.top_bounds, node, c):
                continue
            ch = qs.top_child[node, c]
            if ch >= 0:
                if sp >= _STACK:
                    return True
                stack[sp] = ch
                sp += 1
                continue
            code = ~ch
            start = code >> 3
            for q in range(start, start + (code & 7)):
                inst = qs.top_inst[q]
                skip = False
                for k in range(n_named):
                    if named[k] == inst:
                        skip = True
                if skip:
                    continue
                _to_object(qs.inst_xform[inst], qs.inst_inv[inst], pl, npl, bb, plo, bbo)
                if _mesh_any(qs, qs.inst_mesh[inst], plo, npl, bbo, P, Q):
                    return True
    return False


@njit(cache=True, nogil=True)
def _mesh_any(qs, m, plo, npl, bbo, P, Q):
    stack = np.empty(_STACK, np.int32)
    stack[0] = qs.mesh_root[m]
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(2):
            if _box_out(plo, npl, bbo, qs.bounds, node, c):
                continue
            ch = qs.child[node, c]
            if ch >= 0:
                if sp >= _STACK:
                    return True
                stack[sp] = ch
                sp += 1
            else:
                code = ~ch
                start = code >> 3
                for t in range(start, start + (code & 7)):
                    if _tri_in(qs.tv, t, plo, npl, P, Q):
                        return True
    return False


@njit(cache=True, nogil=True)
def _boundary_edge_in(qs, t, plo, npl):
    """Does a boundary edge of leaf-order triangle ``t`` meet the (object-space) shaft?"""
    mask = qs.tri_boundary[qs.tri[t]]
    if mask == 0:
        return False
    tv = qs.tv
    for e in range(3):
        if not (mask >> e) & 1:
            continue
        f = (e + 1) % 3
        if segment_in(plo, npl, tv[t, 3 * e], tv[t, 3 * e + 1], tv[t, 3 * e + 2],
                      tv[t, 3 * f], tv[t, 3 * f + 1], tv[t, 3 * f + 2]):
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _tri_normal(tv, t):
    e1x = tv[t, 3] - tv[t, 0]
    e1y = tv[t, 4] - tv[t, 1]
    e1z = tv[t, 5] - tv[t, 2]
    e2x = tv[t, 6] - tv[t, 0]
    e2y = tv[t, 7] - tv[t, 1]
    e2z = tv[t, 8] - tv[t, 2]
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x


@njit(cache=True, nogil=True)
def light_side(qs, inv, t, j, nx, ny, nz):
    """Side of leaf-order triangle ``t`` (object-space normal n) facing light ``j``:
    1 faces it, -1 faces away, 0 undecided (within the tolerance)."""
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if qs.light_kind[j] == LIGHT_SUN:
        wx, wy, wz = -qs.light_dir[j, 0], -qs.light_dir[j, 1], -qs.light_dir[j, 2]
        lx = inv[0, 0] * wx + inv[0, 1] * wy + inv[0, 2] * wz
        ly = inv[1, 0] * wx + inv[1, 1] * wy + inv[1, 2] * wz
        lz = inv[2, 0] * wx + inv[2, 1] * wy + inv[2, 2] * wz
        s = nx * lx + ny * ly + nz * lz
        lim = tol.FACING_EPS_REL * ln * math.sqrt(lx * lx + ly * ly + lz * lz)
        return 1 if s > lim else (-1 if s < -lim else 0)
    px, py, pz = qs.light_pos[j, 0], qs.light_pos[j, 1], qs.light_pos[j, 2]
    ox = inv[0, 0] * px + inv[0, 1] * py + inv[0, 2] * pz + inv[0, 3]
    oy = inv[1, 0] * px + inv[1, 1] * py + inv[1, 2] * pz + inv[1, 3]
    oz = inv[2, 0] * px + inv[2, 1] * py + inv[2, 2] * pz + inv[2, 3]
    side = 2
    for v in range(3):
        dx = ox - qs.tv[t, 3 * v]
        dy = oy - qs.tv[t, 3 * v + 1]
        dz = oz - qs.tv[t, 3 * v + 2]
        s = nx * dx + ny * dy + nz * dz
        lim = tol.FACING_EPS_REL * ln * math.sqrt(dx * dx + dy * dy + dz * dz)
        sv = 1 if s > lim else (-1 if s < -lim else 0)
        if side == 2:
            side = sv
        elif side != sv:
            side = 0
    return side


@njit(cache=True, nogil=True)
def light_box(qs, j, lo, hi, blo, bhi):
    """The far end of light ``j``'s shaft from box (lo, hi): the light's point, or for a
    sun the box moved far beyond the scene toward the sun."""
    if qs.light_kind[j] == LIGHT_SUN:
        far = 0.0
        for k in range(3):
            c = 0.5 * (lo[k] + hi[k]) - qs.scene_center[k]
            far += c * c
        far = 4.0 * (math.sqrt(far) + qs.extent + (hi[0] - lo[0]) + (hi[1] - lo[1])
                     + (hi[2] - lo[2]))
        for k in range(3):
            blo[k] = lo[k] - qs.light_dir[j, k] * far
            bhi[k] = hi[k] - qs.light_dir[j, k] * far
    else:
        for k in range(3):
            blo[k] = qs.light_pos[j, k]
            bhi[k] = qs.light_pos[j, k]


# ----------------------------------------------------------------------------- per cell


class SampleArrays(NamedTuple):
    """Traced lines (corner and test samples) and their ray trees, for the kernels."""

    rad: np.ndarray  # (S, 3) float64 radiance
    inst: np.ndarray  # (S,) int32 instance of the slab crossing, -1 when none
    cls: np.ndarray  # (S,) int32 surface class of the crossing
    depth: np.ndarray  # (S,) float64 depth of the crossing below the front face
    node_start: np.ndarray  # (S,) int64 first ray-tree node (the root) in the node arrays
    node_count: np.ndarray  # (S,) int32
    node_path: np.ndarray  # (Nn,) int64 root 1, reflect 2p, refract 2p + 1
    node_inst: np.ndarray  # (Nn,) int32, -1 miss
    node_cls: np.ndarray  # (Nn,) int32, -1 miss
    node_occ: np.ndarray  # (Nn, L) int32 occluder per light (-1 none, -2 not facing)
    node_point: np.ndarray  # (Nn, 3) float64


@njit(cache=True, nogil=True)
def _same_tree(sm, s, r):
    """R_VALID when samples s and r have the same position-independent ray tree, else
    R_CLASS (the root differs), R_LIGHT (a light's state differs) or R_TREE."""
    n = sm.node_count[s]
    if sm.node_count[r] != n:
        return R_TREE
    a = sm.node_start[s]
    b = sm.node_start[r]
    L = sm.node_occ.shape[1]
    for q in range(n):
        if sm.node_path[a + q] != sm.node_path[b + q] or sm.node_inst[a + q] \
                != sm.node_inst[b + q] or sm.node_cls[a + q] != sm.node_cls[b + q]:
            return R_CLASS if q == 0 else R_TREE
        for j in range(L):
            if sm.node_occ[a + q, j] != sm.node_occ[b + q, j]:
                return R_LIGHT
    return R_VALID


@njit(cache=True, nogil=True)
def _points_box(sm, ids, ns, q, margin_rel, slack, lo, hi):
    """Box of node ``q``'s points over samples ``ids[:ns]``, padded."""
    for k in range(3):
        lo[k] = np.inf
        hi[k] = -np.inf
    for u in range(ns):
        row = sm.node_start[ids[u]] + q
        for k in range(3):
            lo[k] = min(lo[k], sm.node_point[row, k])
            hi[k] = max(hi[k], sm.node_point[row, k])
    pad = margin_rel * math.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2
                                 + (hi[2] - lo[2]) ** 2) + slack
    for k in range(3):
        lo[k] -= pad
        hi[k] += pad


@njit(cache=True, nogil=True)
def _slab(box, inst, face, depth, coord, zmin, zmax, V):
    """Slab shaft of a cell around depths [zmin, zmax]: its 8 vertices in ``V``; returns
    (z_lo, z_hi)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    s = 1.0 / (1 << depth)
    a0 = li + coord[0] * s * wi
    a1 = li + (coord[0] + 1) * s * wi
    b0 = lj + coord[1] * s * wj
    b1 = lj + (coord[1] + 1) * s * wj
    c0 = li + coord[2] * s * wi
    c1 = li + (coord[2] + 1) * s * wi
    d0 = lj + coord[3] * s * wj
    d1 = lj + (coord[3] + 1) * s * wj
    zm = 0.5 * (zmin + zmax) / L
    w = max((1 - zm) * (a1 - a0) + zm * (c1 - c0), (1 - zm) * (b1 - b0) + zm * (d1 - d0))
    margin = 0.5 * (zmax - zmin) + SLAB_WIDTH_MARGIN * w + 1e-9 * L
    zlo = max(zmin - margin, 0.0)
    zhi = min(zmax + margin, L)
    for v in range(8):
        z = zhi if v & 4 else zlo
        f = z / L
        x = (1 - f) * (a1 if v & 1 else a0) + f * (c1 if v & 1 else c0)
        y = (1 - f) * (b1 if v & 2 else b0) + f * (d1 if v & 2 else d0)
        V[v, k] = front - z if neg else front + z
        V[v, i] = x
        V[v, j] = y
    return zlo, zhi


@njit(cache=True, nogil=True)
def _self_slab(qs, inst, cls, dirs, pl, bb, cand, P, Q, fac, bfac, hb):
    """Geometry test of the slab shaft ``pl`` (6 planes, world) against the object itself.

    dirs (16, 3) world corner directions. Sets per light ``fac[j]`` / ``bfac[j]`` when some
    slab triangle faces / faces away from light j, and ``hb`` (6,) to the world box of the
    object's surface inside the slab (which holds every slab crossing). Returns True when
    the cell passes.
    """
    xf = qs.inst_xform[inst]
    inv = qs.inst_inv[inst]
    plo = np.empty((6, 4))
    bbo = np.empty(6)
    _to_object(xf, inv, pl, 6, bb, plo, bbo)
    m = qs.inst_mesh[inst]
    nc = mesh_candidates(qs, m, plo, 6, bbo, cand, P, Q)
    if nc < 0:
        return False
    do = np.empty((16, 3))
    for c in range(16):
        for k in range(3):
            do[c, k] = inv[k, 0] * dirs[c, 0] + inv[k, 1] * dirs[c, 1] + inv[k, 2] * dirs[c, 2]
    L = qs.light_kind.shape[0]
    for k in range(3):
        hb[k] = np.inf
        hb[3 + k] = -np.inf
    for q in range(nc):
        t = cand[q]
        if qs.tri_class[qs.tri[t]] != cls:
            return False
        _load_tri(qs.tv, t, P)
        nv = clip_polygon(plo, 0, 6, P, 3, Q)
        for v in range(nv):
            for k in range(3):
                w = xf[k, 0] * P[v, 0] + xf[k, 1] * P[v, 1] + xf[k, 2] * P[v, 2] + xf[k, 3]
                hb[k] = min(hb[k], w)
                hb[3 + k] = max(hb[3 + k], w)
        nx, ny, nz = _tri_normal(qs.tv, t)
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        for c in range(16):
            s = nx * do[c, 0] + ny * do[c, 1] + nz * do[c, 2]
            dl = math.sqrt(do[c, 0] ** 2 + do[c, 1] ** 2 + do[c, 2] ** 2)
            if not s < -tol.FACING_EPS_REL * ln * dl:
                return False
        if _boundary_edge_in(qs, t, plo, 6):
            return False
        # the end rectangles: clip by the four side planes, then look for a crossing of the
        # z-lo / z-hi planes
        _load_tri(qs.tv, t, P)
        n = clip_polygon(plo, 0, 4, P, 3, Q)
        for e in range(4, 6):
            lo_s = np.inf
            hi_s = -np.inf
            for v in range(n):
                s = plo[e, 0] * P[v, 0] + plo[e, 1] * P[v, 1] + plo[e, 2] * P[v, 2] \
                    + plo[e, 3] - qs.slack
                lo_s = min(lo_s, s)
                hi_s = max(hi_s, s)
            if n > 0 and lo_s <= qs.slack and hi_s >= -qs.slack:
                return False
        for j in range(L):
            side = light_side(qs, inv, t, j, nx, ny, nz)
            if side >= 0:
                fac[j] = True
            if side <= 0:
                bfac[j] = True
    return True


@njit(cache=True, nogil=True)
def _self_shadow(qs, inst, j, pl, npl, bb, cand, P, Q):
    """Every triangle of the object inside light j's shaft faces the light, and no boundary
    edge of it is inside the shaft."""
    xf = qs.inst_xform[inst]
    inv = qs.inst_inv[inst]
    plo = np.empty((MAX_PLANES, 4))
    bbo = np.empty(6)
    _to_object(xf, inv, pl, npl, bb, plo, bbo)
    nc = mesh_candidates(qs, qs.inst_mesh[inst], plo, npl, bbo, cand, P, Q)
    if nc < 0:
        return False
    for q in range(nc):
        t = cand[q]
        nx, ny, nz = _tri_normal(qs.tv, t)
        if light_side(qs, inv, t, j, nx, ny, nz) != 1:
            return False
        if _boundary_edge_in(qs, t, plo, npl):
            return False
    return True


@njit(cache=True, nogil=True)
def _light_shafts(qs, sm, s0, row, inst, lo, hi, self_ok, fac, bfac, cand, P, Q, pl, bb,
                  plo, bbo, named):
    """Light tests of one ray-tree node (row offset ``row`` in sample ``s0``) whose points
    lie in box (lo, hi) on instance ``inst``. ``self_ok``: run the self-shadow test (root
    level, where the slab facing flags ``fac``/``bfac`` are known). Returns R_VALID or the
    reason (R_FACING, R_SHAFT, R_SELF; the caller maps these below the root)."""
    L = qs.light_kind.shape[0]
    blo = np.empty(3)
    bhi = np.empty(3)
    for j in range(L):
        occ = sm.node_occ[sm.node_start[s0] + row, j]
        lit = occ == -1
        if occ == -2:
            if not self_ok:
                continue  # below the root: tested only
            if bfac[j] and not fac[j]:
                continue  # behind every slab triangle: off for every line
            if bfac[j]:
                return R_FACING  # the light's facing changes inside the cell
            lit = True  # facing every slab triangle: may contribute inside, treat as lit
        light_box(qs, j, lo, hi, blo, bhi)
        npl = hw_shaft(lo, hi, blo, bhi, qs.slack, pl, bb)
        named[0] = inst
        n_named = 1
        if not lit:
            named[1] = occ
            n_named = 2
        if other_geometry(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q):
            return R_SHAFT
        if lit and self_ok:
            if bfac[j] or not _self_shadow(qs, inst, j, pl, npl, bb, cand, P, Q):
                return R_SELF
    return R_VALID


@njit(cache=True, nogil=True, parallel=True)
def check_cells(qs, box, sm, cell_inst, cell_face, cell_depth, cell_coord, cell_samples,
                cell_nsamp, status, detail, zlo_out, zhi_out, cls_out):
    """Geometric part of the error predicate for a batch of cells.

    cell_samples (nc, S) int32 sample ids: the 16 corners (bit order of
    :func:`~.linetree.corner_weight`) then the test lines; cell_nsamp (nc,) how many.
    Outputs: status (nc,) int32 VALID or a CLASS_FAIL_* code, detail (nc,) int8 an index
    into :data:`REASONS`; the slab (zlo, zhi) and the surface class of valid cells.
    """
    L = qs.light_kind.shape[0]
    for c in prange(cell_inst.shape[0]):
        r = _check_one(qs, box, sm, cell_inst[c], cell_face[c], cell_depth[c], cell_coord[c],
                       cell_samples[c], cell_nsamp[c], L, zlo_out, zhi_out, cls_out, c)
        detail[c] = r
        status[c] = VALID if r == R_VALID else (
            _SIL if r == R_MISS or r == R_CLASS or r == R_SLAB else _SHD)


@njit(cache=True, nogil=True)
def _check_one(qs, box, sm, inst, face, depth, coord, ids, ns, L, zlo_out, zhi_out, cls_out,
               c):
    s0 = ids[0]
    cls = sm.cls[s0]
    for u in range(ns):
        s = ids[u]
        if sm.inst[s] != inst:
            return R_MISS
        if sm.cls[s] != cls:
            return R_CLASS
    for u in range(1, ns):
        r = _same_tree(sm, s0, ids[u])
        if r != R_VALID:
            return r
    zmin = np.inf
    zmax = -np.inf
    for u in range(ns):
        zmin = min(zmin, sm.depth[ids[u]])
        zmax = max(zmax, sm.depth[ids[u]])
    V = np.empty((8, 3))
    zlo, zhi = _slab(box, inst, face, depth, coord, zmin, zmax, V)
    pl = np.empty((MAX_PLANES, 4))
    _hexa_planes(V, qs.slack, pl)
    bb = np.empty(6)
    for k in range(3):
        bb[k] = np.inf
        bb[3 + k] = -np.inf
        for v in range(8):
            bb[k] = min(bb[k], V[v, k])
            bb[3 + k] = max(bb[3 + k], V[v, k])
    # corner directions
    dirs = np.empty((16, 3))
    F = np.empty(3)
    B = np.empty(3)
    sc = 1.0 / (1 << depth)
    for q in range(16):
        line_points(box, inst, face, (coord[0] + (q & 1)) * sc,
                    (coord[1] + ((q >> 1) & 1)) * sc, (coord[2] + ((q >> 2) & 1)) * sc,
                    (coord[3] + ((q >> 3) & 1)) * sc, F, B)
        for m in range(3):
            dirs[q, m] = B[m] - F[m]
    cand = np.empty(MAX_CANDIDATES, np.int32)
    P = np.empty((MAX_PLANES + 8, 3))
    Q = np.empty((MAX_PLANES + 8, 3))
    fac = np.zeros(max(L, 1), np.bool_)
    bfac = np.zeros(max(L, 1), np.bool_)
    hb = np.empty(6)
    if not _self_slab(qs, inst, cls, dirs, pl, bb, cand, P, Q, fac, bfac, hb):
        return R_SLAB
    # the light shafts and the first tunnels start from the surface inside the slab
    if hb[0] > hb[3]:
        hb[:] = bb
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        hb[k] -= qs.slack
        hb[3 + k] += qs.slack
        lo[k] = hb[k]
        hi[k] = hb[3 + k]
    spl = np.empty((MAX_PLANES, 4))
    sbb = np.empty(6)
    plo = np.empty((MAX_PLANES, 4))
    bbo = np.empty(6)
    named = np.empty(2, np.int32)
    r = _light_shafts(qs, sm, s0, 0, inst, lo, hi, True, fac, bfac, cand, P, Q, spl, sbb,
                      plo, bbo, named)
    if r != R_VALID:
        return r
    # reflection / refraction tunnels and their lights
    nn = sm.node_count[s0]
    base = sm.node_start[s0]
    plo_ = np.empty(3)
    phi_ = np.empty(3)
    for q in range(1, nn):
        ppath = sm.node_path[base + q] >> 1
        pq = 0
        for x in range(q):
            if sm.node_path[base + x] == ppath:
                pq = x
        if pq == 0:
            for k in range(3):
                plo_[k] = hb[k]
                phi_[k] = hb[3 + k]
        else:
            _points_box(sm, ids, ns, pq, tol.TUNNEL_MARGIN_REL, qs.slack, plo_, phi_)
        _points_box(sm, ids, ns, q, tol.TUNNEL_MARGIN_REL, qs.slack, lo, hi)
        npl = hw_shaft(plo_, phi_, lo, hi, qs.slack, spl, sbb)
        named[0] = sm.node_inst[base + pq]
        named[1] = sm.node_inst[base + q]
        if other_geometry(qs, spl, npl, sbb, named, 2, plo, bbo, P, Q):
            return R_TUNNEL
        if sm.node_inst[base + q] >= 0:
            r = _light_shafts(qs, sm, s0, q, sm.node_inst[base + q], lo, hi, False, fac, bfac,
                              cand, P, Q, spl, sbb, plo, bbo, named)
            if r != R_VALID:
                return R_TUNNEL_LIGHT
    zlo_out[c] = zlo
    zhi_out[c] = zhi
    cls_out[c] = cls
    return R_VALID
