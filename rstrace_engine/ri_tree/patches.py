"""Patch equivalence classes, the angular threshold and interpolation (seed 004, 2.4-2.5).

A sample's *class key* is its first hit's smooth patch (the surface classes of
:mod:`..geometry.mesh_topology`: faces joined by smooth edges, split at sharp edges, seams of
normals and uvs, and material borders) combined with the topology of its exit path through
glass (how many interfaces inside), or ``MISS``. A final leaf records the classes among its
16 corners:

* one class: interpolate from all 16 corners (quadrilinear: bilinear in ``(c, d)`` within
  each directional group, then in ``(a, b)``);
* exactly two: one cheap test, the query ray's first hit on the object alone, decides its
  class; only the corners of that class are *usable* (the weights renormalised), and at
  least :data:`MIN_USABLE` of them must be;
* three or more: trace.

The angular threshold rejects a class whose corners' output directions (normal, reflected
ray or exit ray) differ pairwise by more than the threshold: high curvature.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..interpolants.linetree import corner_weight, face_frame
from .kdtree import FINAL
from .sampling import MISS, PATH_BITS

#: a class may be interpolated from at least this many of the 16 corners
MIN_USABLE = 6
#: ... and when their quadrilinear weights at the query sum to at least this
MIN_WEIGHT = 1e-3

# query outcomes (ST_SPARSE: the ray's leaf is not final and the cost rule does not refine
# it (too few queries to pay for its samples, or no room in the cache): trace it)
ST_HIT, ST_MISS, ST_TEST, ST_FAIL_CLASS, ST_FAIL_ANGLE, ST_SPARSE = 0, 1, 2, 3, 4, 5

# corner kinds of a cell (:func:`corner_kinds`)
K_ALL_MISS, K_ONE, K_TWO, K_MIXED = 0, 1, 2, 3


@njit(cache=True, nogil=True, inline="always")
def patch_of(key):
    """The patch part of a class key (MISS stays MISS)."""
    return key // PATH_BITS if key >= 0 else MISS


@njit(cache=True, nogil=True)
def _angle_ok(S, ids, key, cosmin):
    for a in range(16):
        sa_ = ids[a]
        if S.cls[sa_] != key:
            continue
        for b in range(a + 1, 16):
            sb = ids[b]
            if S.cls[sb] != key:
                continue
            c = (S.OD[sa_, 0] * S.OD[sb, 0] + S.OD[sa_, 1] * S.OD[sb, 1]
                 + S.OD[sa_, 2] * S.OD[sb, 2])
            if c < cosmin:
                return False
    return True


@njit(cache=True, nogil=True)
def corner_classes(nd, x, S):
    """``(n, c0, c1)``: how many distinct class keys cell ``x``'s 16 corners carry (3 means
    three or more) and the first two of them (``MISS`` where absent)."""
    nc = 0
    c0 = MISS
    c1 = MISS
    for k in range(16):
        key = S.cls[nd.corner[x, k]]
        if nc == 0:
            c0 = key
            nc = 1
        elif key != c0:
            if nc == 1:
                c1 = key
                nc = 2
            elif key != c1:
                nc = 3
    return nc, c0, c1


@njit(cache=True, nogil=True)
def finalize(nd, leaves, S, cosmin, coarse):
    """Mark ``leaves`` FINAL with their classes and angular test results (serial: writes
    through the node tuple are lost from a parallel loop). ``coarse[q]``: leaf ``q`` (at the
    depth constraint) failed the exit-ray test: its classes fail the angular test, its rays
    are traced."""
    for q in range(leaves.shape[0]):
        x = leaves[q]
        nc, c0, c1 = corner_classes(nd, x, S)
        nd.nclass[x] = nc
        nd.cls[x, 0] = c0
        nd.cls[x, 1] = c1
        bits = 0
        if c0 == MISS or _angle_ok(S, nd.corner[x], c0, cosmin):
            bits |= 1
        if nc >= 2 and (c1 == MISS or _angle_ok(S, nd.corner[x], c1, cosmin)):
            bits |= 2
        nd.ang_ok[x] = 0 if coarse[q] else bits
        nd.state[x] = FINAL


@njit(cache=True, nogil=True, parallel=True)
def corner_kinds(nd, leaves, S, out):
    """Kind of each cell ``leaves[q]`` by its 16 corners' class keys: ``K_ALL_MISS`` (every
    corner misses), ``K_ONE`` (one class), ``K_TWO`` (exactly two, a miss included),
    ``K_MIXED`` (three or more)."""
    for q in prange(leaves.shape[0]):
        x = leaves[q]
        nc, c0, c1 = corner_classes(nd, x, S)
        if nc >= 3:
            out[q] = K_MIXED
        elif nc == 2:
            out[q] = K_TWO
        elif c0 == MISS:
            out[q] = K_ALL_MISS
        else:
            out[q] = K_ONE


@njit(cache=True, nogil=True)
def interpolate(nd, x, S, abcd, key, r, P, NS, NG, OP, OD, gain, thick, nint, mat):
    """Interpolate class ``key``'s corners of node ``x`` at line ``abcd`` into row ``r``.

    Returns the number of usable corners (0 when their weights vanish)."""
    u = np.empty(4)
    for m in range(4):
        w = nd.hi[x, m] - nd.lo[x, m]
        t = (abcd[m] - nd.lo[x, m]) / w if w > 0.0 else 0.5
        u[m] = min(max(t, 0.0), 1.0)
    wsum = 0.0
    cnt = 0
    for c in range(3):
        P[r, c] = 0.0
        NS[r, c] = 0.0
        NG[r, c] = 0.0
        OP[r, c] = 0.0
        OD[r, c] = 0.0
        gain[r, c] = 0.0
    thick[r] = 0.0
    for q in range(16):
        s = nd.corner[x, q]
        if S.cls[s] != key:
            continue
        cnt += 1
        w = corner_weight(q, u[0], u[1], u[2], u[3])
        if w <= 0.0:
            continue
        wsum += w
        nint[r] = S.nint[s]
        mat[r] = S.mat[s]
        for c in range(3):
            P[r, c] += w * S.P[s, c]
            NS[r, c] += w * S.NS[s, c]
            NG[r, c] += w * S.NG[s, c]
            OP[r, c] += w * S.OP[s, c]
            OD[r, c] += w * S.OD[s, c]
            gain[r, c] += w * S.gain[s, c]
        thick[r] += w * S.thick[s]
    if wsum < MIN_WEIGHT:
        return 0
    inv = 1.0 / wsum
    for c in range(3):
        P[r, c] *= inv
        OP[r, c] *= inv
        gain[r, c] *= inv
    thick[r] *= inv
    for A in (NS, NG, OD):
        ln = math.sqrt(A[r, 0] ** 2 + A[r, 1] ** 2 + A[r, 2] ** 2)
        if ln > 0.0:
            for c in range(3):
                A[r, c] /= ln
    return cnt


@njit(cache=True, nogil=True)
def interpolate_reflection(nd, x, S, abcd, key, r, RP, RD, rgain):
    """The internal reflection at the exit (:mod:`.sampling`) of class ``key``'s corners of
    node ``x`` at line ``abcd`` into row ``r``, with :func:`interpolate`'s weights."""
    wsum = 0.0
    for c in range(3):
        RP[r, c] = 0.0
        RD[r, c] = 0.0
        rgain[r, c] = 0.0
    u0 = _unit(nd, x, abcd, 0)
    u1 = _unit(nd, x, abcd, 1)
    u2 = _unit(nd, x, abcd, 2)
    u3 = _unit(nd, x, abcd, 3)
    for q in range(16):
        s = nd.corner[x, q]
        if S.cls[s] != key:
            continue
        w = corner_weight(q, u0, u1, u2, u3)
        if w <= 0.0:
            continue
        wsum += w
        for c in range(3):
            RP[r, c] += w * S.RP[s, c]
            RD[r, c] += w * S.RD[s, c]
            rgain[r, c] += w * S.rgain[s, c]
    if wsum < MIN_WEIGHT:
        for c in range(3):
            rgain[r, c] = 0.0
        return
    ln = math.sqrt(RD[r, 0] ** 2 + RD[r, 1] ** 2 + RD[r, 2] ** 2)
    for c in range(3):
        RP[r, c] /= wsum
        rgain[r, c] /= wsum
        RD[r, c] = RD[r, c] / ln if ln > 0.0 else 0.0
    if ln == 0.0:
        for c in range(3):
            rgain[r, c] = 0.0


@njit(cache=True, nogil=True, inline="always")
def _unit(nd, x, abcd, m):
    w = nd.hi[x, m] - nd.lo[x, m]
    t = (abcd[m] - nd.lo[x, m]) / w if w > 0.0 else 0.5
    return min(max(t, 0.0), 1.0)


@njit(cache=True, nogil=True, inline="always")
def _line4(box, inst, face, px, py, pz, dx, dy, dz, out):
    """Unclamped line coordinates of the ray (p, d) in face pair ``face``, in units of the
    object's box faces (as the paper's plane pairs; the linetree faces are grown by the
    box depth on every side); False when the direction is parallel to the faces."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    li += L
    lj += L
    wi -= 2.0 * L
    wj -= 2.0 * L
    p = (px, py, pz)
    dv = (dx, dy, dz)
    if dv[k] == 0.0:
        return False
    back = front - L if neg else front + L
    tf = (front - p[k]) / dv[k]
    tb = (back - p[k]) / dv[k]
    out[0] = (p[i] + tf * dv[i] - li) / wi
    out[1] = (p[j] + tf * dv[j] - lj) / wj
    out[2] = (p[i] + tb * dv[i] - li) / wi
    out[3] = (p[j] + tb * dv[j] - lj) / wj
    return True


@njit(cache=True, nogil=True)
def _misses_box(nd, x, box, aabb, inst, face):
    """True when no line of cell ``x`` can meet instance ``inst``'s world box ``aabb``
    (conservative: the hull of the cell's lateral extent over the box's depth range)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    lo = aabb[inst, 0, k]
    hi = aabb[inst, 1, k]
    t0 = (front - hi if neg else lo - front) / L
    t1 = (front - lo if neg else hi - front) / L
    for axis, ori, wid, ax in ((0, li, wi, i), (1, lj, wj, j)):
        a_lo = ori + nd.lo[x, axis] * wid
        a_hi = ori + nd.hi[x, axis] * wid
        c_lo = ori + nd.lo[x, axis + 2] * wid
        c_hi = ori + nd.hi[x, axis + 2] * wid
        mn = min((1 - t0) * a_lo + t0 * c_lo, (1 - t1) * a_lo + t1 * c_lo)
        mx = max((1 - t0) * a_hi + t0 * c_hi, (1 - t1) * a_hi + t1 * c_hi)
        if mx < aabb[inst, 0, ax] or mn > aabb[inst, 1, ax]:
            return True
    return False


@njit(cache=True, nogil=True)
def blind_at_cap(nd, leaves, S, box, aabb, inst, face, out):
    """``out[q]``: cell ``leaves[q]`` (at the depth constraint) misses at all 16 corners
    although some of its lines can meet the object's box. Its corners cannot tell whether
    those lines hit the object (a thin part, a hole, a whole object between them: at depth
    constraint 1-2 a torus between the corners was declared missed, 0.73 display error), so
    its rays are traced, never declared misses."""
    for q in range(leaves.shape[0]):
        x = leaves[q]
        nc, c0, c1 = corner_classes(nd, x, S)
        out[q] = (nc == 1 and c0 == MISS
                  and not _misses_box(nd, x, box, aabb, inst[q], face[q]))


@njit(cache=True, nogil=True, inline="always")
def _angle(ax, ay, az, bx, by, bz):
    """Angle (radians) between unit vectors a and b (accurate for small angles)."""
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


@njit(cache=True, nogil=True)
def probe_error(S, m, P, NS, OP, OD, RD, diag):
    """How far the interpolation (row 0 of P, NS, OP, OD, RD) of sample ``m`` is off, as the
    angle (radians) under which a viewer at the output ray sees the error: the angle between
    the traced and the interpolated output ray (exit ray through glass, reflected ray,
    normal) or shading normals, or of the internal reflection at the exit times its weight,
    whichever is larger, plus the displacement of the output ray's origin and of the hit
    point over the object's box diagonal ``diag`` (an origin off by 1% of it, seen from one
    diagonal away, is 0.01 rad off)."""
    a = _angle(S.OD[m, 0], S.OD[m, 1], S.OD[m, 2], OD[0, 0], OD[0, 1], OD[0, 2])
    b = max(_angle(S.NS[m, 0], S.NS[m, 1], S.NS[m, 2], NS[0, 0], NS[0, 1], NS[0, 2]),
            min(max(S.rgain[m, 0], S.rgain[m, 1], S.rgain[m, 2]), 1.0)
            * _angle(S.RD[m, 0], S.RD[m, 1], S.RD[m, 2], RD[0, 0], RD[0, 1], RD[0, 2]))
    dp = math.sqrt((S.P[m, 0] - P[0, 0]) ** 2 + (S.P[m, 1] - P[0, 1]) ** 2
                   + (S.P[m, 2] - P[0, 2]) ** 2)
    do = math.sqrt((S.OP[m, 0] - OP[0, 0]) ** 2 + (S.OP[m, 1] - OP[0, 1]) ** 2
                   + (S.OP[m, 2] - OP[0, 2]) ** 2)
    return max(a, b) + max(dp, do) / diag


@njit(cache=True, nogil=True, parallel=True)
def midpoint_distances(nd, leaves, S, mids, box, aabb, inst, face, thickness, diag, cosmin,
                       dist, probe):
    """Distance between each leaf's traced midpoint sample ``mids[q]`` (ids into ``S``) and
    its interpolation from the corners (inf when the midpoint's class cannot be
    interpolated there): the L2 distance of the output rays in 4D line space (the face pair
    of the traced output direction), or for the thickness view the length difference over
    the object's diagonal. A cell whose corners of that class fail the angular threshold
    counts as inf too: it splits while it may, and only cells at the depth constraint are
    left to the query-time angular test.

    ``probe[q]``: the exit-ray test's error at the midpoint (:func:`probe_error`, radians;
    inf where ``dist`` is inf, 0 for a miss and in the thickness view)."""
    for q in prange(leaves.shape[0]):
        x = leaves[q]
        m = mids[q]
        key = S.cls[m]
        probe[q] = np.inf
        abcd = np.empty(4)
        for a in range(4):
            abcd[a] = 0.5 * (nd.lo[x, a] + nd.hi[x, a])
        nc, c0, c1 = corner_classes(nd, x, S)
        if nc >= 3 or (key != c0 and key != c1):
            dist[q] = np.inf
            continue
        # a final leaf must be able to interpolate each of its classes
        bad = False
        for c in (c0, c1):
            if c == MISS or (c == c1 and nc < 2):
                continue
            n_c = 0
            for k in range(16):
                if S.cls[nd.corner[x, k]] == c:
                    n_c += 1
            if n_c < MIN_USABLE or not _angle_ok(S, nd.corner[x], c, cosmin):
                bad = True
        if bad:
            dist[q] = np.inf
            continue
        if key == MISS:
            # a cell that misses at its corners and midpoint is final only when none of
            # its lines can meet the object's box (or it holds hits at some corners)
            if nc == 1 and not _misses_box(nd, x, box, aabb, inst[q], face[q]):
                dist[q] = np.inf
            else:
                dist[q] = 0.0
                probe[q] = 0.0
            continue
        P = np.empty((1, 3))
        NS = np.empty((1, 3))
        NG = np.empty((1, 3))
        OP = np.empty((1, 3))
        OD = np.empty((1, 3))
        gn = np.empty((1, 3))
        th = np.empty(1)
        ni = np.empty(1, np.int16)
        mt = np.empty(1, np.int32)
        cnt = interpolate(nd, x, S, abcd, key, 0, P, NS, NG, OP, OD, gn, th, ni, mt)
        if cnt < MIN_USABLE:
            dist[q] = np.inf
            continue
        if thickness:
            dist[q] = abs(th[0] - S.thick[m]) / diag[q]
            probe[q] = 0.0
            continue
        RP = np.empty((1, 3))
        RD = np.empty((1, 3))
        rg = np.empty((1, 3))
        interpolate_reflection(nd, x, S, abcd, key, 0, RP, RD, rg)
        probe[q] = probe_error(S, m, P, NS, OP, OD, RD, diag[q])
        ox, oy, oz = S.OD[m, 0], S.OD[m, 1], S.OD[m, 2]
        ax, ay, az = abs(ox), abs(oy), abs(oz)
        if ax >= ay and ax >= az:
            f = 0 if ox >= 0.0 else 1
        elif ay >= az:
            f = 2 if oy >= 0.0 else 3
        else:
            f = 4 if oz >= 0.0 else 5
        a4 = np.empty(4)
        b4 = np.empty(4)
        ok1 = _line4(box, inst[q], f, S.OP[m, 0], S.OP[m, 1], S.OP[m, 2], ox, oy, oz, a4)
        ok2 = _line4(box, inst[q], f, OP[0, 0], OP[0, 1], OP[0, 2], OD[0, 0], OD[0, 1],
                     OD[0, 2], b4)
        if not (ok1 and ok2):
            dist[q] = np.inf
            continue
        s2 = 0.0
        for a in range(4):
            s2 += (a4[a] - b4[a]) ** 2
        dist[q] = math.sqrt(s2)


@njit(cache=True, nogil=True, parallel=True)
def class_probes(nd, leaves, S, mids, abcd, want):
    """Where the exit-ray test probes leaf ``leaves[q]`` besides its midpoint ``mids[q]``:
    ``abcd[q]``, a line of class ``want[q]`` (``MISS``: no probe).

    * two classes, neither a miss: the class the midpoint does not carry (the midpoint
      probes its own), half-way from the cell's centre to the mean of that class's corners;
    * one class, or a class and misses (a silhouette): half-way from the centre to the
      corner of the midpoint's class whose output ray turns farthest from the midpoint's
      (where the midpoint says least about the interpolation)."""
    for q in prange(leaves.shape[0]):
        x = leaves[q]
        m = mids[q]
        key = S.cls[m]
        want[q] = MISS
        nc, c0, c1 = corner_classes(nd, x, S)
        if nc >= 3 or (key != c0 and key != c1):
            continue
        other = c1 if key == c0 else c0
        if nc == 2 and other != MISS:
            cnt = 0
            acc = np.zeros(4)
            for k in range(16):
                if S.cls[nd.corner[x, k]] != other:
                    continue
                cnt += 1
                for a in range(4):
                    acc[a] += nd.hi[x, a] if (k >> a) & 1 else nd.lo[x, a]
            for a in range(4):
                abcd[q, a] = 0.25 * (nd.lo[x, a] + nd.hi[x, a]) + 0.5 * acc[a] / cnt
            want[q] = other
            continue
        if key == MISS:
            continue
        worst = -1
        cmin = 2.0
        for k in range(16):
            s = nd.corner[x, k]
            if S.cls[s] != key:
                continue
            c = S.OD[s, 0] * S.OD[m, 0] + S.OD[s, 1] * S.OD[m, 1] + S.OD[s, 2] * S.OD[m, 2]
            if c < cmin:
                cmin = c
                worst = k
        for a in range(4):
            end = nd.hi[x, a] if (worst >> a) & 1 else nd.lo[x, a]
            abcd[q, a] = 0.25 * (nd.lo[x, a] + nd.hi[x, a]) + 0.5 * end
        want[q] = key


@njit(cache=True, nogil=True, parallel=True)
def probe_errors(nd, leaves, S, pids, abcd, want, diag, err):
    """The exit-ray test's error (:func:`probe_error`) of each leaf's traced probe ``pids[q]``
    at line ``abcd[q]`` against the interpolation of class ``want[q]``: inf when the probe
    is not of that class (the class reaches less far than its corners say) or cannot be
    interpolated there."""
    for q in prange(leaves.shape[0]):
        s = pids[q]
        if S.cls[s] != want[q]:
            err[q] = np.inf
            continue
        P = np.empty((1, 3))
        NS = np.empty((1, 3))
        NG = np.empty((1, 3))
        OP = np.empty((1, 3))
        OD = np.empty((1, 3))
        gn = np.empty((1, 3))
        th = np.empty(1)
        ni = np.empty(1, np.int16)
        mt = np.empty(1, np.int32)
        if interpolate(nd, leaves[q], S, abcd[q], want[q], 0, P, NS, NG, OP, OD, gn, th, ni,
                       mt) < MIN_USABLE:
            err[q] = np.inf
            continue
        RP = np.empty((1, 3))
        RD = np.empty((1, 3))
        rg = np.empty((1, 3))
        interpolate_reflection(nd, leaves[q], S, abcd[q], want[q], 0, RP, RD, rg)
        err[q] = probe_error(S, s, P, NS, OP, OD, RD, diag[q])
