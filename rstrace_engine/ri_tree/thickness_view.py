"""The thickness view's tiles through the RI-trees (:mod:`.thickness` for the view itself,
:mod:`.render` for the frame): per camera ray, the traced objects' lengths walked exactly
and the RI-tree objects' interpolated where the ray enters their box from outside."""

from __future__ import annotations

import numpy as np

from ..frame import (
    CLASS_BACKGROUND,
    CLASS_FAIL_NONLINEAR,
    CLASS_FAIL_SILHOUETTE,
    CLASS_INTERPOLATED,
    CLASS_TRACED,
)
from .candidates import _QUERY, _TRACE, candidates
from .patches import ST_FAIL_ANGLE, ST_FAIL_CLASS, ST_HIT, ST_SPARSE
from .thickness import walk


def tile(r, sa, o, d, t0, t1, counters):
    """Lengths inside objects of camera rays for the renderer ``r`` (a
    :class:`~.render.RITreeRenderer`): traced objects walked exactly, RI-tree objects
    interpolated where the ray enters their box from outside."""
    view = True
    n = len(o)
    sub, ids = r._sub[view]
    cache = r.caches[view]
    length = np.zeros(n)
    cls = np.full(n, CLASS_BACKGROUND, np.uint8)
    hit_any = np.full(n, -1, np.int32)
    if sub is not None:
        def through_sub(oo, dd, lo, hi, rows):
            hh = r._timed("ray", len(oo), sub.closest_hit, oo, dd, lo, hi)
            ok = hh.inst >= 0
            inst = np.where(ok, ids[np.maximum(hh.inst, 0)], -1).astype(np.int32)
            return hh._replace(inst=inst)

        length += walk(sa, through_sub, o, d, t0, t1)
        cls[length > 0] = CLASS_TRACED
        hit_any[length > 0] = 0
    ri = r.ri[view]
    if len(ri) == 0:
        return length, cls, hit_any
    rows, objs, kind, _ = candidates(o, d, t0, t1, np.full(n, np.inf), ri, cache.box,
                                     r.convex, np.full(n, -1, np.int32), np.zeros(n))
    if len(rows) == 0:
        return length, cls, hit_any
    qi = np.flatnonzero(kind == _QUERY)
    walk_pairs = [np.flatnonzero(kind == _TRACE)]
    if len(qi):
        qr = rows[qi]
        q = r._timed("query", 0, cache.query, objs[qi], o[qr], d[qr])
        okq = np.flatnonzero(q.status == ST_HIT)
        np.add.at(length, qr[okq], q.thick[okq])
        cls[qr[okq]] = np.maximum(cls[qr[okq]], CLASS_INTERPOLATED)
        hit_any[qr[okq]] = 0
        fail = np.flatnonzero((q.status == ST_FAIL_CLASS) | (q.status == ST_FAIL_ANGLE)
                              | (q.status == ST_SPARSE))
        # a failed test marks the pixel; a sparse leaf's ray is simply traced
        ff = fail[q.status[fail] != ST_SPARSE]
        fc = np.where(q.status[ff] == ST_FAIL_CLASS, CLASS_FAIL_SILHOUETTE,
                      CLASS_FAIL_NONLINEAR).astype(np.uint8)
        cls[qr[ff]] = np.where(cls[qr[ff]] == CLASS_INTERPOLATED, cls[qr[ff]], fc)
        walk_pairs.append(qi[fail])
        # an interpolated length saves the walk past the entry: the exit crossing
        crossed = okq[q.thick[okq] > 0]
        r._count(objs[qi], objs[qi[fail]], objs[qi[crossed]],
                    np.ones(len(crossed), np.int64))
    wp = np.concatenate(walk_pairs)
    if len(wp):
        wr = rows[wp]
        wobj = objs[wp]

        def one(oo, dd, lo, hi, rr):
            return r._timed("obj", len(oo), r._accel.intersect_object, wobj[rr],
                               oo, dd, lo, hi)

        ln = walk(sa, one, o[wr], d[wr], t0[wr], t1[wr])
        np.add.at(length, wr, ln)
        pos = wr[ln > 0]
        cls[pos] = np.where(cls[pos] == CLASS_BACKGROUND, CLASS_TRACED, cls[pos])
        hit_any[pos] = 0
    counters["rays"] = counters.get("rays", 0) + n
    return length, cls, hit_any
