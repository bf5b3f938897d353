"""Frames rendered with radiance interpolants (``mode = "INTERPOLANT"``).

A frame: camera rays (the same rays, jitter and tiles as :func:`~.whitted.render`) -> their
visible hits through the whole scene (``closest_hit``) -> for every ray that hits an object,
its line in that object's linetree -> :meth:`~.interpolants.InterpolantCache.resolve`
interpolates what valid interpolants cover and builds the cells the frame needs -> every
other ray (misses, failed cells, pixels too few to be worth a cell) is traced by the base
tracer from the hits already found. Each pixel gets a class (:data:`~.frame.CLASS_NAMES`).
At epsilon = 0 nothing can be interpolated, and the frame is the base tracer's.

Interpolants are view-independent, so a :class:`InterpolantRenderer` keeps its cache across
frames and camera moves; it starts a new cache when epsilon, the depth cap, the ray depth or
the accelerator change, or when the scene's content changed without the cache being told
(:meth:`~.cache.InterpolantCache.invalidate` then
:meth:`~.cache.InterpolantCache.set_scene` keep every interpolant an edit leaves valid).

``frame.pixel_interpolant`` (h, w) int32 holds the interpolant each pixel used (-1: traced or
background; with several samples per pixel, -2 where its samples used different ones).
"""

from __future__ import annotations

import hashlib
import logging
import time

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..accel.accelerators import Hits
from ..cancel import bound
from ..frame import CLASS_BACKGROUND, CLASS_INTERPOLATED, CLASS_NAMES, Frame, RenderSettings
from ..geometry.cameras import camera_params, camera_rays
from ..tracing.batches import TILE_RAYS, frame_batches, threads_for
from ..tracing.whitted import render, trace
from .bound import bound_notes
from .cache import InterpolantCache

log = logging.getLogger(__name__)


def _take(h: Hits, idx: np.ndarray) -> Hits:
    return Hits(h.t[idx], h.inst[idx], h.prim[idx], h.u[idx], h.v[idx])


@njit(cache=True, nogil=True)
def _to_trace(inst, interp, world, rad, todo):
    """Misses get the world colour (what the tracer gives them); the other rays that were
    not interpolated go to ``todo``. Returns their number."""
    k = 0
    for r in range(inst.shape[0]):
        if inst[r] < 0:
            rad[r, 0] = world[0]
            rad[r, 1] = world[1]
            rad[r, 2] = world[2]
        elif not interp[r]:
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


def render_frame(cache: InterpolantCache, scene, settings: RenderSettings, progress=None,
                 cancel=None, records=None, pixels: np.ndarray | None = None,
                 base: Frame | None = None) -> Frame:
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
    """
    settings = settings.validated()
    if cache.epsilon <= 0.0:
        # nothing can be interpolated within a zero error bound: this is a base frame
        frame = render(scene, settings, accel=cache.accel, progress=progress, cancel=cancel,
                       records=records, pixels=pixels, base=base)
        frame.pixel_interpolant = (np.full(frame.pixel_class.shape, -1, np.int32)
                                   if base is None else base.pixel_interpolant.copy())
        frame.stats.update(mode="INTERPOLANT", interpolated_fraction=0.0, cells_built=0,
                           cells_valid=0, samples_traced=0, interpolants=cache.pool.n_live,
                           memory_mb=cache.memory_bytes / 1e6, epsilon=0.0,
                           depth_cap=cache.depth_cap)
        return frame
    t0 = time.perf_counter()
    sa, accel = cache.sa, cache.accel
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
    # rays sample-major over the pixels: ray s * k + i is sample s of pixel pix[i]
    counters: dict = {}
    with threads_for(n):  # the dirty pixels of an edit: one thread (see batches)
        o, d, tmin, tmax = camera_rays(cp, np.tile(pix, spp), jitter.reshape(-1, 2))
        with bound(accel, cancel):  # incomplete when cancelled: resolve polls first
            hits = accel.closest_hit(o, d, tmin, tmax)
        t_vis = time.perf_counter()
        if progress is not None:
            progress(0.2, "visibility")
        face, abcd, zp, clsp = cache.pixel_lines(hits, o, d)
        res = cache.resolve(hits.inst, face, abcd, zp, clsp, cancel=cancel, hits=hits)
        t_res = time.perf_counter()
        if progress is not None:
            progress(0.7, "interpolants")
        # a miss is the world colour (exactly what the tracer gives it)
        rad, ray_class, interp = res.radiance, res.pixel_class, res.interpolated
        todo = np.empty(n, np.int64)
        todo = todo[:_to_trace(hits.inst, interp, np.asarray(sa.world_color, np.float64),
                               rad, todo)]
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h) + pix[None, :]).ravel()
        cancelled = cancel is not None and cancel()
        if records is not None and not cancelled:  # (a cancelled frame's are dropped)
            records.add_primary(gids, hits.inst, o, d, hits.t)
        if not cancelled:
            # in tiles of about the base tracer's size (its per-level arrays stay
            # cache-sized), split evenly: a small last tile would cost the tracer's per-level
            # overhead alone
            n_tiles = max(1, round(len(todo) / TILE_RAYS)) if len(todo) else 0
            for q in range(n_tiles):
                part = todo[q * len(todo) // n_tiles:(q + 1) * len(todo) // n_tiles]
                segs: list | None = [] if records is not None else None
                with bound(accel, cancel):
                    rad[part], _ = trace(sa, accel, o[part], d[part], tmin[part],
                                         tmax[part], int(settings.max_depth),
                                         primary=_take(hits, part), counters=counters,
                                         segments=segs, cancel=cancel)
                cancelled = cancel is not None and cancel()
                if cancelled:  # an incomplete tile (and frame): the session drops it
                    break
                if records is not None:
                    records.add(gids[part], segs)
    t_trace = time.perf_counter()
    good = np.empty(n, np.bool_)
    counts = np.zeros(len(CLASS_NAMES), np.int64)
    bad_total = int(_finish(rad, float(tol.RADIANCE_MAX), ray_class, good, counts))
    if base is not None and pixels is not None:
        image = base.radiance.reshape(h * w, 3).copy()
        pclass = base.pixel_class.reshape(h * w).copy()
        pinterp = base.pixel_interpolant.reshape(h * w).copy()
    else:
        image = np.zeros((h * w, 3), np.float32)
        pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
        pinterp = np.full(h * w, -1, np.int32)
    if not cancelled:  # (an incomplete frame keeps its base: nobody shows it, fast out)
        r = rad.reshape(spp, k, 3)
        ngood = good.reshape(spp, k).sum(axis=0)
        image[pix] = (r.sum(axis=0) / np.maximum(ngood, 1)[:, None]).astype(np.float32)
        c = ray_class.reshape(spp, k)
        # a pixel's class: its first sample that is not background
        pclass[pix] = c[np.argmax(c != CLASS_BACKGROUND, axis=0), np.arange(k)]
        # the interpolant the pixel's samples used: -2 where they used several
        qi = res.interpolant.reshape(spp, k)
        hi = qi.max(axis=0)
        lo = np.where(qi >= 0, qi, np.iinfo(np.int32).max).min(axis=0)
        pinterp[pix] = np.where(hi < 0, -1, np.where(lo == hi, hi, -2))
    if progress is not None:
        progress(1.0, "done")
    elapsed = time.perf_counter() - t0
    fs = cache.frame_stats
    stats = dict(
        mode="INTERPOLANT", time_s=elapsed, visibility_s=t_vis - t0, resolve_s=t_res - t_vis,
        build_s=fs.get("build_s", 0.0), rst_insert_s=fs.get("deps_s", 0.0),
        trace_s=t_trace - t_res,
        # of the whole frame (kept pixels included)
        interpolated_fraction=float(np.count_nonzero(pclass == CLASS_INTERPOLATED))
        / max(len(pclass), 1),
        traced_pixels=k, traced_rays=len(todo), shadow_rays=counters.get("shadow", 0),
        secondary_rays=counters.get("secondary", 0),
        cells_built=fs.get("cells_built", 0), cells_valid=fs.get("cells_valid", 0),
        samples_traced=fs.get("samples_traced", 0), levels=fs.get("levels", 0),
        cell_outcomes=dict(fs.get("reasons", {})),
        interpolants=cache.pool.n_live, linetree_nodes=cache.trees.live_nodes,
        memory_mb=cache.memory_bytes / 1e6, rst_memory_mb=cache.rst_memory_bytes() / 1e6,
        interpolant_memory_mb=cache.interpolant_bytes / 1e6,
        epsilon=cache.epsilon, depth_cap=cache.depth_cap,
        memory_cap_mb=cache.memory_cap_bytes / 1e6,
        class_counts={CLASS_NAMES[q]: int(counts[q]) for q in range(len(CLASS_NAMES))},
        width=w, height=h, samples=spp, max_depth=int(settings.max_depth),
        cancelled=bool(cancelled), nonfinite_samples=bad_total,
        accelerator=getattr(accel, "name", "?"), cache_setup_s=cache.setup_s,
        bound_notes=[] if cancelled else bound_notes(cache, res.interpolant),
    )
    log.debug("interpolant frame: %.3f s, %d pixels, %.1f%% interpolated, %d cells built",
              elapsed, k, 100 * stats["interpolated_fraction"], stats["cells_built"])
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats,
                 pixel_interpolant=pinterp.reshape(h, w))


def scene_fingerprint(sa) -> bytes:
    """Content hash of a scene packing (geometry, instances, materials, lights, world)."""
    h = hashlib.blake2b(digest_size=16)
    for a in sa:
        h.update(np.ascontiguousarray(a).view(np.uint8) if isinstance(a, np.ndarray)
                 else repr(a).encode())
    return h.digest()


class InterpolantRenderer:
    """The INTERPOLANT mode's state in a session: one cache, kept while it stays valid.

    A change of epsilon, depth cap or ray depth starts a new cache. A new packing of the
    scene or a new accelerator moves the cache to it
    (:meth:`~.cache.InterpolantCache.set_scene`): an unchanged export keeps everything, and
    an edited one loses only the interpolants its changes may affect (a session calls
    :meth:`~.cache.InterpolantCache.invalidate` with its edits first, the fast path).
    """

    def __init__(self) -> None:
        self.cache: InterpolantCache | None = None
        self._fingerprint: bytes | None = None
        self._fingerprint_of = None  # the packing the fingerprint is of

    def reset(self) -> None:
        """Forget every interpolant."""
        self.cache = None
        self._fingerprint = None
        self._fingerprint_of = None

    def _same_scene(self, sa) -> bool:
        c = self.cache
        if sa is c.sa:
            return True
        if self._fingerprint_of is not c.sa:  # moved to an edited scene (set_scene)
            self._fingerprint = scene_fingerprint(c.sa)
            self._fingerprint_of = c.sa
        fp = scene_fingerprint(sa)
        if fp != self._fingerprint:
            return False
        c.sa = sa  # same content, new packing
        self._fingerprint_of = sa
        return True

    def prepare(self, sa, settings: RenderSettings, accel):
        """The cache for scene packing ``sa``, ``settings`` and ``accel`` (see the class
        doc); returns ``(cache, new)``."""
        c = self.cache
        new = False
        if c is None or not c.compatible_settings(settings.epsilon, settings.depth_cap,
                                                  settings.max_depth):
            self.cache = c = InterpolantCache(sa, accel, settings.epsilon, settings.depth_cap,
                                              settings.memory_cap_mb, settings.max_depth)
            self._fingerprint = None
            self._fingerprint_of = None
            new = True
        elif sa is not c.sa or accel is not c.accel:
            c.set_scene(sa, accel)  # diffs the packings: invalidates what changed
        if c.memory_cap_bytes != settings.memory_cap_mb * 1e6:
            c.set_memory_cap(settings.memory_cap_mb)
        return c, new

    def render(self, scene, settings: RenderSettings, accel, progress=None, cancel=None,
               **incremental) -> Frame:
        """Render ``scene``'s camera in INTERPOLANT mode with accelerator ``accel``
        (``incremental``: ``records``, ``pixels``, ``base`` of :func:`render_frame`)."""
        settings = settings.validated()
        c, _ = self.prepare(scene.arrays(), settings, accel)
        frame = render_frame(c, scene, settings, progress=progress, cancel=cancel,
                             **incremental)
        frame.stats["interpolated_pct"] = 100.0 * frame.stats["interpolated_fraction"]
        return frame
