"""The lattice lines of linetree cells: their crossings of the cell's object and their
samples (split from :mod:`.interpolant_cache`, whose cells use them).

A line is named by its keys (``k1``: instance and face pair, ``k2``: its four lattice
coordinates, 15 bits each). :func:`line_geometry` finds where a line first crosses its
object facing it (geometry only, ``intersect_object``), what the cheap tests of a cell
need; :func:`shade_lines` traces the lines that pass them through the whole scene, with
ray trees, into the cache's :class:`~.samples.SampleStore`: a rough root's own light only
(its glossy rays are traced per pixel, :mod:`.glossy_term`), the world's term left out while
the world lights (:mod:`.world_term`), so are the sampled terms of lights with an extent
(:mod:`.sampled_term`), textures split off (:func:`~.samples.texture_split`)
and, when light edits are kept, each light's share (:mod:`.relight`).
"""

from __future__ import annotations

from functools import partial

import numpy as np
from numba import njit

from ..accel.accelerators import Hits
from ..frame import LIGHT_SAMPLES_DEFAULT
from ..tracing.whitted import trace
from .linetree import lattice_lines
from .relight import sample_shares
from .sampled_term import sampled_possible, without_sampled
from .samples import (
    LineCrossings,
    facing,
    glossy_flags,
    seen_flags,
    skip_tmin,
    texture_split,
    unique_keys,
)
from .world_term import without_world

#: Back-facing crossings skipped while looking for a line's front-facing crossing.
MAX_BACKFACE_SKIPS = 8


@njit(cache=True, nogil=True)
def _unpack(k2, lattice):
    for r in range(k2.shape[0]):
        for m in range(4):
            lattice[r, m] = (k2[r] >> (15 * (3 - m))) & 0x7FFF


def front_hits(sa, accel, inst, o, d) -> Hits:
    """Each line's first crossing of its object that faces the line (back faces are
    skipped: from inside a room, its far walls are what is seen)."""
    n = len(inst)
    t = np.full(n, np.inf)
    hi = np.full(n, -1, np.int32)
    pr = np.full(n, -1, np.int32)
    u = np.zeros(n)
    v = np.zeros(n)
    tmin = np.zeros(n)
    todo = np.arange(n)
    for _ in range(MAX_BACKFACE_SKIPS):
        if len(todo) == 0:
            break
        h = accel.intersect_object(inst[todo], o[todo], d[todo], tmin[todo],
                                   np.ones(len(todo)))
        front = np.empty(len(todo), bool)
        facing(sa, h.inst, h.prim, d[todo], front)
        fin = todo[front]
        t[fin], hi[fin], pr[fin] = h.t[front], h.inst[front], h.prim[front]
        u[fin], v[fin] = h.u[front], h.v[front]
        back = ~front
        todo = todo[back]
        nxt = np.empty(len(todo))
        skip_tmin(o[todo], d[todo], h.t[back], float(sa.scene_extent), nxt)
        tmin[todo] = nxt
    return Hits(t, hi, pr, u, v)


def line_geometry(cache, k1: np.ndarray, k2: np.ndarray, geo: LineCrossings):
    """Slab-crossing instance and class of lattice lines (m keys, repeats allowed):
    from stored samples, else from ``geo``, else computed now (``intersect_object``
    only, no shading) and added to ``geo``. Returns ``inst (m,), cls (m,)``."""
    m = len(k1)
    inst = np.empty(m, np.int32)
    cls = np.empty(m, np.int32)
    sid = cache.samples.lookup(k1, k2)
    have = sid >= 0
    inst[have] = cache.samples._inst[sid[have]]
    cls[have] = cache.samples._cls[sid[have]]
    rest = np.flatnonzero(~have)
    if len(rest):
        gid = geo.keys.lookup(k1[rest], k2[rest])
        new = gid < 0
        if np.any(new):
            c1, c2 = k1[rest[new]], k2[rest[new]]
            firsts, _ = unique_keys(c1, c2)
            n1, n2 = c1[firsts], c2[firsts]
            li = (n1 >> 3).astype(np.int32)
            lf = (n1 & 7).astype(np.int8)
            lattice = np.empty((len(n1), 4), np.int64)
            _unpack(n2, lattice)
            o = np.empty((len(n1), 3))
            d = np.empty((len(n1), 3))
            lattice_lines(cache.box, li, lf, lattice, o, d)
            hits = front_hits(cache.sa, cache.accel, li, o, d)
            hcls = np.where(hits.inst >= 0, cache.topo.tri_class[np.maximum(hits.prim, 0)],
                            -1).astype(np.int32)
            geo.add(n1, n2, o, d, hits, hcls)
            gid[new] = geo.keys.lookup(k1[rest[new]], k2[rest[new]])
        inst[rest] = geo.inst[gid]
        cls[rest] = geo.cls[gid]
    return inst, cls


def shade_lines(cache, k1: np.ndarray, k2: np.ndarray, geo: LineCrossings) -> np.ndarray:
    """Sample ids of lattice lines (m keys, repeats allowed); lines not stored yet are
    shaded through the whole scene from their ``geo`` crossings, with ray trees."""
    sid = cache.samples.lookup(k1, k2)
    miss = np.flatnonzero(sid < 0)
    if len(miss) == 0:
        return sid
    gid = geo.keys.lookup(k1[miss], k2[miss])
    firsts, uinv = unique_keys(gid.astype(np.int64), np.zeros(len(gid), np.int64))
    ug = gid[firsts]
    hits = geo.hits(ug)
    # a rough root's own light: its glossy rays are traced per pixel (glossy_term.py);
    # a line with a rough surface deeper in its tree fails (R_GLOSSY): one glossy sample
    # (the lattice lines are not camera rays: a light they cross before the root is the
    # pixel's to see, render.py traces those pixels)
    own = partial(trace, glossy_samples=1, roots="own", camera_lights=False)
    keep = cache._keeps_shares(len(ug))
    segs: list | None = [] if keep else None
    rad, tree = own(cache.sa, cache.accel, geo.o[ug], geo.d[ug], 0.0, 1.0, cache.max_depth,
                    record=True, primary=hits, segments=segs, terms=keep)
    li = hits.inst
    k = (geo.keys.k1[ug] & 7) >> 1
    inst_box = (geo.keys.k1[ug] >> 3)
    depth = np.where(li >= 0, hits.t, 0.0) * (cache.box[inst_box, 1, k]
                                              - cache.box[inst_box, 0, k])
    node_cls = np.where(tree.node_tri >= 0,
                        cache.topo.tri_class[np.maximum(tree.node_tri, 0)], -1)
    rad, dif, texel, flag = texture_split(cache.sa, cache.accel, geo.o[ug], geo.d[ug], hits,
                                          tree, rad, cache.max_depth, own)
    flag |= glossy_flags(cache.sa, tree, len(ug)) | seen_flags(cache.sa, tree, len(ug))
    if cache.qs.world_light:  # interpolated without the world's term (world_term.py)
        rad, flag = without_world(cache.sa, cache.accel, geo.o[ug], geo.d[ug], hits, rad,
                                  dif, flag, cache.max_depth)
    share, shared = sample_shares(cache.sa, segs, hits, flag) if keep else (None, None)
    if sampled_possible(cache.sa):  # lights' sampled terms: per pixel (sampled_term.py)
        rad, flag = without_sampled(cache.sa, cache.accel, geo.o[ug], geo.d[ug], hits, rad,
                                    dif, flag, cache.max_depth, LIGHT_SAMPLES_DEFAULT, share)
    new = cache.samples.add(geo.keys.k1[ug], geo.keys.k2[ug], rad, li, geo.cls[ug], depth,
                           tree, node_cls.astype(np.int32), dif, texel, flag, share,
                           shared)
    cache.frame_stats["samples_traced"] += len(ug)
    sid[miss] = new[uinv.reshape(-1)]
    return sid
