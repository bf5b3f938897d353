"""Sampling the geometric attributes of lines against one object (seed 004, section 1.3).

A sample is the directed line of a kd-tree corner (or a cell's midpoint), traced against
its object *alone* (``intersect_object``) from the front face of the face pair. Its
attributes (:class:`Samples`):

* ``cls``: the patch equivalence class of the first hit (:mod:`.patches`), ``MISS`` when the
  line misses the object.
* ``P``, ``NS``, ``NG``, ``mat``: intersection point, shading and geometric normals (as the
  mesh winding gives them, not turned toward the line) and material.
* the *output ray* ``OP``, ``OD``: for simple surfaces the normal at the hit, for mirrors the
  reflected ray, for glass (any transmission) the *exit ray*: the refracted path through the
  object followed through every total internal reflection until it refracts out, with
  ``nint`` interfaces inside (TIRs plus the exit; 0 for an open sheet the refracted ray
  leaves without meeting again; -1 when there is no exit ray) and ``gain`` (RGB) the weight
  the base tracer gives that path past the entry: ``M + T`` per TIR, ``(1 - F) T`` at the
  exit (:mod:`..tracing.whitted`).
* the *internal reflection* at the exit ``RP``, ``RD``, ``rgain``: the base tracer splits the
  path where it refracts out (a total internal reflection does not split it); the part
  reflected back inside, ``M + F T`` of it, is the one ray a single exit ray leaves out. The
  renderer traces it from the interpolated origin and direction (weight 0: no such ray).
* ``thick``: the length of the line inside the object (thickness view).

The class key also says whether the output ray, where it is a ray (a mirror's reflection,
a glass's exit ray), meets the object again (:data:`REHIT`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.scene import MODEL_PRINCIPLED, SceneArrays
from ..interpolants.linetree import line_points
from ..tracing.shader import _material_of
from ..tracing.shading import (
    dot3,
    geometric_normal,
    mirror_dir,
    normalize3,
    principled_fresnel,
    shading_normal,
    spawn_offset,
    transmit,
)
from ..views import fields, view_type
from .thickness import walk

MISS = -1
#: internal interfaces followed along an exit path before it counts as trapped
MAX_INTERNAL = 12
#: bits of the class key reserved for the exit path's interface count and :data:`REHIT`
PATH_BITS = 64
#: class key bit: the output ray (reflected or exit ray) meets its own object again (past
#: the renderer's self-offset). Where corners differ in it (a rim or another part of a
#: concave object seen in its reflection, a torus's far side through its glass), an
#: interpolated output ray may pass the wrong side of that silhouette: such cells are two
#: classes of one patch, which the cheap test cannot tell apart, so their rays are traced
REHIT = 32


class Samples(NamedTuple):
    """The sample pool (capacity ``S``; ids from :class:`~.kdtree.KdForest`)."""

    cls: np.ndarray  # (S,) int32 class key (patch * PATH_BITS + nint + 1 [+ REHIT]), MISS
    mat: np.ndarray  # (S,) int32 material, -1 on a miss
    P: np.ndarray  # (S, 3) float64 hit point
    NS: np.ndarray  # (S, 3) float64 shading normal (winding side)
    NG: np.ndarray  # (S, 3) float64 geometric normal (winding side)
    OP: np.ndarray  # (S, 3) float64 output ray origin
    OD: np.ndarray  # (S, 3) float64 output ray direction (unit)
    gain: np.ndarray  # (S, 3) float64 exit path weight past the entry
    nint: np.ndarray  # (S,) int16 interfaces inside before the exit, -1: no exit ray
    thick: np.ndarray  # (S,) float64 length inside the object
    RP: np.ndarray  # (S, 3) float64 the internal reflection at the exit: origin (inside)
    RD: np.ndarray  # (S, 3) float64 its direction (unit)
    rgain: np.ndarray  # (S, 3) float64 its weight past the entry (0: none)


#: bytes of one sample
SAMPLE_BYTES = 4 + 4 + 5 * 24 + 24 + 2 + 8 + 3 * 24


def alloc_samples(cap: int) -> Samples:
    return Samples(np.full(cap, MISS, np.int32), np.full(cap, -1, np.int32),
                   *(np.zeros((cap, 3)) for _ in range(6)), np.full(cap, -1, np.int16),
                   np.zeros(cap), *(np.zeros((cap, 3)) for _ in range(3)))


def grow_samples(s: Samples, cap: int) -> Samples:
    """``s`` with capacity at least ``cap`` (doubling)."""
    old = len(s.cls)
    if cap <= old:
        return s
    new = alloc_samples(max(cap, 2 * old))
    for a, b in zip(s, new, strict=True):
        b[:old] = a
    return new


# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True, parallel=True)
def line_rays(box, inst, face, abcd, o, d):
    """Rays of lines ``abcd`` (n, 4): origin on the front face, direction to the back face."""
    for r in prange(inst.shape[0]):
        F = np.empty(3)
        B = np.empty(3)
        line_points(box, inst[r], face[r], abcd[r, 0], abcd[r, 1], abcd[r, 2], abcd[r, 3],
                    F, B)
        for m in range(3):
            o[r, m] = F[m]
            d[r, m] = B[m] - F[m]


_HitScene = view_type("_HitScene", SceneArrays, (
    "inst_mat", "inst_mat_start", "inst_nmat", "mat_ior", "mat_mirror",
    "mat_transmission", "scene_extent", "inst_mesh", "mesh_nrm", "normals", "mesh_slot",
    "tri_slot", "tris", "verts"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def hit_attributes(sa, tri_class, inst, o, d, t, prim, u, v, cls, mat, P, NS, NG, OP, OD,
                   gain, nint, path_o, path_d, glass):
    """First-hit attributes of ``n`` sample rays; for glass hits, the first internal ray.

    Fills cls (patch class * PATH_BITS; the path part is added when the exit is known),
    mat, P, NS, NG, and OP/OD for simple and mirror surfaces (normal, reflection). For
    transmissive hits ``glass[r]`` is set and path_o/path_d hold the refracted ray.
    """
    sa = _HitScene(*fields(sa, _HitScene))  # the fields its loop reads
    ext = sa.scene_extent
    for r in prange(inst.shape[0]):
        glass[r] = False
        gain[r, 0] = 1.0
        gain[r, 1] = 1.0
        gain[r, 2] = 1.0
        nint[r] = -1
        if prim[r] < 0:
            cls[r] = MISS
            mat[r] = -1
            continue
        k = inst[r]
        tri = prim[r]
        px = o[r, 0] + d[r, 0] * t[r]
        py = o[r, 1] + d[r, 1] * t[r]
        pz = o[r, 2] + d[r, 2] * t[r]
        nm = sa.inst_nmat[k]
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, nm, tri)
        sx, sy, sz = shading_normal(sa, sa.inst_mesh[k], nm, tri, u[r], v[r], gx, gy, gz)
        m = _material_of(sa, k, tri)
        cls[r] = tri_class[tri] * PATH_BITS
        mat[r] = m
        P[r, 0], P[r, 1], P[r, 2] = px, py, pz
        NS[r, 0], NS[r, 1], NS[r, 2] = sx, sy, sz
        NG[r, 0], NG[r, 1], NG[r, 2] = gx, gy, gz
        ux, uy, uz, _ = normalize3(d[r, 0], d[r, 1], d[r, 2])
        enter = dot3(ux, uy, uz, gx, gy, gz) < 0.0
        if not enter:
            gx, gy, gz = -gx, -gy, -gz
            sx, sy, sz = -sx, -sy, -sz
        OP[r, 0], OP[r, 1], OP[r, 2] = px, py, pz
        tr = sa.mat_transmission[m]
        if tr[0] > 0.0 or tr[1] > 0.0 or tr[2] > 0.0:
            eta = 1.0 / sa.mat_ior[m] if enter else sa.mat_ior[m]
            ok, tx, ty, tz, f = transmit(ux, uy, uz, sx, sy, sz, gx, gy, gz, eta)
            if ok:
                off = spawn_offset(px, py, pz, ext)
                glass[r] = True
                path_o[r, 0] = px - gx * off
                path_o[r, 1] = py - gy * off
                path_o[r, 2] = pz - gz * off
                path_d[r, 0], path_d[r, 1], path_d[r, 2] = tx, ty, tz
                continue
        mr = sa.mat_mirror[m]
        if mr[0] > 0.0 or mr[1] > 0.0 or mr[2] > 0.0 or tr[0] > 0.0 or tr[1] > 0.0 \
                or tr[2] > 0.0:
            qx, qy, qz = mirror_dir(ux, uy, uz, sx, sy, sz, gx, gy, gz)
            OD[r, 0], OD[r, 1], OD[r, 2] = qx, qy, qz
        else:
            OD[r, 0], OD[r, 1], OD[r, 2] = sx, sy, sz


_PathScene = view_type("_PathScene", SceneArrays, (
    "inst_mat", "inst_mat_start", "inst_nmat", "mat_ior", "mat_metal", "mat_metal_tint",
    "mat_metallic", "mat_mirror", "mat_model", "mat_specular", "mat_specular_ior",
    "mat_transmission", "scene_extent", "inst_mesh", "mesh_nrm", "normals", "mesh_slot",
    "tri_slot", "tris", "verts"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def path_step(sa, inst, rows, po, pd, t, prim, u, v, it, OP, OD, gain, nint, cls, alive,
              RP, RD, rgain):
    """One internal interface of the glass paths ``rows`` (their rays po/pd, hits t/prim/u/v).

    A path whose ray leaves without a hit exits as it is; one that refracts out exits there
    (``gain *= (1 - F) T``); one totally reflected continues (``gain *= M + T``).
    ``alive[q]`` tells whether path ``q`` continues (its po/pd updated).
    """
    sa = _PathScene(*fields(sa, _PathScene))  # the fields its loop reads
    ext = sa.scene_extent
    for q in prange(rows.shape[0]):
        r = rows[q]
        alive[q] = False
        if prim[q] < 0:
            OP[r, 0], OP[r, 1], OP[r, 2] = po[q, 0], po[q, 1], po[q, 2]
            OD[r, 0], OD[r, 1], OD[r, 2] = pd[q, 0], pd[q, 1], pd[q, 2]
            nint[r] = it
            cls[r] += it + 1
            continue
        k = inst[r]
        tri = prim[q]
        px = po[q, 0] + pd[q, 0] * t[q]
        py = po[q, 1] + pd[q, 1] * t[q]
        pz = po[q, 2] + pd[q, 2] * t[q]
        nm = sa.inst_nmat[k]
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, nm, tri)
        sx, sy, sz = shading_normal(sa, sa.inst_mesh[k], nm, tri, u[q], v[q], gx, gy, gz)
        m = _material_of(sa, k, tri)
        dx, dy, dz = pd[q, 0], pd[q, 1], pd[q, 2]
        enter = dot3(dx, dy, dz, gx, gy, gz) < 0.0
        if not enter:
            gx, gy, gz = -gx, -gy, -gz
            sx, sy, sz = -sx, -sy, -sz
        eta = 1.0 / sa.mat_ior[m] if enter else sa.mat_ior[m]
        tr = sa.mat_transmission[m]
        mr = sa.mat_mirror[m]
        off = spawn_offset(px, py, pz, ext)
        ok, tx, ty, tz, f = transmit(dx, dy, dz, sx, sy, sz, gx, gy, gz, eta)
        mx, my, mz = mr[0], mr[1], mr[2]
        if sa.mat_model[m] == MODEL_PRINCIPLED and (mx > 0.0 or my > 0.0 or mz > 0.0):
            # the base tracer's mirror share: times the Principled layer's Fresnel
            sp = sa.mat_specular[m]
            mt = sa.mat_metal[m]
            mq = sa.mat_metal_tint[m]
            fx, fy, fz = principled_fresnel(-dot3(dx, dy, dz, sx, sy, sz), sp[0], sp[1], sp[2],
                                            sa.mat_specular_ior[m], sa.mat_metallic[m],
                                            mt[0], mt[1], mt[2], mq[0], mq[1], mq[2])
            mx, my, mz = mx * fx, my * fy, mz * fz
        if ok and (tr[0] > 0.0 or tr[1] > 0.0 or tr[2] > 0.0):
            # the internal reflection the base tracer splits off here (as its shade kernel)
            qx, qy, qz = mirror_dir(dx, dy, dz, sx, sy, sz, gx, gy, gz)
            RP[r, 0] = px + gx * off
            RP[r, 1] = py + gy * off
            RP[r, 2] = pz + gz * off
            RD[r, 0], RD[r, 1], RD[r, 2] = qx, qy, qz
            rgain[r, 0] = gain[r, 0] * (mx + f * tr[0])
            rgain[r, 1] = gain[r, 1] * (my + f * tr[1])
            rgain[r, 2] = gain[r, 2] * (mz + f * tr[2])
            for c in range(3):
                gain[r, c] *= (1.0 - f) * tr[c]
            OP[r, 0] = px - gx * off
            OP[r, 1] = py - gy * off
            OP[r, 2] = pz - gz * off
            OD[r, 0], OD[r, 1], OD[r, 2] = tx, ty, tz
            nint[r] = it + 1
            cls[r] += it + 2
            continue
        gain[r, 0] *= mx + (tr[0] if not ok else f * tr[0])
        gain[r, 1] *= my + (tr[1] if not ok else f * tr[1])
        gain[r, 2] *= mz + (tr[2] if not ok else f * tr[2])
        qx, qy, qz = mirror_dir(dx, dy, dz, sx, sy, sz, gx, gy, gz)
        po[q, 0] = px + gx * off
        po[q, 1] = py + gy * off
        po[q, 2] = pz + gz * off
        pd[q, 0], pd[q, 1], pd[q, 2] = qx, qy, qz
        alive[q] = True


# ----------------------------------------------------------------------------- driver


def trace_samples(sa, accel, tri_class, box, inst, face, abcd, thickness: bool) -> Samples:
    """Attributes of ``n`` sample lines (inst (n,) int32, face (n,) int8, abcd (n, 4)).

    Returns a :class:`Samples` of length ``n``. ``thickness``: also (only) the length
    inside the object matters; glass paths are not followed then.
    """
    n = len(inst)
    inst = np.ascontiguousarray(inst, np.int32)
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    line_rays(box, inst, np.ascontiguousarray(face, np.int8), np.ascontiguousarray(abcd), o, d)
    s = alloc_samples(n)
    if n == 0:
        return s
    h = accel.intersect_object(inst, o, d, 0.0, np.inf)
    path_o = np.empty((n, 3))
    path_d = np.empty((n, 3))
    glass = np.empty(n, np.bool_)
    hit_attributes(sa, tri_class, inst, o, d, np.ascontiguousarray(h.t, np.float64),
                   np.ascontiguousarray(h.prim, np.int32), np.ascontiguousarray(h.u, np.float64),
                   np.ascontiguousarray(h.v, np.float64), s.cls, s.mat, s.P, s.NS, s.NG,
                   s.OP, s.OD, s.gain, s.nint, path_o, path_d, glass)
    if thickness:
        hit = np.flatnonzero(h.inst >= 0)
        if len(hit):
            def one(oo, dd, lo, hi, rows):
                return accel.intersect_object(inst[hit][rows], oo, dd, lo, hi)

            s.thick[hit] = walk(sa, one, o[hit], d[hit], 0.0, np.inf)
            # the output direction of the thickness view: the normal (angular test)
            s.OD[hit] = s.NS[hit]
            s.OP[hit] = s.P[hit]
        return s
    rows = np.flatnonzero(glass)
    po = path_o[rows]
    pd = path_d[rows]
    for it in range(MAX_INTERNAL):
        if len(rows) == 0:
            break
        hh = accel.intersect_object(inst[rows], po, pd, 0.0, np.inf)
        alive = np.empty(len(rows), np.bool_)
        path_step(sa, inst, rows.astype(np.int64), po, pd, np.ascontiguousarray(hh.t),
                  np.ascontiguousarray(hh.prim, np.int32), np.ascontiguousarray(hh.u),
                  np.ascontiguousarray(hh.v), it, s.OP, s.OD, s.gain, s.nint, s.cls, alive,
                  s.RP, s.RD, s.rgain)
        rows, po, pd = rows[alive], po[alive], pd[alive]
    if len(rows):  # trapped: no exit ray (the class key says so: nint -1)
        s.gain[rows] = 0.0
        s.rgain[rows] = 0.0
        s.OD[rows] = s.NS[rows]
        s.OP[rows] = s.P[rows]
    _mark_rehits(sa, accel, box, inst, glass, s)
    return s


def _mark_rehits(sa, accel, box, inst, glass, s: Samples) -> None:
    """Add :data:`REHIT` to the class keys of samples whose output ray meets their object
    again beyond the self-offset the renderer gives rays leaving an interpolated point
    (``RI_SELF_OFFSET_REL`` of the box diagonal)."""
    m = np.maximum(s.mat, 0)
    reflects = ((sa.mat_mirror[m] > 0).any(axis=1)
                | (sa.mat_transmission[m] > 0).any(axis=1))
    rows = np.flatnonzero((s.cls != MISS) & np.where(glass, s.nint >= 0, reflects))
    if not len(rows):
        return
    k = inst[rows]
    diag = np.linalg.norm(box[k, 1] - box[k, 0], axis=1)
    again = accel.occludes_object(k, s.OP[rows], s.OD[rows], tol.RI_SELF_OFFSET_REL * diag,
                                  np.full(len(rows), np.inf))
    s.cls[rows[again]] += REHIT


def store(pool: Samples, ids: np.ndarray, batch: Samples) -> None:
    """Write ``batch`` into ``pool`` at ``ids``."""
    for a, b in zip(pool, batch, strict=True):
        a[ids] = b
