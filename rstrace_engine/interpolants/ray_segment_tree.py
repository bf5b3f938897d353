"""Global ray segment trees (seed 000, sections 4.2-5.1): which tunnels a world region meets.

Ray segment space
-----------------
The trees cover a fixed *domain*: the scene's box (with its point lights) when the cache is
made, padded. Face pair ``f = 2 k + s`` of the domain is parameterised as the objects' face
pairs are (:mod:`.linetree`): a directed segment whose direction is dominated by ``+-k`` lies
on a line ``(a, b, c, d)`` (its intercepts with the front and back faces, as fractions of the
faces' lateral extents, which are grown by the domain's depth ``L`` on every side) and spans
``t`` in ``[t0, t1]``, the depth below the front face over ``L``. A 5D box
``[a0, a1] x [b0, b1] x [c0, c1] x [d0, d1] x [t0, t1]`` stands for the 3D volume its segments
sweep: at depth ``t`` their lateral coordinate ``a (1 - t) + c t`` lies in an interval whose
ends are affine in ``t``, so the volume is a hexahedron, and whether it meets a world box is
an exact interval test in ``t`` (:func:`box5_meets`).

Trees
-----
Six trees (one per face pair) in one node pool, subdivided lazily: a node splits into 32
children (each of the five axes halved at once, as in the paper) when it holds more than
:data:`SPLIT` entries, down to :data:`MAX_DEPTH`. A section is inserted from the root down
into every child its 5D box meets, but stays at a node where it would go into more than
:data:`KEEP` children (a loose tree: a large section is stored once rather than in hundreds of
leaves); a node that splits keeps the entries it had. A query walks every node whose volume
meets the region and tests the entries met on the way: the section's own 5D box, then the
tunnel's Haines-Wallace shaft (:func:`.shafts.hw_shaft`) against the region box. Both tests
are conservative; an interpolant is reported when one of its tunnels passes.

Sections and tunnels
--------------------
A tunnel (:mod:`.tunnels`: boxes ``A``, ``B``) gets one section per face pair that some of
its segments ``p -> q`` (``p`` in ``A``, ``q`` in ``B``) are dominated by; its 5D box bounds
those segments: ``t`` by the two boxes' depths, the intercepts by the slope limit of the face
pair (``|d lateral| <= |d k|``) from either end and, when ``B`` lies strictly deeper than
``A``, by the 16 vertex combinations of the two boxes (the intercepts are linear-fractional,
so monotone, in each coordinate). Tunnels that leave the domain (or are infinite: misses,
suns) are also kept on an *escape* list, tested directly when a region leaves the domain.

Tunnels name their interpolant by ``(id, serial)``; an entry whose interpolant was freed is
skipped, and :meth:`RaySegmentTrees.compact` rebuilds the trees from the live tunnels once the
dead ones outnumber them.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import tolerances as tol
from .shafts import MAX_PLANES, hw_shaft
from .tunnels import extend_infinite

log = logging.getLogger(__name__)

#: Children per split (every axis of the 5D box halved).
FANOUT = 32
#: A leaf with more entries than this splits (if above MAX_DEPTH).
SPLIT = 64
#: Deepest node level.
MAX_DEPTH = 4
#: A section meeting more children than this stays at the node.
KEEP = 2
_STACK = 4 * FANOUT * (MAX_DEPTH + 1)
#: Dead tunnels tolerated beyond the live ones before a rebuild.
COMPACT_SLACK = 4096


class RSTArrays(NamedTuple):
    """Node pool, entry lists, sections and tunnels (capacities N, E, S, T)."""

    child: np.ndarray  # (N,) int32 first of 32 children, -1 for a leaf
    depth: np.ndarray  # (N,) int8
    coord: np.ndarray  # (N, 5) uint8 lattice coordinates (a, b, c, d, t) at the depth
    head: np.ndarray  # (N,) int32 newest entry at the node, -1 none
    count: np.ndarray  # (N,) int32 entries at the node
    e_sec: np.ndarray  # (E,) int32 section of an entry
    e_next: np.ndarray  # (E,) int32 next entry at the same node
    sec_box: np.ndarray  # (S, 10) float32 a0 a1 b0 b1 c0 c1 d0 d1 t0 t1 (rounded outward)
    sec_face: np.ndarray  # (S,) int8
    sec_tun: np.ndarray  # (S,) int32
    tun_a: np.ndarray  # (T, 6) float32 box A (lo xyz, hi xyz; rounded outward)
    tun_b: np.ndarray  # (T, 6) float32 box B
    tun_inf: np.ndarray  # (T,) bool segments go on to infinity through B
    tun_q: np.ndarray  # (T,) int32 interpolant
    tun_serial: np.ndarray  # (T,) int64 its serial


# ----------------------------------------------------------------------------- geometry


@njit(cache=True, nogil=True, inline="always")
def domain_frame(dom, f):
    """``k, i, j, neg, front, L, li, wi, lj, wj`` of face pair ``f`` of domain ``dom``
    (2, 3) (as :func:`.linetree.face_frame`)."""
    k = f >> 1
    neg = (f & 1) == 1
    i = (k + 1) % 3
    j = (k + 2) % 3
    L = dom[1, k] - dom[0, k]
    front = dom[1, k] if neg else dom[0, k]
    li = dom[0, i] - L
    wi = dom[1, i] - dom[0, i] + 2.0 * L
    lj = dom[0, j] - L
    wj = dom[1, j] - dom[0, j] + 2.0 * L
    return k, i, j, neg, front, L, li, wi, lj, wj


@njit(cache=True, nogil=True)
def unit_box(dom, f, lo, hi, out):
    """World box (lo, hi) in face pair ``f``'s unit coordinates: out (6,) = u0 u1 v0 v1 t0
    t1 (u, v: lateral fractions, t: depth fraction)."""
    k, i, j, neg, front, L, li, wi, lj, wj = domain_frame(dom, f)
    out[0] = (lo[i] - li) / wi
    out[1] = (hi[i] - li) / wi
    out[2] = (lo[j] - lj) / wj
    out[3] = (hi[j] - lj) / wj
    if neg:
        out[4] = (front - hi[k]) / L
        out[5] = (front - lo[k]) / L
    else:
        out[4] = (lo[k] - front) / L
        out[5] = (hi[k] - front) / L


@njit(cache=True, nogil=True, inline="always")
def _clip_t(tlo, thi, alpha, beta, gamma, upper):
    """Restrict [tlo, thi] to ``alpha + beta t <= gamma`` (``upper``) or ``>= gamma``."""
    if not upper:
        alpha = -alpha
        beta = -beta
        gamma = -gamma
    # alpha + beta t <= gamma
    if beta > 0.0:
        thi = min(thi, (gamma - alpha) / beta)
    elif beta < 0.0:
        tlo = max(tlo, (gamma - alpha) / beta)
    elif alpha > gamma:
        thi = -np.inf
    return tlo, thi


@njit(cache=True, nogil=True)
def box5_meets(b, r):
    """Does the volume of the 5D box ``b`` (10,) meet the unit-coordinate box ``r`` (6,)?
    Exact up to ``tolerances.RST_SLACK`` (the lateral bounds are affine in t)."""
    tlo = max(b[8], r[4]) - tol.RST_SLACK
    thi = min(b[9], r[5]) + tol.RST_SLACK
    if tlo > thi:
        return False
    # lateral u: lower end a0 + (c0 - a0) t <= r1, upper end a1 + (c1 - a1) t >= r0
    tlo, thi = _clip_t(tlo, thi, b[0], b[4] - b[0], r[1] + tol.RST_SLACK, True)
    tlo, thi = _clip_t(tlo, thi, b[1], b[5] - b[1], r[0] - tol.RST_SLACK, False)
    tlo, thi = _clip_t(tlo, thi, b[2], b[6] - b[2], r[3] + tol.RST_SLACK, True)
    tlo, thi = _clip_t(tlo, thi, b[3], b[7] - b[3], r[2] - tol.RST_SLACK, False)
    return tlo <= thi


@njit(cache=True, nogil=True)
def node_box(depth, coord, out):
    s = 1.0 / (1 << depth)
    for m in range(4):
        out[2 * m] = coord[m] * s
        out[2 * m + 1] = (coord[m] + 1) * s
    out[8] = coord[4] * s
    out[9] = (coord[4] + 1) * s


@njit(cache=True, nogil=True)
def boxes5_overlap(x, y):
    for m in range(5):
        if x[2 * m] > y[2 * m + 1] + tol.RST_SLACK or y[2 * m] > x[2 * m + 1] + tol.RST_SLACK:
            return False
    return True


@njit(cache=True, nogil=True)
def _min_abs(lo, hi):
    if lo <= 0.0 <= hi:
        return 0.0
    return min(abs(lo), abs(hi))


@njit(cache=True, nogil=True)
def section_box(dom, f, alo, ahi, blo, bhi, out):
    """5D box (10,) in face pair ``f`` of the directed segments ``A -> B`` dominated by
    ``f``'s direction; returns False when there are none inside the domain."""
    k, i, j, neg, front, L, li, wi, lj, wj = domain_frame(dom, f)
    sg = -1.0 if neg else 1.0
    # some direction q - p with sg * d_k >= |d_i|, |d_j| must exist
    dk_max = max(sg * (bhi[k] - alo[k]), sg * (blo[k] - ahi[k]))
    if dk_max <= 0.0:
        return False
    if dk_max < _min_abs(blo[i] - ahi[i], bhi[i] - alo[i]) or dk_max < _min_abs(
            blo[j] - ahi[j], bhi[j] - alo[j]):
        return False
    ua = np.empty(6)
    ub = np.empty(6)
    unit_box(dom, f, alo, ahi, ua)
    unit_box(dom, f, blo, bhi, ub)
    t0 = max(min(ua[4], ub[4]), 0.0)
    t1 = min(max(ua[5], ub[5]), 1.0)
    if t0 > t1:
        return False
    out[8] = t0
    out[9] = t1
    su = L / wi
    sv = L / wj
    # slope limit from either end: a = u - t m, c = u + (1 - t) m with |m| <= s
    for lat in range(2):
        s = su if lat == 0 else sv
        tma = max(abs(ua[4]), abs(ua[5]))
        tna = max(abs(1.0 - ua[4]), abs(1.0 - ua[5]))
        tmb = max(abs(ub[4]), abs(ub[5]))
        tnb = max(abs(1.0 - ub[4]), abs(1.0 - ub[5]))
        out[2 * lat] = max(ua[2 * lat] - s * tma, ub[2 * lat] - s * tmb)
        out[2 * lat + 1] = min(ua[2 * lat + 1] + s * tma, ub[2 * lat + 1] + s * tmb)
        out[4 + 2 * lat] = max(ua[2 * lat] - s * tna, ub[2 * lat] - s * tnb)
        out[5 + 2 * lat] = min(ua[2 * lat + 1] + s * tna, ub[2 * lat + 1] + s * tnb)
    if ub[4] > ua[5]:
        # strictly deeper: the intercepts are monotone in each end coordinate
        for lat in range(2):
            lo_a = np.inf
            hi_a = -np.inf
            lo_c = np.inf
            hi_c = -np.inf
            for v in range(16):
                up = ua[2 * lat + (v & 1)]
                tp = ua[4 + ((v >> 1) & 1)]
                uq = ub[2 * lat + ((v >> 2) & 1)]
                tq = ub[4 + ((v >> 3) & 1)]
                m = (uq - up) / (tq - tp)
                a = up - tp * m
                c = up + (1.0 - tp) * m
                lo_a = min(lo_a, a)
                hi_a = max(hi_a, a)
                lo_c = min(lo_c, c)
                hi_c = max(hi_c, c)
            pad = tol.RST_SLACK * (1.0 + abs(lo_a) + abs(hi_a) + abs(lo_c) + abs(hi_c))
            out[2 * lat] = max(out[2 * lat], lo_a - pad)
            out[2 * lat + 1] = min(out[2 * lat + 1], hi_a + pad)
            out[4 + 2 * lat] = max(out[4 + 2 * lat], lo_c - pad)
            out[4 + 2 * lat + 1] = min(out[4 + 2 * lat + 1], hi_c + pad)
    for m in range(4):
        out[2 * m] = max(out[2 * m], 0.0)
        out[2 * m + 1] = min(out[2 * m + 1], 1.0)
        if out[2 * m] > out[2 * m + 1]:
            return False
    return True


@njit(cache=True, nogil=True)
def _shaft_meets(alo, ahi, blo, bhi, slack, lo, hi, pl, bb):
    """Does the Haines-Wallace shaft between boxes A and B meet the box (lo, hi)?
    (Conservative: False only when the box is outside the joint box or one plane.)"""
    npl = hw_shaft(alo, ahi, blo, bhi, slack, pl, bb)
    for m in range(3):
        if hi[m] < bb[m] or lo[m] > bb[3 + m]:
            return False
    for p in range(npl):
        x = hi[0] if pl[p, 0] > 0.0 else lo[0]
        y = hi[1] if pl[p, 1] > 0.0 else lo[1]
        z = hi[2] if pl[p, 2] > 0.0 else lo[2]
        if pl[p, 0] * x + pl[p, 1] * y + pl[p, 2] * z + pl[p, 3] < 0.0:
            return False
    return True


@njit(cache=True, nogil=True)
def tunnel_meets(rst, t, lo, hi, slack, pl, bb):
    """Does tunnel ``t`` meet the world box (lo, hi)? (Infinite tunnels are prolonged past
    the box first.)"""
    alo = np.empty(3)
    ahi = np.empty(3)
    blo = np.empty(3)
    bhi = np.empty(3)
    for m in range(3):
        alo[m] = rst.tun_a[t, m]
        ahi[m] = rst.tun_a[t, 3 + m]
        blo[m] = rst.tun_b[t, m]
        bhi[m] = rst.tun_b[t, 3 + m]
    if rst.tun_inf[t]:
        elo = np.empty(3)
        ehi = np.empty(3)
        if not extend_infinite(alo, ahi, blo, bhi, lo, hi, elo, ehi):
            return True
        return _shaft_meets(alo, ahi, elo, ehi, slack, lo, hi, pl, bb)
    return _shaft_meets(alo, ahi, blo, bhi, slack, lo, hi, pl, bb)


# ----------------------------------------------------------------------------- building


@njit(cache=True, nogil=True)
def make_sections(dom, tun_a, tun_b, tun_inf, t0, t1, sec_box, sec_face, sec_tun, esc):
    """Sections of tunnels ``t0..t1`` (up to 6 each) written to ``sec_box (6 (t1 - t0),
    10) float64``, ``sec_face``, ``sec_tun``; esc[t - t0]: the tunnel leaves the domain.
    Returns the number of sections."""
    ns = 0
    elo = np.empty(3)
    ehi = np.empty(3)
    dlo = dom[0]
    dhi = dom[1]
    alo = np.empty(3)
    ahi = np.empty(3)
    blo = np.empty(3)
    bhi = np.empty(3)
    for t in range(t0, t1):
        for m in range(3):
            alo[m] = tun_a[t, m]
            ahi[m] = tun_a[t, 3 + m]
            blo[m] = tun_b[t, m]
            bhi[m] = tun_b[t, 3 + m]
        out = tun_inf[t]
        if tun_inf[t]:
            if not extend_infinite(alo, ahi, blo, bhi, dlo, dhi, elo, ehi):
                for m in range(3):
                    elo[m] = blo[m]
                    ehi[m] = bhi[m]
                # no finite reach: every face pair, the whole domain
                for f in range(6):
                    for m in range(8):
                        sec_box[ns, m] = 0.0 if m % 2 == 0 else 1.0
                    sec_box[ns, 8] = 0.0
                    sec_box[ns, 9] = 1.0
                    sec_face[ns] = f
                    sec_tun[ns] = t
                    ns += 1
                esc[t - t0] = True
                continue
        else:
            for m in range(3):
                elo[m] = blo[m]
                ehi[m] = bhi[m]
        for m in range(3):
            if min(alo[m], elo[m]) < dlo[m] or max(ahi[m], ehi[m]) > dhi[m]:
                out = True
        esc[t - t0] = out
        for f in range(6):
            if section_box(dom, f, alo, ahi, elo, ehi, sec_box[ns]):
                sec_face[ns] = f
                sec_tun[ns] = t
                ns += 1
    return ns


@njit(cache=True, nogil=True)
def _append(rst, node, sec, ne):
    rst.e_sec[ne] = sec
    rst.e_next[ne] = rst.head[node]
    rst.head[node] = ne
    rst.count[node] += 1


@njit(cache=True, nogil=True)
def _split(rst, node, nn):
    rst.child[node] = nn
    for c in range(FANOUT):
        x = nn + c
        rst.child[x] = -1
        rst.depth[x] = rst.depth[node] + 1
        rst.head[x] = -1
        rst.count[x] = 0
        for m in range(5):
            rst.coord[x, m] = 2 * rst.coord[node, m] + ((c >> m) & 1)


@njit(cache=True, nogil=True)
def insert_sections(rst, s0, s1, n_nodes, n_entries, node_cap, entry_cap):
    """Insert sections ``s0..s1`` (module doc). Stops before a section when the pools may
    not hold it; returns ``(next section, n_nodes, n_entries)``."""
    worst_e = KEEP ** MAX_DEPTH + 1
    worst_n = FANOUT * (worst_e + 1)
    stack = np.empty(_STACK, np.int32)
    nb = np.empty(10)
    for s in range(s0, s1):
        if n_entries + worst_e > entry_cap or n_nodes + worst_n > node_cap:
            return s, n_nodes, n_entries
        sb = rst.sec_box[s]
        stack[0] = rst.sec_face[s]
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            if rst.child[node] < 0:
                if rst.count[node] >= SPLIT and rst.depth[node] < MAX_DEPTH:
                    _split(rst, node, n_nodes)
                    n_nodes += FANOUT
                else:
                    _append(rst, node, s, n_entries)
                    n_entries += 1
                    continue
            base = rst.child[node]
            nmeet = 0
            for c in range(FANOUT):
                node_box(rst.depth[base + c], rst.coord[base + c], nb)
                if boxes5_overlap(nb, sb):
                    nmeet += 1
            if nmeet > KEEP or sp + nmeet > _STACK:
                _append(rst, node, s, n_entries)
                n_entries += 1
                continue
            for c in range(FANOUT):
                node_box(rst.depth[base + c], rst.coord[base + c], nb)
                if boxes5_overlap(nb, sb):
                    stack[sp] = base + c
                    sp += 1
    return s1, n_nodes, n_entries


# ----------------------------------------------------------------------------- queries


@njit(cache=True, nogil=True)
def query_regions(rst, dom, regions, pool_serial, pool_live, slack, hit):
    """Mark ``hit[q]`` for every live interpolant with a tunnel meeting one of the world
    boxes ``regions`` (k, 2, 3) inside the domain (their part inside it). Returns the number
    of (node visits, tunnel tests)."""
    stack = np.empty(FANOUT * (MAX_DEPTH + 2), np.int32)
    nb = np.empty(10)
    r = np.empty(6)
    pl = np.empty((MAX_PLANES, 4))
    bb = np.empty(6)
    lo = np.empty(3)
    hi = np.empty(3)
    visits = 0
    tests = 0
    for g in range(regions.shape[0]):
        empty = False
        for m in range(3):
            lo[m] = max(regions[g, 0, m], dom[0, m])
            hi[m] = min(regions[g, 1, m], dom[1, m])
            if lo[m] > hi[m]:
                empty = True
        if empty:
            continue
        for f in range(6):
            unit_box(dom, f, lo, hi, r)
            stack[0] = f
            sp = 1
            while sp > 0:
                sp -= 1
                node = stack[sp]
                visits += 1
                node_box(rst.depth[node], rst.coord[node], nb)
                if not box5_meets(nb, r):
                    continue
                e = rst.head[node]
                while e >= 0:
                    s = rst.e_sec[e]
                    e = rst.e_next[e]
                    t = rst.sec_tun[s]
                    q = rst.tun_q[t]
                    if hit[q] or not pool_live[q] or pool_serial[q] != rst.tun_serial[t]:
                        continue
                    if not box5_meets(rst.sec_box[s], r):
                        continue
                    tests += 1
                    if tunnel_meets(rst, t, lo, hi, slack, pl, bb):
                        hit[q] = True
                base = rst.child[node]
                if base >= 0:  # the stack holds a fan per level: never overflows
                    for c in range(FANOUT):
                        stack[sp] = base + c
                        sp += 1
    return visits, tests


@njit(cache=True, nogil=True)
def query_list(rst, tunnels, regions, pool_serial, pool_live, slack, hit):
    """Mark ``hit[q]`` for the live interpolants of ``tunnels`` (ids) meeting a region
    (whole world boxes, no domain clipping): the escape list, and the brute force."""
    pl = np.empty((MAX_PLANES, 4))
    bb = np.empty(6)
    tests = 0
    for x in range(tunnels.shape[0]):
        t = tunnels[x]
        q = rst.tun_q[t]
        if hit[q] or not pool_live[q] or pool_serial[q] != rst.tun_serial[t]:
            continue
        for g in range(regions.shape[0]):
            tests += 1
            if tunnel_meets(rst, t, regions[g, 0], regions[g, 1], slack, pl, bb):
                hit[q] = True
                break
    return tests


@njit(cache=True, nogil=True)
def live_tunnels(rst, n, pool_serial, pool_live, keep):
    cnt = 0
    for t in range(n):
        q = rst.tun_q[t]
        keep[t] = pool_live[q] and pool_serial[q] == rst.tun_serial[t]
        if keep[t]:
            cnt += 1
    return cnt


# ----------------------------------------------------------------------------- the owner


def outward32(lo: np.ndarray, hi: np.ndarray):
    """float32 copies of bounds ``lo <= hi`` rounded outward (never inside the float64)."""
    lo32 = np.asarray(lo).astype(np.float32)
    hi32 = np.asarray(hi).astype(np.float32)
    lo32 = np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)
    return lo32, hi32


def _boxes32(b: np.ndarray) -> np.ndarray:
    """(m, 6) lo-xyz/hi-xyz boxes as float32, rounded outward."""
    lo, hi = outward32(b[:, :3], b[:, 3:])
    return np.concatenate([lo, hi], axis=1)


def _grown(a: np.ndarray, need: int, fill=None) -> np.ndarray:
    if len(a) >= need:
        return a
    new = np.empty((max(need, 2 * len(a)),) + a.shape[1:], a.dtype)
    if fill is not None:
        new[len(a):] = fill
    new[:len(a)] = a
    return new


class RaySegmentTrees:
    """The six trees over ``domain`` (2, 3) and their tunnels (growth, compaction)."""

    #: bytes per node, entry, section, tunnel as stored
    NODE_BYTES = 4 + 1 + 5 + 4 + 4
    ENTRY_BYTES = 4 + 4
    SECTION_BYTES = 40 + 1 + 4
    TUNNEL_BYTES = 24 + 24 + 1 + 4 + 8

    def __init__(self, domain: np.ndarray, slack: float) -> None:
        self.dom = np.ascontiguousarray(domain, np.float64).reshape(2, 3)
        self.slack = float(slack)
        self._reset()

    def _reset(self) -> None:
        nodes, entries, secs, tuns = 1024, 4096, 1024, 256
        self.arrays = RSTArrays(
            np.full(nodes, -1, np.int32), np.zeros(nodes, np.int8),
            np.zeros((nodes, 5), np.uint8), np.full(nodes, -1, np.int32),
            np.zeros(nodes, np.int32), np.empty(entries, np.int32),
            np.empty(entries, np.int32), np.empty((secs, 10), np.float32),
            np.empty(secs, np.int8), np.empty(secs, np.int32),
            np.empty((tuns, 6), np.float32), np.empty((tuns, 6), np.float32),
            np.empty(tuns, np.bool_), np.empty(tuns, np.int32), np.empty(tuns, np.int64))
        self.n_nodes = 6  # the roots, one per face pair
        self.n_entries = 0
        self.n_sec = 0
        self.n_tun = 0
        self.escape = np.empty(0, np.int32)

    def _set(self, **kw) -> None:
        self.arrays = self.arrays._replace(**kw)

    @property
    def memory_bytes(self) -> int:
        return (self.n_nodes * self.NODE_BYTES + self.n_entries * self.ENTRY_BYTES
                + self.n_sec * self.SECTION_BYTES + self.n_tun * self.TUNNEL_BYTES
                + 4 * len(self.escape))

    def add_tunnels(self, ta, tb, tinf, q, serial) -> None:
        """Append tunnels (``ta, tb (m, 6)`` boxes, ``tinf (m,)``, interpolant ids and
        serials) and insert their sections."""
        m = len(q)
        if m == 0:
            return
        a = self.arrays
        t0, t1 = self.n_tun, self.n_tun + m
        self._set(tun_a=_grown(a.tun_a, t1), tun_b=_grown(a.tun_b, t1),
                  tun_inf=_grown(a.tun_inf, t1), tun_q=_grown(a.tun_q, t1),
                  tun_serial=_grown(a.tun_serial, t1))
        a = self.arrays
        a.tun_a[t0:t1] = ta if ta.dtype == np.float32 else _boxes32(ta)
        a.tun_b[t0:t1] = tb if tb.dtype == np.float32 else _boxes32(tb)
        a.tun_inf[t0:t1] = tinf
        a.tun_q[t0:t1] = q
        a.tun_serial[t0:t1] = serial
        self.n_tun = t1
        s0 = self.n_sec
        self._set(sec_box=_grown(a.sec_box, s0 + 6 * m), sec_face=_grown(a.sec_face, s0 + 6 * m),
                  sec_tun=_grown(a.sec_tun, s0 + 6 * m))
        a = self.arrays
        esc = np.zeros(m, np.bool_)
        box = np.empty((6 * m, 10))
        ns = make_sections(self.dom, a.tun_a, a.tun_b, a.tun_inf, t0, t1, box,
                           a.sec_face[s0:], a.sec_tun[s0:], esc)
        lo, hi = outward32(box[:ns, 0::2], box[:ns, 1::2])
        a.sec_box[s0:s0 + ns, 0::2] = lo
        a.sec_box[s0:s0 + ns, 1::2] = hi
        self.n_sec = s0 + ns
        if np.any(esc):
            self.escape = np.concatenate([self.escape,
                                          (t0 + np.flatnonzero(esc)).astype(np.int32)])
        s = s0
        while s < self.n_sec:
            s, self.n_nodes, self.n_entries = insert_sections(
                self.arrays, s, self.n_sec, self.n_nodes, self.n_entries,
                len(self.arrays.child), len(self.arrays.e_sec))
            if s < self.n_sec:
                self._grow_pools()

    def _grow_pools(self) -> None:
        a = self.arrays
        worst_e = KEEP ** MAX_DEPTH + 1
        n_need = self.n_nodes + FANOUT * (worst_e + 1)
        e_need = self.n_entries + worst_e
        self._set(child=_grown(a.child, n_need, -1), depth=_grown(a.depth, n_need, 0),
                  coord=_grown(a.coord, n_need, 0), head=_grown(a.head, n_need, -1),
                  count=_grown(a.count, n_need, 0), e_sec=_grown(a.e_sec, e_need),
                  e_next=_grown(a.e_next, e_need))

    def query(self, regions: np.ndarray, pool_serial, pool_live, hit) -> tuple[int, int]:
        """Mark ``hit[q]`` for the live interpolants with a tunnel meeting a region
        ``(k, 2, 3)``. Returns (node visits, tunnel tests)."""
        regions = np.ascontiguousarray(regions, np.float64).reshape(-1, 2, 3)
        if len(regions) == 0 or self.n_tun == 0:
            return 0, 0
        visits, tests = query_regions(self.arrays, self.dom, regions, pool_serial, pool_live,
                                      self.slack, hit)
        outside = np.any(regions[:, 0] < self.dom[0], axis=1) | np.any(
            regions[:, 1] > self.dom[1], axis=1)
        if np.any(outside) and len(self.escape):
            tests += query_list(self.arrays, self.escape, regions[outside], pool_serial,
                                pool_live, self.slack, hit)
        return int(visits), int(tests)

    def query_brute(self, regions: np.ndarray, pool_serial, pool_live, hit) -> int:
        """Every live tunnel's shaft against the regions (the reference for tests)."""
        regions = np.ascontiguousarray(regions, np.float64).reshape(-1, 2, 3)
        return int(query_list(self.arrays, np.arange(self.n_tun, dtype=np.int32), regions,
                              pool_serial, pool_live, self.slack, hit))

    def live_count(self, pool_serial, pool_live) -> int:
        keep = np.empty(self.n_tun, np.bool_)
        return int(live_tunnels(self.arrays, self.n_tun, pool_serial, pool_live, keep))

    def compact(self, pool_serial, pool_live, force: bool = False, domain=None,
                slack: float | None = None) -> bool:
        """Rebuild from the live tunnels once the dead ones outnumber them (or with
        ``force``; over a new ``domain`` if given). Returns whether it rebuilt."""
        keep = np.empty(self.n_tun, np.bool_)
        live = int(live_tunnels(self.arrays, self.n_tun, pool_serial, pool_live, keep))
        if not force and self.n_tun - live <= live + COMPACT_SLACK:
            return False
        if domain is not None:
            self.dom = np.ascontiguousarray(domain, np.float64).reshape(2, 3)
        if slack is not None:
            self.slack = float(slack)
        a, n = self.arrays, self.n_tun
        ta, tb, ti = a.tun_a[:n][keep], a.tun_b[:n][keep], a.tun_inf[:n][keep]
        tq, ts = a.tun_q[:n][keep], a.tun_serial[:n][keep]
        self._reset()
        self.add_tunnels(ta, tb, ti, tq, ts)
        log.debug("rst: rebuilt from %d live of %d tunnels", live, n)
        return True
