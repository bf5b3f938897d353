"""Whether a ray meets one object, proven without its tree where its shape allows (BASE
re-shade, :mod:`.shadow_reshade`).

A small object moved under soft light is crossed by the soft samples of every point in
its shadow, old and new: most of those rays pass through it, and traversing its tree is
then most of the re-shade's cost (``studio``'s mirror ball: 5,120 triangles, ~95,000 of
the ~111,000 rays its move makes the frame test again). Two proofs, per object, in its
own space, answer most of them as the accelerator's object-space test would
(:meth:`~..accel.interface.Accelerator.occludes_object`; it asks the rest):

* **miss**: the segment stays farther from the centre ``c`` than every vertex (grown by
  :data:`~.tolerances.SOLID_BALL_REL` of that radius): no triangle is on it;
* **meet**: the segment starts outside that sphere and passes within ``r_in`` of ``c``,
  where the mesh is *closed and consistently oriented* (each edge, vertices welded by
  their coordinates, used once in each direction) and ``c`` is at least ``r_in`` on the
  same side of every triangle's plane (``c`` sees the whole surface from inside: a convex
  mesh, or one star-shaped about a ball) -- ``r_in`` shrunk by the same margin. Then the
  solid angle of every triangle seen from ``c`` has one sign, their sum is a non-zero
  multiple of 4 pi (a closed oriented surface), so ``c`` is inside and the segment
  crosses the surface on its way from the outside; at the first such point every
  triangle holding it is crossed from its outer side to its inner side, at an angle
  bounded below by the margin, and the watertight triangle test (:mod:`~..accel.triangle`)
  lets no ray slip between triangles that share an edge or a vertex: the test reports a
  hit, before the segment's end (the crossing comes before its closest point to ``c``).

Both hold for any ray within rounding of the one the accelerator takes to object space
(:func:`~..accel.bvh.ray_to_object`, the same matrices): the margins are ~10^10 ulps of the
object's size and ~10^4 ulps of the ray's coordinates (:data:`~.tolerances.
SOLID_RAY_SLACK_REL`). A segment whose closest point to ``c`` is its end (``tmax``) is
proven as well: the crossing still comes first. They
hold for accelerators whose object test is that watertight float64 one (the BVH and the
brute force: :attr:`~..accel.interface.Accelerator.any_hit_by_object`).
"""

from __future__ import annotations

import math
import weakref

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..accel.bvh import ray_to_object

#: meshes with more triangles are not examined (their rays go to the accelerator)
SOLID_MAX_TRIS = 200_000


def solid_ball(verts: np.ndarray, tris: np.ndarray) -> tuple:
    """``(c (3,), r_in, r_out)`` of a mesh (``tris`` (T, 3) into ``verts``), in its own
    space (module doc): ``r_out`` the grown radius of its vertices about ``c``, ``r_in``
    the shrunk inner radius, 0 where the mesh is not closed and oriented or ``c`` does
    not see all of it from inside. ``c``: the centre of its vertices' box. A mesh of more
    than :data:`SOLID_MAX_TRIS` triangles proves nothing (``r_out`` infinite)."""
    if len(tris) > SOLID_MAX_TRIS:
        return np.zeros(3), 0.0, np.inf
    used = np.unique(tris)
    v = np.asarray(verts[used], np.float64)
    if len(v) == 0:
        return np.zeros(3), 0.0, 0.0  # (no triangle: every ray misses)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    r = float(np.sqrt(((v - c) ** 2).sum(axis=1).max()))
    grow = tol.SOLID_BALL_REL * r
    r_out = r + grow
    if not _closed_oriented(v, np.searchsorted(used, tris)):
        return c, 0.0, r_out
    a, b, e = (np.asarray(verts[tris[:, k]], np.float64) for k in range(3))
    n = np.cross(b - a, e - a)
    nl = np.sqrt((n * n).sum(axis=1))
    if not (nl > 0.0).all():
        return c, 0.0, r_out
    side = ((a - c) * n).sum(axis=1) / nl  # (c's signed distance to each plane, negated)
    if not ((side > 0.0).all() or (side < 0.0).all()):
        return c, 0.0, r_out
    r_in = float(np.abs(side).min()) - grow
    return c, max(r_in, 0.0), r_out


def _closed_oriented(v: np.ndarray, tris: np.ndarray) -> bool:
    """Every edge of ``tris`` (into ``v``; vertices with equal coordinates welded) is used
    once in each direction, and none joins a vertex to itself."""
    _, weld = np.unique(v, axis=0, return_inverse=True)
    t = weld.reshape(-1)[tris].astype(np.int64)
    a = t.reshape(-1)
    b = t[:, [1, 2, 0]].reshape(-1)
    if (a == b).any():
        return False
    w = int(t.max()) + 1
    fwd = np.sort(a * w + b)
    if (fwd[1:] == fwd[:-1]).any():
        return False
    return bool(np.array_equal(fwd, np.sort(b * w + a)))


def _slot_get(holder, sa, mesh: int, compute):
    """``compute(verts, tris)`` of mesh ``mesh`` of packing ``sa``, kept in ``holder``'s
    one slot ``_kept`` (weak references to ``sa.verts`` and ``sa.tris``, {mesh: value}):
    the slot is read once and a new one put whole, and the value goes into the dict read
    with its references, so a packing's dict holds that packing's values only (an earlier
    ``_of`` and dict set one after the other let a call for another packing, from another
    thread, swap the dict between them and receive this packing's value)."""
    kept = holder._kept
    if kept is None or kept[0]() is not sa.verts or kept[1]() is not sa.tris:
        kept = (weakref.ref(sa.verts), weakref.ref(sa.tris), {})
        holder._kept = kept
    got = kept[2].get(mesh)
    if got is None:
        s, e = int(sa.mesh_tri_start[mesh]), int(sa.mesh_tri_start[mesh + 1])
        got = kept[2][mesh] = compute(sa.verts, np.asarray(sa.tris[s:e]))
    return got


class SolidBalls:
    """:func:`solid_ball` per mesh of the last packing asked about (its ``verts`` and
    ``tris`` arrays, held weakly: a packing that moves objects shares them)."""

    def __init__(self) -> None:
        # (weak references to verts and tris, {mesh: ball}): one slot, read once and
        # replaced whole, so that a packing's dict never receives another packing's
        # values (two threads, or a call made while one computes: session 42 review)
        self._kept: tuple | None = None

    def get(self, sa, mesh: int) -> tuple:
        return _slot_get(self, sa, mesh, solid_ball)


BALLS = SolidBalls()

#: convexity certificates cost (triangles x vertices): meshes past this certify nothing
CONVEX_MAX_WORK = 200_000_000


def convexity(verts: np.ndarray, tris: np.ndarray) -> tuple:
    """``(out, inn, r)``: a mesh's convexity certificate (``tris`` (T, 3) into ``verts``),
    in its own space. ``out``: the most any of its vertices lies in front of any of its
    triangles' planes (unit normal by the winding: ``(b - a) x (c - a)``), ``inn`` the
    same behind them (the winding reversed); each is infinite unless it is at most
    :data:`~.tolerances.CONVEX_TOL_REL` of ``2 r`` (the mesh is not convex on that side, or
    too large to examine: :data:`CONVEX_MAX_WORK`). ``r``: the vertices' radius about
    their box's centre, grown by ``SOLID_BALL_REL``. Degenerate triangles give no plane
    (their vertices are still tested). A closed convex mesh wound outward has a small
    ``out``; a flat one both; a non-convex one neither. Open meshes may be certified:
    the certificate speaks of the vertices alone (:func:`~.shaft_skip.own_clear`)."""
    used = np.unique(tris)
    v = np.ascontiguousarray(verts[used], np.float64)
    if len(v) == 0:
        return np.inf, np.inf, 0.0
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    r = float(np.sqrt(((v - c) ** 2).sum(axis=1).max())) * (1.0 + tol.SOLID_BALL_REL)
    if len(tris) * len(v) > CONVEX_MAX_WORK:
        return np.inf, np.inf, r
    ext = np.empty((len(tris), 2))
    _plane_excess(v, np.ascontiguousarray(np.searchsorted(used, tris), np.int64), r,
                  float(np.abs(v).max()), ext)
    lim = tol.CONVEX_TOL_REL * 2.0 * r
    out, inn = float(ext[:, 0].max()), float(ext[:, 1].max())
    return (out if out <= lim else np.inf), (inn if inn <= lim else np.inf), r


@njit(cache=True, nogil=True, parallel=True)
def _plane_excess(v, tris, r, big, ext):
    """``ext[t]``: (most in front of, most behind) triangle ``t``'s plane any vertex ``v``
    lies (unit normal; -inf, -inf for a degenerate triangle), each grown past its
    rounding (:data:`~.tolerances.CONVEX_ROUND_REL` of the coordinates' magnitude ``big``,
    and of the normal's direction, over the vertices' diameter ``2 r``)."""
    for t in prange(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        hi = -np.inf
        lo = np.inf
        if ln > 0.0:
            for k in range(v.shape[0]):
                s = (nx * (v[k, 0] - v[a, 0]) + ny * (v[k, 1] - v[a, 1])
                     + nz * (v[k, 2] - v[a, 2])) / ln
                hi = max(hi, s)
                lo = min(lo, s)
        l1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        l2 = math.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
        err = tol.CONVEX_ROUND_REL * (big + 2.0 * r * (big * (l1 + l2) + l1 * l2) / ln
                                      if ln > 0.0 else 0.0)
        ext[t, 0] = hi + err
        ext[t, 1] = -lo + err


class Convexities:
    """:func:`convexity` per mesh of the last packing asked about (as :class:`SolidBalls`:
    its ``verts`` and ``tris`` held weakly, so a packing that moves objects keeps them)."""

    def __init__(self) -> None:
        self._kept: tuple | None = None  # (as SolidBalls': one slot, replaced whole)

    def get(self, sa, mesh: int) -> tuple:
        return _slot_get(self, sa, mesh, convexity)


CONVEX = Convexities()


@njit(cache=True, nogil=True, parallel=True)
def prove_rays(inv, i, c, r_in, r_out, o, d, tmax, rows, out):
    """For the rays ``rows`` of ``o, d`` (t in [0, ``tmax``]) against object ``i`` (its
    inverse matrix in ``inv``, its :func:`solid_ball` ``c, r_in, r_out``): ``out`` (len
    rows) int8, 1 proven to meet it, -1 proven to miss it, 0 not proven."""
    for k in prange(rows.shape[0]):
        r = rows[k]
        ox, oy, oz, dx, dy, dz = ray_to_object(inv, i, o[r, 0], o[r, 1], o[r, 2], d[r, 0],
                                               d[r, 1], d[r, 2])
        wx, wy, wz = c[0] - ox, c[1] - oy, c[2] - oz
        dd = dx * dx + dy * dy + dz * dz
        s = (wx * dx + wy * dy + wz * dz) / dd
        s = min(max(s, 0.0), tmax[r])
        if math.isnan(s):
            out[k] = 0
            continue
        px, py, pz = wx - s * dx, wy - s * dy, wz - s * dz
        near = math.sqrt(px * px + py * py + pz * pz)
        start = math.sqrt(wx * wx + wy * wy + wz * wz)
        slack = tol.SOLID_RAY_SLACK_REL * (start + s * math.sqrt(dd))
        if near > r_out + slack:
            out[k] = -1
        elif near < r_in - slack and start > r_out + slack:
            out[k] = 1
        else:
            out[k] = 0


def meets_object(sa, accel, i: int, o, d, tmax, rows, counters=None) -> np.ndarray:
    """(len rows,) bool: the rays ``rows`` of ``o, d, tmax`` (from t = 0) meet live object
    ``i`` of ``sa`` -- :meth:`~..accel.interface.Accelerator.occludes_object`'s answer,
    proven here where the module doc's proofs hold, asked of ``accel`` for the rest.
    ``counters``: adds ``shadow_proven`` (rays answered without the accelerator)."""
    ball = BALLS.get(sa, int(sa.inst_mesh[i]))
    proof = np.zeros(len(rows), np.int8)
    if len(rows):
        prove_rays(sa.inst_inv, i, ball[0], ball[1], ball[2], o, d, tmax,
                   np.ascontiguousarray(rows, np.int64), proof)
    met = proof > 0
    ask = np.flatnonzero(proof == 0)
    if len(ask):
        r = rows[ask]
        met[ask] = accel.occludes_object(i, o[r], d[r], np.zeros(len(r)), tmax[r])
    if counters is not None:
        counters["shadow_proven"] = counters.get("shadow_proven", 0) + len(rows) - len(ask)
    return met
