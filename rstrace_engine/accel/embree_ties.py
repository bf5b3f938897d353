"""Which objects a float32 (Embree) hit may tie with: the objects to re-test at a hit point.

Embree cannot order hits on two objects whose faces are within float32 rounding of each
other along a ray (``tolerances.FLOAT32_TIE_REL``; a box resting on a floor): which one it
reports depends on its BVH, so on every other object of the scene. :mod:`.embree` re-tests,
for each hit, every other live object whose box holds the hit point (padded by the ray's
tie reach, twice ``FLOAT32_TIE_REL * (magnitude + |origin|)``), and keeps the closest
float64 hit. This module finds those objects cheaply:

* **pairs**: the live objects whose boxes overlap, each pair with the overlap of its two
  boxes padded by :data:`PAIR_ORIGIN_MAGNITUDES` times the scene magnitude's reach, in a
  small BVH (:func:`.bvh_mesh.build_top`), and per object the bounds of its pairs' regions. A
  hit point on object ``i`` outside those bounds has nothing to re-test (one box test: most
  hits); inside, the regions holding it name the objects to re-test.
* **objects**: for rays starting farther out than the pairs were padded for, the live
  objects' boxes themselves, padded per ray.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .. import tolerances as tol
from .bvh_mesh import build_top

#: The pair regions are padded for ray origins up to this many scene magnitudes from the
#: world origin (rays starting farther out take the per-object query).
PAIR_ORIGIN_MAGNITUDES = 4.0


class TieIndex(NamedTuple):
    """Boxes of the live objects and of their overlaps (see the module docstring)."""

    obj_bounds: np.ndarray  # (N, 24) float64, top-level BVH over the live objects' boxes
    obj_child: np.ndarray  # (N, 4) int32
    obj_inst: np.ndarray  # (I,) int32 instance ids in leaf order
    pair_bounds: np.ndarray  # (P, 24) float64, BVH over the padded overlap regions
    pair_child: np.ndarray  # (P, 4) int32
    pair_a: np.ndarray  # (K,) int32 first instance of each pair, in leaf order
    pair_b: np.ndarray  # (K,) int32 second instance
    pair_pad: float  # world padding the regions were built with
    near_lo: np.ndarray  # (I, 3) float64 per instance id: bounds of its pairs' regions
    near_hi: np.ndarray  # (I, 3) (empty, lo > hi, for an object overlapping none)


def tie_reach_pad(magnitude: float, origin_magnitude) -> float:
    """World distance from a hit point within which another object may tie with it."""
    return 2.0 * tol.FLOAT32_TIE_REL * (magnitude + origin_magnitude)


@njit(cache=True, nogil=True)
def _overlaps(lo, hi, order, a, b):
    """Pairs ``(i, j)`` of boxes ``lo, hi`` (n, 3) that overlap (sweep along x in ``order``,
    the boxes sorted by ``lo[:, 0]``); writes up to ``len(a)`` and returns how many."""
    n = order.shape[0]
    k = 0
    for x in range(n):
        i = order[x]
        for y in range(x + 1, n):
            j = order[y]
            if lo[j, 0] > hi[i, 0]:
                break
            if (lo[j, 1] <= hi[i, 1] and lo[i, 1] <= hi[j, 1] and lo[j, 2] <= hi[i, 2]
                    and lo[i, 2] <= hi[j, 2]):
                if k < a.shape[0]:
                    a[k] = i
                    b[k] = j
                k += 1
    return k


def build_tie_index(inst_aabb: np.ndarray, live: np.ndarray, magnitude: float) -> TieIndex | None:
    """The index over the live objects ``live`` (instance ids) with world boxes
    ``inst_aabb`` (I, 2, 3); None with fewer than two live objects (nothing can tie)."""
    if len(live) < 2:
        return None
    boxes = inst_aabb[live]
    top = build_top(boxes)
    pad = tie_reach_pad(magnitude, PAIR_ORIGIN_MAGNITUDES * magnitude)
    lo = np.ascontiguousarray(boxes[:, 0] - pad)
    hi = np.ascontiguousarray(boxes[:, 1] + pad)
    order = np.argsort(lo[:, 0], kind="stable").astype(np.int64)
    a = np.empty(4 * len(live), np.int64)
    b = np.empty(4 * len(live), np.int64)
    k = _overlaps(lo, hi, order, a, b)
    if k > len(a):
        a = np.empty(k, np.int64)
        b = np.empty(k, np.int64)
        _overlaps(lo, hi, order, a, b)
    a, b = a[:k], b[:k]
    near_lo = np.full((len(inst_aabb), 3), np.inf)
    near_hi = np.full((len(inst_aabb), 3), -np.inf)
    if k:
        region = np.stack([np.maximum(lo[a], lo[b]), np.minimum(hi[a], hi[b])], axis=1)
        for side in (a, b):
            np.minimum.at(near_lo, live[side], region[:, 0])
            np.maximum.at(near_hi, live[side], region[:, 1])
        pt = build_top(region)
        pair_bounds, pair_child = pt.bounds, pt.child
        pa = np.ascontiguousarray(live[a[pt.perm]], np.int32)
        pb = np.ascontiguousarray(live[b[pt.perm]], np.int32)
    else:
        pair_bounds, pair_child = np.zeros((0, 24)), np.zeros((0, 4), np.int32)
        pa = pb = np.zeros(0, np.int32)
    return TieIndex(top.bounds, top.child, np.ascontiguousarray(live[top.perm], np.int32),
                    pair_bounds, pair_child, pa, pb, float(pad), near_lo, near_hi)


@njit(cache=True, nogil=True)
def _holding(bounds, child, px, py, pz, pad, stack, out):
    """Leaf positions of the boxes of a flat BVH (:func:`.bvh_mesh.build_top`) that hold the
    point padded by ``pad``; writes up to ``len(out)`` and returns how many there are."""
    k = 0
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp]
        for j in range(4):
            c = child[node, j]
            if c == -1:
                continue
            if not (bounds[node, j] - pad <= px <= bounds[node, 12 + j] + pad
                    and bounds[node, 4 + j] - pad <= py <= bounds[node, 16 + j] + pad
                    and bounds[node, 8 + j] - pad <= pz <= bounds[node, 20 + j] + pad):
                continue
            if c >= 0:
                stack[sp] = c
                sp += 1
                continue
            code = ~c
            for q in range(code >> 3, (code >> 3) + (code & 7)):
                if k < out.shape[0]:
                    out[k] = q
                k += 1
    return k


@njit(cache=True, nogil=True)
def tie_candidates(ix: TieIndex, o, d, t, inst, magnitude, rows, objs):
    """(ray, object) pairs to re-test: every live object other than the one hit whose box
    holds the hit point ``o + t d`` padded by the ray's tie reach. Writes up to ``len(rows)``
    pairs into ``rows, objs`` and returns how many there are (run again with room for all
    when that is more)."""
    stack = np.empty(256, np.int32)
    found = np.empty(64, np.int64)
    has_pairs = ix.pair_a.shape[0] > 0
    k = 0
    for r in range(inst.shape[0]):
        i = inst[r]
        if i < 0:
            continue
        om = max(abs(o[r, 0]), abs(o[r, 1]), abs(o[r, 2]))
        pad = 2.0 * tol.FLOAT32_TIE_REL * (magnitude + om)
        px = o[r, 0] + t[r] * d[r, 0]
        py = o[r, 1] + t[r] * d[r, 1]
        pz = o[r, 2] + t[r] * d[r, 2]
        by_pairs = pad <= ix.pair_pad
        if by_pairs and not (has_pairs and ix.near_lo[i, 0] <= px <= ix.near_hi[i, 0]
                             and ix.near_lo[i, 1] <= py <= ix.near_hi[i, 1]
                             and ix.near_lo[i, 2] <= pz <= ix.near_hi[i, 2]):
            continue
        while True:
            if by_pairs:
                n = _holding(ix.pair_bounds, ix.pair_child, px, py, pz, 0.0, stack, found)
            else:
                n = _holding(ix.obj_bounds, ix.obj_child, px, py, pz, pad, stack, found)
            if n <= found.shape[0]:
                break
            found = np.empty(2 * n, np.int64)
        for x in range(n):
            q = found[x]
            j = -1
            if by_pairs:
                if ix.pair_a[q] == i:
                    j = ix.pair_b[q]
                elif ix.pair_b[q] == i:
                    j = ix.pair_a[q]
            elif ix.obj_inst[q] != i:
                j = ix.obj_inst[q]
            if j >= 0:
                if k < rows.shape[0]:
                    rows[k] = r
                    objs[k] = j
                k += 1
    return k


@njit(cache=True, nogil=True)
def tie_reach(o, d, r, magnitude):
    """Half-width (in ``t``) of the window where float32 cannot order hits of ray ``r``."""
    dl = max(abs(d[r, 0]), abs(d[r, 1]), abs(d[r, 2]))
    om = max(abs(o[r, 0]), abs(o[r, 1]), abs(o[r, 2]))
    return tol.FLOAT32_TIE_REL * (magnitude + om) / dl if dl > 0.0 else 0.0


@njit(cache=True, nogil=True)
def tie_window(o, d, t, t0, tmax, magnitude, lo, hi):
    """The re-test window of each hit: ``t`` +- the tie reach, within ``[t0, tmax]``."""
    for r in range(t.shape[0]):
        w = tie_reach(o, d, r, magnitude)
        lo[r] = max(t[r] - w, t0[r])
        hi[r] = min(t[r] + w, tmax[r])


@njit(cache=True, nogil=True)
def merge_closer(rows, ct, ci, cp, cu, cv, t, inst, prim, u, v):
    """Keep the closer hit of each row (equal distances: the higher instance id)."""
    for k in range(rows.shape[0]):
        if ci[k] < 0:
            continue
        r = rows[k]
        if ct[k] < t[r] or (ct[k] == t[r] and ci[k] > inst[r]):
            t[r], inst[r], prim[r], u[r], v[r] = ct[k], ci[k], cp[k], cu[k], cv[k]
