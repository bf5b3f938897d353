"""The per-light records' node arrays (:mod:`.light_records`): the compressed (CSR) terms
of each node built from the shade kernel's dense terms, one light's entries replaced or kept
apart, and an incremental frame's new nodes spliced in place.

An incremental frame traces its dirty pixels again; their samples' new primary nodes replace
the old ones in the per-light records (:class:`~.light_records.LightRecords`, primary nodes
by sample id, CSR terms, the surface nodes' geometry). Rebuilding every node for that (a
concatenation and a gather of every entry and every geometry row: about 35-45 ms of one
thread on museum at 640x480, most of a small edit's frame) is replaced by one pass that
copies the kept nodes and the new ones into place (:func:`splice`), in the nodes' order.

A light being dragged keeps its term apart from the CSR entries (``dj``, ``d_on``,
``d_val``: :meth:`~.light_records._Part.detach`); the splice carries it: kept nodes keep
theirs, new nodes (traced with every light, so their CSR entries hold the light's fresh
term) get it from their own entry of slot ``dj`` (:func:`term_of`). Folding it back into
the entries, which rewrote every entry, is no longer needed when a frame traces pixels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: slot codes of the world light's and the emission's entries (entries' slots are a byte)
WORLD = 254
EMIT = 255
#: the light slots the records keep terms of (a scene with more keeps none:
#: :meth:`~.light_records.LightRecords.widen`)
RECORD_SLOTS = WORLD


@njit(cache=True, nogil=True)
def count_terms(t_on, t_val, hit, count):
    """Entries per node of a batch's dense terms (the shade kernel's ``tp``, ``tv``)."""
    L = t_on.shape[1] - 2
    for i in range(t_on.shape[0]):
        c = 0
        if hit[i]:
            for j in range(L + 1):
                if t_on[i, j]:
                    c += 1
            if t_val[i, L + 1, 0] != 0.0 or t_val[i, L + 1, 1] != 0.0 or \
                    t_val[i, L + 1, 2] != 0.0:
                c += 1
        count[i] = c


@njit(cache=True, nogil=True)
def fill_terms(t_on, t_val, hit, start, slot, val):
    L = t_on.shape[1] - 2
    for i in range(t_on.shape[0]):
        if not hit[i]:
            continue
        e = start[i]
        for j in range(L + 1):
            if t_on[i, j]:
                slot[e] = j if j < L else WORLD
                val[e, 0] = t_val[i, j, 0]
                val[e, 1] = t_val[i, j, 1]
                val[e, 2] = t_val[i, j, 2]
                e += 1
        if t_val[i, L + 1, 0] != 0.0 or t_val[i, L + 1, 1] != 0.0 or \
                t_val[i, L + 1, 2] != 0.0:
            slot[e] = EMIT
            val[e, 0] = t_val[i, L + 1, 0]
            val[e, 1] = t_val[i, L + 1, 1]
            val[e, 2] = t_val[i, L + 1, 2]

@njit(cache=True, nogil=True)
def replace_entries(start, slot, val, j, on, nval, new_start, new_slot, new_val):
    """Node entries with slot ``j``'s replaced: present where ``on`` (k,), value ``nval``
    (k, 3); entries stay in slot order. ``new_start`` (k + 1,) is filled first (counts)."""
    k = start.shape[0] - 1
    new_start[0] = 0
    for i in range(k):
        c = 0
        for e in range(start[i], start[i + 1]):
            if slot[e] != j:
                c += 1
        new_start[i + 1] = new_start[i] + c + (1 if on[i] else 0)
    if new_slot.shape[0] == 0:
        return
    for i in range(k):
        o = new_start[i]
        placed = not on[i]
        for e in range(start[i], start[i + 1]):
            c = slot[e]
            if c == j:
                continue
            if not placed and c > j:
                new_slot[o] = j
                new_val[o, 0] = nval[i, 0]
                new_val[o, 1] = nval[i, 1]
                new_val[o, 2] = nval[i, 2]
                o += 1
                placed = True
            new_slot[o] = c
            new_val[o, 0] = val[e, 0]
            new_val[o, 1] = val[e, 1]
            new_val[o, 2] = val[e, 2]
            o += 1
        if not placed:
            new_slot[o] = j
            new_val[o, 0] = nval[i, 0]
            new_val[o, 1] = nval[i, 1]
            new_val[o, 2] = nval[i, 2]


@njit(cache=True, nogil=True)
def detach_terms(rows, tp, tv, c, d_on, d_val):
    """A detached term (:meth:`_Part.detach`): present at nodes ``rows[r]`` where
    ``tp[r, c]``, with the value ``tv[r, c]``, absent elsewhere."""
    for i in range(d_on.shape[0]):
        d_on[i] = False
    for r in range(rows.shape[0]):
        if tp[r, c]:
            g = rows[r]
            d_on[g] = True
            d_val[g, 0] = tv[r, c, 0]
            d_val[g, 1] = tv[r, c, 1]
            d_val[g, 2] = tv[r, c, 2]

def node_ranges(start: np.ndarray, rows: np.ndarray):
    """Entry indices of nodes ``rows`` (concatenated) and their counts."""
    a = start[rows]
    n = start[rows + 1] - a
    total = int(n.sum())
    if total == 0:
        return np.zeros(0, np.int64), n
    off = np.cumsum(n) - n
    return np.repeat(a - off, n) + np.arange(total), n


@njit(cache=True, nogil=True)
def _splice_start(start, hit, rows, n_start, n_hit, out_start, out_hit):
    """CSR starts and hit flags of nodes ``0 .. n - 1`` with the sorted ``rows`` replaced
    by the new nodes (``n_start``, ``n_hit``, in the order of ``rows``). Returns the number
    of hit nodes."""
    n = hit.shape[0]
    m = rows.shape[0]
    r = 0
    h = 0
    out_start[0] = 0
    for i in range(n):
        if r < m and rows[r] == i:
            c = n_start[r + 1] - n_start[r]
            out_hit[i] = n_hit[r]
            r += 1
        else:
            c = start[i + 1] - start[i]
            out_hit[i] = hit[i]
        out_start[i + 1] = out_start[i] + c
        if out_hit[i]:
            h += 1
    return h


@njit(cache=True, nogil=True)
def _splice_entries(start, slot, val, hit, rows, n_start, n_slot, n_val, n_hit, out_start,
                    out_slot, out_val, geo_src, dj, d_on, d_val):
    """The entries of the spliced nodes (:func:`_splice_start`'s ``out_start``), and each
    output hit node's geometry row in ``geo_src``: ``a >= 0`` the old nodes' row ``a``,
    ``-1 - b`` the new nodes' row ``b``. ``dj >= 0``: a replaced node's detached term
    (``d_on``, ``d_val``, per node, in place) becomes its new entry of slot ``dj``."""
    n = hit.shape[0]
    m = rows.shape[0]
    r = 0
    a = 0
    b = 0
    h = 0
    for i in range(n):
        o = out_start[i]
        if r < m and rows[r] == i:
            if dj >= 0:
                d_on[i] = False
            for e in range(n_start[r], n_start[r + 1]):
                out_slot[o] = n_slot[e]
                out_val[o, 0] = n_val[e, 0]
                out_val[o, 1] = n_val[e, 1]
                out_val[o, 2] = n_val[e, 2]
                o += 1
                if dj >= 0 and n_slot[e] == dj:
                    d_on[i] = True
                    d_val[i, 0] = n_val[e, 0]
                    d_val[i, 1] = n_val[e, 1]
                    d_val[i, 2] = n_val[e, 2]
            if hit[i]:
                a += 1
            if n_hit[r]:
                geo_src[h] = -1 - b
                b += 1
                h += 1
            r += 1
        else:
            for e in range(start[i], start[i + 1]):
                out_slot[o] = slot[e]
                out_val[o, 0] = val[e, 0]
                out_val[o, 1] = val[e, 1]
                out_val[o, 2] = val[e, 2]
                o += 1
            if hit[i]:
                geo_src[h] = a
                a += 1
                h += 1


@njit(cache=True, nogil=True, inline="always")
def _geo_row(h, a, o, d, t, inst, prim, u, v, seed, oo, od, ot, oinst, oprim, ou, ov, oseed):
    """Geometry row ``a`` of ``o`` ... into row ``h`` of ``oo`` ..."""
    for k in range(3):
        oo[h, k] = o[a, k]
        od[h, k] = d[a, k]
    ot[h] = t[a]
    oinst[h] = inst[a]
    oprim[h] = prim[a]
    ou[h] = u[a]
    ov[h] = v[a]
    oseed[h] = seed[a]


@njit(cache=True, nogil=True)
def _splice_geo(src, o, d, t, inst, prim, u, v, seed, no, nd, nt, ninst, nprim, nu, nv,
                nseed, oo, od, ot, oinst, oprim, ou, ov, oseed):
    """The spliced nodes' geometry rows (``src``: :func:`_splice_entries`' ``geo_src``)
    from the old rows (``o`` ...) and the new ones (``no`` ...)."""
    for h in range(src.shape[0]):
        a = src[h]
        if a >= 0:
            _geo_row(h, a, o, d, t, inst, prim, u, v, seed, oo, od, ot, oinst, oprim, ou, ov,
                     oseed)
        else:
            _geo_row(h, -1 - a, no, nd, nt, ninst, nprim, nu, nv, nseed, oo, od, ot, oinst,
                     oprim, ou, ov, oseed)


#: the geometry arrays' order in :func:`_splice_geo` (``light_records._GEO``'s keys)
GEO_KEYS = ("o", "d", "t", "inst", "prim", "u", "v", "seed")


def splice(old, rows: np.ndarray, new) -> tuple:
    """Nodes of ``old`` (a ``_Part``) with the sorted rows ``rows`` replaced by the nodes
    of ``new`` (in that order): ``(hit, start, slot, val, geo)``; ``old``'s detached term
    (if any) is updated in place for the replaced rows (see the module doc), and so are its
    geometry arrays where every replaced node's hit flag is unchanged (then the hit nodes'
    rows are the same: only the replaced ones are written; ``old`` is spent)."""
    n = len(old.hit)
    rows = np.ascontiguousarray(rows, np.int64)
    out_start = np.empty(n + 1, np.int64)
    out_hit = np.empty(n, np.bool_)
    h = _splice_start(old.start, old.hit, rows, new.start, new.hit, out_start, out_hit)
    total = int(out_start[-1])
    out_slot = np.empty(total, np.uint8)
    out_val = np.empty((total, 3))
    geo_src = np.empty(h, np.int64)
    dj, d_on, d_val = old.detached()
    if dj >= 0:
        d_on, d_val = old.d_on, old.d_val
    _splice_entries(old.start, old.slot, old.val, old.hit, rows, new.start, new.slot, new.val,
                    new.hit, out_start, out_slot, out_val, geo_src, int(dj), d_on, d_val)
    geo = None
    if old.geo is not None and new.geo is not None:
        if np.array_equal(old.hit[rows], new.hit):
            # every hit node keeps its geometry row: the replaced ones written over in
            # place (``old`` gives its rows up, as it does its detached term), the others
            # not copied
            geo = old.geo
            at = np.flatnonzero(geo_src < 0)
            for key in GEO_KEYS:
                geo[key][at] = new.geo[key]
        else:
            geo = {key: np.empty((h,) + old.geo[key].shape[1:], old.geo[key].dtype)
                   for key in GEO_KEYS}
            _splice_geo(geo_src, *[old.geo[k] for k in GEO_KEYS],
                        *[new.geo[k] for k in GEO_KEYS], *[geo[k] for k in GEO_KEYS])
    return out_hit, out_start, out_slot, out_val, geo


def term_of(start: np.ndarray, slot: np.ndarray, val: np.ndarray, j: int) -> tuple:
    """``(d_on (k,), d_val (k, 3))``: slot ``j``'s entry of each of ``k`` nodes (CSR
    ``start``, ``slot``, ``val``), as a detached term."""
    k = len(start) - 1
    node = np.repeat(np.arange(k), np.diff(start))
    sel = slot == j
    d_on = np.zeros(k, np.bool_)
    d_val = np.zeros((k, 3))
    d_on[node[sel]] = True
    d_val[node[sel]] = val[sel]
    return d_on, d_val
