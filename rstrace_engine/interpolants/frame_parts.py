"""The parts of an INTERPOLANT frame's pass (:mod:`.render`) that are not kernels: the
pass's visible hits (reprojected where proven, else closest-hit rays), the rays traced
after all (the base tracer from the hits found), the glossy rays of interpolated samples on
rough surfaces, the rays whose camera ray may cross a light, and the fallback's counts.

A pass goes in *chunks* of its rays (:func:`.render.render_frame`): each chunk either goes
through the cells (line coordinates, the walk, builds) or is traced whole by the base
tracer from the hits the pass found -- which one, the frame's ledger decides
(:class:`.fallback.Budget`). Every function here takes the arrays of one chunk (views of
the pass's arrays: what it writes lands in the pass).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..accel.accelerators import Hits
from ..cancel import bound
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_INTERPOLATED,
    CLASS_NAMES,
    CLASS_REBUILT,
    CLASS_TRACED,
)
from ..geometry.cameras import camera_rays
from ..tracing.batches import TILE_RAYS, threads_for
from ..tracing.glossy_strata import frame_strata
from ..tracing.seen_lights import SEEN_CAMERA, seen
from ..tracing.shaft_skip import tile_keys
from ..tracing.soft_lights import sample_seeds
from ..tracing.whitted import trace
from . import fallback
from .bound import bound_notes
from .glossy_term import glossy_term, rough_objects, rough_roots
from .interpolant_cache import ResolveResult
from .reproject import reproject, slab_points


def take(h: Hits, idx: np.ndarray) -> Hits:
    """The hits of rays ``idx`` (a copy)."""
    return Hits(h.t[idx], h.inst[idx], h.prim[idx], h.u[idx], h.v[idx])


def part(h, sl: slice):
    """The arrays of a named tuple ``h`` (:class:`Hits`, :class:`ResolveResult`) for the
    rays ``sl`` (views)."""
    return type(h)(*(x[sl] for x in h))


class Visible(NamedTuple):
    """A pass's visible hits (:func:`visible`)."""

    hits: Hits
    res: ResolveResult  # the pass's resolve arrays, the reprojected rays filled in
    rep: np.ndarray | None  # (n,) bool reprojected rays, or None
    exact: tuple | None  # (inst (n,), t (n,)) of the reprojected rays, for pixel records
    reproject_s: float  # seconds reprojecting (the mode's)
    closest_s: float  # seconds of closest-hit rays (the base tracer's primary rays)


def visible(cache, cand, cells, pix, o, d, tmin, tmax, exact, cancel) -> Visible:
    """Visible hits of one ray per pixel ``pix``: reprojected from the candidates ``cand``
    where proven (:func:`.reproject.reproject`), closest-hit rays for the others. A
    reprojected ray's hit is left a miss (it is not walked); with ``exact`` (pixel records)
    ``Visible.exact`` has its object and the far end of its slab, which
    :meth:`.render._Run.chunk` puts into its hit after the chunk's walk."""
    t0 = fallback.CLOCK()
    rp = reproject(cache, cand, cells, pix, o, d, tmax)
    t1 = fallback.CLOCK()
    n = len(o)
    if rp is None:
        with bound(cache.accel, cancel):  # incomplete when cancelled: the frame polls
            hits = cache.accel.closest_hit(o, d, tmin, tmax)
        res = ResolveResult(np.zeros((n, 3)), np.zeros(n, np.bool_),
                            np.full(n, CLASS_BACKGROUND, np.uint8), np.full(n, -1, np.int32))
        return Visible(hits, res, None, None, t1 - t0, fallback.CLOCK() - t1)
    pre, hi, _ = rp
    with bound(cache.accel, cancel):
        hits = cache.accel.closest_hit(o, d, tmin, hi)
    t2 = fallback.CLOCK()
    rep = hi < 0.0
    ex = None
    if exact:
        # pixel records keep a view segment per sample: the reprojected ones reach the far
        # end of their slab, past their hit (a longer segment can only make more pixels
        # dirty after an edit). Before the walk, which may evict (and reuse) the
        # interpolants used.
        g = np.flatnonzero(rep)
        t = np.full(n, np.inf)
        slab_points(cache, pre[3], o, d, t, rep, 1.0)
        inst = np.full(n, -1, np.int32)
        inst[g] = cache.trees.arrays.tree[cache.pool.node[pre[3][g]]] // 6
        ex = (inst, t)
    return Visible(hits, ResolveResult(*pre), rep, ex, t1 - t0 + fallback.CLOCK() - t2,
                   t2 - t1)


def camera_seen(cache, o, d, tmin, tmax, hits, rep, res, todo) -> np.ndarray:
    """The rays whose camera ray may cross a light the camera sees (anywhere within its
    bounds, or a sun's cone on a miss: :mod:`~..tracing.seen_lights`) are traced, not
    interpolated: their hits found again where they were reprojected (left a miss), and
    added to ``todo``, which is returned."""
    sa = cache.sa
    miss = hits.inst < 0
    if rep is not None:
        miss &= ~rep
    one = np.ones((len(o), 3))
    sel = np.flatnonzero(seen(sa, o, d, tmin, tmax, miss, np.full(len(o), SEEN_CAMERA,
                                                                   np.int8), one).any(axis=1))
    if len(sel) == 0:
        return todo
    if rep is not None and rep[sel].any():
        r = sel[rep[sel]]
        found = cache.accel.closest_hit(o[r], d[r], tmin[r], tmax[r])
        for a, b in zip(hits, found, strict=True):
            a[r] = b
    res.interpolated[sel] = False
    res.pixel_class[sel] = np.where(hits.inst[sel] >= 0, CLASS_TRACED, CLASS_BACKGROUND)
    res.interpolant[sel] = -1
    return np.union1d(todo, sel)


def count(cache, ledger, hits, res, rep, skipped) -> None:
    """A chunk's rays per visible object for the fallback's ledger: walked, interpolated
    of those, reprojected (interpolated without a walk)."""
    walked = hits.inst >= 0
    if skipped is not None:
        walked &= ~skipped
    if rep is not None:
        walked &= ~rep
    wi = hits.inst[walked]
    ii = hits.inst[walked & res.interpolated]
    ri = np.zeros(0, np.int64)
    if rep is not None and rep.any():
        ids = res.interpolant[rep]
        ids = ids[(ids >= 0) & (ids < len(cache.pool.node))]
        node = cache.pool.node[ids]
        node = node[(node >= 0) & (node < len(cache.trees.arrays.tree))]
        ri = cache.trees.arrays.tree[node] // 6
    ledger.count(wi, ii, ri)


def tiles(n: int):
    """Slices of ``n`` rays in tiles of about the base tracer's size (its per-level arrays
    stay cache-sized), split evenly: a small last tile would cost the tracer's per-level
    overhead alone."""
    n_tiles = max(1, round(n / TILE_RAYS)) if n else 0
    for q in range(n_tiles):
        yield slice(q * n // n_tiles, (q + 1) * n // n_tiles)


def trace_rest(cache, todo, o, d, tmin, tmax, hits, rad, max_depth, counters, records, gids,
               cancel, settings, keys=None, strata=None) -> bool:
    """Trace rays ``todo`` (not interpolated) with the base tracer from the hits already
    found, into ``rad``; their ray trees go to ``records``; soft lights are sampled as the
    base tracer samples these pixel samples (``gids``, ``settings``' seed and light
    samples), and their shadow rays skipped where proven per tile as the base tracer does
    (``keys``: the rays' pixels' tiles, :func:`~..tracing.shaft_skip.tile_keys`). Returns
    whether ``cancel`` stopped it (the frame is then incomplete). ``todo`` a slice: every
    ray of that range (misses too: the tracer gives them the world, as :func:`~.render.
    _to_trace` does), traced from views of the arrays -- exactly the base tracer's tiles.
    ``strata``: the rays' :class:`~..tracing.glossy_strata.Strata` (the base frame's)."""
    sa, accel = cache.sa, cache.accel
    if isinstance(todo, slice):
        a, b, _ = todo.indices(len(o))
        parts = [slice(a + q.start, a + q.stop) for q in tiles(b - a)]
    else:
        parts = [todo[q] for q in tiles(len(todo))]
    for rows in parts:
        segs: list | None = [] if records is not None else None
        with bound(accel, cancel):
            rad[rows], _ = trace(sa, accel, o[rows], d[rows], tmin[rows], tmax[rows],
                                 max_depth, primary=(part(hits, rows) if isinstance(rows, slice)
                                                     else take(hits, rows)),
                                 counters=counters,
                                 segments=segs, cancel=cancel,
                                 seeds=sample_seeds(gids[rows], int(settings.seed)),
                                 light_samples=int(settings.light_samples),
                                 glossy_samples=int(settings.glossy_samples),
                                 terms=records is not None and records.light is not None,
                                 skip_keys=None if keys is None else keys[rows],
                                 strata=None if strata is None else strata.take(rows))
        if cancel is not None and cancel():
            return True
        if records is not None:
            records.add(gids[rows], segs)
    return False


def trace_tail(cache, cp, pix, jitter, settings, counters, records, cancel, lrec,
               known: Hits | None = None):
    """Every sample of the pixels ``pix`` (k,) int64 (``jitter`` (spp, k, 2) theirs) traced
    by the base tracer in its own tiles: a tile's rows of pixels with all their samples at
    once (:func:`~..tracing.whitted.trace_pixels`' rays, seeds and shadow-ray skips, so its
    samples are the base frame's bit for bit), what a pass cut short by the ledger leaves
    (:func:`.render.render_frame`). Per pass, a tile proved the shadow-ray skips of one sample
    of its pixels (:mod:`~..tracing.shaft_skip`: four times the proofs at 4 samples) and
    traced tiles of another size. Yields per tile ``(rows of pix, radiance (spp m, 3),
    instance (spp m,), closest-hit seconds, tracing seconds)``, sample-major (sample ``s``
    of the tile's pixel ``p`` at row ``s m + p``); None when ``cancel`` stopped it. Its
    trees go to ``records``; ``lrec`` (partial per-light records, or None) learns that no
    sample of it kept a world term. ``known``: the hits of sample 0 of the first
    ``len(known.t)`` pixels, found already (the rays of the tile where the ledger cut the
    pass, :func:`visible`'s closest hits): not traced again (a ray's closest hit is its own,
    whatever the batch)."""
    sa, accel = cache.sa, cache.accel
    spp = jitter.shape[0]
    w = cp.width
    per = max(1, TILE_RAYS // max(1, w * spp)) * w  # the base tracer's tile, in pixels
    for a in range(0, len(pix), per):
        tp = pix[a:a + per]
        m = len(tp)
        px = np.tile(tp, spp)
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * cp.height) + tp[None, :]).ravel()
        segs: list | None = [] if records is not None else None
        t0 = fallback.CLOCK()
        with threads_for(len(px)), bound(accel, cancel):
            o, d, tmin, tmax = camera_rays(cp, px, jitter[:, a:a + m].reshape(-1, 2))
            kn = 0 if known is None else max(0, min(m, len(known.t) - a))
            if kn:  # (rows 0..kn: sample 0 of the tile's first pixels)
                rest = accel.closest_hit(o[kn:], d[kn:], tmin[kn:], tmax[kn:])
                hits = Hits(*(np.concatenate([x[a:a + kn], y])
                              for x, y in zip(known, rest, strict=True)))
            else:
                hits = accel.closest_hit(o, d, tmin, tmax)
            t1 = fallback.CLOCK()
            rad, _ = trace(sa, accel, o, d, tmin, tmax, int(settings.max_depth), primary=hits,
                           counters=counters, segments=segs, cancel=cancel,
                           seeds=sample_seeds(gids, int(settings.seed)),
                           light_samples=int(settings.light_samples),
                           glossy_samples=int(settings.glossy_samples),
                           terms=records is not None and records.light is not None,
                           skip_keys=tile_keys(px, w),
                           strata=frame_strata(sa, int(settings.max_depth), gids,
                                               w * cp.height, int(settings.seed), spp))
        t2 = fallback.CLOCK()
        if cancel is not None and cancel():
            yield None
            return
        if records is not None:
            records.add(gids, segs)
        if lrec is not None:
            lrec.set_world(gids, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        yield slice(a, a + m), rad, np.asarray(hits.inst, np.int32), t1 - t0, t2 - t1


def glossy_rest(cache, interp, o, d, tmin, tmax, hits, rep, interpolant, rad, counters,
                records, gids, cancel, settings, strata=None) -> bool:
    """Add to ``rad`` the glossy rays' part of the interpolated samples (``interp`` (k,)
    bool) whose hit is on a rough surface (:mod:`.glossy_term`); their segments go to
    ``records``. Returns whether ``cancel`` stopped it. A reprojected sample (``rep`` (k,)
    bool or None) has no hit: where its interpolant (``interpolant`` (k,) pool ids) lies on
    an object with a rough material, its visibility ray is traced here. ``strata`` as
    :func:`trace_rest`."""
    sa, accel = cache.sa, cache.accel
    rows = np.flatnonzero(interp)
    h = take(hits, rows)
    if rep is not None and rep[rows].any():
        r = np.flatnonzero(rep[rows])
        obj = cache.trees.arrays.tree[cache.pool.node[interpolant[rows[r]]]] // 6
        r = r[rough_objects(sa)[obj]]
        h.inst[rep[rows]] = -1
        if len(r):
            c = rows[r]
            with bound(accel, cancel):
                found = accel.closest_hit(o[c], d[c], tmin[c], tmax[c])
            for dst, src in zip(h, found, strict=True):
                dst[r] = src
    rough = rough_roots(sa, h, int(settings.max_depth))
    rows, h = rows[rough], take(h, np.flatnonzero(rough))
    counters["rough_interpolated"] = counters.get("rough_interpolated", 0) + len(rows)
    for sel in tiles(len(rows)):
        rr = rows[sel]
        segs: list | None = [] if records is not None else None
        with bound(accel, cancel):
            rad[rr] += glossy_term(sa, accel, o[rr], d[rr], tmin[rr], tmax[rr],
                                   take(h, sel), gids[rr], int(settings.seed),
                                   int(settings.max_depth), int(settings.light_samples),
                                   int(settings.glossy_samples), counters, segs, cancel,
                                   None if strata is None else strata.take(rr))
        if cancel is not None and cancel():
            return True
        if records is not None:
            records.add(gids[rr], segs)
    return False


def frame_stats(cache, fs, counts, pclass, used, elapsed, t_res, t_trace, reprojected,
                 k, n_todo, counters, w, h, spp, max_depth, cancelled, bad_total) -> dict:
    """The statistics of an INTERPOLANT frame."""
    accel = cache.accel
    return dict(
        mode="INTERPOLANT", time_s=elapsed, visibility_s=fs.get("visibility_s", 0.0),
        resolve_s=t_res - fs.get("visibility_s", 0.0),
        build_s=fs.get("build_s", 0.0), rst_insert_s=fs.get("deps_s", 0.0),
        trace_s=t_trace,
        # samples whose visible hit came from reprojection instead of a closest-hit ray
        reprojected_fraction=reprojected,
        # of the whole frame (kept pixels included; a kept pixel "rebuilt after an edit" is
        # interpolated too: the stat once said 0% with 959 magenta pixels)
        interpolated_fraction=float(np.count_nonzero((pclass == CLASS_INTERPOLATED)
                                                     | (pclass == CLASS_REBUILT)))
        / max(len(pclass), 1),
        traced_pixels=k, traced_rays=n_todo, shadow_rays=counters.get("shadow", 0),
        shadow_rays_skipped=counters.get("shadow_skipped", 0),
        secondary_rays=counters.get("secondary", 0),
        # interpolated samples on rough surfaces, their glossy rays traced (glossy_term.py)
        rough_interpolated=counters.get("rough_interpolated", 0),
        cells_built=fs.get("cells_built", 0), cells_valid=fs.get("cells_valid", 0),
        samples_traced=fs.get("samples_traced", 0), levels=fs.get("levels", 0),
        cell_outcomes=dict(fs.get("reasons", {})),
        interpolants=cache.pool.n_live, linetree_nodes=cache.trees.live_nodes,
        memory_mb=cache.memory_bytes / 1e6, rst_memory_mb=cache.rst_memory_bytes() / 1e6,
        interpolant_memory_mb=cache.interpolant_bytes / 1e6,
        epsilon=cache.epsilon, depth_cap=cache.depth_cap,
        memory_cap_mb=cache.memory_cap_bytes / 1e6,
        class_counts={CLASS_NAMES[q]: int(counts[q]) for q in range(len(CLASS_NAMES))},
        width=w, height=h, samples=spp, max_depth=max_depth,
        cancelled=bool(cancelled), nonfinite_samples=bad_total,
        accelerator=getattr(accel, "name", "?"), cache_setup_s=cache.setup_s,
        bound_notes=[] if cancelled else bound_notes(cache, used),
    )
