"""Frames rendered with radiance interpolants (``mode = "INTERPOLANT"``).

A frame goes one sample of every pixel at a time (the same rays and jitter as
:func:`~.whitted.render`), each pass in tiles of the base tracer's size (cache-sized arrays,
reused) and each tile in chunks that either go through the cells or are traced whole, as the
frame's ledger decides (:mod:`.fallback`: what the mode adds may exceed what it saved by a
small share of the frame's base cost). Per tile: rays whose
interpolant is found by reprojection (:mod:`.reproject`: from the previous frame's pixels
after a camera move, from the pixel's first sample for the later samples; proven exact) are
interpolated at once; the others get their visible hits through the whole scene
(``closest_hit``) -> for every ray that hits an object, its line in that object's linetree
-> :meth:`~.interpolants.InterpolantCache.resolve` interpolates what valid interpolants
cover and builds the cells the chunk needs -> every other ray (misses, failed cells, pixels
too few to be worth a cell) is traced by the base tracer from the hits already found. When
the ledger cuts the first pass short and nothing reprojects, the rest of the frame is traced
in the base tracer's own tiles, every sample of a pixel together
(:func:`~.frame_parts.trace_tail`: its shadow-ray proofs over the base frame's groups, not
once per pass). Each pixel gets a class (:data:`~.frame.CLASS_NAMES`). At epsilon = 0
nothing can be interpolated, and the frame is the base tracer's.

Interpolants are view-independent, so a :class:`InterpolantRenderer` keeps its cache across
frames and camera moves; it starts a new cache when epsilon, the depth cap or the ray depth
change, or when it is handed a scene packing it was not told of
(:meth:`InterpolantRenderer.take_edits` keeps every interpolant an edit leaves valid).

``frame.pixel_interpolant`` (h, w) int32 holds the interpolant each pixel used (-1: traced or
background; with several samples per pixel, -2 where its samples used different ones).
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from .. import heap
from .. import tolerances as tol
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_NAMES,
    CLASS_TRACED,
    Frame,
    RenderSettings,
)
from ..geometry.cameras import camera_params, camera_rays
from ..tracing.batches import TILE_RAYS, frame_batches, threads_for
from ..tracing.glossy_strata import draws_glossy, frame_strata
from ..tracing.seen_lights import SEEN_CAMERA, any_seen, first_seen_below
from ..tracing.shaft_skip import tile_keys
from ..tracing.soft_lights import world_lights
from ..tracing.whitted import render
from . import build_beside
from . import fallback as fb_mod
from .added_light import keeps_cache
from .frame_parts import (
    Visible,
    camera_seen,
    count,
    frame_stats,
    glossy_rest,
    part,
    tiles,
    trace_rest,
    trace_tail,
    visible,
)
from .interpolant_cache import InterpolantCache
from .invalidation import Invalidation
from .pixel_sums import _accumulate, _assemble, _finish, _to_trace
from .reproject import FrameCells, Remember, candidates, slab_points
from .sampled_term import add_sampled_terms, sampled_possible
from .world_term import keep_world, kept_world_term

log = logging.getLogger(__name__)


def _newly_seen(old_sa, sa) -> bool:
    """Whether mirror or refraction rays may see a light's surface in ``sa`` where they
    could see none in ``old_sa``: the cells' samples were flagged only while some light was
    seen (:func:`~.samples.seen_flags` flags every sample whose tree goes below its root
    while any light is, whichever light it is), so a light seen as well as others (moved,
    added) finds every such sample flagged -- and its cell failed -- already."""
    return first_seen_below(old_sa, sa)


def _add_stats(a: dict, b: dict) -> dict:
    """Frame statistics of two resolves together."""
    out = dict(a)
    for key, val in b.items():
        if key == "reasons":
            r = dict(a.get("reasons", {}))
            for x, c in val.items():
                r[x] = r.get(x, 0) + c
            out["reasons"] = r
        elif isinstance(val, (int, float)):
            out[key] = a.get(key, 0) + val
    return out


def _base_frame(cache, scene, settings, progress, cancel, records, pixels, base) -> Frame:
    """Nothing can be interpolated within a zero error bound: the base tracer's frame, with
    the INTERPOLANT mode's statistics."""
    frame = render(scene, settings, accel=cache.accel, progress=progress, cancel=cancel,
                   records=records, pixels=pixels, base=base)
    frame.pixel_interpolant = (np.full(frame.pixel_class.shape, -1, np.int32)
                               if base is None else base.pixel_interpolant.copy())
    frame.stats.update(mode="INTERPOLANT", interpolated_fraction=0.0, cells_built=0,
                       cells_valid=0, samples_traced=0, interpolants=cache.pool.n_live,
                       memory_mb=cache.memory_bytes / 1e6, epsilon=0.0,
                       depth_cap=cache.depth_cap)
    return frame


def _traced_frame(cache, scene, settings, progress, cancel, records, pixels, base,
                  fallback: dict, notes: list) -> Frame:
    """The base tracer's frame where the measured fallback traces the whole frame
    (:mod:`.fallback`, :mod:`.build_beside`): no reprojection from it, and what was decided
    (``fallback``, ``notes``) in its statistics."""
    cache.view = None
    frame = _base_frame(cache, scene, settings, progress, cancel, records, pixels, base)
    frame.stats.update(epsilon=cache.epsilon, reprojected_fraction=0.0, cell_outcomes={},
                       fallback=fallback, fallback_notes=notes)
    return frame


def render_frame(cache: InterpolantCache, scene, settings: RenderSettings, progress=None,
                 cancel=None, records=None, pixels: np.ndarray | None = None,
                 base: Frame | None = None, fallback: bool = False) -> Frame:
    """Render ``scene``'s camera with the interpolants of ``cache`` (building what it needs).

    ``settings``: ``samples``, ``seed`` and ``max_depth`` are used here; epsilon and the caps
    are the cache's. progress(fraction, message); cancel() -> bool is polled between stages
    and between the tracing tiles (a cancelled frame is incomplete, ``stats["cancelled"]``);
    a :class:`~rstrace_engine.cancel.CancelFlag` also stops the visibility and tracing
    queries within a few dozen rays (never the building of interpolants).

    Incremental frames (the session's, with a fixed camera): ``pixels`` (h * w,) bool renders
    only those pixels (all their samples, with the jitter of a full frame) over a copy of
    ``base``, the previous frame. ``records`` (a :class:`~.tracing.pixel_records.PixelRecords`)
    receives every rendered sample's view segment and the compact ray tree of every traced
    one; what an interpolated sample depends on beyond its view segment is its interpolant's,
    which the ray segment trees track.

    ``fallback``: trace where cells do not pay, learned from measured costs
    (:mod:`.fallback`: the frame's ledger, objects traced; ``stats["fallback"]``); the
    renderer's :attr:`InterpolantRenderer.auto_fallback`. Off, cells are built wherever
    the rays need them (what the cache's own tests count).
    """
    settings = settings.validated()
    heap.keep()  # a batch's arrays on pages already touched (heap.py: 0.80x -> 1.00x)
    if cache.epsilon <= 0.0:
        return _base_frame(cache, scene, settings, progress, cancel, records, pixels, base)
    fb = cache.fallback if fallback else None
    traced = (cache, scene, settings, progress, cancel, records, pixels, base)
    if fb is not None and fb.whole_frame_traced():
        # the frame's cells did not pay (fallback.py): the base tracer's frame, as fast
        frame = _traced_frame(*traced, fb.stats(None), fb.notes())
        if pixels is None and not frame.stats.get("cancelled"):
            fb.frames_all += 1
        return frame
    if fb is not None and cache.pool.n_live == 0 and build_beside.compiling():
        # no cell yet and the build's kernels not compiled: they compile in a background
        # process (build_beside.py), this frame is the base tracer's, exact
        return _traced_frame(*traced, dict(fb.stats(None), build_compiling=True),
                             [build_beside.note()] + fb.notes())
    t0 = fb_mod.CLOCK()
    sa = cache.sa
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    parts = list(frame_batches(w, h, spp, int(settings.seed), rows_per_tile, pixels))
    if parts:
        pix = np.concatenate([q for q, _, _ in parts])
        jitter = np.concatenate([j for _, j, _ in parts], axis=1)
    else:
        pix, jitter = np.zeros(0, np.int64), np.zeros((spp, 0, 2))
    k = len(pix)
    n = k * spp
    if base is not None and pixels is not None:
        image = base.radiance.reshape(h * w, 3).copy()
        pclass = base.pixel_class.reshape(h * w).copy()
        pinterp = base.pixel_interpolant.reshape(h * w).copy()
    else:
        image = np.zeros((h * w, 3), np.float32)
        pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
        pinterp = np.full(h * w, -1, np.int32)
    # per pixel over its samples: radiance sum, good samples, class, interpolants used
    acc_rad = np.zeros((k, 3))
    acc_good = np.zeros(k, np.int64)
    acc_cls = np.zeros(k, np.uint8)
    acc_lo = np.full(k, -1, np.int32)
    acc_hi = np.full(k, -1, np.int32)
    counts = np.zeros(len(CLASS_NAMES), np.int64)
    bad_total = 0
    n_rep = 0
    used = np.zeros(0, np.bool_)  # interpolants used (by pool id)
    run = _Run(cache, settings, records, cancel, w, h)
    # a full frame after a full frame of this cache: samples whose interpolant is found by
    # reprojection (reproject.py) need neither a visibility ray nor a walk; an incremental
    # frame keeps its camera. One sample of every pixel at a time (arrays of a 1-sample
    # frame, reused); the samples after the first reproject from it too (same eye: a sample
    # whose line lies in a proven cell costs a look-up, not a ray and a walk).
    # while the world lights, an interpolated pixel traces the world's term at its own hit
    # (world_term.py): it needs the hit, which a reprojected ray does not find
    view = cache.view if pixels is None and not run.world else None
    cache.view = None
    here = None
    cells = FrameCells(cp)
    # where cells do not pay (fallback.py): objects traced, the frame's ledger
    n_inst = len(sa.inst_mesh)
    cache.cells_by_inst = np.zeros(n_inst, np.int64)
    if fb is not None:
        fb.resize(n_inst)
        run.ledger = fb_mod.FrameLedger(n_inst)
        run.traced_now = fb.frame_traced()
        run.budget = fb.budget(n, n_inst, spp, cache.pool.n_live == 0)
        run.budget.owed, run.budget.owed_build = fb_mod.owed_at_once(
            cache.structures_missing(), len(sa.tris), cache.pool.n_live > 0)
        if run.budget.owed > run.budget.limit:  # (priced: its walk could never be paid)
            return _traced_frame(*traced, fb.stats(run.budget), fb.notes())
    budget = run.budget
    n_closest, t_closest = 0, 0.0
    pass_tiles = list(tiles(k))  # a pass goes in tiles of the base tracer's size
    tail = k  # pixels from here on: cut from the first pass, the base tracer's (trace_tail)
    known = None  # the cut tile's hits after the cut (sample 0 of the tail's first pixels)
    n_interp0 = 0  # rays the first pass interpolated (their later samples may reproject)
    with threads_for(n):  # the dirty pixels of an edit: one thread (see batches)
        for s in range(spp):
            if cancel is not None and cancel():
                run.cancelled = True
                break
            tq = fb_mod.CLOCK()
            cand = None if run.world else candidates(view if s == 0 else here, cp, s == 0)
            rem = Remember(w, h) if s == 0 and pixels is None else None
            if budget is not None:
                budget.spent += fb_mod.CLOCK() - tq
                budget.start_pass(s)
            walked = False
            for tsl in pass_tiles:
                if run.cancelled:
                    break
                tp = fb_mod.CLOCK()
                tpix = pix[tsl]
                kt = len(tpix)
                o, d, tmin, tmax = camera_rays(cp, tpix, jitter[s][tsl])
                gids = s * (w * h) + tpix
                vis = visible(cache, cand, cells, tpix, o, d, tmin, tmax, records is not None,
                              cancel)
                t_closest += vis.closest_s
                rep = vis.rep
                n_closest += kt if rep is None else kt - int(np.count_nonzero(rep))
                if rep is not None:
                    n_rep += int(np.count_nonzero(rep))
                # (the tiles' keys: the base tracer's shadow-ray skips)
                ps = _Pass(o, d, tmin, tmax, gids, vis, tile_keys(tpix, w))
                if budget is not None:
                    budget.spent += vis.reproject_s
                    if budget.ray_s is None:  # what the first chunk's price needs
                        fb.vis_s = vis.closest_s / max(kt, 1)
                        fb.hit_share = float(np.count_nonzero(vis.hits.inst >= 0)) / max(kt, 1)
                a = 0
                cut_here = False
                while a < kt and not run.cancelled:
                    if budget is None:  # cells everywhere
                        b, on = kt, True
                    elif budget.ray_s is None:  # a first frame's first chunk prices a ray
                        b, on = min(kt, a + max(fb_mod.CHUNK_MIN,
                                                int(k * fb_mod.PRICE_SHARE))), False
                    else:
                        m = budget.chunk(kt - a)
                        # (the later passes reproject only from this pass: never while
                        # the world lights or in an incremental frame, rem None)
                        later = (0 if run.world or rem is None else (n_interp0 + int(
                            np.count_nonzero(vis.res.interpolated[:a]))) * (spp - 1))
                        if not m and s == 0 and cand is None and budget.spent_for_good(later):
                            # the ledger cut the first pass for good and nothing reprojects
                            # from another frame: the rest of the frame is traced as the
                            # base tracer traces it
                            tail = tsl.start + a
                            cut_here = True
                            known = part(vis.hits, slice(a, kt))  # (found: not again)
                            break
                        b, on = (a + m, True) if m else (kt, False)
                    run.chunk(ps, slice(a, b), on)
                    walked |= on
                    if on and budget is not None and budget.owed + budget.owed_build:
                        budget.owed, budget.owed_build = fb_mod.owed_at_once(  # (paid: spent)
                            cache.structures_missing(), len(sa.tris), cache.pool.n_live > 0)
                    if budget is not None and budget.ray_s is None:
                        budget.pricing += b - a
                        if run.traced_rays >= fb_mod.MIN_PRICE_RAYS:
                            budget.price(run.trace_s / run.traced_rays, fb.vis_s, fb.hit_share)
                    a = b
                tq = fb_mod.CLOCK()
                hd = slice(0, a)  # the rays done (the whole tile but where the tail begins)
                res = part(vis.res, hd)
                if res.interpolated.any():
                    if rem is not None:  # what the next pass and frame reproject from
                        t = vis.hits.t[hd].copy()
                        slab_points(cache, res.interpolant, o[hd], d[hd], t,
                                    np.zeros(a, np.bool_) if rep is None else rep[hd])
                        rem.add(tpix[hd], res.interpolant, o[hd], d[hd], t)
                    used = _mark_used(used, res.interpolant)
                if budget is not None:
                    budget.spent += fb_mod.CLOCK() - tq
                good = np.empty(a, np.bool_)
                bad_total += int(_finish(res.radiance, float(tol.RADIANCE_MAX),
                                         res.pixel_class, good, counts))
                td = slice(tsl.start, tsl.start + a)
                _accumulate(res.radiance, good, res.pixel_class, res.interpolant,
                            acc_rad[td], acc_good[td], acc_cls[td], acc_lo[td], acc_hi[td])
                run.t_res += fb_mod.CLOCK() - tp
                n_interp0 += int(np.count_nonzero(res.interpolated)) if s == 0 else 0
                if cut_here:
                    break
            pass_tiles = list(tiles(tail))  # (the passes after a cut: the pixels before it)
            tq = fb_mod.CLOCK()
            if walked:
                cache.finish_resolve()
            if rem is not None:
                here = rem.view()
            if budget is not None:
                budget.spent += fb_mod.CLOCK() - tq
            if progress is not None:  # (the passes' share of the pixels; the tail's after)
                progress(0.05 + 0.9 * tail / max(k, 1) * (s + 1) / spp, "interpolants")
        if tail < k and not run.cancelled:
            tc = run.tail(cp, pix[tail:], jitter[:, tail:], spp, counts,
                          (x[tail:] for x in (acc_rad, acc_good, acc_cls, acc_lo, acc_hi)),
                          None if progress is None else lambda f: progress(
                              0.05 + 0.9 * (tail + f * (k - tail)) / k, "traced"), known)
            t_closest += tc
            n_closest += (k - tail) * spp - (0 if known is None else len(known.t))
            bad_total += run.bad_tail
    t_res = run.t_res - run.t_trace_all
    cancelled = run.cancelled
    if pixels is None and not cancelled:
        cache.view = here
    fs = run.fs
    if fb is not None:
        led = run.ledger
        led.cells = cache.cells_by_inst.copy()
        led.build_s = fs.get("build_s", 0.0)
        led.walk_s = budget.spent - led.build_s
        led.trace_s = run.trace_s
        led.traced_rays = run.traced_rays
        costs = led.costs(fb) if (pixels is None and not cancelled) else None
        if pixels is not None:  # (an edit's pixels: clustered, on one thread under
            budget.learned = None  # SERIAL_BELOW rays; as costs, only full frames teach)
        fb.walked_or_declined(budget)  # (a first walk priced: fallback.PRICE_FIRST_WALK)
        # (a full frame that compiled or loaded a kernel: not judged)
        compiled = costs is not None and budget.seal(fb.compiled)
        if costs is not None:
            fb.learn(costs, run.traced_now, budget.deferred_inst, budget.cut, budget.declined,
                     compiled)
            if n_closest and not compiled:
                fb.vis_s = t_closest / n_closest
    if not cancelled:  # (an incomplete frame keeps its base: nobody shows it, fast out)
        _assemble(acc_rad, acc_good, acc_cls, acc_lo, acc_hi, pix, image, pclass, pinterp)
    if progress is not None:
        progress(1.0, "done")
    elapsed = fb_mod.CLOCK() - t0
    fs = dict(fs, visibility_s=t_closest)
    stats = frame_stats(cache, fs, counts, pclass, np.flatnonzero(used), elapsed,
                         t_res, run.t_trace_all, n_rep / max(n, 1), k, run.n_todo,
                         run.counters, w, h, spp, int(settings.max_depth), cancelled,
                         bad_total)
    stats["world_s"] = run.t_world  # the interpolated pixels' world terms (in resolve_s)
    stats["sampled_s"] = run.t_sampled  # their lights' sampled terms (in resolve_s)
    if fb is not None:
        # (tail_pixels: pixels the base tracer's tiles traced after a cut, trace_tail)
        stats["fallback"] = dict(fb.stats(budget), tail_pixels=k - tail)
        stats["fallback_notes"] = fb.notes(budget)  # what it decided, for the user
    log.debug("interpolant frame: %.3f s, %d pixels, %.1f%% interpolated, %d cells built",
              elapsed, k, 100 * stats["interpolated_fraction"], stats["cells_built"])
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats,
                 pixel_interpolant=pinterp.reshape(h, w))


def _mark_used(used: np.ndarray, interp: np.ndarray) -> np.ndarray:
    """``used`` (bool by pool id) with the interpolants ``interp`` (>= 0) marked."""
    ids = interp[interp >= 0]
    if len(ids) == 0:
        return used
    top = int(ids.max()) + 1
    if top > len(used):
        used = np.concatenate([used, np.zeros(top - len(used), np.bool_)])
    used[ids] = True
    return used


class _Pass(NamedTuple):
    """One pass's rays (one sample of every pixel) and their visible hits."""

    o: np.ndarray
    d: np.ndarray
    tmin: np.ndarray
    tmax: np.ndarray
    gids: np.ndarray  # global sample ids
    vis: Visible
    keys: np.ndarray  # the pixels' tiles (the base tracer's shadow-ray skips)


class _Run:
    """What the chunks of an INTERPOLANT frame share (:func:`render_frame`): the frame's
    settings and records, what the scene needs per pixel, the fallback's ledger and
    budget, and the running times and counts."""

    def __init__(self, cache, settings, records, cancel, width: int, height: int) -> None:
        sa = cache.sa
        self.cache, self.settings, self.records, self.cancel = cache, settings, records, cancel
        self.width, self.npix = width, width * height  # (npix: for frame_strata)
        self.world = world_lights(sa)
        self.sampled = sampled_possible(sa)  # and its lights' sampled terms (sampled_term.py)
        # one on a rough surface traces its glossy rays (glossy_term.py) from its hit: a
        # reprojected one on a rough object traces its visibility ray for it
        self.rough_on = draws_glossy(sa, int(settings.max_depth))
        self.camera_seen = any_seen(sa, (SEEN_CAMERA,))
        self.ledger = self.budget = self.traced_now = None
        self.counters: dict = {}
        self.fs: dict = {}
        self.cancelled = False
        self.t_res = 0.0  # the passes' time
        self.t_trace = 0.0  # of it, tracing what was not interpolated
        self.t_trace_all = 0.0  # and the glossy rays of interpolated rough pixels
        self.t_world = self.t_sampled = 0.0
        self.trace_s = 0.0  # (the ledger's) tracing time, over
        self.traced_rays = 0  # rays traced
        self.n_todo = 0

    def tail(self, cp, pix, jitter, spp, counts, acc, progress=None, known=None) -> float:
        """Every sample of pixels ``pix`` traced by the base tracer in its tiles (``known``:
        :func:`~.frame_parts.trace_tail`'s) into their sums ``acc`` (:func:`_accumulate`'s,
        from sample 0 on, as the base frame sums them); returns the closest-hit seconds.
        ``progress(fraction of pix done)`` after each tile, or None."""
        records = self.records
        lrec = records.light if records is not None else None
        acc = tuple(acc)
        closest, self.bad_tail = 0.0, 0
        t0 = fb_mod.CLOCK()
        for out in trace_tail(self.cache, cp, pix, jitter, self.settings, self.counters,
                              records, self.cancel,
                              lrec if lrec is not None and lrec.partial else None, known):
            if out is None:
                self.cancelled = True
                break
            sl, rad, inst, t_hit, t_trace = out
            m = sl.stop - sl.start
            cls = np.where(inst >= 0, CLASS_TRACED, CLASS_BACKGROUND).astype(np.uint8)
            good = np.empty(len(rad), np.bool_)
            self.bad_tail += int(_finish(rad, float(tol.RADIANCE_MAX), cls, good, counts))
            none = np.full(m, -1, np.int32)
            for q in range(spp):
                r = slice(q * m, (q + 1) * m)
                _accumulate(rad[r], good[r], cls[r], none, *(x[sl] for x in acc))
            n_hit = int(np.count_nonzero(inst >= 0))
            closest += t_hit
            self.n_todo += n_hit
            self.traced_rays += n_hit
            self.trace_s += t_trace
            self.t_trace += t_trace
            self.t_trace_all += t_trace
            if progress is not None:
                progress(sl.stop / max(len(pix), 1))
        self.t_res += fb_mod.CLOCK() - t0
        return closest

    def chunk(self, ps: _Pass, sl: slice, cells: bool) -> None:
        """Rays ``sl`` of pass ``ps``: through the cells (``cells``: line coordinates, the
        walk, the builds the budget allows) or traced whole from their hits; then the
        interpolated ones' own terms, and the base tracer for the rest. What the mode
        added goes to the budget (everything but tracing the rays not interpolated)."""
        cache, settings, records, cancel = self.cache, self.settings, self.records, self.cancel
        budget = self.budget
        t0 = fb_mod.CLOCK()
        spent0 = 0.0 if budget is None else budget.spent
        later0 = 0.0 if budget is None else budget.later
        o, d, tmin, tmax, gids = (x[sl] for x in ps[:5])
        strata = frame_strata(cache.sa, int(settings.max_depth), gids, self.npix,
                              int(settings.seed), int(settings.samples))
        vis = ps.vis
        hits, res = part(vis.hits, sl), part(vis.res, sl)
        rep = None if vis.rep is None else vis.rep[sl]
        keys = ps.keys[sl]
        skipped = None
        if cells:
            if self.traced_now is not None:  # objects traced (fallback.py)
                skipped = (hits.inst >= 0) & self.traced_now[np.maximum(hits.inst, 0)]
                skipped = skipped if skipped.any() else None
            walk_inst = hits.inst if skipped is None else np.where(skipped, -1, hits.inst)
            if budget is not None:  # the builds see the walk so far (fallback.Budget.open)
                budget.open()
            face, abcd, zp, clsp = cache.pixel_lines(hits, o, d)
            cache.resolve(walk_inst, face, abcd, zp, clsp, cancel=cancel, hits=hits, pre=res,
                          budget=budget, finish=False)
            if budget is not None:
                budget.close()
            self.fs = _add_stats(self.fs, cache.frame_stats)
            if skipped is not None:  # traced, not background
                res.pixel_class[skipped] = CLASS_TRACED
        else:  # traced whole (the reprojected rays stay interpolated: proven, free)
            rest = ~res.interpolated
            res.pixel_class[rest] = np.where(hits.inst[rest] >= 0, CLASS_TRACED,
                                             CLASS_BACKGROUND)
        if vis.exact is not None and rep is not None and rep.any():
            hits.inst[rep] = vis.exact[0][sl][rep]
            hits.t[rep] = vis.exact[1][sl][rep]
        # the per-light records keep the interpolated samples' world terms apart
        # (world_samples.py: a world colour edit rescales them)
        lrec = records.light if records is not None else None
        if lrec is not None and not lrec.partial:
            lrec = None
        if self.sampled:  # the lights' sampled terms, per pixel, where cells interpolated
            self.t_sampled += add_sampled_terms(cache, res, None, o, d, tmin, tmax, hits, rep,
                                                gids, settings, self.counters, cancel, lrec)
        wi = w_coef = w_rest = None
        if self.world:  # the world's term, per pixel, where cells interpolated
            tw = fb_mod.CLOCK()
            wi = np.flatnonzero(res.interpolated & (hits.inst >= 0))
            w_coef = np.empty((len(wi), 3)) if lrec is not None else None
            w_rest = res.radiance[wi] if lrec is not None else None
            res.radiance[wi] += kept_world_term(  # (kept from the last frame, or traced)
                lrec, cache.sa, cache.accel, o, d, tmax, hits, wi, gids, settings,
                self.counters, w_coef)
            self.t_world += fb_mod.CLOCK() - tw
        if cells and self.ledger is not None:
            count(cache, self.ledger, hits, res, rep, skipped)
        if not cells and (rep is None or not rep.any()):
            # nothing interpolated: the base tracer's tiles, misses and all (views, no copies)
            todo = slice(0, len(o))
            n_traced = int(np.count_nonzero(hits.inst >= 0))
        else:  # a miss is the world colour (exactly what the tracer gives it)
            todo = np.empty(len(o), np.int64)
            todo = todo[:_to_trace(hits.inst, res.interpolated,
                                   np.asarray(cache.sa.world_color, np.float64),
                                   res.radiance, todo)]
            if self.camera_seen:
                todo = camera_seen(cache, o, d, tmin, tmax, hits, rep, res, todo)
            n_traced = len(todo)
            if budget is not None:
                budget.saved += int(np.count_nonzero(res.interpolated))
        self.n_todo += n_traced
        tt = fb_mod.CLOCK()
        trace_s = 0.0
        if cancel is not None and cancel():
            self.cancelled = True  # (a cancelled frame's records are dropped)
        else:
            if records is not None:
                records.add_primary(gids, hits.inst, o, d, hits.t)
            self.cancelled = trace_rest(cache, todo, o, d, tmin, tmax, hits, res.radiance,
                                        int(settings.max_depth), self.counters, records, gids,
                                        cancel, settings, keys, strata)
            trace_s = fb_mod.CLOCK() - tt
            if self.rough_on and not self.cancelled:  # rough surfaces' glossy rays
                self.cancelled = glossy_rest(cache, res.interpolated, o, d, tmin, tmax, hits,
                                             rep, res.interpolant, res.radiance,
                                             self.counters, records, gids, cancel, settings,
                                             strata)
        self.t_trace_all += fb_mod.CLOCK() - tt
        self.t_trace += trace_s
        self.trace_s += trace_s
        self.traced_rays += n_traced
        if lrec is not None and not self.cancelled:
            keep_world(lrec, cache.sa, gids, wi, w_coef, w_rest, res.interpolated, hits,
                       self.rough_on, int(settings.max_depth))
        if budget is not None:  # all the mode added: the chunk but its tracing
            # (less the builds' shares put off to the frame's later passes)
            budget.spent = (spent0 + (fb_mod.CLOCK() - t0) - trace_s
                            - (budget.later - later0))
            if cells:  # (its builds whole: what a first walk is priced at, fallback.py)
                budget.walked_chunk(len(o), budget.spent - spent0 + budget.later - later0)


class InterpolantRenderer:
    """The INTERPOLANT mode's state in a session: one cache, kept while it stays valid.

    A change of epsilon, depth cap or ray depth starts a new cache. Edits reach the cache
    through :meth:`take_edits` (their effects, computed once by the session), which keeps
    every interpolant they leave valid; a scene packing the cache was not told of starts a
    new cache (the renderer never diffs scenes), and so does a batch that changes the number
    of light slots but by adding lights (:mod:`.added_light`: a state per light).
    """

    #: trace where cells do not pay, learned from measured costs (:mod:`.fallback`), where
    #: the settings' ``interpolant_fallback`` asks for it too
    auto_fallback = True

    def __init__(self) -> None:
        self.cache: InterpolantCache | None = None

    def reset(self) -> None:
        """Forget every interpolant."""
        self.cache = None

    def take_edits(self, fx, sa, accel) -> Invalidation | None:
        """Hand an edit batch's effects ``fx`` (an ``EditEffects``) to the cache and move it
        to ``sa``; None without a cache. ``restarted``: every interpolant is gone."""
        c = self.cache
        if c is None:
            return None
        if sa is c.sa and not fx.scene_content_changed:
            c.accel = accel
            return Invalidation.nothing(c.pool.n_live)
        if not keeps_cache(c.sa, sa, fx) or _newly_seen(c.sa, sa):
            # (a light mirror or refraction rays now see: the samples were not flagged)
            live = c.pool.n_live
            self.cache = InterpolantCache(sa, accel, c.epsilon, c.depth_cap,
                                          c.memory_cap_bytes / 1e6, c.max_depth)
            return Invalidation.nothing(live, restarted=True)
        return c.take_edits(fx, sa, accel)

    def prepare(self, sa, settings: RenderSettings, accel):
        """The cache for scene packing ``sa``, ``settings`` and ``accel`` (see the class
        doc); returns ``(cache, new)``."""
        c = self.cache
        new = False
        if (c is None or sa is not c.sa
                or not c.compatible_settings(settings.epsilon, settings.depth_cap,
                                             settings.max_depth)):
            self.cache = c = InterpolantCache(sa, accel, settings.epsilon, settings.depth_cap,
                                              settings.memory_cap_mb, settings.max_depth)
            new = True
        c.accel = accel  # (interpolants hold radiance, not the accelerator's structures)
        if c.memory_cap_bytes != settings.memory_cap_mb * 1e6:
            c.set_memory_cap(settings.memory_cap_mb)
        return c, new

    def render(self, scene, settings: RenderSettings, accel, progress=None, cancel=None,
               **incremental) -> Frame:
        """Render ``scene``'s camera in INTERPOLANT mode with accelerator ``accel``
        (``incremental``: ``records``, ``pixels``, ``base`` of :func:`render_frame`; a caller
        that keeps pixels calls :meth:`prepare` first to learn whether the cache is new)."""
        settings = settings.validated()
        c, _ = self.prepare(scene.arrays(), settings, accel)
        frame = render_frame(c, scene, settings, progress=progress, cancel=cancel,
                             fallback=self.auto_fallback and settings.interpolant_fallback,
                             **incremental)
        frame.stats["interpolated_pct"] = 100.0 * frame.stats["interpolated_fraction"]
        return frame
