"""Proof that a named occluder blocks a light for every line of a cell (issue 8).

A cell whose corners see light ``j`` occluded by object ``b`` is certified by the shaft
test only up to "no third object is involved": ``b`` itself could let light through between
the test lines (a hole, its silhouette). :func:`occluder_covers` proves coverage: some
triangle of ``b`` in the shaft spans a plane that separates the surface box from the light,
and the projection of the box onto that plane (central from a point or spot light, parallel
for a sun) -- the convex hull of its 8 projected corners, which holds the crossing of every
segment from the box to the light -- lies inside the union of ``b``'s triangles in that
plane (clipped areas of same-facing coplanar triangles summing to the hull's area, not more:
overlaps prove nothing). Then every shadow segment crosses ``b``.
Computed in ``b``'s object space (affine maps keep coverage and area ratios in a plane).

A closed convex occluder K (a tessellated sphere) is proven differently: the set of points
whose segment to a point light crosses K, ``{p + t (k - p): k in K, t >= 1}``, is convex
(and so is a sun's, with a direction instead of p), so the cell's surface lies in it when
the vertices of its hull do: one segment test per vertex against K (strictly inside a
triangle, strictly inside the segment).
Curved non-convex occluders (no plane of triangles holds the whole projection) fail:
conservative.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import LIGHT_SUN
from .shafts import instance_candidates, shaft_instances, tri_normal, tvx

#: Seeds tried (triangles whose plane may hold the projection) before giving up.
MAX_SEEDS = 48


@njit(cache=True, nogil=True)
def _clip2(px, py, n, ax, ay, bx, by, qx, qy):
    """Clip polygon (px, py)[:n] to the left of edge a -> b; result in (qx, qy), returns
    its vertex count."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        si = (bx - ax) * (py[i] - ay) - (by - ay) * (px[i] - ax)
        sj = (bx - ax) * (py[j] - ay) - (by - ay) * (px[j] - ax)
        if si >= 0.0:
            qx[m] = px[i]
            qy[m] = py[i]
            m += 1
        if (si >= 0.0) != (sj >= 0.0):
            t = si / (si - sj)
            qx[m] = px[i] + t * (px[j] - px[i])
            qy[m] = py[i] + t * (py[j] - py[i])
            m += 1
    return m


@njit(cache=True, nogil=True)
def _area2(px, py, n):
    a = 0.0
    for i in range(n):
        j = (i + 1) % n
        a += px[i] * py[j] - px[j] * py[i]
    return 0.5 * a


@njit(cache=True, nogil=True)
def _hull(ux, uy, n, hx, hy):
    """Convex hull (counter-clockwise) of n points (monotone chain); returns its size."""
    order = np.argsort(ux[:n] + tol.HULL_ORDER_TIE * uy[:n])
    xs = ux[:n][order]
    ys = uy[:n][order]
    k = 0
    for i in range(n):  # lower
        while k >= 2 and (hx[k - 1] - hx[k - 2]) * (ys[i] - hy[k - 2]) - (
                hy[k - 1] - hy[k - 2]) * (xs[i] - hx[k - 2]) <= 0.0:
            k -= 1
        hx[k] = xs[i]
        hy[k] = ys[i]
        k += 1
    lo = k + 1
    for i in range(n - 2, -1, -1):  # upper
        while k >= lo and (hx[k - 1] - hx[k - 2]) * (ys[i] - hy[k - 2]) - (
                hy[k - 1] - hy[k - 2]) * (xs[i] - hx[k - 2]) <= 0.0:
            k -= 1
        hx[k] = xs[i]
        hy[k] = ys[i]
        k += 1
    return max(k - 1, 0)


@njit(cache=True, nogil=True)
def _segment_hits(qs, cand, nc, ox, oy, oz, dx, dy, dz, tmax):
    """Does the segment o + t d, t in (COVER_T_MARGIN, tmax - COVER_T_MARGIN), cross a
    triangle of ``cand`` strictly inside (a margin on the barycentrics: a crossing on an edge
    does not count, which only makes the proof more conservative)?"""
    for q in range(nc):
        t = cand[q]
        v0x, v0y, v0z = tvx(qs, t, 0), tvx(qs, t, 1), tvx(qs, t, 2)
        e1x, e1y, e1z = tvx(qs, t, 3) - v0x, tvx(qs, t, 4) - v0y, tvx(qs, t, 5) - v0z
        e2x, e2y, e2z = tvx(qs, t, 6) - v0x, tvx(qs, t, 7) - v0y, tvx(qs, t, 8) - v0z
        px = dy * e2z - dz * e2y
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        if det == 0.0:
            continue
        inv = 1.0 / det
        sx, sy, sz = ox - v0x, oy - v0y, oz - v0z
        u = (sx * px + sy * py + sz * pz) * inv
        if not (tol.COVER_BARY_MARGIN < u < 1.0 - tol.COVER_BARY_MARGIN):
            continue
        qx = sy * e1z - sz * e1y
        qy = sz * e1x - sx * e1z
        qz = sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        if not (tol.COVER_BARY_MARGIN < v and u + v < 1.0 - tol.COVER_BARY_MARGIN):
            continue
        tt = (e2x * qx + e2y * qy + e2z * qz) * inv
        if tol.COVER_T_MARGIN < tt < tmax - tol.COVER_T_MARGIN:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def to_points(inv, pts, n):
    """World points ``pts[:n]`` in the object space of the inverse matrix ``inv``."""
    X = np.empty((n, 3))
    for c in range(n):
        for k in range(3):
            X[c, k] = (inv[k, 0] * pts[c, 0] + inv[k, 1] * pts[c, 1] + inv[k, 2] * pts[c, 2]
                       + inv[k, 3])
    return X


@njit(cache=True, nogil=True)
def occluder_covers(qs, b, j, pts, npts, pl, npl, bb, cand, P, Q):
    """Does instance ``b`` block light ``j`` for every point of the convex hull of world
    points ``pts[:npts]`` (the cell's surface: the vertices of its slab polygons, or the
    corners of its box)? ``pl``/``npl``/``bb``: the light shaft from there (world). See the
    module doc.

    One function on purpose: split into its parts (object space, the convex test, each seed
    plane's projection and covered area), it measured 3-8% slower in numba (calls with many
    array arguments, in a loop over up to MAX_SEEDS seeds)."""
    if b < 0:
        return False
    inv = qs.inst_inv[b]
    nc = instance_candidates(qs, b, pl, npl, bb, cand, P, Q)
    if nc <= 0:
        return False
    # the box corners and the light in object space
    n = npts
    X = to_points(inv, pts, n)
    sun = qs.light_kind[j] == LIGHT_SUN
    L = np.empty(3)
    for k in range(3):
        if sun:  # toward the sun
            L[k] = -(inv[k, 0] * qs.light_dir[j, 0] + inv[k, 1] * qs.light_dir[j, 1]
                     + inv[k, 2] * qs.light_dir[j, 2])
        else:
            L[k] = (inv[k, 0] * qs.light_pos[j, 0] + inv[k, 1] * qs.light_pos[j, 1]
                    + inv[k, 2] * qs.light_pos[j, 2] + inv[k, 3])
    if qs.mesh_convex[qs.inst_mesh[b]]:
        # a closed convex occluder: its shadow is convex, so the 8 corners' shadow
        # segments crossing it prove every segment from the box does
        far = 0.0
        for c in range(n):
            for k in range(3):
                far = max(far, abs(X[c, k]))
        for k in range(3):
            far = max(far, abs(L[k]))
        for q in range(nc):  # and beyond every candidate triangle
            for k in range(9):
                far = max(far, abs(tvx(qs, cand[q], k)))
        all_in = True
        for c in range(n):
            if sun:  # toward the sun, far beyond the occluder
                f = 4.0 * (far + 1.0) / max(math.sqrt(L[0] ** 2 + L[1] ** 2 + L[2] ** 2),
                                            1e-300)
                hit = _segment_hits(qs, cand, nc, X[c, 0], X[c, 1], X[c, 2], L[0] * f,
                                    L[1] * f, L[2] * f, 1.0)
            else:
                hit = _segment_hits(qs, cand, nc, X[c, 0], X[c, 1], X[c, 2], L[0] - X[c, 0],
                                    L[1] - X[c, 1], L[2] - X[c, 2], 1.0)
            if not hit:
                all_in = False
                break
        if all_in:
            return True
    ux = np.empty(n)
    uy = np.empty(n)
    hx = np.empty(2 * n + 1)
    hy = np.empty(2 * n + 1)
    ax = np.empty(2 * n + 8)
    ay = np.empty(2 * n + 8)
    bx = np.empty(2 * n + 8)
    by = np.empty(2 * n + 8)
    scale = 0.0
    for c in range(n):
        for k in range(3):
            scale = max(scale, abs(X[c, k] - X[0, k]))
    for k in range(3):
        scale = max(scale, abs(L[k] - X[0, k]) if not sun else 0.0)
    for s in range(min(nc, MAX_SEEDS)):
        t = cand[s]
        nx, ny, nz = tri_normal(qs, t)
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln == 0.0:
            continue
        nx /= ln
        ny /= ln
        nz /= ln
        d0 = nx * tvx(qs, t, 0) + ny * tvx(qs, t, 1) + nz * tvx(qs, t, 2)
        tolp = tol.COVER_PLANE_REL * (scale + abs(d0)) + qs.slack
        if sun:
            sl = nx * L[0] + ny * L[1] + nz * L[2]
            if abs(sl) <= tol.COVER_PLANE_REL:
                continue
        else:
            sl = nx * L[0] + ny * L[1] + nz * L[2] - d0
            if abs(sl) <= tolp:
                continue
        # every corner strictly on the other side from the light
        ok = True
        sx = np.empty(n)
        for c in range(n):
            sx[c] = nx * X[c, 0] + ny * X[c, 1] + nz * X[c, 2] - d0
            if not (sx[c] * sl < 0.0 and abs(sx[c]) > tolp):
                ok = False
        if not ok:
            continue
        # a basis of the plane
        if abs(nx) < 0.9:
            e1x, e1y, e1z = 0.0, nz, -ny
        else:
            e1x, e1y, e1z = -nz, 0.0, nx
        le = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x /= le
        e1y /= le
        e1z /= le
        e2x = ny * e1z - nz * e1y
        e2y = nz * e1x - nx * e1z
        e2z = nx * e1y - ny * e1x
        for c in range(n):
            if sun:
                f = sx[c] / sl
                y0 = X[c, 0] - L[0] * f
                y1 = X[c, 1] - L[1] * f
                y2 = X[c, 2] - L[2] * f
            else:
                f = sl / (sl - sx[c])
                y0 = L[0] + (X[c, 0] - L[0]) * f
                y1 = L[1] + (X[c, 1] - L[1]) * f
                y2 = L[2] + (X[c, 2] - L[2]) * f
            ux[c] = e1x * y0 + e1y * y1 + e1z * y2
            uy[c] = e2x * y0 + e2y * y1 + e2z * y2
        nh = _hull(ux, uy, n, hx, hy)
        if nh < 3:
            continue
        area = _area2(hx, hy, nh)
        if not area > 0.0:
            continue
        covered = 0.0
        for q in range(nc):
            t2 = cand[q]
            mx, my, mz = tri_normal(qs, t2)
            lm = math.sqrt(mx * mx + my * my + mz * mz)
            if lm == 0.0:
                continue
            # same plane, same orientation (back-to-back faces would count twice)
            if mx * nx + my * ny + mz * nz < lm * (1.0 - tol.COVER_AREA_REL):
                continue
            off = 0.0
            for v in range(3):
                off = max(off, abs(nx * tvx(qs, t2, 3 * v) + ny * tvx(qs, t2, 3 * v + 1)
                                   + nz * tvx(qs, t2, 3 * v + 2) - d0))
            if off > tolp:
                continue
            # the triangle in plane coordinates, counter-clockwise
            tx = np.empty(3)
            ty = np.empty(3)
            for v in range(3):
                tx[v] = (e1x * tvx(qs, t2, 3 * v) + e1y * tvx(qs, t2, 3 * v + 1)
                         + e1z * tvx(qs, t2, 3 * v + 2))
                ty[v] = (e2x * tvx(qs, t2, 3 * v) + e2y * tvx(qs, t2, 3 * v + 1)
                         + e2z * tvx(qs, t2, 3 * v + 2))
            if (tx[1] - tx[0]) * (ty[2] - ty[0]) - (ty[1] - ty[0]) * (tx[2] - tx[0]) < 0.0:
                tx[1], tx[2] = tx[2], tx[1]
                ty[1], ty[2] = ty[2], ty[1]
            m = nh
            for v in range(m):
                ax[v] = hx[v]
                ay[v] = hy[v]
            for e in range(3):
                if m == 0:
                    break
                w = (e + 1) % 3
                m = _clip2(ax, ay, m, tx[e], ty[e], tx[w], ty[w], bx, by)
                for v in range(m):
                    ax[v] = bx[v]
                    ay[v] = by[v]
            if m >= 3:
                covered += _area2(ax, ay, m)
        # a partition of the hull sums to its area; more means overlapping triangles
        # (duplicated faces), which prove nothing
        if area * (1.0 - tol.COVER_AREA_REL) <= covered <= area * (1.0 + tol.COVER_AREA_REL):
            return True
    return False


#: Largest sun half angle the cone umbra proof takes (its square cone's corners at tan h).
CONE_UMBRA_MAX_HALF = 1.2


@njit(cache=True, nogil=True)
def cone_umbra(qs, b, j, pts, npts, pl, npl, bb, cand, P, Q):
    """Does closed convex instance ``b`` block sun ``j`` -- every direction of its cone --
    from every point of the convex hull of world points ``pts[:npts]``? ``pl``/``npl``/
    ``bb``: the shaft from there to the sun's cone (world).

    For a point outside a convex body the directions whose rays meet it form a convex cone,
    and for a direction the points whose rays meet it form a convex set. So the rays from
    the hull's vertices along the four corner directions of a square cone that holds the
    sun's circular cone (``axis + tan(h) (+-u +-v)``) all crossing ``b`` prove every ray
    from the hull in the sun's cone crosses it: every shadow sample of the sun is blocked
    (its value 0 in the tracer, the ratio estimator's sums both over no visible sample)."""
    if b < 0 or qs.light_kind[j] != LIGHT_SUN or npts <= 0:
        return False
    if not qs.mesh_convex[qs.inst_mesh[b]]:
        return False
    h = qs.light_half[j]
    if not 0.0 <= h < CONE_UMBRA_MAX_HALF:
        return False
    inv = qs.inst_inv[b]
    nc = instance_candidates(qs, b, pl, npl, bb, cand, P, Q)
    if nc <= 0:
        return False
    n = npts
    X = to_points(inv, pts, n)
    far = 0.0
    for c in range(n):
        for k in range(3):
            far = max(far, abs(X[c, k]))
    for q in range(nc):
        for k in range(9):
            far = max(far, abs(tvx(qs, cand[q], k)))
    # the axis toward the sun and a basis across it (world)
    ax, ay, az = -qs.light_dir[j, 0], -qs.light_dir[j, 1], -qs.light_dir[j, 2]
    la = math.sqrt(ax * ax + ay * ay + az * az)
    if not la > 0.0:
        return False
    ax /= la
    ay /= la
    az /= la
    if abs(ax) < 0.9:
        ux, uy, uz = 0.0, az, -ay
    else:
        ux, uy, uz = -az, 0.0, ax
    lu = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux /= lu
    uy /= lu
    uz /= lu
    vx = ay * uz - az * uy
    vy = az * ux - ax * uz
    vz = ax * uy - ay * ux
    tn = math.tan(h) * (1.0 + tol.COVER_AREA_REL) + tol.COVER_PLANE_REL
    for k in range(4):
        su = tn if k & 1 else -tn
        sv = tn if k & 2 else -tn
        wx = ax + su * ux + sv * vx
        wy = ay + su * uy + sv * vy
        wz = az + su * uz + sv * vz
        dx = inv[0, 0] * wx + inv[0, 1] * wy + inv[0, 2] * wz
        dy = inv[1, 0] * wx + inv[1, 1] * wy + inv[1, 2] * wz
        dz = inv[2, 0] * wx + inv[2, 1] * wy + inv[2, 2] * wz
        ld = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not ld > 0.0:
            return False
        f = 4.0 * (far + 1.0) / ld
        for c in range(n):
            if not _segment_hits(qs, cand, nc, X[c, 0], X[c, 1], X[c, 2], dx * f, dy * f,
                                 dz * f, 1.0):
                return False
    return True


#: Objects in a sun's shaft tried as the one that hides it (:func:`sun_umbra`).
MAX_UMBRA_CANDIDATES = 8


@njit(cache=True, nogil=True)
def sun_umbra(qs, j, pl, npl, bb, cand, P, Q, plo, bbo, named, pts, npts):
    """Is sun ``j`` hidden from every point of the hull ``pts[:npts]`` by one closed convex
    object in its shaft ``pl`` (not ``named[0]``, the cell's own)?"""
    if npts <= 0:
        return False
    ids = np.empty(MAX_UMBRA_CANDIDATES, np.int32)
    n = shaft_instances(qs, pl, npl, bb, named, np.int64(1), plo, bbo, P, Q, ids)
    for q in range(max(n, 0)):
        if cone_umbra(qs, ids[q], j, pts, npts, pl, npl, bb, cand, P, Q):
            return True
    return False
