"""Frames rendered with radiance interpolants (``mode = "INTERPOLANT"``).

A frame goes one sample of every pixel at a time (the same rays and jitter as
:func:`~.whitted.render`; each pass has the arrays of a 1-sample frame). Per pass: rays whose
interpolant is found by reprojection (:mod:`.reproject`: from the previous frame's pixels
after a camera move, from the pixel's first sample for the later samples; proven exact) are
interpolated at once; the others get their visible hits through the whole scene
(``closest_hit``) -> for every ray that hits an object, its line in that object's linetree
-> :meth:`~.interpolants.InterpolantCache.resolve` interpolates what valid interpolants
cover and builds the cells the pass needs -> every other ray (misses, failed cells, pixels
too few to be worth a cell) is traced by the base tracer from the hits already found. Each
pixel gets a class (:data:`~.frame.CLASS_NAMES`). At epsilon = 0 nothing can be
interpolated, and the frame is the base tracer's.

Interpolants are view-independent, so a :class:`InterpolantRenderer` keeps its cache across
frames and camera moves; it starts a new cache when epsilon, the depth cap or the ray depth
change, or when it is handed a scene packing it was not told of
(:meth:`InterpolantRenderer.take_edits` keeps every interpolant an edit leaves valid).

``frame.pixel_interpolant`` (h, w) int32 holds the interpolant each pixel used (-1: traced or
background; with several samples per pixel, -2 where its samples used different ones).
"""

from __future__ import annotations

import logging
import time

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..accel.accelerators import Hits
from ..cancel import bound
from ..frame import (
    CLASS_BACKGROUND,
    CLASS_INTERPOLATED,
    CLASS_NAMES,
    CLASS_REBUILT,
    CLASS_TRACED,
    Frame,
    RenderSettings,
)
from ..geometry.cameras import camera_params, camera_rays
from ..tracing.batches import TILE_RAYS, frame_batches, threads_for
from ..tracing.seen_lights import (
    SEEN_CAMERA,
    SEEN_GLOSSY,
    SEEN_TRANSMISSION,
    any_seen,
    seen,
    seen_lights,
)
from ..tracing.shaft_skip import tile_keys
from ..tracing.soft_lights import sample_seeds, world_lights
from ..tracing.whitted import render, trace
from . import fallback as fb_mod
from .added_light import keeps_cache
from .bound import bound_notes
from .glossy_term import glossy_term, rough_objects, rough_roots, rough_roots_possible
from .interpolant_cache import InterpolantCache
from .invalidation import Invalidation
from .reproject import FrameCells, remember, reproject, slab_points
from .sampled_term import add_sampled_terms, sampled_possible
from .world_term import keep_world, kept_world_term

log = logging.getLogger(__name__)


def _take(h: Hits, idx: np.ndarray) -> Hits:
    return Hits(h.t[idx], h.inst[idx], h.prim[idx], h.u[idx], h.v[idx])


@njit(cache=True, nogil=True)
def _to_trace(inst, interp, world, rad, todo):
    """Misses get the world colour (what the tracer gives them); the other rays that were
    not interpolated go to ``todo``. Returns their number."""
    k = 0
    for r in range(inst.shape[0]):
        if interp[r]:  # reprojected rays are interpolated without a hit
            continue
        if inst[r] < 0:
            rad[r, 0] = world[0]
            rad[r, 1] = world[1]
            rad[r, 2] = world[2]
        else:
            todo[k] = r
            k += 1
    return k


@njit(cache=True, nogil=True)
def _finish(rad, radmax, ray_class, good, counts):
    """good[r]: ray r's radiance is finite and at most ``radmax`` per channel (else it
    becomes 0); counts[c] += rays of class c. Returns the number of bad rays."""
    bad = 0
    for r in range(rad.shape[0]):
        ok = True
        for c in range(3):
            if not abs(rad[r, c]) <= radmax:  # also false for NaN
                ok = False
        good[r] = ok
        if not ok:
            rad[r, 0] = 0.0
            rad[r, 1] = 0.0
            rad[r, 2] = 0.0
            bad += 1
        counts[ray_class[r]] += 1
    return bad


@njit(cache=True, nogil=True)
def _accumulate(rad, good, ray_class, interp, acc_rad, acc_good, acc_cls, acc_lo, acc_hi):
    """Adds one sample of every pixel (``rad`` etc. (k, ...)) to the pixels' sums: radiance
    (bad samples are 0 in the sum, not counted), good samples, the class of the first
    sample that is not background, the least and largest interpolant used."""
    for i in range(rad.shape[0]):
        acc_rad[i, 0] += rad[i, 0]
        acc_rad[i, 1] += rad[i, 1]
        acc_rad[i, 2] += rad[i, 2]
        if good[i]:
            acc_good[i] += 1
        if acc_cls[i] == CLASS_BACKGROUND:
            acc_cls[i] = ray_class[i]
        q = interp[i]
        if q >= 0:
            if acc_lo[i] < 0 or q < acc_lo[i]:
                acc_lo[i] = q
            if q > acc_hi[i]:
                acc_hi[i] = q


@njit(cache=True, nogil=True)
def _assemble(acc_rad, acc_good, acc_cls, acc_lo, acc_hi, pix, image, pclass, pinterp):
    """Pixels from their sums (:func:`_accumulate`): mean radiance of the good samples'
    count, class, the interpolant all its interpolated samples used (-1: none, -2:
    several)."""
    for i in range(pix.shape[0]):
        ng = max(acc_good[i], 1)
        p = pix[i]
        image[p, 0] = acc_rad[i, 0] / ng
        image[p, 1] = acc_rad[i, 1] / ng
        image[p, 2] = acc_rad[i, 2] / ng
        pclass[p] = acc_cls[i]
        lo = acc_lo[i]
        hi = acc_hi[i]
        pinterp[p] = -1 if hi < 0 else (hi if lo == hi else -2)


def _resolve_part(cache, view, cells, splat, cp, pix, o, d, tmin, tmax, exact, cancel,
                  skip=None, budget=None):
    """Visible hits (reprojected from ``view`` where proven, else closest-hit rays) and
    :meth:`~.cache.InterpolantCache.resolve` of one ray per pixel ``pix``. Returns
    ``(hits, resolve result, reprojected (n,) bool or None, skipped (n,) bool or None)``;
    ``cache.frame_stats`` gets ``visibility_s``. A reprojected ray's hit is left a miss
    (with ``exact``, for pixel records: its object, at the far end of its slab).
    ``skip(hits)``: (n,) bool of the rays left to the tracer (not walked), or None;
    ``budget``: the frame's build budget (:mod:`.fallback`)."""
    tv = time.perf_counter()
    rp = reproject(cache, view, cells, cp, pix, o, d, tmax, splat)
    pre = exact_hits = None
    if rp is None:
        with bound(cache.accel, cancel):  # incomplete when cancelled: resolve polls first
            hits = cache.accel.closest_hit(o, d, tmin, tmax)
    else:
        pre, hi, _ = rp
        with bound(cache.accel, cancel):
            hits = cache.accel.closest_hit(o, d, tmin, hi)
        reprojected = hi < 0.0
        if exact:
            # pixel records keep a view segment per sample: the reprojected ones reach the
            # far end of their slab, past their hit (a longer segment can only make more
            # pixels dirty after an edit). Before resolve, which may evict (and reuse) the
            # interpolants used.
            g = np.flatnonzero(reprojected)
            t = np.full(len(o), np.inf)
            slab_points(cache, pre[3], o, d, t, reprojected, 1.0)
            exact_hits = g, cache.trees.arrays.tree[cache.pool.node[pre[3][g]]] // 6, t[g]
    tv = time.perf_counter() - tv
    skipped = None if skip is None else skip(hits)
    walk_inst = hits.inst if skipped is None else np.where(skipped, -1, hits.inst)
    face, abcd, zp, clsp = cache.pixel_lines(hits, o, d)
    res = cache.resolve(walk_inst, face, abcd, zp, clsp, cancel=cancel, hits=hits, pre=pre,
                        budget=budget)
    if skipped is not None:  # traced, not background
        res.pixel_class[skipped] = CLASS_TRACED
    cache.frame_stats["visibility_s"] = tv
    if rp is None:
        return hits, res, None, skipped
    if exact_hits is not None:
        g, inst, t = exact_hits
        hits.inst[g] = inst
        hits.t[g] = t
    return hits, res, reprojected, skipped


def _camera_seen(cache, o, d, tmin, tmax, hits, rep, res, todo) -> np.ndarray:
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


def _newly_seen(old_sa, sa) -> bool:
    """Whether mirror or refraction rays see a light in ``sa`` they did not in ``old_sa``
    (the cells' samples are flagged by what they saw: :func:`~.samples.seen_flags`)."""
    def below(x):
        return seen_lights(x, SEEN_GLOSSY) | seen_lights(x, SEEN_TRANSMISSION)
    new, old = below(sa), below(old_sa)  # (lights added: new slots)
    return bool(np.any(new[:len(old)] & ~old) or np.any(new[len(old):]))


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


def _count(cache, ledger, hits, res, rep, skipped) -> None:
    """A pass's rays per visible object for the fallback's ledger: walked, interpolated
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


def _tiles(n: int):
    """Slices of ``n`` rays in tiles of about the base tracer's size (its per-level arrays
    stay cache-sized), split evenly: a small last tile would cost the tracer's per-level
    overhead alone."""
    n_tiles = max(1, round(n / TILE_RAYS)) if n else 0
    for q in range(n_tiles):
        yield slice(q * n // n_tiles, (q + 1) * n // n_tiles)


def _trace_rest(cache, todo, o, d, tmin, tmax, hits, rad, max_depth, counters, records, gids,
                cancel, settings, keys=None) -> bool:
    """Trace rays ``todo`` (not interpolated) with the base tracer from the hits already
    found, into ``rad``; their ray trees go to ``records``; soft lights are sampled as the
    base tracer samples these pixel samples (``gids``, ``settings``' seed and light
    samples), and their shadow rays skipped where proven per tile as the base tracer does
    (``keys``: the rays' pixels' tiles, :func:`~..tracing.shaft_skip.tile_keys`). Returns
    whether ``cancel`` stopped it (the frame is then incomplete)."""
    sa, accel = cache.sa, cache.accel
    for sel in _tiles(len(todo)):
        part = todo[sel]
        segs: list | None = [] if records is not None else None
        with bound(accel, cancel):
            rad[part], _ = trace(sa, accel, o[part], d[part], tmin[part], tmax[part],
                                 max_depth, primary=_take(hits, part), counters=counters,
                                 segments=segs, cancel=cancel,
                                 seeds=sample_seeds(gids[part], int(settings.seed)),
                                 light_samples=int(settings.light_samples),
                                 glossy_samples=int(settings.glossy_samples),
                                 terms=records is not None and records.light is not None,
                                 skip_keys=None if keys is None else keys[part])
        if cancel is not None and cancel():
            return True
        if records is not None:
            records.add(gids[part], segs)
    return False


def _glossy_rest(cache, interp, skip_rows, o, d, tmin, tmax, hits, rep, interpolant, rad,
                 counters, records, gids, cancel, settings) -> bool:
    """Add to ``rad`` the glossy rays' part of the interpolated samples (``interp`` (k,)
    bool, but the rows ``skip_rows`` traced whole) whose hit is on a rough surface
    (:mod:`.glossy_term`); their segments go to ``records``. Returns whether ``cancel``
    stopped it. A reprojected sample (``rep`` (k,) bool or None) has no hit: where its
    interpolant (``interpolant`` (k,) pool ids) lies on an object with a rough material,
    its visibility ray is traced here."""
    sa, accel = cache.sa, cache.accel
    rows = np.flatnonzero(interp)
    rows = np.setdiff1d(rows, skip_rows)
    h = _take(hits, rows)
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
    rows, h = rows[rough], _take(h, np.flatnonzero(rough))
    counters["rough_interpolated"] = counters.get("rough_interpolated", 0) + len(rows)
    for sel in _tiles(len(rows)):
        part = rows[sel]
        segs: list | None = [] if records is not None else None
        with bound(accel, cancel):
            rad[part] += glossy_term(sa, accel, o[part], d[part], tmin[part], tmax[part],
                                     _take(h, sel), gids[part], int(settings.seed),
                                     int(settings.max_depth), int(settings.light_samples),
                                     int(settings.glossy_samples), counters, segs, cancel)
        if cancel is not None and cancel():
            return True
        if records is not None:
            records.add(gids[part], segs)
    return False


def _frame_stats(cache, fs, counts, pclass, used, elapsed, t_res, t_trace, reprojected,
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
        bound_notes=[] if cancelled else bound_notes(
            cache, np.concatenate(used) if used else np.zeros(0, np.int32)),
    )


def render_frame(cache: InterpolantCache, scene, settings: RenderSettings, progress=None,
                 cancel=None, records=None, pixels: np.ndarray | None = None,
                 base: Frame | None = None, fallback: bool = True) -> Frame:
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
    (:mod:`.fallback`: a build budget per frame, objects traced; ``stats["fallback"]``).
    """
    settings = settings.validated()
    if cache.epsilon <= 0.0:
        return _base_frame(cache, scene, settings, progress, cancel, records, pixels, base)
    fb = cache.fallback if fallback else None
    if fb is not None and fb.whole_frame_traced():
        # the frame's cells did not pay (fallback.py): the base tracer's frame, as fast
        cache.view = None
        frame = _base_frame(cache, scene, settings, progress, cancel, records, pixels, base)
        if pixels is None and not frame.stats.get("cancelled"):
            fb.frames_all += 1
        frame.stats.update(epsilon=cache.epsilon, reprojected_fraction=0.0, cell_outcomes={},
                           fallback=fb.stats(None, 0))
        return frame
    t0 = time.perf_counter()
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
    counters: dict = {}
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
    n_todo = 0
    used: list = []
    fs: dict = {}
    t_res = t_trace = 0.0
    # a full frame after a full frame of this cache: samples whose interpolant is found by
    # reprojection (reproject.py) need neither a visibility ray nor a walk; an incremental
    # frame keeps its camera. One sample of every pixel at a time (arrays of a 1-sample
    # frame, reused); the samples after the first reproject from it too (same eye: a sample
    # whose line lies in a proven cell costs a look-up, not a ray and a walk).
    # while the world lights, an interpolated pixel traces the world's term at its own hit
    # (world_term.py): it needs the hit, which a reprojected ray does not find
    world = world_lights(sa)
    sampled = sampled_possible(sa)  # and its lights' sampled terms (sampled_term.py)
    # one on a rough surface traces its glossy rays (glossy_term.py) from its hit: a
    # reprojected one on a rough object traces its visibility ray for it (_glossy_rest)
    rough_on = bool(rough_roots_possible(sa, int(settings.max_depth)))
    camera_seen = any_seen(sa, (SEEN_CAMERA,))
    view = cache.view if pixels is None and not world else None
    cache.view = None
    t_world = t_sampled = 0.0
    here = None
    cells = FrameCells(cp)
    cancelled = False
    # where cells do not pay (fallback.py): objects traced, the build budget, the probe
    n_inst = len(sa.inst_mesh)
    ledger = traced_now = budget = None
    probe = dict(rays=0, s=0.0)
    cache.cells_by_inst = np.zeros(n_inst, np.int64)
    if fb is not None:
        fb.resize(n_inst)
        ledger = fb_mod.FrameLedger(n_inst)
        traced_now = fb.frame_traced()
        budget = fb_mod.Budget(n, fb.ray_s, n_inst)

    def skip(hits, o, d, tmin, tmax, gids, rad_probe):
        """The rays left to the tracer: those of objects traced, and on a first frame the
        probe's (traced here, timed: the price of a ray for the build budget)."""
        if fb is None:
            return None
        hit = hits.inst >= 0
        out = hit & traced_now[np.maximum(hits.inst, 0)]
        if fb.ray_s is None and records is None:
            cand = np.flatnonzero(hit & ~out)
            if len(cand) >= fb_mod.PROBE_MIN * fb_mod.PROBE_STRIDE:
                pr = cand[::fb_mod.PROBE_STRIDE]
                t = fb_mod.CLOCK()
                _trace_rest(cache, pr, o, d, tmin, tmax, hits, rad_probe,
                            int(settings.max_depth), counters, None, gids, None, settings,
                            keys)
                dt = fb_mod.CLOCK() - t
                probe["rays"] += len(pr)
                probe["s"] += dt
                probe["idx"] = pr
                fb.ray_s = max(dt, 1e-9) / len(pr)
                budget.price(fb.ray_s)
                out[pr] = True
        return out if out.any() else None

    keys = tile_keys(pix, w)  # the base tracer's shadow-ray skips, per tile
    with threads_for(n):  # the dirty pixels of an edit: one thread (see batches)
        for s in range(spp):
            if cancel is not None and cancel():
                cancelled = True
                break
            tr = time.perf_counter()
            o, d, tmin, tmax = camera_rays(cp, pix, jitter[s])
            gids = s * (w * h) + pix
            rad_probe = np.zeros((k, 3))
            probe.pop("idx", None)
            hits, res, rep, skipped = _resolve_part(
                cache, None if world else (view if s == 0 else here), cells, s == 0, cp,
                pix, o, d, tmin, tmax,
                records is not None, cancel,
                lambda hh, a=(o, d, tmin, tmax, gids, rad_probe): skip(hh, *a), budget)
            fs = _add_stats(fs, cache.frame_stats)
            if rep is not None:
                n_rep += int(np.count_nonzero(rep))
            # the per-light records keep the interpolated samples' world terms apart
            # (world_samples.py: a world colour edit rescales them)
            lrec = records.light if records is not None else None
            if lrec is not None and not lrec.partial:
                lrec = None
            if sampled:  # the lights' sampled terms, per pixel, where cells interpolated
                t_sampled += add_sampled_terms(cache, res, probe.get("idx"), o, d, tmin, tmax,
                                               hits, rep, gids, settings, counters, cancel, lrec)
            if world:  # the world's term, per pixel, where cells interpolated
                tw = time.perf_counter()
                wi = np.flatnonzero(res.interpolated & (hits.inst >= 0))
                if "idx" in probe:
                    wi = np.setdiff1d(wi, probe["idx"])
                w_coef = np.empty((len(wi), 3)) if lrec is not None else None
                w_rest = res.radiance[wi] if lrec is not None else None
                res.radiance[wi] += kept_world_term(  # (kept from the last frame, or traced)
                    lrec, sa, cache.accel, o, d, tmax, hits, wi, gids, settings, counters, w_coef)
                t_world += time.perf_counter() - tw
            if "idx" in probe:  # traced already: done
                pr = probe["idx"]
                res.radiance[pr] = rad_probe[pr]
                res.interpolated[pr] = True
            if ledger is not None:
                _count(cache, ledger, hits, res, rep, skipped)
            if budget is not None:
                budget.saved += int(np.count_nonzero(res.interpolated)) - len(
                    probe.get("idx", ()))
            if s == 0 and pixels is None:
                t = hits.t.copy()
                slab_points(cache, res.interpolant, o, d, t,
                            np.zeros(k, np.bool_) if rep is None else rep)
                here = remember(pix, res.interpolant, o, d, t, w, h)
            used.append(np.unique(res.interpolant))
            # a miss is the world colour (exactly what the tracer gives it)
            rad, ray_class, interp = res.radiance, res.pixel_class, res.interpolated
            todo = np.empty(k, np.int64)
            todo = todo[:_to_trace(hits.inst, interp, np.asarray(sa.world_color, np.float64),
                                   rad, todo)]
            if camera_seen:
                todo = _camera_seen(cache, o, d, tmin, tmax, hits, rep, res, todo)
            n_todo += len(todo)
            tt = time.perf_counter()
            t_res += tt - tr
            if cancel is not None and cancel():
                cancelled = True  # (a cancelled frame's records are dropped)
            else:
                if records is not None:
                    records.add_primary(gids, hits.inst, o, d, hits.t)
                cancelled = _trace_rest(cache, todo, o, d, tmin, tmax, hits, rad,
                                        int(settings.max_depth), counters, records, gids,
                                        cancel, settings, keys)
                if rough_on and not cancelled:  # rough surfaces' glossy rays, per pixel
                    skip_rows = probe.get("idx", np.zeros(0, np.int64))
                    cancelled = _glossy_rest(cache, interp, skip_rows, o, d, tmin, tmax, hits,
                                             rep, res.interpolant, rad, counters, records,
                                             gids, cancel, settings)
            t_trace += time.perf_counter() - tt
            if lrec is not None and not cancelled:
                keep_world(lrec, sa, gids, *((wi, w_coef, w_rest) if world else (None,) * 3),
                           res.interpolated, hits, rough_on, int(settings.max_depth))
            good = np.empty(k, np.bool_)
            bad_total += int(_finish(rad, float(tol.RADIANCE_MAX), ray_class, good, counts))
            _accumulate(rad, good, ray_class, res.interpolant, acc_rad, acc_good, acc_cls,
                        acc_lo, acc_hi)
            if progress is not None:
                progress(0.05 + 0.9 * (s + 1) / spp, "interpolants")
            if cancelled:
                break
    if pixels is None and not cancelled:
        cache.view = here
    if ledger is not None:
        ledger.cells = cache.cells_by_inst.copy()
        ledger.build_s = fs.get("build_s", 0.0)
        ledger.walk_s = t_res - fs.get("visibility_s", 0.0) - ledger.build_s - probe["s"]
        ledger.trace_s = t_trace + probe["s"]
        ledger.traced_rays = n_todo + probe["rays"]
        costs = ledger.costs(fb) if (pixels is None and not cancelled) else None
        if costs is not None:
            fb.learn(costs, traced_now, budget.deferred_inst)
    if not cancelled:  # (an incomplete frame keeps its base: nobody shows it, fast out)
        _assemble(acc_rad, acc_good, acc_cls, acc_lo, acc_hi, pix, image, pclass, pinterp)
    if progress is not None:
        progress(1.0, "done")
    elapsed = time.perf_counter() - t0
    stats = _frame_stats(cache, fs, counts, pclass, used, elapsed, t_res, t_trace,
                         n_rep / max(n, 1), k, n_todo, counters, w, h, spp,
                         int(settings.max_depth), cancelled, bad_total)
    stats["world_s"] = t_world  # the interpolated pixels' world terms (in resolve_s)
    stats["sampled_s"] = t_sampled  # their lights' sampled terms (in resolve_s)
    if fb is not None:
        stats["fallback"] = fb.stats(budget, probe["rays"])
    log.debug("interpolant frame: %.3f s, %d pixels, %.1f%% interpolated, %d cells built",
              elapsed, k, 100 * stats["interpolated_fraction"], stats["cells_built"])
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats,
                 pixel_interpolant=pinterp.reshape(h, w))


class InterpolantRenderer:
    """The INTERPOLANT mode's state in a session: one cache, kept while it stays valid.

    A change of epsilon, depth cap or ray depth starts a new cache. Edits reach the cache
    through :meth:`take_edits` (their effects, computed once by the session), which keeps
    every interpolant they leave valid; a scene packing the cache was not told of starts a
    new cache (the renderer never diffs scenes), and so does a batch that changes the number
    of light slots but by adding lights (:mod:`.added_light`: a state per light).
    """

    #: trace where cells do not pay, learned from measured costs (:mod:`.fallback`)
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
                             fallback=self.auto_fallback, **incremental)
        frame.stats["interpolated_pct"] = 100.0 * frame.stats["interpolated_fraction"]
        return frame
