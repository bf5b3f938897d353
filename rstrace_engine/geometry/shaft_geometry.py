"""Shaft geometry: Haines-Wallace shafts, clipping, light extents (no scene queries).

A *shaft* is a convex polyhedron given by planes ``pl (P, 4)`` (inside: ``n . x + d >= 0``)
and a world box ``bb (6,)`` containing it (:func:`hw_shaft`). Planes are moved outward by an
absolute slack (:data:`~.tolerances.SHAFT_SLACK_REL` of the scene's coordinate magnitude) so
rounding never lets a touching triangle escape. The interpolant predicate's queries
(:mod:`~rstrace_engine.interpolants.shafts`) and the base tracer's shadow-ray skips
(:mod:`~rstrace_engine.tracing.shaft_skip`) build their shafts here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from .scene import LIGHT_AREA, LIGHT_SUN, SceneArrays

#: Most planes a shaft has (6 box planes and 12 edge planes).
MAX_PLANES = 18


def light_extents(sa: SceneArrays):
    """``(lo (L, 3), hi (L, 3), chord (L,))``: the world box of every light's extent -- a
    sphere light's ball (the disk of Blender's soft falloff lies in it), an area light's
    rectangle (an ellipse's bounding rectangle), a point light's position -- and for a sun
    with an angle the chord ``2 sin(h / 2)`` of its cone (every direction of the cone is
    within it of the axis); 0 for the others."""
    pos = np.asarray(sa.light_pos, np.float64).reshape(-1, 3)
    nl = len(pos)
    half = np.zeros((nl, 3))
    chord = np.zeros(nl)
    for j in range(nl):
        if not sa.light_ext[j] or sa.light_kind[j] < 0:
            continue
        if sa.light_kind[j] == LIGHT_SUN:
            chord[j] = 2.0 * math.sin(0.5 * float(sa.light_half[j]))
        elif sa.light_kind[j] == LIGHT_AREA:
            half[j] = (0.5 * sa.light_size[j, 0] * np.abs(sa.light_u[j])
                       + 0.5 * sa.light_size[j, 1] * np.abs(sa.light_v[j]))
        else:
            half[j] = sa.light_radius[j]
    return pos - half, pos + half, chord


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


@njit(cache=True, nogil=True, inline="always")
def box_outside(pl, npl, bb, lx, ly, lz, hx, hy, hz):
    """The box ``lo, hi`` lies outside the shaft: empty, off its box ``bb`` (lo, hi), or
    wholly behind one of its planes ``pl[:npl]`` (its nearest corner to the plane's
    normal)."""
    if not (lx <= hx and ly <= hy and lz <= hz):
        return True
    if hx < bb[0] or hy < bb[1] or hz < bb[2] or lx > bb[3] or ly > bb[4] or lz > bb[5]:
        return True
    for p in range(npl):
        px = hx if pl[p, 0] > 0.0 else lx
        py = hy if pl[p, 1] > 0.0 else ly
        pz = hz if pl[p, 2] > 0.0 else lz
        if pl[p, 0] * px + pl[p, 1] * py + pl[p, 2] * pz + pl[p, 3] < 0.0:
            return True
    return False


@njit(cache=True, nogil=True)
def to_object(xf, inv, pl, npl, bb, plo, bbo):
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
    pad = tol.BOX_ROUND_REL * (abs(bbo[0]) + abs(bbo[1]) + abs(bbo[2]) + abs(bbo[3]) + abs(bbo[4])
                   + abs(bbo[5]) + (bbo[3] - bbo[0]) + (bbo[4] - bbo[1]) + (bbo[5] - bbo[2]))
    for k in range(3):
        bbo[k] -= pad
        bbo[3 + k] += pad


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
def extent_plane_side(qs, j, wx, wy, wz, px, py, pz, margin):
    """Side of the world plane through ``p`` with unit normal ``w`` on which light ``j``'s
    extent lies (a sphere's ball, an area light's four corners; the light's point for
    other lights): 1 wholly in front by more than ``margin``, -1 wholly behind, else 0; a
    sun's extent is its cone of directions (every one of them on that side, beyond the sine
    of its half angle by ``FACING_EPS_REL``; ``margin`` plays no part). ``qs``: anything
    with the lights' arrays of :class:`~.scene.SceneArrays` (``light_pos``, ``light_dir``,
    ``light_half``, ``light_kind``, ``light_ext``, ``light_size``, ``light_u``,
    ``light_v``, ``light_radius``)."""
    if qs.light_kind[j] == LIGHT_SUN:
        s = -(wx * qs.light_dir[j, 0] + wy * qs.light_dir[j, 1] + wz * qs.light_dir[j, 2])
        lim = math.sin(qs.light_half[j]) + tol.FACING_EPS_REL
        return 1 if s > lim else (-1 if s < -lim else 0)
    cx = qs.light_pos[j, 0] - px
    cy = qs.light_pos[j, 1] - py
    cz = qs.light_pos[j, 2] - pz
    d = wx * cx + wy * cy + wz * cz
    m = margin + tol.FACING_EPS_REL * math.sqrt(cx * cx + cy * cy + cz * cz)
    if qs.light_kind[j] == LIGHT_AREA and qs.light_ext[j]:
        hu = 0.5 * qs.light_size[j, 0] * abs(wx * qs.light_u[j, 0] + wy * qs.light_u[j, 1]
                                             + wz * qs.light_u[j, 2])
        hv = 0.5 * qs.light_size[j, 1] * abs(wx * qs.light_v[j, 0] + wy * qs.light_v[j, 1]
                                             + wz * qs.light_v[j, 2])
        r = hu + hv  # the corners' largest distance from the centre along w
    elif qs.light_ext[j]:
        r = qs.light_radius[j]
    else:
        r = 0.0
    if d - r > m:
        return 1
    if d + r < -m:
        return -1
    return 0


@njit(cache=True, nogil=True)
def sun_box(lo, hi, direction, chord, center, extent, blo, bhi):
    """The far end of a sun's shaft from box (lo, hi): the box moved far beyond the scene
    (centre ``center``, diagonal ``extent``) against the sun's unit ``direction``, grown
    by the ``chord`` of its cone (:func:`light_extents`) at that distance. Every shadow
    ray from the box within the cone, to as far as the scene reaches, then lies in the
    Haines-Wallace shaft between the two boxes."""
    far = 0.0
    for k in range(3):
        c = 0.5 * (lo[k] + hi[k]) - center[k]
        far += c * c
    far = 4.0 * (math.sqrt(far) + extent + (hi[0] - lo[0]) + (hi[1] - lo[1])
                 + (hi[2] - lo[2]))
    grow = far * chord
    for k in range(3):
        blo[k] = lo[k] - direction[k] * far - grow
        bhi[k] = hi[k] - direction[k] * far + grow
