"""Shadow rays the base tracer need not trace: lights proven fully visible over a tile.

Fernandez, Bala and Greenberg 2002 ("Local Illumination Environments for Direct Lighting
Acceleration") skip the shadow rays of every light proven fully visible over a region. Here
a *group* is the primary hits of one instance in a :data:`SKIP_TILE` x :data:`SKIP_TILE`
pixel tile, and per group and light with an extent (sphere, area, sun with an angle) the
proof is the Haines-Wallace shaft from the box of the group's shadow-ray origins to the
light's extent (:func:`~..geometry.shaft_geometry.hw_shaft`; a sun's cone as a box far
toward it, :func:`~..geometry.shaft_geometry.sun_box`). Every shadow sample of a point of
the group runs inside that shaft. Each triangle the shaft meets (clipped against its
planes, in the accelerator's own object space) must be *harmless* for every point ``q``
of the group that samples the light:

* **behind the point's own plane**: its three vertices lie behind the plane through ``q``
  with the point's geometric normal by at least half the point's shadow-ray offset
  (:data:`~.tolerances.SKIP_SELF_MARGIN_FRAC`). A traced sample goes away from that plane
  (its weight is zero, and no ray is traced, unless it points into the normal's side), so
  the whole segment stays in front of it and never meets the triangle. This is what lets
  the receiver's own surface through: a floor's coplanar triangles, the rest of a convex
  object behind the tangent plane of each point;
* **on the far side of its own plane from nothing**: the point and the light's whole
  extent (a sphere's ball, an area light's four corners, a sun's whole cone of directions)
  lie strictly on the same side of the triangle's plane, by the shaft's slack: no segment
  between them crosses that plane. Walls, a ceiling behind the light, anything beside the
  shaft.

A group whose points all lie on a convex instance, seen from outside, skips that instance
altogether (:func:`own_clear`: its mesh's convexity certificate bounds every vertex
behind each point's plane by the first argument's margin, so every one of its triangles
would pass it; studio's mirror ball, 5,120 triangles tested against each point of its
tiles, was nearly all of the proofs' time). Any other triangle (an object between the
points and the light, a non-convex receiver shadowing itself) fails the group's proof for
that light, and its samples are traced as
before. Both arguments leave a margin far above the rounding of the watertight ray-triangle
test, so a proven sample is exactly one the tracer would have found unoccluded: the skip
sets its visibility to true where tracing would have, and the image, the ray trees and
the pixel and light records are bit for bit those of the frame without skips
(``tests/test_shaft_skip.py``). The proof reads the accelerator's own trees (the numba
:class:`~..accel.accelerators.BVHAccelerator`: the geometry the rays are traced against);
other accelerators (float32 Embree, the visibility field's approximation, the brute-force
oracle) trace every sample. Secondary hits (behind mirrors and glass) are not grouped and
trace every sample; so does the world's light (its hemisphere has no extent to prove).
Measured in docs/SOFT_LIGHT.md ("Base-mode shaft skips").
"""

from __future__ import annotations

import math
import time
import weakref

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..accel.accelerators import BVHAccelerator
from ..accel.bvh import STACK_SIZE
from ..accel.bvh_mesh import leaf_size, leaf_triangle
from ..geometry.scene import LIGHT_SUN, SceneArrays
from ..geometry.shaft_geometry import (
    MAX_PLANES,
    box_outside,
    clip_polygon,
    extent_plane_side,
    hw_shaft,
    light_extents,
    sun_box,
    to_object,
)
from ..views import fields, view_type
from .glossy_rays import MATERIAL_FLAGS
from .memo import Memo
from .object_rays import CONVEX
from .shading import spawn_offset
from .soft_lights import SH_SOFT

#: The skips on (a module switch: tests and the measurement in docs/SOFT_LIGHT.md compare
#: frames with and without them, which are the same bit for bit).
SHAFT_SKIP = True
#: Pixels on a side of the tiles whose primary hits (per instance) are proven together;
#: measured in docs/SOFT_LIGHT.md.
SKIP_TILE = 8
#: Soft shadow rays leave their point's own convex instance out of their traversal
#: (:func:`own_instances`; a module switch: the tests compare frames with and without it,
#: the same bit for bit).
OWN_SKIP = True
#: Instances of meshes with fewer triangles are not offered :func:`own_clear`'s skip (a
#: floor's two triangles cost less to test than the bound): a speed choice, not a proof's.
OWN_MIN_TRIS = 32


def tile_keys(pixels: np.ndarray, width: int, tile: int | None = None) -> np.ndarray:
    """(k,) int64 the tile (``tile`` pixels on a side, default :data:`SKIP_TILE`) of each
    pixel index of an image ``width`` pixels wide."""
    tile = int(SKIP_TILE if tile is None else tile)
    p = np.asarray(pixels, np.int64)
    y, x = np.divmod(p, int(width))
    return (y // tile) * ((int(width) + tile - 1) // tile) + x // tile


def proven_rows(sa, accel, surf, inst: np.ndarray, keys: np.ndarray | None,
                counters: dict | None = None, prim: np.ndarray | None = None,
                own: np.ndarray | None = None) -> np.ndarray | None:
    """(n L,) bool: the (point, light) rows ``i * L + j`` of the surface points ``surf``
    (:class:`~.shader.Surfaces` of primary hits on instances ``inst``) whose light ``j``
    (sampled there, ``SH_SOFT``) is proven fully visible, the points grouped by ``keys``
    (n,) int64 and instance; None where nothing is tried (the skips off, no group keys, no
    light with an extent, an accelerator whose geometry the proof does not read).
    ``counters`` gains ``skip_rows`` (rows of lights with an extent), ``skip_rows_proven``
    and ``skip_s`` (seconds in the proofs); :func:`~.soft_lights.soft_visibility` adds
    ``shadow_skipped`` (samples not traced). ``prim`` (n,): the points' global triangles,
    with which a group skips its own convex instance (:func:`own_clear`; ``skip_own``
    counts the points it holds for); ``own`` (n,) int32: :func:`own_instances`' answer for
    the points, taken instead of computing it again."""
    if not SHAFT_SKIP or keys is None or not isinstance(accel, BVHAccelerator):
        return None
    t0 = time.perf_counter()
    L = len(sa.light_kind)
    ext = np.asarray(sa.light_ext, np.bool_) & (np.asarray(sa.light_kind) >= 0)
    n = len(surf.P)
    if not ext.any() or n == 0:
        return None
    soft = surf.sh_state.reshape(n, L)[:, ext] == SH_SOFT
    # a rough interface's samples may leave through its far side: the proofs cover the
    # shadow origins on the viewer's side alone
    flags = MATERIAL_FLAGS.get(sa)
    if flags.any_interface:
        soft &= ~flags.interface[surf.mat][:, None]
    todo = np.flatnonzero(soft.any(axis=1))
    proven = np.zeros(n * L, np.bool_)
    if len(todo) == 0:
        return proven
    inst = np.asarray(inst, np.int64)
    gk = np.asarray(keys, np.int64)[todo] * (len(sa.inst_mesh) + 1) + inst[todo]
    order = np.argsort(gk, kind="stable")
    gk = gk[order]
    members = todo[order]
    gstart = np.flatnonzero(np.r_[True, gk[1:] != gk[:-1], True]).astype(np.int64)
    geo = accel.sa  # the geometry the accelerator traces against
    lo, hi, chord = light_extents(sa)
    mag = float(geo.scene_extent + np.max(np.abs(geo.scene_aabb)))
    xf = np.ascontiguousarray(geo.inst_xform, np.float64)
    if own is not None:
        own = own >= 0
    else:
        own = np.zeros(n, np.bool_)
        if prim is not None:
            own_clear(geo, xf, surf.Q, surf.NG, inst, np.asarray(prim, np.int64), todo, own)
    _prove_groups(accel.sb, xf, sa,
                  np.ascontiguousarray(lo), np.ascontiguousarray(hi), chord,
                  np.ascontiguousarray(0.5 * (geo.scene_aabb[0] + geo.scene_aabb[1])),
                  float(geo.scene_extent), mag, surf.Q, surf.NG, surf.sh_state,
                  members.astype(np.int64), gstart, inst, own, proven)
    if counters is not None:
        counters["skip_own"] = counters.get("skip_own", 0) + int(own.sum())
        counters["skip_rows"] = counters.get("skip_rows", 0) + int(soft.sum())
        counters["skip_rows_proven"] = counters.get("skip_rows_proven", 0) + int(
            proven.sum())
        counters["skip_s"] = counters.get("skip_s", 0.0) + time.perf_counter() - t0
    return proven


_ProofScene = view_type("_ProofScene", SceneArrays, (
    "light_dir", "light_ext", "light_half", "light_kind", "light_pos", "light_radius",
    "light_size", "light_u", "light_v"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def _prove_groups(sb, xf, sa, llo, lhi, chord, center, extent, mag, Q, NG, sh_state,
                  members, gstart, inst, own, proven):
    """Per group ``g`` (points ``members[gstart[g]:gstart[g + 1]]``) and light with an
    extent: set ``proven`` (n L,) at the group's rows of the light when its shaft holds
    only harmless triangles (:func:`_shaft_clear`). ``sb``: the accelerator's
    :class:`~..accel.bvh.SceneBVH`, ``xf`` its instances' object-to-world transforms;
    ``llo``, ``lhi``, ``chord``: :func:`~..geometry.shaft_geometry.light_extents`;
    ``center``, ``extent``: the scene box's centre and diagonal; ``mag`` its coordinates'
    magnitude (the shafts' slack); ``inst`` (n,) the points' instances, ``own`` (n,)
    :func:`own_clear`'s answer: a group all of whose points sampling the light hold it
    skips its own instance."""
    sa = _ProofScene(*fields(sa, _ProofScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    for g in prange(gstart.shape[0] - 1):
        pl = np.empty((MAX_PLANES, 4))
        plo = np.empty((MAX_PLANES, 4))
        bb = np.empty(6)
        bbo = np.empty(6)
        lo = np.empty(3)
        hi = np.empty(3)
        blo = np.empty(3)
        bhi = np.empty(3)
        P = np.empty((3 + MAX_PLANES, 3))
        S = np.empty((3 + MAX_PLANES, 3))
        stack = np.empty(STACK_SIZE, np.int32)
        stack2 = np.empty(STACK_SIZE, np.int32)
        for j in range(L):
            if not sa.light_ext[j] or sa.light_kind[j] < 0:
                continue
            cnt = 0
            skip = inst[members[gstart[g]]]  # (every point of a group is on it)
            for k in range(3):
                lo[k] = np.inf
                hi[k] = -np.inf
            for a in range(gstart[g], gstart[g + 1]):
                i = members[a]
                if sh_state[i * L + j] != SH_SOFT:
                    continue
                cnt += 1
                if not own[i]:
                    skip = -1
                for k in range(3):
                    lo[k] = min(lo[k], Q[i, k])
                    hi[k] = max(hi[k], Q[i, k])
            if cnt == 0:
                continue
            if sa.light_kind[j] == LIGHT_SUN:
                sun_box(lo, hi, sa.light_dir[j], chord[j], center, extent, blo, bhi)
            else:
                for k in range(3):
                    blo[k] = llo[j, k]
                    bhi[k] = lhi[j, k]
            big = mag
            for k in range(3):
                big = max(big, abs(lo[k]), abs(hi[k]), abs(blo[k]), abs(bhi[k]))
            slack = tol.SHAFT_SLACK_REL * big
            npl = hw_shaft(lo, hi, blo, bhi, slack, pl, bb)
            if _shaft_clear(sb, xf, sa, j, pl, npl, bb, slack, lo, hi, extent, Q, NG,
                            sh_state, members, gstart[g], gstart[g + 1], skip, plo, bbo, P,
                            S, stack, stack2):
                for a in range(gstart[g], gstart[g + 1]):
                    i = members[a]
                    if sh_state[i * L + j] == SH_SOFT:
                        proven[i * L + j] = True


@njit(cache=True, nogil=True, inline="always")
def _lane_out(pl, npl, bb, bounds, node, c):
    """Lane ``c`` of 4-wide BVH node ``node`` (:mod:`..accel.bvh`'s layout) lies outside
    the shaft (its box or some plane); an unused lane (``lo = +inf``) always does."""
    return box_outside(pl, npl, bb, bounds[node, c], bounds[node, 4 + c], bounds[node, 8 + c],
                       bounds[node, 12 + c], bounds[node, 16 + c], bounds[node, 20 + c])


@njit(cache=True, nogil=True)
def _shaft_clear(sb, xf, sa, j, pl, npl, bb, slack, lo, hi, extent, Q, NG, sh_state,
                 members, a0, a1, skip, plo, bbo, P, S, stack, stack2):
    """Is every triangle of the scene that meets the world shaft ``pl``, ``bb`` harmless
    to light ``j``'s samples from the group's points ``members[a0:a1]`` (box lo, hi)?
    Walks the top level of ``sb`` and, per instance it meets (but ``skip``, whose every
    triangle :func:`own_clear` proved behind each point's plane), the mesh's tree with
    the shaft taken to object space."""
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(4):
            if _lane_out(pl, npl, bb, sb.top_bounds, node, c):
                continue
            ch = sb.top_child[node, c]
            if ch >= 0:
                stack[sp] = ch
                sp += 1
                continue
            code = ~ch
            for q in range(code >> 3, (code >> 3) + (code & 7)):
                inst = sb.top_inst[q]
                if inst == skip:
                    continue
                to_object(xf[inst], sb.inst_inv[inst], pl, npl, bb, plo, bbo)
                if not _mesh_clear(sb, xf[inst], sb.mesh_root[sb.inst_mesh[inst]], sa, j,
                                   plo, npl, bbo, slack, lo, hi, extent, Q, NG, sh_state,
                                   members, a0, a1, P, S, stack2):
                    return False
    return True


@njit(cache=True, nogil=True)
def _mesh_clear(sb, xf, root, sa, j, plo, npl, bbo, slack, lo, hi, extent, Q, NG, sh_state,
                members, a0, a1, P, S, stack):
    """:func:`_shaft_clear` within one instance: its mesh's tree from node ``root`` against
    the object-space shaft ``plo``, ``bbo``; ``xf`` the instance's transform."""
    stack[0] = root
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for c in range(4):
            if _lane_out(plo, npl, bbo, sb.bounds, node, c):
                continue
            ch = sb.child[node, c]
            if ch >= 0:
                stack[sp] = ch
                sp += 1
                continue
            code = ~ch
            s, k = code >> 3, code & 7
            for i in range(leaf_size(k)):
                t = leaf_triangle(sb.tri, s, k, i)  # (global triangle)
                for v in range(3):
                    P[v, 0] = sb.verts[sb.tris[t, v], 0]
                    P[v, 1] = sb.verts[sb.tris[t, v], 1]
                    P[v, 2] = sb.verts[sb.tris[t, v], 2]
                if clip_polygon(plo, 0, npl, P, 3, S) == 0:
                    continue
                if not _harmless(sb.verts, sb.tris, t, xf, sa, j, slack, lo, hi, extent, Q,
                                 NG, sh_state, members, a0, a1):
                    return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _world(xf, verts, tris, t, v):
    """Vertex ``v`` of triangle ``t`` (its vertex indices ``tris[t]``) taken to world space
    by ``xf``."""
    x, y, z = verts[tris[t, v], 0], verts[tris[t, v], 1], verts[tris[t, v], 2]
    return (xf[0, 0] * x + xf[0, 1] * y + xf[0, 2] * z + xf[0, 3],
            xf[1, 0] * x + xf[1, 1] * y + xf[1, 2] * z + xf[1, 3],
            xf[2, 0] * x + xf[2, 1] * y + xf[2, 2] * z + xf[2, 3])


@njit(cache=True, nogil=True)
def _harmless(verts, tris, t, xf, sa, j, slack, lo, hi, extent, Q, NG, sh_state, members,
              a0, a1):
    """Can no shadow sample of light ``j`` from the group's points meet triangle ``t``
    (vertices ``verts[tris[t]]``, object space, transform ``xf``)? Per point: the
    triangle lies behind the point's own plane, or the point and the light's whole extent
    lie on one side of the triangle's plane (see the module's docstring)."""
    L = sa.light_kind.shape[0]
    ax, ay, az = _world(xf, verts, tris, t, 0)
    bx, by, bz = _world(xf, verts, tris, t, 1)
    cx, cy, cz = _world(xf, verts, tris, t, 2)
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    side = 0
    if ln > 0.0:
        nx /= ln
        ny /= ln
        nz /= ln
        side = extent_plane_side(sa, j, nx, ny, nz, ax, ay, az, slack)
        if side != 0:
            # the whole box of the points on the light's side: so is every point
            sx, sy, sz = side * nx, side * ny, side * nz
            near = (sx * ((lo[0] if sx > 0.0 else hi[0]) - ax)
                    + sy * ((lo[1] if sy > 0.0 else hi[1]) - ay)
                    + sz * ((lo[2] if sz > 0.0 else hi[2]) - az))
            if near > slack:
                return True
    for a in range(a0, a1):
        i = members[a]
        if sh_state[i * L + j] != SH_SOFT:
            continue
        qx, qy, qz = Q[i, 0], Q[i, 1], Q[i, 2]
        if side != 0 and side * (nx * (qx - ax) + ny * (qy - ay) + nz * (qz - az)) > slack:
            continue  # the point on the light's side of the triangle's plane
        gx, gy, gz = NG[i, 0], NG[i, 1], NG[i, 2]
        m = -tol.SKIP_SELF_MARGIN_FRAC * spawn_offset(qx, qy, qz, extent)
        if (gx * (ax - qx) + gy * (ay - qy) + gz * (az - qz) <= m
                and gx * (bx - qx) + gy * (by - qy) + gz * (bz - qz) <= m
                and gx * (cx - qx) + gy * (cy - qy) + gz * (cz - qz) <= m):
            continue  # the triangle behind the point's own plane
        return False
    return True


def own_instances(sa, accel, surf, inst: np.ndarray, prim: np.ndarray) -> np.ndarray | None:
    """(n,) int32: per surface point ``surf`` (hit on instances ``inst``, global triangles
    ``prim``) the instance its soft shadow samples leave out of their traversal, -1 none;
    None where none is offered (:data:`OWN_SKIP` off, an accelerator other than the BVH).

    A point's own instance, where :func:`own_clear` holds for it: every triangle of that
    instance lies behind the plane through the point's shadow origin ``Q`` with its
    geometric normal, past the half offset :func:`_harmless` asks -- and every soft sample
    the tracer traces from ``Q`` points into the normal's side (its weight is zero, and no
    ray traced, otherwise: :func:`~.soft_lights.sample_weight`), so its whole segment stays
    in front of that plane and the watertight test meets none of those triangles, as the
    shaft proofs argue. The BVH's query without that instance then answers as the whole
    one, bit for bit, without walking the instance's tree: a ray leaving a convex
    object's surface starts inside its box and its tree's boxes near it (the mirror ball's
    world rays spent 80% of their query there, docs/bench-edit.md). Not at rough interfaces
    (their samples below the surface leave from the far side), nor for meshes of fewer than
    :data:`OWN_MIN_TRIS` triangles."""
    if not OWN_SKIP or not isinstance(accel, BVHAccelerator):
        return None
    n = len(surf.P)
    inst = np.asarray(inst, np.int64)
    geo = accel.sa  # the geometry the accelerator traces against
    # the points own_clear would look at, in a few passes over the level: hits on
    # instances of meshes of OWN_MIN_TRIS triangles or more (own_clear's own filter, per
    # instance, kept per packing), not at rough interfaces
    keep = _OWN_MESHES.get(geo)[2][inst]
    flags = MATERIAL_FLAGS.get(sa)
    if flags.any_interface:
        keep &= ~flags.interface[surf.mat]
    pts = np.flatnonzero(keep)
    out = np.full(n, -1, np.int32)
    if len(pts):
        clear = np.zeros(n, np.bool_)
        own_clear(geo, np.ascontiguousarray(geo.inst_xform, np.float64), surf.Q, surf.NG,
                  inst, np.asarray(prim, np.int64), pts, clear)
        mine = pts[clear[pts]]
        out[mine] = inst[mine]
    return out


def _own_meshes(geo) -> tuple:
    """``(mesh_tri_start (M + 1,), inst_mesh (I,) int64, big (I + 1,) bool)``: whether each
    instance's mesh has :data:`OWN_MIN_TRIS` triangles or more (the appended False: -1, a
    miss)."""
    start = np.asarray(geo.mesh_tri_start, np.int64)
    inst_mesh = np.asarray(geo.inst_mesh, np.int64)
    return start, inst_mesh, np.append(np.diff(start)[inst_mesh] >= OWN_MIN_TRIS, False)


#: :func:`_own_meshes` per packing
_OWN_MESHES = Memo(("mesh_tri_start", "inst_mesh"), _own_meshes)


class _OwnBounds:
    """:func:`own_clear`'s certificates per mesh and stretches per instance, for the last
    packing and instance matrices asked about (held weakly, as :class:`~.memo.Memo`),
    filled for the instances the points hit as they come (each level asks for a few)."""

    def __init__(self) -> None:
        self._kept: tuple | None = None  # (weak references, cert, have_mesh, sig, have_inst)

    def get(self, geo, xf, ks: np.ndarray) -> tuple:
        """``(cert (M, 3), sig (I,))`` with the rows of the instances ``ks`` (unique,
        int64) filled (infinite elsewhere, as the kernel reads only those)."""
        arrays = (geo.verts, geo.tris, geo.mesh_tri_start, geo.inst_mesh, xf)
        kept = self._kept  # read once: another thread may replace it
        if kept is None or any(r() is not a for r, a in zip(kept[0], arrays, strict=True)):
            n_mesh = len(_OWN_MESHES.get(geo)[0]) - 1
            kept = (None, np.full((n_mesh, 3), np.inf), np.zeros(n_mesh, np.bool_),
                    np.full(len(xf), np.inf), np.zeros(len(xf), np.bool_))
            try:
                self._kept = (tuple(weakref.ref(a) for a in arrays),) + kept[1:]
            except TypeError:  # not arrays: nothing kept
                self._kept = None
        _, cert, have_mesh, sig, have_inst = kept
        new = ks[~have_inst[ks]]
        if len(new):
            inst_mesh = _OWN_MESHES.get(geo)[1]
            for m in np.unique(inst_mesh[new]):
                if not have_mesh[m]:
                    cert[m] = CONVEX.get(geo, int(m))
                    have_mesh[m] = True
            # each instance's largest stretch (its linear part's spectral norm, past
            # rounding)
            lin = xf[new, :3, :3]
            ok = np.isfinite(lin).all(axis=(1, 2))
            if ok.any():
                sig[new[ok]] = (np.linalg.svd(lin[ok], compute_uv=False)[:, 0]
                                * (1.0 + 1e3 * tol.CONVEX_ROUND_REL))
            have_inst[new] = True
        return cert, sig


_OWN_BOUNDS = _OwnBounds()


def own_clear(geo, xf, Q, NG, inst, prim, pts, out) -> None:
    """Set ``out[i]`` (bool) for the points ``pts`` whose own instance (``inst``, hit on
    global triangle ``prim``; shadow origin ``Q``, geometric normal ``NG``) lies wholly
    behind the point's own plane, past the half offset :func:`_harmless` asks of each
    of its triangles: every such triangle is harmless to the point, so a group of such
    points need not test its own instance at all.

    The proof: the instance's mesh holds a convexity certificate
    (:func:`~.object_rays.convexity`, in its own space, kept per mesh): every vertex lies
    at most ``tau`` in front of each triangle's plane, on the side the point's normal
    takes (the winding's side, or the other one for a flat mesh seen from behind: a point
    seen from inside a closed convex mesh has no certificate). Under the instance's
    matrix (linear part ``A``, mirrored or not: the world normal follows the inverse
    transpose) that distance grows to at most ``tau |A|``; the point's normal differs from
    its triangle's world normal by a measured angle, over the instance's world diameter
    ``2 r |A|``; the point lies in front of the triangle's plane by its offset. Their sum,
    each term grown past its rounding (:data:`~.tolerances.CONVEX_ROUND_REL`), must stay
    at least half the offset behind (:data:`~.tolerances.SKIP_SELF_MARGIN_FRAC`), as
    :func:`_harmless`'s own test of each vertex asks: where it does, that test would have
    passed for every triangle of the instance, so the proof proves the same rows and the
    frames are unchanged bit for bit. ``geo``: the accelerator's geometry, ``xf`` its
    instance matrices."""
    start, inst_mesh, big = _OWN_MESHES.get(geo)
    k = inst[pts]
    worth = big[k]
    pts, k = pts[worth], k[worth]
    if len(pts) == 0:
        return
    hit = np.zeros(len(inst_mesh), np.bool_)
    hit[k] = True
    cert, sig = _OWN_BOUNDS.get(geo, xf, np.flatnonzero(hit))
    _own_kernel(geo.verts, geo.tris, xf, sig, start, inst_mesh, cert, Q, NG, inst, prim,
                float(geo.scene_extent), np.asarray(pts, np.int64), out)


@njit(cache=True, nogil=True, parallel=True)
def _own_kernel(verts, tris, xf, sig, mesh_start, inst_mesh, cert, Q, NG, inst, prim,
                extent, pts, out):
    """:func:`own_clear`'s bound per point (``cert`` (M, 3): each mesh's certificate
    ``out, inn, r``, infinite where it has none; ``sig`` (I,) a bound on each instance's
    largest stretch)."""
    for a in prange(pts.shape[0]):
        i = pts[a]
        k = inst[i]
        t = prim[i]
        out[i] = False
        if k < 0:
            continue
        m = inst_mesh[k]
        if t < mesh_start[m] or t >= mesh_start[m + 1]:
            continue
        M = xf[k]
        det = (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
               - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
               + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))
        ax, ay, az = _world(M, verts, tris, t, 0)
        bx, by, bz = _world(M, verts, tris, t, 1)
        cx, cy, cz = _world(M, verts, tris, t, 2)
        e1x, e1y, e1z = bx - ax, by - ay, bz - az
        e2x, e2y, e2z = cx - ax, cy - ay, cz - az
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not (ln > 0.0 and det != 0.0 and math.isfinite(det)):
            continue
        f = (1.0 if det > 0.0 else -1.0) / ln  # outward by the winding, mirrored or not
        nx, ny, nz = nx * f, ny * f, nz * f
        gx, gy, gz = NG[i, 0], NG[i, 1], NG[i, 2]
        if gx * nx + gy * ny + gz * nz > 0.0:
            tau = cert[m, 0]
        else:
            tau = cert[m, 1]
            nx, ny, nz = -nx, -ny, -nz
        if not tau < np.inf:
            continue
        diam = 2.0 * cert[m, 2] * sig[k]
        qx, qy, qz = Q[i, 0], Q[i, 1], Q[i, 2]
        big = max(abs(ax), abs(ay), abs(az), abs(bx), abs(by), abs(bz), abs(cx), abs(cy),
                  abs(cz), abs(qx), abs(qy), abs(qz))
        l1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        l2 = math.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
        err_n = tol.CONVEX_ROUND_REL * (big * (l1 + l2) + l1 * l2) / ln
        dn = math.sqrt((gx - nx) ** 2 + (gy - ny) ** 2 + (gz - nz) ** 2)
        bound = (gx * (ax - qx) + gy * (ay - qy) + gz * (az - qz) + max(tau, 0.0) * sig[k]
                 + (dn + err_n) * diam + 4.0 * tol.CONVEX_ROUND_REL * (big + diam))
        out[i] = bound <= -tol.SKIP_SELF_MARGIN_FRAC * spawn_offset(qx, qy, qz, extent)


def ball_rows(sa, accel, j: int, center, radius: float, surf, traced: np.ndarray,
              inst: np.ndarray, keys: np.ndarray, counters: dict | None = None,
              prim: np.ndarray | None = None):
    """(n,) bool: the surface points ``surf`` (primary hits on instances ``inst``, grouped
    by tile ``keys``) that see *every* point of the ball (``center``, ``radius``) -- the
    proof above with hard light ``j`` (a point or spot: one shadow ray) taken as a sphere
    light of that ball, over the points ``traced`` (n,) bool that trace a ray to it. A
    light dragged within the ball needs no shadow ray from the proven points: each of its
    segments lies in the group's shaft to the ball, and the harmless triangles' arguments
    (behind the point's own plane, which the ray leaves since the light faces the point;
    the point and the whole ball on one side of the triangle's plane) hold for every
    position in it. None where nothing is tried (as :func:`proven_rows`; ``prim`` as
    there)."""
    n = len(traced)
    ball = sa._replace(
        light_ext=np.ones(1, np.bool_),
        light_radius=np.full(1, float(radius)),
        light_pos=np.asarray(center, np.float64).reshape(1, 3),
        **{f: getattr(sa, f)[j:j + 1] for f in ("light_kind", "light_dir", "light_half",
                                               "light_size", "light_u", "light_v")})
    state = np.where(traced, SH_SOFT, -2).astype(np.int8)
    proven = proven_rows(ball, accel, surf._replace(sh_state=state), inst, keys, counters,
                         prim)
    return None if proven is None else proven.reshape(n)


def own_reflections(mine: np.ndarray | None, slots: np.ndarray, which: np.ndarray,
                    o: np.ndarray, d: np.ndarray, surf, counters: dict | None = None
                    ) -> np.ndarray | None:
    """(k,) int32: per spawned ray (``slots`` (k,) its slots in the level's
    :class:`~.shader.Spawned`, ``which`` (k,) its points of ``surf``, ``o``, ``d`` (k, 3)
    its origin and direction) the instance its closest-hit query leaves out, -1 none; None
    where ``mine`` (:func:`own_instances`' answer for the level's points) is None.
    ``counters["secondary_own_skip"]`` counts the rays offered one.

    A reflected ray (an even slot: mirror or glossy) of a point whose own instance
    :func:`own_clear` proved wholly behind the plane through its shadow origin ``Q`` with
    its geometric normal ``NG``, that leaves from ``Q`` itself (bit for bit) into the
    normal's side (``d . NG > 0``), stays in front of that plane all the way: the
    watertight test meets none of that instance's triangles, as for the soft samples
    :func:`own_instances` speaks of, so the BVH's query without it answers as the whole
    one, bit for bit (a ray leaving a convex ball starts inside the boxes of its tree near
    the point: a rough ball's glossy rays walked ~13 nodes where a camera ray walks ~2.5,
    docs/glossy.md). Refracted rays (odd slots) go into the surface: never offered."""
    if mine is None:
        return None
    out = np.full(len(slots), -1, np.int32)
    if len(slots):
        _own_reflections(np.asarray(mine, np.int32), np.asarray(slots, np.int64),
                         np.asarray(which, np.int64), o, d, surf.Q, surf.NG, out)
    if counters is not None:
        counters["secondary_own_skip"] = (counters.get("secondary_own_skip", 0)
                                          + int(np.count_nonzero(out >= 0)))
    return out


@njit(cache=True, nogil=True)
def _own_reflections(mine, slots, which, o, d, Q, NG, out):
    for k in range(slots.shape[0]):
        p = which[k]
        if mine[p] < 0 or slots[k] & 1:
            continue
        if not (o[k, 0] == Q[p, 0] and o[k, 1] == Q[p, 1] and o[k, 2] == Q[p, 2]):
            continue
        if d[k, 0] * NG[p, 0] + d[k, 1] * NG[p, 1] + d[k, 2] * NG[p, 2] > 0.0:
            out[k] = mine[p]
