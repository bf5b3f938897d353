"""Reprojected visibility (seed 000, section 2, and its reference [2]): after a camera move,
the pixels that the previous frame interpolated find their interpolant from that frame,
with neither a closest-hit ray nor a walk down the linetrees -- conservatively: a ray is
reprojected only where its visible surface is proven to be the interpolant's.

Per frame that follows a full frame of the same cache (no edit between, perspective camera):

1. **Candidates.** Each pixel of the previous frame that was interpolated leaves its
   interpolant at its pixel, and its hit point is projected into the new camera (forward
   reprojection; the previous value stays where nothing lands: the gaps). One candidate
   interpolant per pixel, for all its samples.
2. **Cells, once per frame and candidate** (``_cell_ok``), from the new eye ``E``:
   (a) the Haines-Wallace shaft from ``E`` to the world box of the interpolant's slab
   hexahedron (the lines of its cell between its certified depths ``z_lo, z_hi``) meets no
   triangle of any other object; (b) the eye lies in front of the slab (depth below
   ``z_lo``), and the object has no triangle in the hexahedron of the cell's lines between
   the eye's depth (at least 0, the front face) and ``z_lo``; (c) the slab box is within the
   camera's clipping range; (d) the interpolant's corner samples carry no texture term (a
   textured pixel needs its own hit for its texel).
3. **Rays** (``_reproject_rays``): the ray's face pair is the cell's and its line
   coordinates (unclamped) lie in the cell; then it is interpolated at once.

Why that is the ray's visible surface: every line of a valid cell crosses the object
exactly once between ``z_lo`` and ``z_hi`` (the slab guarantee, INTERPOLANTS.md); along the
ray, depth grows (the face pair is the ray's dominant direction), so before that crossing
the ray runs first through the near hexahedron, where (b) leaves no triangle of the object,
then through the slab, where the crossing is the only one. The segment from ``E`` to the
crossing lies in the shaft of (a), so no other object is crossed before it, and (c) keeps
it inside the ray's ``[tmin, tmax]``. So the crossing is the ray's closest hit, the leaf
its walk would reach is the candidate's, and the interpolated radiance is the one a
closest-hit ray and a walk would give. Tests with slack move every plane outward.

Every other ray (no candidate, another cell, a failed test -- disocclusions, silhouettes,
cells that an object now hides) gets its closest-hit ray and walk as before. A reprojected
ray has no hit: the pixel records of a session get its object and a view segment to the far
end of its slab (past the hit: it can only make more pixels dirty after an edit).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ..frame import CLASS_INTERPOLATED, CLASS_REBUILT
from ..geometry.cameras import CameraParams
from .linetree import (
    EMPTY,
    cell_bounds,
    descend_one,
    dominant_face,
    face_frame,
    interpolate16,
)
from .shafts import MAX_PLANES, hexa_planes, hw_shaft, mesh_any, other_geometry, to_object

#: Reprojection on or off (benchmarks and tests compare; frames are the same either way).
ENABLED = True


class Reprojected(NamedTuple):
    """Rays interpolated by reprojection, as :meth:`~.cache.InterpolantCache.resolve` takes
    them (``pre``)."""

    rad: np.ndarray  # (n, 3) float64 interpolated radiance
    done: np.ndarray  # (n,) bool: interpolated here
    pcls: np.ndarray  # (n,) uint8 pixel class
    pinterp: np.ndarray  # (n,) int32 interpolant, -1 elsewhere


class CellArrays(NamedTuple):
    """A frame's eye and clipping range, and step 2's outcomes per pool id
    (:class:`FrameCells`)."""

    eye: np.ndarray  # (3,) float64
    tnear: float  # the largest clip-start distance of any ray
    tfar: float  # the smallest clip-end distance of any ray
    serial: np.ndarray  # (cap,) int64 pool serial the outcome was found for
    ok: np.ndarray  # (cap,) bool


class View(NamedTuple):
    """What a full frame leaves for the next one's reprojection."""

    width: int
    height: int
    same_pixel: np.ndarray  # (h * w,) int32 interpolant of the pixel's first interpolated
    # sample, else -1
    points: np.ndarray  # (m, 3) float32 hit point of each such sample
    interp: np.ndarray  # (m,) int32 its interpolant


@njit(cache=True, nogil=True)
def _remember(pix, pinterp, o, d, t, same_pixel, points, pq):
    """Fill a :class:`View` from a frame's rays (sample-major over ``pix``): per pixel, its
    first interpolated sample; returns their number."""
    k = pix.shape[0]
    m = 0
    for r in range(pinterp.shape[0]):
        q = pinterp[r]
        if q < 0:
            continue
        i = pix[r - (r // k) * k]
        if same_pixel[i] >= 0 or not math.isfinite(t[r]):
            continue
        same_pixel[i] = q
        points[m, 0] = o[r, 0] + d[r, 0] * t[r]
        points[m, 1] = o[r, 1] + d[r, 1] * t[r]
        points[m, 2] = o[r, 2] + d[r, 2] * t[r]
        pq[m] = q
        m += 1
    return m


@njit(cache=True, nogil=True)
def _splat(cp, points, interp, cand):
    """Forward reprojection: each point's interpolant at the pixel it projects to
    (perspective camera)."""
    m = cp.xform
    w = cp.width
    h = cp.height
    for p in range(points.shape[0]):
        x = points[p, 0] - m[0, 3]
        y = points[p, 1] - m[1, 3]
        z = points[p, 2] - m[2, 3]
        cx = x * m[0, 0] + y * m[1, 0] + z * m[2, 0]
        cy = x * m[0, 1] + y * m[1, 1] + z * m[2, 1]
        cz = -(x * m[0, 2] + y * m[1, 2] + z * m[2, 2])
        if not cz > 0.0:
            continue
        px = np.floor((cx / cz - cp.x0) / cp.pixsize)
        py = np.floor((cy / cz - cp.y0) / cp.pixsize)
        if not (0 <= px < w and 0 <= py < h):
            continue
        cand[int(py) * w + int(px)] = interp[p]


@njit(cache=True, nogil=True)
def _cell_hexa(box, inst, face, depth, coord, z0, z1, V):
    """The 8 vertices of the hexahedron of a cell's lines between depths z0 and z1 (the
    vertex order of :func:`.shafts.hexa_planes`)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    s = 1.0 / (1 << depth)
    for v in range(8):
        z = z1 if v & 4 else z0
        f = z / L
        bi = v & 1
        bj = (v >> 1) & 1
        V[v, k] = front - z if neg else front + z
        V[v, i] = (1 - f) * (li + (coord[0] + bi) * s * wi) + f * (li + (coord[2] + bi) * s * wi)
        V[v, j] = (1 - f) * (lj + (coord[1] + bj) * s * wj) + f * (lj + (coord[3] + bj) * s * wj)


@njit(cache=True, nogil=True)
def _cell_ok(qs, box, lt, inode, izlo, izhi, dif, isamples, eye, tnear, tfar, q):
    """Step 2 of the module doc: whether interpolant ``q`` (its linetree leaf ``inode[q]``,
    slab ``izlo[q], izhi[q]``, corner samples ``isamples[q]`` with texture terms ``dif``)
    may be reprojected from ``eye``. ``tnear``: the largest clip-start distance of any ray,
    ``tfar`` the smallest clip-end distance. (The arrays one by one: called once per
    interpolant, a call with the pool's and the frame's tuples measured 2-10% slower.)"""
    if True:
        # (d) no texture term in the corner samples
        textured = False
        for c in range(16):
            sid = isamples[q, c]
            if dif[sid, 0] != 0.0 or dif[sid, 1] != 0.0 or dif[sid, 2] != 0.0:
                textured = True
        if textured:
            return False
        nd = inode[q]
        tree = lt.tree[nd]
        inst = tree // 6
        face = tree % 6
        k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
        ze = front - eye[k] if neg else eye[k] - front  # the eye's depth
        zlo = izlo[q]
        if not ze < zlo:
            return False
        V = np.empty((8, 3))
        _cell_hexa(box, inst, face, lt.depth[nd], lt.coord[nd], zlo, izhi[q], V)
        lo = np.empty(3)
        hi = np.empty(3)
        for m in range(3):
            lo[m] = V[0, m]
            hi[m] = V[0, m]
            for v in range(1, 8):
                lo[m] = min(lo[m], V[v, m])
                hi[m] = max(hi[m], V[v, m])
        # (c) the slab box within every ray's clipping range
        dn = 0.0
        df = 0.0
        for m in range(3):
            g = max(lo[m] - eye[m], 0.0, eye[m] - hi[m])
            dn += g * g
            gf = max(abs(lo[m] - eye[m]), abs(hi[m] - eye[m]))
            df += gf * gf
        if not (math.sqrt(dn) > tnear and math.sqrt(df) < tfar):
            return False
        plo = np.empty((MAX_PLANES, 4))
        bbo = np.empty(6)
        P = np.empty((MAX_PLANES + 8, 3))
        Q = np.empty((MAX_PLANES + 8, 3))
        # (a) nothing else between the eye and the slab
        pl = np.empty((MAX_PLANES, 4))
        bb = np.empty(6)
        npl = hw_shaft(eye, eye, lo, hi, qs.slack, pl, bb)
        named = np.empty(1, np.int32)
        named[0] = inst
        if other_geometry(qs, pl, npl, bb, named, np.int64(1), plo, bbo, P, Q):
            return False
        # (b) nothing of the object itself between the eye (or the front face) and the slab.
        # The side planes of a cell's lines do not depend on the depths: taken from the
        # whole depth (well conditioned however thin the near region), the depth planes
        # set apart
        z0 = max(ze, 0.0)
        if zlo > z0:
            _cell_hexa(box, inst, face, lt.depth[nd], lt.coord[nd], z0, zlo, V)
            for m in range(3):
                bb[m] = V[0, m]
                bb[3 + m] = V[0, m]
                for v in range(1, 8):
                    bb[m] = min(bb[m], V[v, m])
                    bb[3 + m] = max(bb[3 + m], V[v, m])
                bb[m] -= qs.slack
                bb[3 + m] += qs.slack
            _cell_hexa(box, inst, face, lt.depth[nd], lt.coord[nd], 0.0, L, V)
            hexa_planes(V, qs.slack, pl)
            for f in range(4, 6):
                pl[f, 0] = 0.0
                pl[f, 1] = 0.0
                pl[f, 2] = 0.0
            # inside: z0 <= depth <= zlo, depth = x_k - front (front - x_k when neg)
            sgn = -1.0 if neg else 1.0
            pl[4, k] = sgn
            pl[4, 3] = -sgn * front - z0 + qs.slack
            pl[5, k] = -sgn
            pl[5, 3] = sgn * front + zlo + qs.slack
            to_object(qs.inst_xform[inst], qs.inst_inv[inst], pl, np.int64(6), bb, plo, bbo)
            if mesh_any(qs, qs.inst_mesh[inst], plo, np.int64(6), bbo, P, Q):
                return False
        return True


@njit(cache=True, nogil=True)
def _reproject_rays(qs, box, lt, roots, pool, dif, clock, cells, cand_pix, pix, o, d, tmax,
                    out):
    """Step 3 of the module doc, with step 2 run for each interpolant the first time a ray
    reaches it in this frame (``cells.ok[q]`` holds for pool serial ``cells.serial[q]``).

    Each ray (one per pixel ``pix``): its line in the object of its pixel's candidate
    ``cand_pix[pix[r]]`` down that object's linetree (``lt``, roots ``roots``; reusing the
    leaf of the ray before it where the line lies in it, as the walk does); if the leaf's
    interpolant is proven, the ray is interpolated (``out``, a :class:`Reprojected`; the
    interpolant's LRU stamp set to ``clock``) and gets ``tmax[r] = -1`` (an empty clipping
    range: no closest hit). Serial: the proofs are written as they are found. Returns the
    number of rays interpolated."""
    inode, live, serial, rad16 = pool.node, pool.live, pool.serial, pool.rad
    irebuilt, stamp = pool.rebuilt, pool.stamp
    cell_serial, cell_ok = cells.serial, cells.ok
    rad, done, pcls, pinterp = out
    n = o.shape[0]
    abcd = np.empty(4)
    lo = np.zeros(4)
    hi = np.zeros(4)
    pinst = -1
    pface = -1
    pleaf = -1
    got = 0
    for r in range(n):
        q0 = cand_pix[pix[r]]
        if q0 < 0 or q0 >= live.shape[0] or not live[q0]:
            continue
        inst = lt.tree[inode[q0]] // 6
        face = dominant_face(d[r, 0], d[r, 1], d[r, 2])
        kk, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
        back = front - L if neg else front + L
        tf = (front - o[r, kk]) / d[r, kk]
        tb = (back - o[r, kk]) / d[r, kk]
        abcd[0] = (o[r, i] + tf * d[r, i] - li) / wi
        abcd[1] = (o[r, j] + tf * d[r, j] - lj) / wj
        abcd[2] = (o[r, i] + tb * d[r, i] - li) / wi
        abcd[3] = (o[r, j] + tb * d[r, j] - lj) / wj
        if not (0.0 <= abcd[0] <= 1.0 and 0.0 <= abcd[1] <= 1.0 and 0.0 <= abcd[2] <= 1.0
                and 0.0 <= abcd[3] <= 1.0):
            continue  # the line misses the face pair (no crossing in any cell)
        if (inst == pinst and face == pface and lo[0] <= abcd[0] < hi[0]
                and lo[1] <= abcd[1] < hi[1] and lo[2] <= abcd[2] < hi[2]
                and lo[3] <= abcd[3] < hi[3]):
            nd = pleaf
        else:
            root = roots[inst, face]
            if root < 0:
                continue
            nd, _ = descend_one(lt, root, abcd, EMPTY)
            pinst = inst
            pface = face
            pleaf = nd
            cell_bounds(lt, nd, lo, hi)
        q = lt.leaf[nd]
        if q < 0:
            continue
        if cell_serial[q] != serial[q]:
            cell_ok[q] = _cell_ok(qs, box, lt, inode, pool.zlo, pool.zhi, dif, pool.samples,
                                  cells.eye, cells.tnear, cells.tfar, q)
            cell_serial[q] = serial[q]
        if not cell_ok[q]:
            continue
        s = float(1 << lt.depth[nd])
        x0 = abcd[0] * s - lt.coord[nd, 0]
        x1 = abcd[1] * s - lt.coord[nd, 1]
        x2 = abcd[2] * s - lt.coord[nd, 2]
        x3 = abcd[3] * s - lt.coord[nd, 3]
        if not (0.0 <= x0 <= 1.0 and 0.0 <= x1 <= 1.0 and 0.0 <= x2 <= 1.0
                and 0.0 <= x3 <= 1.0):
            continue  # (rounding at a cell's edge)
        interpolate16(rad16, q, rad, r, x0, x1, x2, x3)
        done[r] = True
        pinterp[r] = q
        pcls[r] = CLASS_REBUILT if irebuilt[q] else CLASS_INTERPOLATED
        stamp[q] = clock
        tmax[r] = -1.0
        got += 1
    return got


@njit(cache=True, nogil=True)
def _slab_points(box, lt, inode, izlo, izhi, pinterp, o, d, t, reprojected, frac):
    """``t[r]`` of reprojected rays (they have no hit): the ray parameter at depth ``z_lo +
    frac (z_hi - z_lo)`` of their interpolant's slab (the middle: a point for the next
    frame's reprojection; the far end: a view segment that reaches past the hit)."""
    for r in range(t.shape[0]):
        q = pinterp[r]
        if q < 0 or not reprojected[r]:
            continue
        nd = inode[q]
        tree = lt.tree[nd]
        inst = tree // 6
        face = tree % 6
        kk, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
        zm = izlo[q] + frac * (izhi[q] - izlo[q])
        t[r] = ((front - zm if neg else front + zm) - o[r, kk]) / d[r, kk]


class Remember:
    """The :class:`View` a full frame leaves (its interpolated samples), filled tile by tile
    (:meth:`add`) of its first pass."""

    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self.same = np.full(width * height, -1, np.int32)
        self.points: list = []
        self.pq: list = []

    def add(self, pix: np.ndarray, pinterp: np.ndarray, o: np.ndarray, d: np.ndarray,
            t: np.ndarray) -> None:
        """The rays of one tile (one per pixel ``pix``; ``t`` their hit distances)."""
        m = min(int(np.count_nonzero(pinterp >= 0)), len(pix))
        points = np.empty((m, 3), np.float32)
        pq = np.empty(m, np.int32)
        m = _remember(np.ascontiguousarray(pix, np.int64), pinterp, o, d, t, self.same,
                      points, pq)
        self.points.append(points[:m])
        self.pq.append(pq[:m])

    def view(self) -> View:
        pts = np.concatenate(self.points) if self.points else np.zeros((0, 3), np.float32)
        pq = np.concatenate(self.pq) if self.pq else np.zeros(0, np.int32)
        return View(self.width, self.height, self.same, pts, pq)


def slab_points(cache, pinterp, o, d, t, reprojected, frac: float = 0.5) -> None:
    """``t`` of reprojected rays at ``frac`` of their interpolant's slab
    (:func:`_slab_points`)."""
    p = cache.pool
    _slab_points(cache.box, cache.trees.arrays, p.node, p.zlo, p.zhi, pinterp, o, d, t,
                 reprojected, float(frac))


class FrameCells:
    """Step 2's outcomes for one frame's eye, kept across its samples (per pool id, with the
    serial it was found for: an id freed and reused within the frame is tested again)."""

    def __init__(self, cp: CameraParams) -> None:
        self.eye = np.ascontiguousarray(cp.xform[:3, 3], np.float64)
        # every ray's clipping range (distances along the ray: the clip planes are measured
        # along the view axis, so a ray's distances grow with its slope, at least 1)
        u = (cp.x0, cp.x0 + cp.width * cp.pixsize)
        v = (cp.y0, cp.y0 + cp.height * cp.pixsize)
        slope = max(math.sqrt(1.0 + a * a + b * b) for a in u for b in v)
        self.tnear = float(cp.clip_start) * slope
        self.tfar = float(cp.clip_end)
        self.serial = np.zeros(0, np.int64)
        self.ok = np.zeros(0, np.bool_)

    def arrays(self) -> CellArrays:
        return CellArrays(self.eye, self.tnear, self.tfar, self.serial, self.ok)

    def grow(self, n: int) -> None:
        """Room for pool ids below ``n``."""
        if len(self.serial) < n:
            grow = n - len(self.serial)
            self.serial = np.concatenate([self.serial, np.zeros(grow, np.int64)])
            self.ok = np.concatenate([self.ok, np.zeros(grow, np.bool_)])


def candidates(view: View | None, cp: CameraParams, splat: bool = True):
    """(h * w,) int32 each pixel's candidate interpolant (-1: none) from ``view`` (module
    doc, step 1; ``splat``: the view is another camera's, its points are projected into this
    one), or None when nothing can be reprojected."""
    if (not ENABLED or view is None or cp.ortho or view.width != cp.width
            or view.height != cp.height or len(view.interp) == 0):
        return None
    cand_pix = view.same_pixel
    if splat:
        cand_pix = cand_pix.copy()
        _splat(cp, view.points, view.interp, cand_pix)
    return cand_pix


def reproject(cache, cand_pix: np.ndarray | None, cells: FrameCells, pix: np.ndarray,
              o, d, tmax):
    """The rays (one per pixel ``pix``) whose interpolant is found by reprojection from the
    candidates ``cand_pix`` (:func:`candidates`; module doc). Returns None when nothing
    can be, else ``(pre, tmax, m)``: ``pre`` the :class:`Reprojected` arrays for
    :meth:`~.cache.InterpolantCache.resolve` with the reprojected rays filled in, ``tmax``
    a copy with an empty range for them, ``m`` their number."""
    n = len(o)
    if cand_pix is None or n == 0:
        return None
    p = cache.pool
    cells.grow(len(p.serial))
    out = Reprojected(np.zeros((n, 3)), np.zeros(n, np.bool_), np.zeros(n, np.uint8),
                      np.full(n, -1, np.int32))
    hi = np.array(np.broadcast_to(tmax, (n,)), np.float64)
    cache.clock += 1
    m = _reproject_rays(cache.qs, cache.box, cache.trees.arrays, cache.trees.roots, p.arrays(),
                        cache.samples.texture_terms()[0], cache.clock, cells.arrays(),
                        cand_pix, np.ascontiguousarray(pix, np.int64), o, d, hi, out)
    if m == 0:
        return None
    return out, hi, int(m)
