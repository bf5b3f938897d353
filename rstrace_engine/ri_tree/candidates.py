"""Which RI-tree objects a ray batch must resolve, and the nearest of their answers.

A ray meets an RI-tree object's (expanded) box before its nearest traced hit: from outside
the box it *queries* the object's tree, from inside (or leaving the object itself) it traces
the object (:mod:`.render`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .. import tolerances as tol

# candidate kinds
_QUERY, _TRACE = 0, 1


@njit(cache=True, nogil=True)
def _candidates(o, d, t0, t1, best, ri, box, convex, self_inst, self_tmin, rows, objs,
                kind, tlo):
    """Ray/object pairs to resolve, in one pass: each RI-tree object ``ri[k]`` whose box ray
    ``r`` meets before ``best[r]`` (a ray with ``best[r] < t0[r]``, already blocked, has
    none). Fills rows, objs, kind, tlo (capacity ``n * len(ri)``) ray after ray and returns
    the number of pairs."""
    n = o.shape[0]
    c = 0
    inv = np.empty(3)
    for r in range(n):
        if best[r] < t0[r]:
            continue
        for a in range(3):
            inv[a] = 1.0 / d[r, a] if d[r, a] != 0.0 else 0.0
        for q in range(ri.shape[0]):
            k = ri[q]
            if self_inst[r] == k and convex[k]:
                continue
            tn = t0[r]
            tf = min(t1[r], best[r])
            inside = True
            for a in range(3):
                lo = box[k, 0, a]
                hi = box[k, 1, a]
                if o[r, a] < lo or o[r, a] > hi:
                    inside = False
                if d[r, a] != 0.0:
                    ta = (lo - o[r, a]) * inv[a]
                    tb = (hi - o[r, a]) * inv[a]
                    if ta > tb:
                        ta, tb = tb, ta
                    tn = max(tn, ta)
                    tf = min(tf, tb * tol.BOX_TFAR_SCALE)
                elif o[r, a] < lo or o[r, a] > hi:
                    tf = -1.0
            if tn > tf:
                continue
            rows[c] = r
            objs[c] = k
            if inside or self_inst[r] == k:
                kind[c] = _TRACE
                tlo[c] = max(t0[r], self_tmin[r]) if self_inst[r] == k else t0[r]
            else:
                kind[c] = _QUERY
                tlo[c] = t0[r]
            c += 1
    return c


def candidates(o, d, t0, t1, best, ri, box, convex, self_inst, self_tmin):
    """(rows, objs, kind, tlo) of :func:`_candidates`, trimmed to the pairs found."""
    cap = len(o) * len(ri)
    rows = np.empty(cap, np.int64)
    objs = np.empty(cap, np.int32)
    kind = np.empty(cap, np.int8)
    tlo = np.empty(cap)
    c = _candidates(o, d, t0, t1, best, ri, box, convex, self_inst, self_tmin, rows, objs,
                    kind, tlo)
    return rows[:c], objs[:c], kind[:c], tlo[:c]


@njit(cache=True, nogil=True)
def pick(rows, t, ci, best, win):
    """win[r] = candidate with the smallest t below best[r] (best updated)."""
    for q in range(rows.shape[0]):
        r = rows[q]
        if t[q] < best[r]:
            best[r] = t[q]
            win[r] = ci[q]
