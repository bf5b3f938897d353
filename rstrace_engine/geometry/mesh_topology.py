"""Surface classes, boundary edges and convexity of meshes (for the interpolant predicate).

* A **surface class** is a smooth patch: adjacent triangles (vertices welded by exact
  position) are in one class when they use the same material slot and their per-corner
  shading normals and uvs agree at the shared edge (:data:`~.tolerances.CLASS_NORMAL_TOL`,
  :data:`~.tolerances.CLASS_UV_TOL`). A box has one class per face; a smooth sphere or torus
  is one class. Class ids are global (the smallest triangle index of the class).
* A **boundary edge** is an edge used by one triangle, by more than two, or twice in the same
  direction (inconsistent winding).
* A mesh is **convex** when it is closed and no vertex lies in front of any triangle's plane
  (:data:`~.tolerances.CONVEX_TOL_REL` of its diagonal).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import tolerances as tol
from .attributes import scene_corners, slots_of
from .scene import SceneArrays

#: Meshes with more than sqrt(this) triangles are not tested for convexity (the test is
#: quadratic); they count as non-convex, which only adds test lines.
CONVEXITY_TEST_MAX = 4e8


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
               scene_corners(sa, "normals").astype(np.float64),
               scene_corners(sa, "uvs").astype(np.float64),
               slots_of(sa, tri_mesh, np.arange(n_tri)).astype(np.int32), parent, boundary,
               tol.CLASS_NORMAL_TOL, tol.CLASS_UV_TOL)
    closed = np.ones(n_mesh, bool)
    convex = np.zeros(n_mesh, bool)
    for m in range(n_mesh):
        s, e = sa.mesh_tri_start[m], sa.mesh_tri_start[m + 1]
        closed[m] = not np.any(boundary[s:e])
        if closed[m] and 0 < e - s and (e - s) * (e - s) <= CONVEXITY_TEST_MAX:
            vids = np.unique(sa.tris[s:e])
            v = sa.verts[vids.min():vids.max() + 1]
            diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
            convex[m] = _is_convex(sa.verts, sa.tris[s:e], int(vids.min()), int(vids.max()) + 1,
                                   tol.CONVEX_TOL_REL * diag)
    return MeshTopology(parent.astype(np.int32), boundary, closed, convex)


_LAST: list = [None]  # (tris, verts, MeshTopology) of the last packing asked for


def mesh_topology_cached(sa: SceneArrays) -> MeshTopology:
    """:func:`mesh_topology` of ``sa``, kept for the last packing asked for (its arrays are
    immutable, so the same ``tris`` and ``verts`` objects are the same meshes)."""
    memo = _LAST[0]
    if memo is None or memo[0] is not sa.tris or memo[1] is not sa.verts:
        memo = (sa.tris, sa.verts, mesh_topology(sa))
        _LAST[0] = memo
    return memo[2]
