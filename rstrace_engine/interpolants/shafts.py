"""Shafts and triangle queries: what the interpolant predicate (and edits) cull with.

A *shaft* is a convex polyhedron given by planes ``pl (P, 4)`` (inside: ``n . x + d >= 0``)
and a world box ``bb (6,)`` containing it: the Haines-Wallace shaft between two boxes
(:func:`~..geometry.shaft_geometry.hw_shaft`), or a hexahedron with box topology
(:func:`hexa_planes`). Planes are moved outward by an absolute slack
(:data:`~.tolerances.SHAFT_SLACK_REL` of the scene's coordinate magnitude) so rounding never
lets a touching triangle escape. The shaft geometry without scene queries (the shaft, the
clipping, the lights' extents) is :mod:`..geometry.shaft_geometry`'s, shared with the base
tracer's shadow-ray skips; its names are re-exported here.

Queries walk per-mesh binary BVHs built with :func:`.bvh_build.build_flat` (object space: a shaft's
planes are taken to object space exactly, :func:`to_object`) under a BVH over the instances'
world boxes (:class:`QueryScene`). Triangles are clipped against the planes
(Sutherland-Hodgman, :func:`clip_polygon`), so "meets the shaft" is exact up to the slack.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..accel import bvh_build, bvh_mesh
from ..geometry.mesh_topology import MeshTopology
from ..geometry.scene import LIGHT_AREA, LIGHT_SPOT, LIGHT_SUN, MODEL_PRINCIPLED, SceneArrays
from ..geometry.shaft_geometry import (  # noqa: F401 - re-exported: the predicate's names
    MAX_PLANES,
    box_outside,
    clip_polygon,
    extent_plane_side,
    hw_shaft,
    light_extents,
    sun_box,
    to_object,
)

_STACK = 128


class QueryScene(NamedTuple):
    """What the predicate kernels read: instance and triangle BVHs, topology, lights.

    The BVHs are binary (:func:`.bvh_build.build_flat`): ``bounds (N, 12)`` float64 holds the boxes
    of both children (``lo xyz, hi xyz`` each), ``child (N, 2)`` an inner node or a leaf
    ``~(start << 3 | count)`` over consecutive primitives in leaf order.
    """

    top_bounds: np.ndarray  # (Nt, 12) float64 instance BVH over world boxes
    top_child: np.ndarray  # (Nt, 2) int32
    top_inst: np.ndarray  # (I,) int32 instance ids in leaf order
    bounds: np.ndarray  # (N, 12) float64 all mesh BVH nodes (object space)
    child: np.ndarray  # (N, 2) int32
    tvi: np.ndarray  # (T, 3) int32 the triangles' vertex indices (into verts), leaf order
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
    # spot cone cosines (1 / -1 for other lights); a reshaped (elliptical) spot: the round
    # cone that holds it and NaN inner (:func:`cone_bounds`: never on, never smooth)
    light_cos_outer: np.ndarray  # (L,)
    light_cos_inner: np.ndarray  # (L,)
    mesh_convex: np.ndarray  # (M,) bool closed and convex
    world_light: bool  # the world's colour lights surfaces (not black)
    light_ext: np.ndarray  # (L,) bool the light has an extent (sampled)
    # lights with an extent (:func:`light_extents`): the box of a sphere's ball or an area
    # light's rectangle (a point for the others), and for a sun the chord ``2 sin(h / 2)``
    # of its cone of half angle h (0 for the others)
    light_lo: np.ndarray  # (L, 3) float64
    light_hi: np.ndarray  # (L, 3) float64
    light_chord: np.ndarray  # (L,) float64
    light_radius: np.ndarray  # (L,) sphere radius (POINT, SPOT), 0 otherwise
    light_half: np.ndarray  # (L,) SUN: half its angle
    light_u: np.ndarray  # (L, 3) AREA: unit +X of the emitter
    light_v: np.ndarray  # (L, 3) AREA: unit +Y
    light_size: np.ndarray  # (L, 2) AREA: full extents along u and v
    light_closed: np.ndarray  # (L,) bool the tracer has a closed form for the light's
    # unshadowed diffuse term where it is above the horizon (a sphere that is not a spot,
    # a sun, a rectangle without spread: soft_lights._row_exact)
    # the packing's shading normals (:func:`~..geometry.attributes.corner_normals`)
    normals: np.ndarray  # (N, 3) float32 rows
    mesh_nrm: np.ndarray  # (M, 2) int64 (mode, bias) per mesh
    verts: np.ndarray  # (V, 3) float64 the packing's vertices (flat normals)
    tris: np.ndarray  # (T, 3) int32 the packing's triangles
    inst_nmat: np.ndarray  # (I, 3, 3) float64 normal matrices
    inst_mat_start: np.ndarray  # (I + 1,) int32
    inst_mat: np.ndarray  # (K,) int32
    tri_slot: np.ndarray  # (S,) int32 slot rows (:mod:`~..geometry.packing`)
    mesh_slot: np.ndarray  # (M, 2) int64 (constant slot or -1, row bias) per mesh
    mat_glossy: np.ndarray  # (NM,) bool the BRDF has a glossy lobe that soft samples estimate


def glossy_materials(sa: SceneArrays) -> np.ndarray:
    """(NM,) bool: the material's BRDF has a glossy lobe (Ward's specular, the Principled
    GGX layer above ``GLOSSY_ALPHA_MIN``), which the tracer estimates from a soft light's
    samples (noise); without one the BRDF is Lambertian and a fully visible light with a
    closed form gives its closed form exactly (:mod:`..tracing.soft_lights`)."""
    spec = np.any(np.asarray(sa.mat_specular) > 0.0, axis=1)
    principled = np.asarray(sa.mat_model) == MODEL_PRINCIPLED
    lobe = (np.asarray(sa.mat_roughness) >= tol.GLOSSY_ALPHA_MIN) & (
        spec | (np.asarray(sa.mat_metallic) > 0.0))
    return np.ascontiguousarray(np.where(principled, lobe, spec), np.bool_)


def binary_bvh(lo: np.ndarray, hi: np.ndarray, max_leaf: int):
    b, c, perm, _ = bvh_build.build_flat(np.ascontiguousarray(lo), np.ascontiguousarray(hi),
                                         max_leaf)
    return b, c, perm


def query_scene(sa: SceneArrays, topo: MeshTopology, bvh=binary_bvh) -> QueryScene:
    """Build the predicate's query structures over ``sa`` (binary BVHs of :mod:`.bvh_build`;
    ``bvh``: another builder of :func:`binary_bvh`'s arrays, as the warm-up's stand-in)."""
    bounds, childs, tvs, tris, roots = [], [], [], [], []
    n_nodes = n_tris = 0
    for m in range(len(sa.mesh_tri_start) - 1):
        tv = bvh_mesh.mesh_triangles(sa, m)
        b, c, perm = bvh(tv.min(axis=1), tv.max(axis=1), bvh_build.MAX_LEAF)
        c = c.astype(np.int64)
        code = ~c
        c = np.where(c < 0, ~(((code >> 3) + n_tris) << 3 | (code & 7)), c + n_nodes)
        bounds.append(b)
        childs.append(c.astype(np.int32))
        tvs.append(sa.tris[sa.mesh_tri_start[m] + perm])
        tris.append(perm.astype(np.int64) + sa.mesh_tri_start[m])
        roots.append(n_nodes)
        n_nodes += len(b)
        n_tris += len(perm)
    lo, hi = sa.inst_aabb[:, 0], sa.inst_aabb[:, 1]
    mag = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))
    pad = (tol.INSTANCE_BOX_PAD_REL * (mag + np.linalg.norm(hi - lo, axis=1)))[:, None]
    tb, tc, tperm = bvh(lo - pad, hi + pad, 1)
    lo_s, hi_s = sa.scene_aabb
    mag = float(sa.scene_extent + np.max(np.abs(sa.scene_aabb)))
    return QueryScene(tb, tc, tperm.astype(np.int32), np.concatenate(bounds),
                      np.concatenate(childs),
                      np.ascontiguousarray(np.concatenate(tvs), np.int32),
                      np.concatenate(tris).astype(np.int32), np.array(roots, np.int32),
                      np.ascontiguousarray(sa.inst_mesh, np.int32), sa.inst_xform, sa.inst_inv,
                      topo.tri_class, topo.tri_boundary, **light_fields(sa),
                      scene_center=0.5 * (lo_s + hi_s), extent=float(sa.scene_extent),
                      slack=tol.SHAFT_SLACK_REL * mag,
                      mesh_convex=np.ascontiguousarray(topo.mesh_convex, np.bool_),
                      normals=sa.normals, mesh_nrm=sa.mesh_nrm, verts=sa.verts, tris=sa.tris,
                      inst_nmat=np.ascontiguousarray(sa.inst_nmat, np.float64),
                      inst_mat_start=np.ascontiguousarray(sa.inst_mat_start, np.int32),
                      inst_mat=np.ascontiguousarray(sa.inst_mat, np.int32),
                      tri_slot=np.ascontiguousarray(sa.tri_slot, np.int32),
                      mesh_slot=sa.mesh_slot, mat_glossy=glossy_materials(sa))


def lights_only(old: SceneArrays, new: SceneArrays) -> bool:
    """Whether packings ``old`` and ``new`` differ in their lights and world alone: every
    other field the same object (a light or world edit repacks those alone,
    :meth:`~..geometry.scene.Scene.repack_lights`; packed arrays are never modified), so
    their :class:`QueryScene` differ in :func:`light_fields` alone."""
    return all(getattr(old, f) is getattr(new, f) for f in old._fields
               if not f.startswith(("light_", "world_")))


def light_fields(sa: SceneArrays) -> dict:
    """The fields of :class:`QueryScene` that ``sa``'s lights and world make (the rest are
    its geometry's and materials': a light or world edit changes these alone,
    :meth:`~.interpolant_cache.InterpolantCache.qs`)."""
    co, ci = cone_bounds(sa)
    lo, hi, chord = light_extents(sa)
    return dict(light_kind=sa.light_kind, light_pos=sa.light_pos.reshape(-1, 3),
                light_dir=sa.light_dir.reshape(-1, 3), light_cos_outer=co,
                light_cos_inner=ci, world_light=bool(np.any(np.asarray(sa.world_light) > 0.0)),
                light_ext=np.ascontiguousarray(sa.light_ext, np.bool_), light_lo=lo,
                light_hi=hi, light_chord=chord,
                light_radius=np.ascontiguousarray(sa.light_radius, np.float64),
                light_half=np.ascontiguousarray(sa.light_half, np.float64),
                light_u=np.ascontiguousarray(sa.light_u, np.float64).reshape(-1, 3),
                light_v=np.ascontiguousarray(sa.light_v, np.float64).reshape(-1, 3),
                light_size=np.ascontiguousarray(sa.light_size, np.float64).reshape(-1, 2),
                light_closed=closed_forms(sa))


def closed_forms(sa: SceneArrays) -> np.ndarray:
    """(L,) bool: lights whose unshadowed diffuse term the tracer takes from a closed form
    above the horizon (``soft_lights._row_exact``): a sphere that is not a spot, a sun with
    an angle, a rectangle (or square) without spread."""
    kind = np.asarray(sa.light_kind)
    ext = np.asarray(sa.light_ext, np.bool_)
    area = (kind == LIGHT_AREA) & ~np.asarray(sa.light_ellipse, np.bool_) & ~(
        np.asarray(sa.light_spread)[:, 0] < np.inf)
    other = (kind >= 0) & (kind != LIGHT_AREA) & (kind != LIGHT_SPOT)
    return np.ascontiguousarray(ext & (area | other), np.bool_)


@njit(cache=True, nogil=True)
def hexa_planes(V, slack, pl):
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
def box_out(pl, npl, bb, bounds, node, c):
    """Child ``c`` of BVH node ``node`` lies outside the shaft (box or some plane)."""
    o = 6 * c
    return box_outside(pl, npl, bb, bounds[node, o], bounds[node, o + 1], bounds[node, o + 2],
                       bounds[node, o + 3], bounds[node, o + 4], bounds[node, o + 5])


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


@njit(cache=True, nogil=True, inline="always")
def tvx(qs, t, k):
    """Coordinate ``k`` (0-8: vertex ``k // 3``, axis ``k % 3``) of leaf-order triangle
    ``t``: read from the packing's vertices through the leaf-order indices (a copy of the
    coordinates took 72 bytes a triangle, the indices take 12)."""
    return qs.verts[qs.tvi[t, k // 3], k % 3]


@njit(cache=True, nogil=True)
def load_tri(qs, t, P):
    for v in range(3):
        P[v, 0] = tvx(qs, t, 3 * v)
        P[v, 1] = tvx(qs, t, 3 * v + 1)
        P[v, 2] = tvx(qs, t, 3 * v + 2)


@njit(cache=True, nogil=True)
def tri_in(qs, t, plo, npl, P, Q):
    load_tri(qs, t, P)
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
            if box_out(plo, npl, bbo, qs.bounds, node, c):
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
                    if tri_in(qs, t, plo, npl, P, Q):
                        if cnt >= out.shape[0]:
                            return -1
                        out[cnt] = t
                        cnt += 1
    return cnt


@njit(cache=True, nogil=True, inline="always")
def instance_candidates(qs, inst, pl, npl, bb, cand, P, Q):
    """:func:`mesh_candidates` of instance ``inst`` for the world shaft ``pl``/``npl``/``bb``
    (taken to its object space): their count (-1: ``cand`` too small)."""
    plo = np.empty((MAX_PLANES, 4))
    bbo = np.empty(6)
    to_object(qs.inst_xform[inst], qs.inst_inv[inst], pl, npl, bb, plo, bbo)
    return mesh_candidates(qs, qs.inst_mesh[inst], plo, npl, bbo, cand, P, Q)


@njit(cache=True, nogil=True)
def other_geometry(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q):
    """Does a triangle of an instance not in ``named[:n_named]`` meet the world shaft?
    (:func:`shaft_instances` with room for none: it stops at the first such instance, and a
    walk that overflows its stack answers yes.)"""
    none = np.empty(0, np.int32)
    return shaft_instances(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q, none) != 0


@njit(cache=True, nogil=True)
def shaft_instances(qs, pl, npl, bb, named, n_named, plo, bbo, P, Q, out):
    """The instances not in ``named[:n_named]`` with a triangle in the world shaft, into
    ``out``: their number, or -1 when more than ``out`` holds (or the stack overflows)."""
    stack = np.empty(_STACK, np.int32)
    stack[0] = 0
    sp = 1
    n = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(2):
            if box_out(pl, npl, bb, qs.top_bounds, node, c):
                continue
            ch = qs.top_child[node, c]
            if ch >= 0:
                if sp >= _STACK:
                    return -1
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
                for k in range(n):
                    if out[k] == inst:
                        skip = True
                if skip:
                    continue
                to_object(qs.inst_xform[inst], qs.inst_inv[inst], pl, npl, bb, plo, bbo)
                if mesh_any(qs, qs.inst_mesh[inst], plo, npl, bbo, P, Q):
                    if n >= out.shape[0]:
                        return -1
                    out[n] = inst
                    n += 1
    return n


@njit(cache=True, nogil=True)
def mesh_any(qs, m, plo, npl, bbo, P, Q):
    stack = np.empty(_STACK, np.int32)
    stack[0] = qs.mesh_root[m]
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(2):
            if box_out(plo, npl, bbo, qs.bounds, node, c):
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
                    if tri_in(qs, t, plo, npl, P, Q):
                        return True
    return False


@njit(cache=True, nogil=True)
def boundary_edge_in(qs, t, plo, npl):
    """Does a boundary edge of leaf-order triangle ``t`` meet the (object-space) shaft?"""
    mask = qs.tri_boundary[qs.tri[t]]
    if mask == 0:
        return False
    for e in range(3):
        if not (mask >> e) & 1:
            continue
        f = (e + 1) % 3
        if segment_in(plo, npl, tvx(qs, t, 3 * e), tvx(qs, t, 3 * e + 1),
                      tvx(qs, t, 3 * e + 2), tvx(qs, t, 3 * f), tvx(qs, t, 3 * f + 1),
                      tvx(qs, t, 3 * f + 2)):
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def tri_normal(qs, t):
    e1x = tvx(qs, t, 3) - tvx(qs, t, 0)
    e1y = tvx(qs, t, 4) - tvx(qs, t, 1)
    e1z = tvx(qs, t, 5) - tvx(qs, t, 2)
    e2x = tvx(qs, t, 6) - tvx(qs, t, 0)
    e2y = tvx(qs, t, 7) - tvx(qs, t, 1)
    e2z = tvx(qs, t, 8) - tvx(qs, t, 2)
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
        dx = ox - tvx(qs, t, 3 * v)
        dy = oy - tvx(qs, t, 3 * v + 1)
        dz = oz - tvx(qs, t, 3 * v + 2)
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
    """The far end of light ``j``'s shaft from box (lo, hi): the light's extent (its point,
    a sphere light's ball, an area light's rectangle: :func:`light_extents`), or for a sun
    the box moved far beyond the scene toward the sun, grown by the chord of its cone at
    that distance (every shadow ray from the box, to as far as the scene reaches, then lies
    in the Haines-Wallace shaft between the two boxes)."""
    if qs.light_kind[j] == LIGHT_SUN:
        sun_box(lo, hi, qs.light_dir[j], qs.light_chord[j], qs.scene_center, qs.extent, blo,
                bhi)
    else:
        for k in range(3):
            blo[k] = qs.light_lo[j, k]
            bhi[k] = qs.light_hi[j, k]


@njit(cache=True, nogil=True)
def extent_side(qs, xf, inv, t, j, nx, ny, nz):
    """Side of leaf-order triangle ``t`` (object-space normal n) of an instance with
    transform ``xf`` (inverse ``inv``) facing every point of light ``j``'s extent: 1 the
    whole extent is in front of its plane (a sphere's ball, an area light's four corners, a
    sun's whole cone of directions), -1 wholly behind, 0 otherwise (within the tolerance).
    A light without an extent: :func:`light_side`."""
    if not qs.light_ext[j]:
        return light_side(qs, inv, t, j, nx, ny, nz)
    # the world normal (the normal matrix is inv's transpose)
    wx = inv[0, 0] * nx + inv[1, 0] * ny + inv[2, 0] * nz
    wy = inv[0, 1] * nx + inv[1, 1] * ny + inv[2, 1] * nz
    wz = inv[0, 2] * nx + inv[1, 2] * ny + inv[2, 2] * nz
    ln = math.sqrt(wx * wx + wy * wy + wz * wz)
    if not ln > 0.0:
        return 0
    wx /= ln
    wy /= ln
    wz /= ln
    v = np.empty(3)
    for k in range(3):
        v[k] = (xf[k, 0] * tvx(qs, t, 0) + xf[k, 1] * tvx(qs, t, 1) + xf[k, 2] * tvx(qs, t, 2)
                + xf[k, 3])
    return extent_plane_side(qs, j, wx, wy, wz, v[0], v[1], v[2], qs.slack)


#: :func:`cone_state` outcomes: the spot falloff over a box is 1 everywhere, 0 everywhere,
#: a smooth part of the blend region, or it may jump (a step: blend 0, or a cell wider than
#: the blend region).
CONE_ON, CONE_OFF, CONE_SMOOTH, CONE_STEP = 1, -1, 0, 2


def cone_bounds(sa) -> tuple:
    """The spots' cone cosines for the shafts' cone test: a reshaped (elliptical, Cycles'
    non-uniformly scaled) spot gets the round cone that holds its outer cone (tangent
    times the largest ratio of its cross scales to its length scale) and a NaN inner
    cosine, so that a box is off outside that cone and otherwise traced (never taken as
    fully lit or smooth)."""
    co = np.array(sa.light_cos_outer, np.float64)
    ci = np.array(sa.light_cos_inner, np.float64)
    for j in np.flatnonzero(sa.light_spot_scaled):
        f = sa.light_spot_frame[j]
        # rows are axis / scale: the scale along each axis is 1 / |row|
        su, sv, sw = (1.0 / float(np.linalg.norm(f[r])) for r in range(3))
        t = math.sqrt(max(0.0, 1.0 - co[j] * co[j])) / max(co[j], 1e-300)
        big = t * max(su, sv) / sw
        u = f / np.linalg.norm(f, axis=1)[:, None]
        sheared = np.abs(u @ u.T - np.eye(3)).max() > 1e-9  # then no round bound is taken
        co[j] = -1.0 if co[j] <= 0.0 or sheared else 1.0 / math.sqrt(1.0 + big * big)
        ci[j] = np.nan
    return co, ci


@njit(cache=True, nogil=True)
def cone_state(qs, j, lo, hi):
    """How light ``j``'s spot cone meets the world box (lo, hi) (:data:`CONE_ON` ...).

    The angle from the spot axis of every point of the box lies within the angular radius
    ``asin(r / |c - p|)`` of the box's bounding sphere (centre c, radius r) around the angle
    of c: a conservative interval ``[ca_min, ca_max]`` of the cosine. Off when ``ca_max <=
    cos_outer``, on when ``ca_min > cos_inner``; in between the falloff is a smoothstep of
    the cosine (C1), accepted only when the interval fits in the blend region's width
    (``cos_inner - cos_outer``; 0 for blend 0: a step). Lights other than spots are on."""
    if qs.light_kind[j] != LIGHT_SPOT:
        return CONE_ON
    r2 = 0.0
    v2 = 0.0
    vd = 0.0
    for k in range(3):
        h = 0.5 * (hi[k] - lo[k])
        r2 += h * h
        v = 0.5 * (hi[k] + lo[k]) - qs.light_pos[j, k]
        v2 += v * v
        vd += v * qs.light_dir[j, k]
    r = math.sqrt(r2) + qs.slack
    dc = math.sqrt(v2)
    co = qs.light_cos_outer[j]
    ci = qs.light_cos_inner[j]
    if dc <= r:
        ca_min = -1.0
        ca_max = 1.0
    else:
        tc = math.acos(min(1.0, max(-1.0, vd / dc)))
        al = math.asin(min(1.0, r / dc))
        ca_max = math.cos(max(0.0, tc - al)) + tol.CONE_COS_SLACK
        ca_min = math.cos(min(math.pi, tc + al)) - tol.CONE_COS_SLACK
    if ca_max <= co:
        return CONE_OFF
    if ca_min > ci:
        return CONE_ON
    span = ci - co
    if span > 0.0 and ca_max - ca_min <= span:
        return CONE_SMOOTH
    return CONE_STEP
