"""The world's light at the root of a line, traced per pixel (issue 20, the decomposition).

While the world lights, a point receives it through its whole hemisphere, so no cell can
prove it unoccluded on a floor that objects stand on. Interpolants therefore leave it out:
a sample stores its radiance *without* the world's term at its root, ``R' = L - W``, the
interpolated part; every interpolated pixel adds its own ``W``, computed here at its own hit
with the base tracer's own stages and seeds (its cosine-weighted samples, the same shadow
rays, the same BRDF evaluation). So ``W`` is exactly the base tracer's term for that pixel
sample, occlusion and noise included, and the pixel's error is that of ``R'`` alone
(docs/INTERPOLANTS.md, "The world's light").

``W`` is the shade kernel's light term of the world's row (:func:`~..tracing.whitted.shade`
with ``terms``), times the world's radiance: the value the tracer adds to the point's
radiance, last of its direct terms.
"""

from __future__ import annotations

import numpy as np

from ..accel.accelerators import Hits
from ..frame import LIGHT_SAMPLES_DEFAULT
from ..tracing.light_linking import any_hit_shadows
from ..tracing.soft_lights import node_seeds, sample_seeds, soft_visibility
from ..tracing.whitted import shade, surfaces
from .glossy_term import rough_roots
from .samples import TEX_MISMATCH, textured_roots


def world_term(sa, accel, o: np.ndarray, d: np.ndarray, tmax, hits: Hits,
               seeds: np.ndarray, light_samples: int, counters: dict | None = None,
               max_depth: int = 0, coefficient: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float64: the world's light term at the root hits ``hits`` of rays ``o, d``
    ((n, 3), bounds ``tmax`` (n,) or a scalar, as the tracer was given them) with input-ray
    seeds ``seeds`` (n,) uint64 (:func:`~..tracing.soft_lights.sample_seeds`) and
    ``light_samples`` per point: what :func:`~..tracing.whitted.trace` adds for the world
    at the root, bit for bit. Misses get 0. ``counters["shadow"]`` counts its rays. With
    ``max_depth`` above 0 a rough root's glossy rays carry the world's glossy reflection and
    its world samples light its diffuse part only, as in the tracer. ``coefficient`` (n, 3)
    float64, when given, receives the term over the world's radiance (0 where it is not
    added): the term is ``coefficient * sa.world_light`` bit for bit, so a world colour or
    strength edit rescales it without a ray (:meth:`~..tracing.light_records.LightRecords.
    set_world`)."""
    n = len(o)
    out = np.zeros((n, 3))
    if coefficient is not None:
        coefficient[:] = 0.0
    if n == 0:
        return out
    o = np.ascontiguousarray(o, np.float64)
    d = np.ascontiguousarray(d, np.float64)
    # a writeable copy: a read-only view would compile the surface kernel a second time
    t1 = np.array(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    surf = surfaces(sa, o, d, t1, hits)
    L = len(sa.light_kind)
    root = node_seeds(np.ascontiguousarray(seeds, np.uint64), np.arange(n, dtype=np.int32),
                      np.ones(n, np.int64))
    # no light row is sampled, only the world's (its samples' hash names the world alone)
    none = np.zeros(len(surf.sh_state), np.int8)
    soft, _, _ = soft_visibility(sa, surf, root, int(light_samples), none,
                                 _any_hit(accel), counters)
    vis = np.zeros(n * L, np.bool_)
    _, _, (tv, tp) = shade(sa, hits, surf, vis, np.ones((n, 3)), max_depth > 0, soft, True,
                           seeds=root)
    on = tp[:, L]
    out[on] = tv[on, L] * np.asarray(sa.world_light, np.float64)[None, :]
    if coefficient is not None:
        coefficient[on] = tv[on, L]
    return out


def kept_world_term(lrec, sa, accel, o, d, tmax, hits: Hits, wi, gids, settings,
                    counters, coefficient) -> np.ndarray:
    """:func:`world_term` at rows ``wi`` of a frame's pass (rays ``o, d``, bounds ``tmax``,
    hits ``hits``, sample ids ``gids``), taking it from the per-light records ``lrec`` where
    they keep the sample's coefficient from an earlier frame (:class:`~..tracing.
    world_samples.WorldSamples`; :meth:`~..tracing.frame_reuse.FrameReuse.take_edits` drops
    the rows of samples an edit of anything but the lights and the world makes dirty): the
    term is then ``coef * world_light``, bit for bit what :func:`world_term` gives (its
    seeds, shadow rays and BRDF are the sample's and the hit's), without its rays -- the
    pixels a light edit renders again (an interpolant rescaled, a light added) keep theirs.
    ``coefficient`` (k, 3) receives the coefficients (as :func:`world_term`'s) or is None."""
    k = len(wi)
    ws = lrec.world if lrec is not None and coefficient is not None else None
    row = ws.row[gids[wi]] if ws is not None else np.full(k, -1)
    have = np.flatnonzero(row >= 0)
    rest = np.flatnonzero(row < 0)
    out = np.zeros((k, 3))
    if len(have):
        coefficient[have] = ws.coef[row[have]]
        out[have] = coefficient[have] * np.asarray(sa.world_light, np.float64)[None, :]
    if len(rest):
        r = wi[rest]
        c = np.empty((len(rest), 3)) if coefficient is not None else None
        out[rest] = world_term(sa, accel, o[r], d[r], np.asarray(tmax)[r],
                               Hits(hits.t[r], hits.inst[r], hits.prim[r], hits.u[r],
                                    hits.v[r]),
                               sample_seeds(gids[r], int(settings.seed)),
                               int(settings.light_samples), counters,
                               max_depth=int(settings.max_depth), coefficient=c)
        if c is not None:
            coefficient[rest] = c
    return out


def keep_world(lrec, sa, gids, wi, coef, rest, interp, hits: Hits, rough_on: bool,
               max_depth: int) -> None:
    """A frame's pass of samples ``gids`` to the per-light records ``lrec``: which were
    interpolated with their world term added last (rows ``wi`` (None: the world does not
    light), still ``interp``olated, not on a rough surface whose glossy rays were added
    after it), with that term's ``coef`` (:func:`world_term`'s ``coefficient``) and the
    radiance ``rest`` it was added to (:meth:`~..tracing.light_records.LightRecords.
    set_world`: a world colour or strength edit rescales them)."""
    if wi is None or len(wi) == 0:
        lrec.set_world(gids, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        return
    keep = interp[wi].copy()
    if rough_on:
        h = Hits(hits.t[wi], hits.inst[wi], hits.prim[wi], hits.u[wi], hits.v[wi])
        keep &= ~rough_roots(sa, h, max_depth)
    lrec.set_world(gids, gids[wi[keep]], coef[keep], rest[keep])


def _any_hit(accel):
    """The tracer's occlusion query of soft samples (any hit up to each sample's end:
    :func:`~..tracing.light_linking.any_hit_shadows`)."""
    def occluded(o, d, tmax, rows):
        return any_hit_shadows(accel, o, d, tmax)
    return occluded


def without_world(sa, accel, o: np.ndarray, d: np.ndarray, hits: Hits, rad: np.ndarray,
                  dif: np.ndarray, flag: np.ndarray, max_depth: int):
    """Samples' radiance without the world's term at their root: ``(R' (n, 3), flag
    (n,) uint8)``, for lines ``o, d`` traced by :func:`~..tracing.whitted.trace` with its
    default seeds and light samples from ``tmin 0, tmax 1`` with root ``hits`` (the
    interpolant builder's call, to ``max_depth``). ``rad``, ``dif``, ``flag``:
    :func:`.samples.texture_split`'s.
    A textured root is flagged :data:`~.samples.TEX_MISMATCH` (its cell fails): the world's
    term there is affine in the texel, but the split's extra traces draw other samples."""
    n = len(rad)
    w = world_term(sa, accel, o, d, 1.0, hits,
                   sample_seeds(np.arange(n, dtype=np.int64), 0), LIGHT_SAMPLES_DEFAULT,
                   max_depth=max_depth)
    flag = flag.copy()
    flag[np.any(dif != 0.0, axis=1)] |= TEX_MISMATCH
    tex_root = np.zeros(n, np.bool_)
    textured_roots(sa, np.ascontiguousarray(hits.inst, np.int32),
                   np.ascontiguousarray(np.maximum(hits.prim, 0), np.int32), tex_root)
    flag[tex_root] |= TEX_MISMATCH
    return np.asarray(rad, np.float64) - w, flag
