"""What a light with an extent still samples at the root of a line, per pixel (issue 20).

Where a light with an extent is proven fully visible over a cell (:mod:`.predicate`, the
shaft to its extent), every shadow sample of every line of the cell is unoccluded, so the
tracer's value of that light at a pixel's root needs no shadow ray -- but it may still be a
Monte Carlo estimate: the glossy lobe of a surface under an extended light (its highlight,
``f - k_d`` at each sample) and a light without a closed form (a spot with a radius, a
disk, an ellipse, a spread: the plain estimator throughout). Such terms are noise that no
interpolant reproduces and that the base frame has. So they are split off, as the world's
term is (:mod:`.world_term`):

* a *sampled row* is a (root, light) pair the tracer samples (``SH_SOFT``) where the root's
  material has a glossy lobe (:func:`.shafts.glossy_materials`) or the light has no closed
  form (:func:`.shafts.closed_forms`);
* (a sun's rows trace their shadow rays: a valid cell proves a sun either fully visible
  or hidden from every line -- an umbra, :func:`.occluders.cone_umbra` -- and the term
  must follow which);
* its *sampled term* is what the shade kernel adds for it less its closed-form diffuse
  part: with the closed form (the ratio estimator) ``sum_k V_k (f_k - k_d) w_k``, which the
  kernel computes exactly so when the row's closed form is set to 0 (the ratio term it adds
  last is then ``k_d * 0``); without one, the whole plain estimate;
* samples store their radiance without it, ``R' = L - S``; every interpolated pixel adds
  its own ``S``, computed at its own hit by the shade kernel with the base tracer's samples
  (its seeds, sample counts, directions, weights and BRDF evaluations), every sample of a
  row visible -- what the cell's shaft proof says of every line of a valid cell.

So where the proof holds, ``S`` is the base tracer's term for that pixel sample to float
rounding, noise included, and costs no shadow ray (the samples' directions and BRDFs only);
the pixel's error is that of ``R'`` alone. The closed-form diffuse part ``k_d E`` stays in
``R'``: smooth in the line, interpolated.
"""

from __future__ import annotations

import time

import numpy as np

from ..accel.accelerators import Hits
from ..cancel import bound
from ..geometry.scene import LIGHT_SUN
from ..tracing.light_linking import any_hit_shadows
from ..tracing.soft_lights import SH_SOFT, node_seeds, sample_seeds, soft_visibility
from ..tracing.whitted import shade, surfaces
from ..tracing.world_samples import TermSamples
from .samples import TEX_MISMATCH, hit_materials, textured_roots
from .shafts import closed_forms, glossy_materials

#: Split the sampled terms off (per pixel) and let the predicate pass cells whose lights
#: with an extent are sampled on a glossy surface or have no closed form; off, such cells
#: fail (``soft_sampled``) as before -- a module switch for measuring the two.
PER_PIXEL = True


def sampled_possible(sa) -> bool:
    """Whether some (root, light) row of the scene can be sampled (:data:`PER_PIXEL` on, a
    light with an extent, and a glossy material or a light without a closed form)."""
    if not PER_PIXEL:
        return False
    ext = np.asarray(sa.light_ext, np.bool_) & (np.asarray(sa.light_kind) >= 0)
    if not ext.any():
        return False
    return bool(glossy_materials(sa).any() or (ext & ~closed_forms(sa)).any())


def per_pixel_query(qs, sa):
    """The predicate's query structures ``qs`` (:func:`.shafts.query_scene`, with ``sa``'s
    light fields) as it reads them while ``sa``'s sampled terms are traced per pixel
    (:func:`sampled_possible`): a fully visible light needs no closed form and no Lambertian
    surface over a cell, only the horizon conditions of :func:`.soft_slab.soft_slab` (its
    closed form's, when it has one) -- ``light_closed`` is ``light_ext`` and no material
    counts as glossy. ``qs`` itself otherwise."""
    if not sampled_possible(sa):
        return qs
    return qs._replace(light_closed=np.ascontiguousarray(qs.light_ext, np.bool_),
                       mat_glossy=np.zeros_like(qs.mat_glossy))


def sampled_objects(sa) -> np.ndarray:
    """(n_instances,) bool: the objects whose hits may have sampled rows (a material with a
    glossy lobe in one of their slots; every object while a light with an extent has no
    closed form)."""
    starts = np.asarray(sa.inst_mat_start, np.int64)
    n = len(starts) - 1
    ext = np.asarray(sa.light_ext, np.bool_) & (np.asarray(sa.light_kind) >= 0)
    if (ext & ~closed_forms(sa)).any():
        return np.ones(n, np.bool_)
    owner = np.repeat(np.arange(n), np.diff(starts))  # each slot's object
    out = np.zeros(n, np.bool_)
    out[owner[glossy_materials(sa)[np.asarray(sa.inst_mat)]]] = True
    return out


def sampled_term(sa, accel, o: np.ndarray, d: np.ndarray, tmax, hits: Hits,
                 seeds: np.ndarray, light_samples: int, max_depth: int,
                 proven: bool = True, counters: dict | None = None,
                 coefficient: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float64: the sampled terms of the root hits ``hits`` of rays ``o, d`` ((n,
    3), bounds ``tmax`` (n,) or a scalar, as the tracer was given them) with input-ray seeds
    ``seeds`` (n,) uint64 and ``light_samples`` per light, summed over the lights and times
    each light's radiance. ``proven``: every sample of a sampled row is visible (the
    interpolated pixels of valid cells: no ray) but a sun's, which valid cells may prove
    hidden instead (an umbra, :func:`.occluders.cone_umbra`): their rays are traced; else
    every sampled row's shadow rays are traced
    (``counters["shadow"]``), which makes the term the tracer's wherever it is. ``max_depth``
    as the tracer's (a rough root's world samples light its diffuse part only; here it
    only keeps the shade kernel's inputs the tracer's). ``coefficient`` (n, L, 3), when
    given, receives each light's term over its radiance."""
    n = len(o)
    L = len(sa.light_kind)
    out = np.zeros((n, 3))
    if coefficient is not None:
        coefficient[:] = 0.0
    if n == 0 or not sampled_possible(sa):
        return out
    m = hit_materials(sa, hits.inst, hits.prim)
    rows = np.flatnonzero(m >= 0)
    if len(rows) == 0:
        return out
    o = np.ascontiguousarray(np.asarray(o, np.float64)[rows])
    d = np.ascontiguousarray(np.asarray(d, np.float64)[rows])
    t1 = np.array(np.broadcast_to(np.asarray(tmax, np.float64), (n,))[rows])
    h = Hits(*(np.ascontiguousarray(np.asarray(a)[rows]) for a in hits))
    nr = len(rows)
    # the world's rows are the world term's (world_term.py): not drawn here (every row's
    # samples hash its own light and seed, so the others are the same without them)
    sa = sa._replace(world_light=np.zeros_like(sa.world_light))
    surf = surfaces(sa, o, d, t1, h)
    need = (np.asarray(surf.sh_state).reshape(nr, L) == SH_SOFT) & (
        glossy_materials(sa)[m[rows]][:, None] | ~closed_forms(sa)[None, :])
    if not need.any():
        return out
    root = node_seeds(np.ascontiguousarray(np.asarray(seeds, np.uint64)[rows]),
                      np.arange(nr, dtype=np.int32), np.ones(nr, np.int64))
    state = np.where(need.reshape(-1), np.int8(SH_SOFT), np.int8(0)).astype(np.int8)

    def occluded(oo, dd, tt, which):
        if counters is not None:
            counters["shadow"] = counters.get("shadow", 0) + len(oo)
        return any_hit_shadows(accel, oo, dd, tt)

    prov = None
    if proven:  # a sun's rows are traced: a cell may prove it hidden instead (an umbra)
        prov = np.ascontiguousarray(np.broadcast_to(
            np.asarray(sa.light_kind) != LIGHT_SUN, (nr, L)).reshape(-1))
    soft, srows, _ = soft_visibility(sa, surf, root, int(light_samples), state, occluded,
                                     None, prov)
    # the closed form's share of a sampled row is left to the interpolants: 0 here, so
    # the kernel's ratio term adds k_d * 0 and the row's value is its glossy remainder
    lit = srows >= 0
    ex = soft.exact
    ex[lit & (ex >= 0.0)] = 0.0
    vis = np.zeros(nr * L, np.bool_)
    _, _, (tv, tp) = shade(sa, h, surf, vis, np.ones((nr, 3)), max_depth > 0, soft, True,
                           seeds=root)
    coef = np.where((need & tp[:, :L])[:, :, None], tv[:, :L], 0.0)
    out[rows] = np.einsum("ilc,lc->ic", coef, np.asarray(sa.light_radiance, np.float64))
    if coefficient is not None:
        coefficient[rows] = coef
    return out


def without_sampled(sa, accel, o: np.ndarray, d: np.ndarray, hits: Hits, rad: np.ndarray,
                    dif: np.ndarray, flag: np.ndarray, max_depth: int, light_samples: int,
                    share: np.ndarray | None = None):
    """Samples' radiance without their roots' sampled terms: ``(R' (n, 3), flag (n,)
    uint8)``, for lines ``o, d`` traced by :func:`~..tracing.whitted.trace` with its
    default seeds and ``light_samples`` from ``tmin 0, tmax 1`` with root ``hits`` (the
    interpolant builder's call). ``share`` (n, L, 3) (the lines' per-light shares,
    :mod:`.relight`), when given, loses each light's sampled term too. The rows are taken
    as all visible (``proven``): a line with an occluded sample of a sampled row is in no
    valid cell (the shaft proof of every cell it belongs to fails), so its ``R'`` is never
    interpolated; a sun's rows are traced (:func:`sampled_term`). A textured root with a
    sampled term is flagged :data:`~.samples.TEX_MISMATCH` (its texture split traces other
    samples)."""
    n = len(rad)
    L = len(sa.light_kind)
    coef = np.zeros((n, L, 3))
    s = sampled_term(sa, accel, o, d, 1.0, hits, sample_seeds(np.arange(n, dtype=np.int64), 0),
                     light_samples, max_depth, proven=True, coefficient=coef)
    flag = flag.copy()
    has = np.any(coef != 0.0, axis=(1, 2))
    if has.any():
        tex_root = np.zeros(n, np.bool_)
        textured_roots(sa, np.ascontiguousarray(hits.inst, np.int32),
                       np.ascontiguousarray(np.maximum(hits.prim, 0), np.int32), tex_root)
        flag[has & (tex_root | np.any(dif != 0.0, axis=1))] |= TEX_MISMATCH
    if share is not None:
        share -= coef
    return np.asarray(rad, np.float64) - s, flag


def add_sampled_terms(cache, res, skip_rows, o, d, tmin, tmax, hits: Hits, rep, gids,
                      settings, counters: dict, cancel=None, lrec=None) -> float:
    """A frame pass's interpolated samples (``res``, :mod:`.render`'s resolved part: rays
    ``o, d`` within ``tmin, tmax``, hits ``hits``, global sample ids ``gids``) add their
    lights' sampled terms to ``res.radiance``, with ``settings``' seed, Light Samples and ray
    depth; ``skip_rows`` (or None): rows traced whole. A reprojected sample (``rep`` (k,)
    bool or None) has no hit: where its interpolant lies on an object that may have sampled
    rows (:func:`sampled_objects`) its visibility ray is traced here; the others keep the
    saving. ``lrec``: the frame's per-light records (INTERPOLANT), whose kept terms
    (:class:`~..tracing.world_samples.TermSamples`: the same hit, seeds, lights with an
    extent and geometry) a sample takes instead of tracing its samples again -- bit for bit
    the term :func:`sampled_term` gives it -- and which keep the terms traced here. Returns
    the seconds it took."""
    t0 = time.perf_counter()
    rows = np.flatnonzero(res.interpolated)
    if skip_rows is not None:
        rows = np.setdiff1d(rows, skip_rows)
    h = _take(hits, rows)
    if rep is not None and rep[rows].any():
        back = rep[rows]
        r = np.flatnonzero(back)
        obj = cache.trees.arrays.tree[cache.pool.node[res.interpolant[rows[r]]]] // 6
        r = r[sampled_objects(cache.sa)[obj]]
        h.inst[back] = -1
        if len(r):
            c = rows[r]
            with bound(cache.accel, cancel):
                found = cache.accel.closest_hit(o[c], d[c], tmin[c], tmax[c])
            for dst, src in zip(h, found, strict=True):
                dst[r] = src
    keep = np.flatnonzero(h.inst >= 0)
    ok = lrec is not None and lrec.overflow is None
    if ok and lrec.sampled is not None:
        have, value = lrec.sampled.get(gids[rows[keep]])
        res.radiance[rows[keep[have]]] += value[have]
        keep = keep[~have]
    rows = rows[keep]
    term = sampled_term(
        cache.sa, cache.accel, o[rows], d[rows], tmax[rows], _take(h, keep),
        sample_seeds(gids[rows], int(settings.seed)), int(settings.light_samples),
        int(settings.max_depth), counters=counters)
    res.radiance[rows] += term
    if ok and len(rows):
        if lrec.sampled is None:
            lrec.sampled = TermSamples(lrec.n_rays)
        lrec.sampled.set(gids[rows], term)
    return time.perf_counter() - t0


def _take(h: Hits, idx: np.ndarray) -> Hits:
    return Hits(h.t[idx], h.inst[idx], h.prim[idx], h.u[idx], h.v[idx])
