"""Tunnel sections of radiance interpolants: the world volumes an interpolant depends on.

Seed 000, section 3.3: the 16 extremal ray trees of an interpolant share their
position-independent part; each of their arcs (a ray segment from a surface point to a light,
or to the reflected / refracted surface) bounds, with its 15 siblings, the segments of every
ray the interpolant covers. A *tunnel section* here is that volume taken conservatively as the
Haines-Wallace shaft between two world boxes ``A`` (where the segments start) and ``B`` (where
they end):

* the root's points: the box of the cell's *slab hexahedron* (every covered line crosses the
  object inside it, see :mod:`.predicate`) clipped to the object's world box: it holds the
  box the predicate's light shafts start from (the object's surface inside the slab);
* a reflected / refracted node's points: the box of the node's points over the corner *and*
  test samples, padded by :data:`~.tolerances.TUNNEL_MARGIN_REL` exactly as the predicate's
  tunnel test pads it (the same samples, at build time);
* a light: its extent's box (its position; a sphere light's ball; an area light's
  rectangle, :func:`.shafts.light_extents`), or for a sun the start box moved far against
  its direction, grown by the chord of its cone of directions when it has an angle (the
  segments of every shadow ray from ``A`` then run from ``A`` through ``B``).

Sections are made for every reflection / refraction arc and, at every node that hits a
surface, for every light that contributes *or* is off at the corners (off by the shading
normal or the cone: it may still light covered rays between the corners, so geometry in its
shaft matters). A light occluded at the corners depends only on its occluder (the
membership index, :mod:`.membership`): the paper's rule, any occluder blocks all light.

A section whose segments leave the scene (a reflected ray that misses, a sun) is *infinite*:
``B`` is then a box of far points on the segments, and the section stands for the rays from
``A`` through ``B`` to infinity (:func:`extend_infinite`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import LIGHT_SUN
from .linetree import face_frame
from .predicate import _points_box

#: Membership key kinds (``2 * id + kind``): an object hit by a ray-tree node (its surface
#: and material matter) or occluding a light (only its geometry matters); a light that
#: contributes or is off by facing (``LIGHT_SHADES``) or is occluded (``LIGHT_OCCLUDED``).
OBJ_HIT = 0
OBJ_OCCLUDES = 1
LIGHT_SHADES = 0
LIGHT_OCCLUDED = 1


@njit(cache=True, nogil=True)
def slab_box(box, inst, face, depth, coord, zlo, zhi, slack, lo, hi):
    """World box of the slab hexahedron of a valid cell (depths ``[zlo, zhi]`` below the
    front face of ``face``), padded by ``slack``: every covered line crosses the object in
    it (the predicate's vertices, :func:`.predicate._slab`, for the certified slab)."""
    k, i, j, neg, front, L, li, wi, lj, wj = face_frame(box, inst, face)
    s = 1.0 / (1 << depth)
    for m in range(3):
        lo[m] = np.inf
        hi[m] = -np.inf
    P = np.empty(3)
    for v in range(8):
        z = zhi if v & 4 else zlo
        f = z / L
        ba = v & 1
        bb = (v >> 1) & 1
        x = li + wi * s * ((1 - f) * (coord[0] + ba) + f * (coord[2] + ba))
        y = lj + wj * s * ((1 - f) * (coord[1] + bb) + f * (coord[3] + bb))
        P[k] = front - z if neg else front + z
        P[i] = x
        P[j] = y
        for m in range(3):
            lo[m] = min(lo[m], P[m])
            hi[m] = max(hi[m], P[m])
    for m in range(3):
        pad = slack + tol.BOX_ROUND_REL * (abs(lo[m]) + abs(hi[m]))
        lo[m] -= pad
        hi[m] += pad


@njit(cache=True, nogil=True)
def _parent_row(sm, base, q):
    """Row (within the tree) of node ``q``'s parent."""
    ppath = sm.node_path[base + q] >> 1
    pq = 0
    for x in range(q):
        if sm.node_path[base + x] == ppath:
            pq = x
    return pq


@njit(cache=True, nogil=True)
def _emit(row, write, ta, tb, tinf, alo, ahi, blo, bhi, inf):
    if write:
        for m in range(3):
            ta[row, m] = alo[m]
            ta[row, 3 + m] = ahi[m]
            tb[row, m] = blo[m]
            tb[row, 3 + m] = bhi[m]
        tinf[row] = inf


def tunnel_sections(sm, box, aabb, light_kind, mask, arcs, light_lo, light_hi, light_chord,
                    light_dir, reach, slack, inst, face, depth, coord, zlo, zhi, ids, ns):
    """:func:`cell_tunnels`' sections, counted then written: ``(counts, ta, tb, tinf)``,
    cell c's ``counts[c]`` rows in order."""
    args = (sm, box, aabb, light_kind, mask, arcs, light_lo, light_hi, light_chord, light_dir,
            reach, slack, inst, face, depth, coord, zlo, zhi, ids, ns)
    counts = np.zeros(len(inst), np.int64)
    none = np.empty((0, 6))
    cell_tunnels(*args, False, counts, counts, none, none, np.empty(0, np.bool_))
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    m = int(counts.sum())
    ta, tb, tinf = np.empty((m, 6)), np.empty((m, 6)), np.empty(m, np.bool_)
    cell_tunnels(*args, True, start, counts, ta, tb, tinf)
    return counts, ta, tb, tinf


@njit(cache=True, nogil=True)
def cell_tunnels(sm, box, aabb, light_kind, mask, arcs, light_lo, light_hi, light_chord,
                 light_dir, reach, slack, inst, face, depth, coord, zlo, zhi, ids, ns, write,
                 start, counts, ta, tb, tinf):
    """Tunnel sections of ``nc`` valid cells (see the module doc): the light sections of
    the lights in ``mask`` (L,) and, with ``arcs``, the nodes' reflection and refraction
    arcs (False: a light added to kept cells, whose arcs are in the trees already).

    sm : :class:`~.predicate.SampleArrays`; box : (I, 2, 3) the objects' expanded boxes;
    aabb : (I, 2, 3) their world boxes (the root points are on the object, in the slab);
    light_lo, light_hi (L, 3), light_chord (L,): the lights' extents
    (:func:`.shafts.light_extents`); reach : a length beyond which every point of the scene
    lies from any scene point (sun shafts end that far); slack : absolute outward padding.
    Per cell: inst, face, depth, coord (nc, 4), slab zlo, zhi, sample ids (nc, S) (corners
    then test lines) and their number ns. With ``write`` False only ``counts`` (nc,) is
    filled; else cell c's sections go to rows ``start[c]..``: ``ta, tb (R, 6)`` boxes ``A``
    and ``B`` (lo xyz, hi xyz), ``tinf (R,)`` infinite flags.
    """
    L = light_kind.shape[0]
    rlo = np.empty(3)
    rhi = np.empty(3)
    plo = np.empty(3)
    phi = np.empty(3)
    nlo = np.empty(3)
    nhi = np.empty(3)
    llo = np.empty(3)
    lhi = np.empty(3)
    for c in range(inst.shape[0]):
        row = start[c] if write else 0
        k = 0
        s0 = ids[c, 0]
        base = sm.node_start[s0]
        nn = sm.node_count[s0]
        slab_box(box, inst[c], face[c], depth[c], coord[c], zlo[c], zhi[c], slack, rlo, rhi)
        for m in range(3):
            pad = slack + tol.BOX_ROUND_REL * (abs(aabb[inst[c], 0, m]) + abs(aabb[inst[c], 1, m]))
            rlo[m] = max(rlo[m], aabb[inst[c], 0, m] - pad)
            rhi[m] = min(rhi[m], aabb[inst[c], 1, m] + pad)
        for q in range(nn):
            if q == 0:
                for m in range(3):
                    nlo[m] = rlo[m]
                    nhi[m] = rhi[m]
            else:
                _points_box(sm, ids[c], ns[c], q, tol.TUNNEL_MARGIN_REL, slack, nlo, nhi)
            if q > 0 and arcs:
                pq = _parent_row(sm, base, q)
                if pq == 0:
                    for m in range(3):
                        plo[m] = rlo[m]
                        phi[m] = rhi[m]
                else:
                    _points_box(sm, ids[c], ns[c], pq, tol.TUNNEL_MARGIN_REL, slack, plo, phi)
                _emit(row + k, write, ta, tb, tinf, plo, phi, nlo, nhi,
                      sm.node_inst[base + q] < 0)
                k += 1
            if sm.node_inst[base + q] < 0:
                continue
            for j in range(L):
                occ = sm.node_occ[base + q, j]
                if occ >= 0 or light_kind[j] < 0 or not mask[j]:
                    continue  # occluded: depends on the occluder alone (membership); or a
                    # deleted light's slot (membership again, should a light come back)
                if light_kind[j] == LIGHT_SUN:
                    grow = reach * light_chord[j]
                    for m in range(3):
                        llo[m] = nlo[m] - light_dir[j, m] * reach - grow
                        lhi[m] = nhi[m] - light_dir[j, m] * reach + grow
                    inf = True
                else:
                    for m in range(3):
                        llo[m] = light_lo[j, m]
                        lhi[m] = light_hi[j, m]
                    inf = False
                _emit(row + k, write, ta, tb, tinf, nlo, nhi, llo, lhi, inf)
                k += 1
        counts[c] = k


@njit(cache=True, nogil=True)
def _add_key(keys, n, key):
    for x in range(n):
        if keys[x] == key:
            return n
    keys[n] = key
    return n + 1


@njit(cache=True, nogil=True)
def cell_members(sm, ids, ns, write, ostart, lstart, ocount, lcount, okeys, lkeys, world):
    """Membership keys of cells: the union over the ray trees of samples ``ids[c, :ns[c]]``
    (a valid cell's samples share one position-independent tree: one sample is enough).

    Object keys ``2 * instance + OBJ_HIT / OBJ_OCCLUDES``, light keys ``2 * light +
    LIGHT_SHADES / LIGHT_OCCLUDED`` (each once per cell); ``world[c]``: some node misses (the
    world colour shows). With ``write`` False only the counts are filled.
    """
    L = sm.node_occ.shape[1]
    ob = np.empty(64, np.int64)
    lb = np.empty(2 * max(L, 1), np.int64)
    for c in range(ids.shape[0]):
        no = 0
        nl = 0
        w = False
        for u in range(ns[c]):
            s0 = ids[c, u]
            base = sm.node_start[s0]
            for q in range(sm.node_count[s0]):
                oi = sm.node_inst[base + q]
                if oi < 0:
                    w = True
                    continue
                if no + 1 + L > ob.shape[0]:
                    nb = np.empty(2 * ob.shape[0] + L, np.int64)
                    nb[:no] = ob[:no]
                    ob = nb
                no = _add_key(ob, no, 2 * oi + OBJ_HIT)
                for j in range(L):
                    occ = sm.node_occ[base + q, j]
                    if occ >= 0:
                        no = _add_key(ob, no, 2 * occ + OBJ_OCCLUDES)
                        nl = _add_key(lb, nl, 2 * j + LIGHT_OCCLUDED)
                    else:
                        nl = _add_key(lb, nl, 2 * j + LIGHT_SHADES)
        ocount[c] = no
        lcount[c] = nl
        world[c] = w
        if write:
            for x in range(no):
                okeys[ostart[c] + x] = ob[x]
            for x in range(nl):
                lkeys[lstart[c] + x] = lb[x]


@njit(cache=True, nogil=True)
def extend_infinite(alo, ahi, blo, bhi, tlo, thi, elo, ehi):
    """Far box of an infinite section reaching past the box (tlo, thi): the segments from
    ``A`` through ``B`` prolonged. Every ray from ``p`` in ``A`` through ``q`` in ``B`` meets
    the box only at ``p + s (q - p)`` with ``s <= S``; those points lie in ``A + S (B - A)``
    (``B - A`` the Minkowski difference box), written to (elo, ehi). Returns False when the
    direction box holds the zero vector (no finite reach: the caller treats the section as
    meeting everything)."""
    # distance from the origin to the direction box B - A
    d2 = 0.0
    for m in range(3):
        lo = blo[m] - ahi[m]
        hi = bhi[m] - alo[m]
        if lo > 0.0:
            d2 += lo * lo
        elif hi < 0.0:
            d2 += hi * hi
    if d2 <= 0.0:
        return False
    far2 = 0.0
    for m in range(3):
        e = max(abs(thi[m] - alo[m]), abs(tlo[m] - ahi[m]))
        far2 += e * e
    S = max(1.0, 2.0 * math.sqrt(far2 / d2))
    for m in range(3):
        elo[m] = alo[m] + S * (blo[m] - ahi[m])
        ehi[m] = ahi[m] + S * (bhi[m] - alo[m])
    return True
