"""Object edits under soft light, at the level of rays (BASE, issue 20 item 5).

A point lit by a light with an extent or by the world shoots ``n`` shadow rays per such
light (:mod:`.soft_lights`); an object moved, added or deleted near it may cross a few of
them. The per-pixel records find, per sample, *which* of its rays may cross an edited box
(:meth:`~.pixel_records.PixelRecords.dirty_split`): a sample whose primary ray, reflection
and refraction rays and hard lights' shadow rays are untouched, and only some lights' (or
the world's) shadow rays at its primary hit or at its secondary hits may change, is not
traced again. Those nodes' terms of those lights are shaded again (:func:`reshade`, once
for the primary nodes and once for the secondary ones), the others kept, and the frame is
recombined from the per-light records (:meth:`~.light_records.LightRecords.recombine`) --
as a moved light is relit (:mod:`.light_reshade`), but at those nodes only:

* a light with an extent: its state at the rebuilt surface, its ``n`` samples from the
  node's seed (the same rays a fresh frame traces, through the edited scene), the shade
  kernel with it alone -- the ratio estimator's ``sum V w / sum w`` times the closed form, or
  the plain estimator, in the kernel's own order;
* the world: its ``n`` cosine-weighted rays and the shade kernel with no light, spawning
  as the tracer's level does (a rough point's world term lights its diffuse part only).

Every operand is the one a fresh frame's shade kernel reads, so each term is bit for bit a
fresh frame's, and the recombination sums them in the tracer's order. Shadow linking is
honoured (the tracer's own occlusion test).

**Per-sample visibility.** The records keep the hits' samples' visibility, a bit per
sample and light (:attr:`~.pixel_records.PixelRecords.p_vis` for the primary hits,
:attr:`~.pixel_records.PixelRecords.s_vis` for the secondary ones, written by the tracer:
:func:`~.sample_rays.soft_bits`; 2 bytes per light and node at 16 light samples). Then
only the samples whose exact rays (regenerated from the rebuilt surface and the node seed,
:func:`~.sample_rays.crossing_rows`) may cross an edited box, grown as the records grow it,
are traced again; the others keep their bits (a ray that crosses no edited box meets what
it met). A node whose bits all stay what they were keeps its term (the shade kernel would
read the same operands); only the nodes where a sample's visibility changed are shaded,
from the bits, with the tracer's arithmetic in its order (the ratio estimator's ``sum V w
/ sum w`` times the closed form, the plain estimator, the world's cosine-weighted sum). The
bits are dropped (re-shaded lights then trace all their samples, as above) when a light's
shadows may move: a light moved or added (or its extent, kind or links changed), the world
starting or stopping to light.

**Which samples, against what.** The records' queries keep, per row, the samples they found
may cross (:class:`~.sample_rays.SampleCandidates`: an area light's, a sun's, the world's;
a sphere light's rows have none), and only those are tested again exactly. A sample that
was unblocked is then tested against the objects the edits placed alone (it met nothing
else), one that was blocked against them first and the whole scene only where they do not
block it (:func:`_blocked`); most of those rays are answered by proofs on the placed
object, without its tree (:mod:`.object_rays`).
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from ..accel.accelerators import Hits
from ..geometry.edits import PART_NEW, PART_OLD
from .batches import threads_for
from .light_bits import column
from .light_linking import links_shadows
from .light_nodes import WORLD, term_of
from .light_records import _GEO
from .light_reshade import one_light_states, tick
from .object_rays import meets_object, prove_rays
from .record_codes import _secondary_depths as secondary_depths_kernel
from .sample_rays import ALL, crossing_rays, crossing_rows, unpack_bits
from .shader import Surfaces
from .soft_lights import SH_SOFT, soft_rays
from .whitted import _occluded_by, shade, surfaces


def _surfaces(sa, geo: dict) -> Surfaces:
    """The nodes' surfaces, rebuilt by the tracer's surface stage from their rays and hits
    (as :meth:`~.light_records._Part.surfaces`)."""
    k = len(geo["t"])
    hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
    no_lights = sa._replace(light_kind=np.empty(0, sa.light_kind.dtype))
    with threads_for(k):
        return surfaces(no_lights, geo["o"], geo["d"], np.full(k, np.inf), hits)


def _samples(sa, accel, geo: dict, sf: Surfaces, n: int, kept, counters):
    """The soft samples of the nodes (one row each: a light's, or the world's) with their
    visibility: the bits ``kept`` (k,) per node (:func:`~.sample_rays.soft_bits`' column,
    :func:`_traced_bits`), or where None every sample traced. ``sa``: the packing the
    samples are drawn in (the world off for a light's). Returns ``(SoftSamples, rows,
    any_vis)``, rows as :func:`~.soft_lights.soft_rays` numbers them."""
    split = {} if counters is None else counters.setdefault("split", {})
    t0 = time.perf_counter()
    soft, o, tmax, rows = soft_rays(sa, sf, geo["seed"], n, sf.sh_state)
    m = len(rows)
    if kept is not None:
        pt = np.where(rows >= 0, rows // max(len(sa.light_kind), 1), -1 - rows)
        unpack_bits(np.ascontiguousarray(kept[pt], np.uint64), n, soft.vis)
    else:
        go = np.flatnonzero(soft.w > 0.0)
        if len(go):
            soft.vis[go] = ~np.asarray(_occluded_by(sa, accel)(
                o[go], soft.d[go], tmax[go], np.repeat(rows, n)[go]), np.bool_)
            if counters is not None:
                counters["shadow"] = counters.get("shadow", 0) + len(go)
    any_vis = soft.vis.reshape(m, n).any(axis=1) if m else np.zeros(0, np.bool_)
    tick(split, "samples", t0)
    return soft, rows, any_vis


def _traced_bits(sa, accel, surf: Surfaces, seed, pt, lj, n: int, kept, cand, regions,
                 changed, counters) -> np.ndarray:
    """New visibility bits of (point, light) rows (points ``pt`` of ``surf``, lights
    ``lj``, ``L`` for the world) whose bits were ``kept``: the samples whose visibility
    the edited objects ``regions`` (lo, hi, centre, radius, tag: grown boxes and spheres,
    where objects were and are, :func:`~.sample_rays.crossing_rows`; of the samples
    ``cand``) may change traced again, through the edited scene (:func:`_blocked`;
    ``changed``: the edited objects), the others kept."""
    split = {} if counters is None else counters.setdefault("split", {})
    t0 = time.perf_counter()
    m = len(pt)
    mask = np.empty(m, np.uint64)
    count = np.empty(m, np.int64)
    pt = np.ascontiguousarray(pt, np.int64)
    lj = np.ascontiguousarray(lj, np.int64)
    seed = np.ascontiguousarray(seed, np.uint64)
    kept = np.ascontiguousarray(kept, np.uint64)
    tag = regions[4]
    if links_shadows(sa):
        # (hit by hit past the objects that are not a light's blockers: an object that
        # came may unblock a ray, light_linking.first_blocker; one that went may block it)
        tag = np.full(len(tag), PART_OLD | PART_NEW, np.int8)
    with threads_for(m):
        crossing_rows(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat, seed, pt, lj, n,
                      *regions[:4], tag, kept, np.ascontiguousarray(cand, np.uint64), True,
                      mask, count)
    tick(split, "crossing", t0)
    t0 = time.perf_counter()
    start = np.zeros(m + 1, np.int64)
    np.cumsum(count, out=start[1:])
    k = int(start[-1])
    o, d, tmax = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
    row, bit = np.empty(k, np.int64), np.empty(k, np.uint64)
    crossing_rays(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat, seed, pt, lj, n, mask, start,
                  o, d, tmax, row, bit)
    tick(split, "rays", t0)
    new = kept & ~mask
    if k:
        t0 = time.perf_counter()
        L = len(sa.light_kind)
        was = (kept[row] & bit) != 0

        def rows_of(i):  # (the rays' rows as the tracer numbers them: light linking)
            r = row[i]
            return np.where(lj[r] < L, pt[r] * L + lj[r], -1 - pt[r])

        blocked = _blocked(sa, accel, o, d, tmax, rows_of, was, changed, counters)
        _set_bits(new, row, bit, blocked)
        if counters is not None:
            counters["shadow"] = counters.get("shadow", 0) + k
        tick(split, "trace", t0)
    return new


@njit(cache=True, nogil=True)
def _set_bits(new, row, bit, blocked):
    """``new[row[r]] |= bit[r]`` for the rays ``r`` not ``blocked``."""
    for r in range(row.shape[0]):
        if not blocked[r]:
            new[row[r]] |= bit[r]


def _blocked(sa, accel, o, d, tmax, rows_of, was, changed, counters) -> np.ndarray:
    """(k,) bool: the shadow rays ``o, d, tmax`` (``rows_of(i)``: the rows of rays ``i``
    as :func:`~.whitted._occluded_by` numbers them) are blocked in the edited scene, bit for
    bit the whole scene's query. ``was``: each was unblocked in the records' frame;
    ``changed``: the live objects the edits placed since (moved, added, re-meshed, shown),
    or None to query the whole scene. A ray that met nothing then meets only what was
    placed (the accelerator's :attr:`~..accel.interface.Accelerator.any_hit_by_object`;
    most of them proven without its tree, :func:`~.object_rays.meets_object`); one that
    was blocked stays so where a placed object blocks it, else the whole scene is asked
    (its blocker may have been an object the edits took away)."""
    occluded = _occluded_by(sa, accel)
    if changed is None:
        return np.asarray(occluded(o, d, tmax, rows_of(slice(None))), np.bool_)
    blocked = np.zeros(len(o), np.bool_)
    for i in changed:
        todo = np.flatnonzero(~blocked)
        blocked[todo] = meets_object(sa, accel, i, o, d, tmax, todo, counters)
    rest = np.flatnonzero(~blocked & ~was)
    if len(rest):
        # (each of these rays met none of the placed objects: the query leaves one out,
        # its tree not walked again -- they pass close by it, its old place being theirs)
        skip = np.full(len(rest), changed[0] if changed else -1, np.int32)
        blocked[rest] = occluded(o[rest], d[rest], tmax[rest], rows_of(rest), skip)
    return blocked


def _light_term(sa, accel, j: int, n: int, geo: dict, surf: Surfaces, kept, counters):
    """Light ``j``'s (an extent's) terms at the nodes, its samples' visibility ``kept``
    (:func:`_samples`): ``(present (k,), value (k, 3), lit (k,))``."""
    k = len(geo["t"])
    L = len(sa.light_kind)
    state = np.empty(k, np.int8)
    with threads_for(k):
        one_light_states(sa, j, surf.P, surf.NG, surf.NS, surf.Q, surf.mat, geo["inst"],
                         state, np.empty(k, np.int32))
        sh_state = np.full((k, L), -2, np.int8)
        sh_state[:, j] = state
        sf = Surfaces(*surf[:7], sh_state.reshape(-1))
        sa1 = sa._replace(world_light=np.zeros(3))  # (the world's term is not this one)
        soft, rows, any_vis = _samples(sa1, accel, geo, sf, n, kept, counters)
        vis = np.zeros(k * L, np.bool_)
        vis[rows] = any_vis
        hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
        _, _, (tv, tp) = shade(sa1, hits, sf, vis, np.ones((k, 3)), False, soft, True)
    return tp[:, j], tv[:, j], vis.reshape(k, L)[:, j]


def _world_term(sa, accel, n: int, spawn: bool, geo: dict, surf: Surfaces, kept, counters):
    """The world's terms at the nodes, its samples' visibility ``kept`` (:func:`_samples`):
    ``(present (k,), value (k, 3))``. ``spawn``: the level spawns rays (a rough point's
    world samples then light its diffuse part only)."""
    k = len(geo["t"])
    L = len(sa.light_kind)
    with threads_for(k):
        sh_state = np.full(k * L, -2, np.int8)
        sf = Surfaces(*surf[:7], sh_state)
        soft, _, _ = _samples(sa, accel, geo, sf, n, kept, counters)
        hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
        _, _, (tv, tp) = shade(sa, hits, sf, np.zeros(k * L, np.bool_), np.ones((k, 3)),
                               spawn, soft, True, seeds=geo["seed"])
    return tp[:, L], tv[:, L]


def load_kernels(sa) -> None:
    """Load (or compile) the re-shade's own kernels for scene packings like ``sa``:
    called once per process, after the first BASE frame that keeps light terms under soft
    light (:data:`~.edit_kernels.LOADERS`) -- so that the first object edit does not pay
    it (about 0.04 s of CPU on the 2-core machine, studio)."""
    geo = {key: np.zeros((0,) + sh, dt) for key, (sh, dt) in _GEO.items()}
    surf = _surfaces(sa, geo)
    e3, e1 = np.zeros((0, 3)), np.zeros(0)
    i64, u64 = np.zeros(0, np.int64), np.zeros(0, np.uint64)
    with threads_for(0):
        one_light_states(sa, 0, surf.P, surf.NG, surf.NS, surf.Q, surf.mat, geo["inst"],
                         np.empty(0, np.int8), np.empty(0, np.int32))
        crossing_rows(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat, u64, i64, i64, 1, e3,
                      e3, e3, e1, np.zeros(0, np.int8), u64, u64.copy(), True, u64.copy(),
                      i64.copy())
        crossing_rays(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat, u64, i64, i64, 1, u64,
                      np.zeros(1, np.int64), e3, e3.copy(), e1, i64.copy(), u64.copy())
        unpack_bits(u64, 1, np.zeros(0, np.bool_))
        prove_rays(np.zeros((1, 4, 4)), 0, np.zeros(3), 0.0, 1.0, e3, e3.copy(), e1, i64,
                   np.zeros(0, np.int8))
        _set_bits(u64.copy(), i64, u64, np.zeros(0, np.bool_))
        _set_entries(np.zeros(1, np.int64), np.zeros(0, np.uint8), e3.copy(), i64, 0,
                     np.zeros(0, np.bool_), e3.copy(), np.zeros(0, np.bool_))
        secondary_depths_kernel(np.zeros(0, np.int32), 0, np.zeros(0, np.int32))


@njit(cache=True, nogil=True)
def _set_entries(start, slot, val, nodes, j, on, new, left):
    """Slot ``j``'s entry of each node ``nodes[r]`` (CSR ``start``, ``slot``, ``val``) set
    to ``new[r]`` in place where ``on[r]`` and the node has one; ``left[r]``: the entry
    comes or goes (for a splice)."""
    for r in range(nodes.shape[0]):
        e = -1
        for k in range(start[nodes[r]], start[nodes[r] + 1]):
            if slot[k] == j:
                e = k
                break
        left[r] = (e >= 0) != on[r]
        if e >= 0 and on[r]:
            val[e, 0] = new[r, 0]
            val[e, 1] = new[r, 1]
            val[e, 2] = new[r, 2]


def _set_terms(p, nodes, c: int, on, val) -> np.ndarray:
    """:func:`_set_entries` over the records' nodes ``p``: the positions in ``nodes``
    whose entry comes or goes."""
    left = np.empty(len(nodes), np.bool_)
    _set_entries(p.start, p.slot, p.val, np.ascontiguousarray(nodes, np.int64), int(c),
                 np.ascontiguousarray(on, np.bool_), np.ascontiguousarray(val, np.float64),
                 left)
    return np.flatnonzero(left)


def _splice_terms(lr, p, rows, left, changes, secondary: bool) -> None:
    """The nodes of ``left``'s terms (``(slot, sel, on, val)``: ``sel`` into ``rows``)
    taken, their entries replaced, and spliced back into the records."""
    at = np.unique(np.concatenate([sel for _, sel, _, _ in left]))
    sub = p.take(rows[at])
    sub.fold()
    for c, sel, on, val in changes:
        d_on, d_val = term_of(sub.start, sub.slot, sub.val, c)
        k = np.searchsorted(at, sel)
        inside = (k < len(at)) & (at[np.minimum(k, len(at) - 1)] == sel)
        d_on[k[inside]] = on[inside]
        d_val[k[inside]] = val[inside]
        sub.replace_slot(c, d_on, d_val)
    if secondary:
        lr.s = p.splice(rows[at], sub)
    else:
        lr.p = p.splice(rows[at], sub)


def reshade(lr, sa, accel, lights: np.ndarray, world: np.ndarray, light_samples: int,
            spawn, vis_bits: np.ndarray | None = None, regions=None,
            counters: dict | None = None, secondary: bool = False,
            changed=None, cand=None) -> dict:
    """Shade again, at the primary (``secondary``: the secondary) nodes of the per-light
    records ``lr`` (with geometry), the lights with an extent in the sets ``lights`` ((n, W)
    uint64, :mod:`.light_bits`) and the world's light where ``world`` (bool per node), through
    ``accel`` over the edited scene ``sa``; their entries replaced, every other term kept.
    Returns ``{j: (rows, lit)}``: each light's nodes and its visibility bit there (for the
    pixel records). ``spawn``: the nodes spawn rays (their depth is below the ray depth;
    a bool, or one per node). ``changed``: the live objects the edits placed since the
    records' frame, the only ones a kept visible sample may now meet (:func:`_blocked`),
    or None. ``cand``: the samples of each row the records' queries found may cross an
    edited part (:class:`~.sample_rays.SampleCandidates`: only those are tested again), or
    None (all). ``counters``: adds ``shadow`` and ``split`` seconds."""
    split = {} if counters is None else counters.setdefault("split", {})
    t0 = time.perf_counter()
    p = lr.s if secondary else lr.p
    spawn = np.broadcast_to(np.asarray(spawn, np.bool_), (len(p),))
    rows = np.flatnonzero((lights.any(axis=1) | world) & p.hit)  # (a miss has no shadow ray)
    out: dict = {}
    if len(rows) == 0:
        return out
    # the nodes' geometry (their terms are taken below, where one changes)
    grow = (np.cumsum(p.hit) - 1)[rows]
    geo = {key: x[grow] for key, x in p.geo.items()}
    surf = _surfaces(sa, geo)
    tick(split, "surfaces", t0)
    n = int(light_samples)
    L = len(sa.light_kind)
    changes = []
    jobs = [(c, np.flatnonzero(column(lights[rows], c))) for c in range(L)
            if c >> 6 < lights.shape[1]]
    jobs.append((L, np.flatnonzero(world[rows])))  # (column L: the world)
    for c, sel in jobs:
        if len(sel) == 0:
            continue
        t0 = time.perf_counter()
        kept = None
        if vis_bits is not None:
            # the samples that may cross an edited box traced again, the others' bits
            # kept: only the nodes where a sample's visibility changed are shaded again
            # (the others' inputs, and so their term, are what they were)
            old = vis_bits[rows[sel], c].astype(np.uint64)
            if c < L:  # (the nodes the light samples: it faces them)
                state = np.empty(len(rows), np.int8)
                with threads_for(len(rows)):
                    one_light_states(sa, c, surf.P, surf.NG, surf.NS, surf.Q, surf.mat,
                                     geo["inst"], state, np.empty(len(rows), np.int32))
                pt = np.flatnonzero(state[sel] == SH_SOFT)
            else:
                pt = np.arange(len(sel))
            kept = old.copy()
            cb = (np.full(len(pt), ALL, np.uint64) if cand is None
                  else cand.of_rows(rows[sel[pt]], c))
            kept[pt] = _traced_bits(sa, accel, surf, geo["seed"], sel[pt],
                                    np.full(len(pt), c), n, old[pt], cb, regions, changed,
                                    counters)
            vis_bits[rows[sel], c] = kept
            moved = np.flatnonzero(kept != old)
            tick(split, "shadow_rays", t0)
            t0 = time.perf_counter()
            sel, kept = sel[moved], kept[moved]
        # (the geometry of the nodes shaded again alone)
        g = {key: x[sel] for key, x in geo.items()}
        s = Surfaces(*(x[sel] for x in surf[:7]), surf.sh_state)
        if len(sel) and c < L:
            on, val, lit = _light_term(sa, accel, c, n, g, s, kept, counters)
            changes.append((c, sel, on, val))
            out[c] = (rows[sel], lit)
        elif len(sel):
            # (grouped by whether the nodes spawn rays: a rough point's world samples then
            # light its diffuse part only)
            for sp in (False, True):
                i = np.flatnonzero(spawn[rows[sel]] == sp)
                if len(i) == 0:
                    continue
                gi = {key: x[i] for key, x in g.items()}
                si = Surfaces(*(x[i] for x in s[:7]), s.sh_state)
                on, val = _world_term(sa, accel, n, sp, gi, si,
                                      None if kept is None else kept[i], counters)
                changes.append((WORLD, sel[i], on, val))
        tick(split, "shade", t0)
    t0 = time.perf_counter()
    if changes:
        # the changed terms written in place where the node keeps an entry for them
        # (a soft row's term is present whatever its samples see); the nodes where one
        # comes or goes (or a dragged light's term is apart) taken and spliced back
        left = [(c, sel[_set_terms(p, rows[sel], c, on, val)], on, val)
                for c, sel, on, val in changes] if p.dj < 0 else changes
        left = [x for x in left if len(x[1])]
        if left:
            _splice_terms(lr, p, rows, left, changes, secondary)
    tick(split, "terms", t0)
    return out
