"""Incremental INTERPOLANT frames: only the dirty pixels, with per-pixel records.

The INTERPOLANT counterpart of :func:`~rstrace_engine.tracing.whitted.render` with
``pixels=`` / ``records=``: the frame pipeline of :func:`~.interpolants.render.render_frame`
(visibility, line coordinates, :meth:`~.interpolants.cache.InterpolantCache.resolve`, the
base tracer for what is not interpolated) run over the rays of the dirty pixels only (all
their samples, the jitter of a full frame), every other pixel copied from the previous frame,
and the per-pixel records kept: every rendered sample's view segment
(:meth:`~.tracing.pixel_records.PixelRecords.add_primary`; what an interpolated pixel
depends on beyond it is its interpolant's, which the ray segment trees track) and the full
compact ray tree of every traced one. The session uses this while
:class:`~.interpolants.render.InterpolantRenderer` does not take ``records`` itself.
"""

from __future__ import annotations

import time

import numpy as np

from . import tolerances as tol
from .frame import CLASS_BACKGROUND, CLASS_INTERPOLATED, CLASS_NAMES, Frame, RenderSettings
from .geometry.cameras import camera_params, camera_rays
from .interpolants.cache import InterpolantCache
from .interpolants.render import _finish, _take, _to_trace
from .tracing.batches import TILE_RAYS, frame_batches, threads_for
from .tracing.whitted import render as whitted_render
from .tracing.whitted import trace


def render_interpolant(cache: InterpolantCache, scene, settings: RenderSettings, records,
                       pixels: np.ndarray | None = None, base: Frame | None = None,
                       progress=None, cancel=None) -> Frame:
    """An INTERPOLANT frame of ``scene`` (all pixels, or the ``pixels`` (h * w,) bool ones
    over a copy of ``base``), recording every rendered sample in ``records``."""
    settings = settings.validated()
    if cache.epsilon <= 0.0:  # nothing is interpolated: the base frame
        frame = whitted_render(scene, settings, accel=cache.accel, progress=progress,
                               cancel=cancel, records=records, pixels=pixels, base=base)
        pinterp = (np.full(frame.pixel_class.shape, -1, np.int32) if base is None
                   else base.pixel_interpolant)
        frame.pixel_interpolant = pinterp
        frame.stats.update(mode="INTERPOLANT", interpolated_fraction=0.0)
        return frame
    t0 = time.perf_counter()
    sa, accel = cache.sa, cache.accel
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    parts = list(frame_batches(w, h, spp, int(settings.seed), rows_per_tile, pixels))
    if parts:
        pix = np.concatenate([p for p, _, _ in parts])
        jitter = np.concatenate([j for _, j, _ in parts], axis=1)
    else:
        pix, jitter = np.zeros(0, np.int64), np.zeros((spp, 0, 2))
    k = len(pix)
    if k == 0 and base is not None:  # nothing is dirty: the previous frame, no work done
        interp = np.count_nonzero(base.pixel_class == CLASS_INTERPOLATED)
        stats = dict(mode="INTERPOLANT", time_s=time.perf_counter() - t0, traced_pixels=0,
                     traced_rays=0, cells_built=0, cells_valid=0,
                     interpolated_fraction=interp / max(base.pixel_class.size, 1),
                     interpolants=cache.pool.n_live, memory_mb=cache.memory_bytes / 1e6,
                     rst_memory_mb=cache.rst_memory_bytes() / 1e6, epsilon=cache.epsilon,
                     depth_cap=cache.depth_cap, width=w, height=h, samples=spp,
                     max_depth=int(settings.max_depth), cancelled=False, nonfinite_samples=0,
                     accelerator=getattr(accel, "name", "?"))
        stats["interpolated_pct"] = 100.0 * stats["interpolated_fraction"]
        return Frame(base.radiance.copy(), base.pixel_class.copy(), stats,
                     pixel_interpolant=base.pixel_interpolant.copy())
    with threads_for(k * spp):  # the dirty pixels of an edit: one thread (see batches)
        o, d, tmin, tmax = camera_rays(cp, np.tile(pix, spp), jitter.reshape(-1, 2))
        n = len(o)
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h) + pix[None, :]).ravel()
        hits = accel.closest_hit(o, d, tmin, tmax)
        if progress is not None:
            progress(0.2, "visibility")
        face, abcd, zp, clsp = cache.pixel_lines(hits, o, d)
        res = cache.resolve(hits.inst, face, abcd, zp, clsp, cancel=cancel)
        if progress is not None:
            progress(0.7, "interpolants")
        rad, ray_class, interp = res.radiance, res.pixel_class, res.interpolated
        todo = np.empty(n, np.int64)
        todo = todo[:_to_trace(hits.inst, interp, np.asarray(sa.world_color, np.float64), rad,
                               todo)]
        records.add_primary(gids, hits.inst, o, d, hits.t)
        cancelled = cancel is not None and cancel()
        counters: dict = {}
        if not cancelled:
            n_tiles = max(1, round(len(todo) / TILE_RAYS)) if len(todo) else 0
            for q in range(n_tiles):
                part = todo[q * len(todo) // n_tiles:(q + 1) * len(todo) // n_tiles]
                segs: list = []
                rad[part], _ = trace(sa, accel, o[part], d[part], tmin[part], tmax[part],
                                     int(settings.max_depth), primary=_take(hits, part),
                                     counters=counters, segments=segs)
                records.add(gids[part], segs)
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
    r = rad.reshape(spp, k, 3)
    ngood = good.reshape(spp, k).sum(axis=0)
    image[pix] = (r.sum(axis=0) / np.maximum(ngood, 1)[:, None]).astype(np.float32)
    c = ray_class.reshape(spp, k)
    pclass[pix] = c[np.argmax(c != CLASS_BACKGROUND, axis=0), np.arange(k)]
    qi = res.interpolant.reshape(spp, k)
    hi = qi.max(axis=0)
    lo = np.where(qi >= 0, qi, np.iinfo(np.int32).max).min(axis=0)
    pinterp[pix] = np.where(hi < 0, -1, np.where(lo == hi, hi, -2))
    if progress is not None:
        progress(1.0, "done")
    fs = cache.frame_stats
    stats = dict(
        mode="INTERPOLANT", time_s=time.perf_counter() - t0,
        # of the whole frame (kept pixels included)
        interpolated_fraction=float(np.count_nonzero(pclass == CLASS_INTERPOLATED))
        / max(len(pclass), 1),
        traced_rays=len(todo), traced_pixels=k, cells_built=fs.get("cells_built", 0),
        cells_valid=fs.get("cells_valid", 0), interpolants=cache.pool.n_live,
        memory_mb=cache.memory_bytes / 1e6, rst_memory_mb=cache.rst_memory_bytes() / 1e6,
        epsilon=cache.epsilon, depth_cap=cache.depth_cap,
        class_counts={CLASS_NAMES[q]: int(counts[q]) for q in range(len(CLASS_NAMES))},
        width=w, height=h, samples=spp, max_depth=int(settings.max_depth),
        cancelled=bool(cancelled), nonfinite_samples=bad_total,
        shadow_rays=counters.get("shadow", 0), secondary_rays=counters.get("secondary", 0),
        accelerator=getattr(accel, "name", "?"),
    )
    stats["interpolated_pct"] = 100.0 * stats["interpolated_fraction"]
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats,
                 pixel_interpolant=pinterp.reshape(h, w))
