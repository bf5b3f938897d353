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


#: Vertices per box of :func:`vertex_boxes` (the convexity test skips a box behind a plane).
CONVEX_BOX_VERTS = 16


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """10-bit integers with two zero bits after each bit (one axis of a Morton code)."""
    x = x.astype(np.int64) & 0x3FF
    x = (x | (x << 16)) & 0x30000FF
    x = (x | (x << 8)) & 0x300F00F
    x = (x | (x << 4)) & 0x30C30C3
    return (x | (x << 2)) & 0x9249249


def vertex_boxes(v: np.ndarray, per: int = CONVEX_BOX_VERTS):
    """A tree of boxes over vertices ``v (n, 3)``: ``order (n,)`` their indices in Morton
    order; level 0 boxes each hold a run of ``per`` of them, a box of level ``L > 0`` the
    boxes ``j * per .. j * per + per - 1`` of level ``L - 1``; ``lo, hi (B, 3)`` the boxes of
    every level, level ``L`` at rows ``first[L]:first[L + 1]``; ``mag (B, 3)`` their largest
    absolute coordinate per axis. The top level has at most ``per`` boxes."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    q = np.floor((v - lo) / np.maximum(hi - lo, 1e-300) * 1023.0).clip(0, 1023)
    code = (_spread_bits(q[:, 0]) << 2) | (_spread_bits(q[:, 1]) << 1) | _spread_bits(q[:, 2])
    order = np.argsort(code, kind="stable")
    los, his = [v[order]], [v[order]]
    while len(los) == 1 or len(los[-1]) > per:
        pad = (-len(los[-1])) % per
        los.append(np.concatenate([los[-1], np.repeat(los[-1][-1:], pad, axis=0)])
                   .reshape(-1, per, 3).min(axis=1))
        his.append(np.concatenate([his[-1], np.repeat(his[-1][-1:], pad, axis=0)])
                   .reshape(-1, per, 3).max(axis=1))
    first = np.cumsum([0] + [len(x) for x in los[1:]]).astype(np.int64)
    blo, bhi = np.concatenate(los[1:]), np.concatenate(his[1:])
    return (order.astype(np.int64), blo, bhi, np.maximum(np.abs(blo), np.abs(bhi)), first)


@njit(cache=True, nogil=True)
def _is_convex(verts, tris, order, box_lo, box_hi, box_mag, first, per, tol_abs):
    """No vertex ``verts[order]`` lies more than ``tol_abs`` in front of any triangle's
    plane (unit normal by the winding), over the box tree of :func:`vertex_boxes`: a box
    whose farthest corner stays behind the plane by more than the rounding of both
    computations (``BOX_ROUND_REL`` of the magnitudes) holds no such vertex; the vertices of
    every other leaf box are tested one by one, by the same formula as without boxes (so the
    answer is the brute-force test's)."""
    n = order.shape[0]
    top = first.shape[0] - 2
    stack = np.empty((top + 1) * per + 1, np.int64)
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e1 = verts[b] - verts[a]
        e2 = verts[c] - verts[a]
        nrm = np.cross(e1, e2)
        ln = math.sqrt(nrm[0] ** 2 + nrm[1] ** 2 + nrm[2] ** 2)
        if ln == 0.0:
            continue
        sp = 0
        for j in range(first[top], first[top + 1]):
            stack[sp] = j
            sp += 1
        while sp > 0:
            sp -= 1
            k = stack[sp]
            bound = 0.0
            mag = 0.0
            for q in range(3):
                bound += max(nrm[q] * (box_lo[k, q] - verts[a, q]),
                             nrm[q] * (box_hi[k, q] - verts[a, q]))
                mag += abs(nrm[q]) * (abs(verts[a, q]) + box_mag[k, q])
            if (bound + tol.BOX_ROUND_REL * mag) / ln <= tol_abs:
                continue
            if k >= first[1]:  # an inner box: its children
                lev = 0
                while k >= first[lev + 1]:
                    lev += 1
                c0 = first[lev - 1] + (k - first[lev]) * per
                for j in range(c0, min(c0 + per, first[lev])):
                    stack[sp] = j
                    sp += 1
                continue
            for i in range(k * per, min((k + 1) * per, n)):
                v = order[i]
                s = ((verts[v, 0] - verts[a, 0]) * nrm[0] + (verts[v, 1] - verts[a, 1]) * nrm[1]
                     + (verts[v, 2] - verts[a, 2]) * nrm[2]) / ln
                if s > tol_abs:
                    return False
    return True


def is_convex(verts: np.ndarray, tris: np.ndarray, tol_abs: float) -> bool:
    """Whether no vertex of ``verts`` (all of them: the mesh's range) lies more than
    ``tol_abs`` in front of the plane of any triangle ``tris`` (into ``verts``)."""
    v = np.ascontiguousarray(verts, np.float64)
    if len(v) == 0:
        return True
    order, lo, hi, mag, first = vertex_boxes(v)
    return bool(_is_convex(v, np.ascontiguousarray(tris, np.int64), order, lo, hi, mag, first,
                           CONVEX_BOX_VERTS, float(tol_abs)))


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
            convex[m] = is_convex(v, sa.tris[s:e] - vids.min(), tol.CONVEX_TOL_REL * diag)
    return MeshTopology(parent.astype(np.int32), boundary, closed, convex)


_LAST: list = [None]  # (tris, verts, MeshTopology) of the last packing asked for


def topology_kept(sa: SceneArrays) -> bool:
    """Whether :func:`mesh_topology_cached` has ``sa``'s topology already."""
    memo = _LAST[0]
    return memo is not None and memo[0] is sa.tris and memo[1] is sa.verts


def mesh_topology_cached(sa: SceneArrays) -> MeshTopology:
    """:func:`mesh_topology` of ``sa``, kept for the last packing asked for (its arrays are
    immutable, so the same ``tris`` and ``verts`` objects are the same meshes)."""
    memo = _LAST[0]
    if memo is None or memo[0] is not sa.tris or memo[1] is not sa.verts:
        memo = (sa.tris, sa.verts, mesh_topology(sa))
        _LAST[0] = memo
    return memo[2]
