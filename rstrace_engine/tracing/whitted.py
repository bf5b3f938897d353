"""The base tracer: wavefront Whitted ray tracing that also records ray trees.

The radiance it computes, and the kernels that compute it for one depth level, are
:mod:`.shader`'s; this module drives them (stages, the wavefront, a frame's tiles).

The wavefront: every depth level intersects its batch of rays, runs a surface kernel (hit
point, normals, material, one shadow ray per light), intersects the shadow rays, runs a shade
kernel (direct light, reflection/refraction rays into preallocated slots), compacts the
spawned rays and goes on with them. Each spawned ray carries the index of the input ray it
contributes to and its path weight; it is not spawned when that weight is below
``tolerances.PATH_WEIGHT_MIN``. ``max_depth`` counts reflection/refraction bounces (0: primary
rays and direct light only). The three stages are public (:func:`surfaces`,
:func:`shadow_rays`, :func:`shade`) for the RI-tree renderer, whose levels find their hits
and shadow visibility otherwise but are shaded alike.

With ``record=True`` the ray tree of every input ray is returned as a :class:`RayTree`; its
shadow rays then use ``closest_hit`` so that each occluder's instance id is known.
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import heap, stripes
from ..accel.accelerators import Hits, create_accelerator, per_ray
from ..cancel import bound, cancelled
from ..frame import (
    CLASS_BACKGROUND,
    GLOSSY_SAMPLES_DEFAULT,
    LIGHT_SAMPLES_DEFAULT,
    Frame,
    RenderSettings,
)
from ..geometry.cameras import camera_params, camera_rays
from ..geometry.scene import Scene, SceneArrays
from .batches import TILE_RAYS, accumulate, frame_batches, scatter_add, threads_for
from .dielectric_albedo import dielectric_albedos
from .glossy_rays import glossy_counts, has_glossy, roulette
from .glossy_strata import (  # (child_paths, _child_tags: re-exported)
    Strata,
    _child_tags,  # noqa: F401
    child_paths,
    draws_glossy,
    frame_strata,
    lattices,
    next_paths,
    no_strata,
)
from .light_bits import words
from .light_linking import any_hit_shadows, first_blocker, links_shadows
from .light_linking import occluded as linked_occluded
from .sample_rays import VIS_BITS_MAX, soft_bits
from .seen_lights import SEEN_CAMERA, SEEN_GLOSSY, SEEN_NONE, SEEN_TRANSMISSION, any_seen, seen
from .shader import (  # (re-exported: the stages' kernels and types)
    _SH_TRACE,
    OCC_NONE,
    OCC_NOT_FACING,
    SH_FAR,
    Spawned,
    Surfaces,
    _shade_kernel,
    _shadow_kernel,
    _surface_kernel,
    light_state,
    light_states,
)
from .shaft_skip import own_instances, own_reflections, proven_rows, tile_keys
from .soft_lights import (
    SH_SOFT,
    SoftSamples,
    has_soft_light,
    no_samples,
    node_seeds,
    sample_seeds,
    soft_direct,
)

log = logging.getLogger(__name__)

__all__ = ["OCC_NONE", "OCC_NOT_FACING", "RayTree", "Spawned", "Surfaces", "child_paths",
           "light_state", "light_states", "render", "shade", "shade_paths", "shadow_rays",
           "soft_direct", "surfaces", "trace", "trace_pixels"]


class RayTree(NamedTuple):
    """Ray trees of a batch of rays, one row per node (see docs/CONTRACTS.md).

    Rows are ordered by depth level; the first ``n`` rows are the input rays (row i is
    ray i). ``node_occluder[k, j]`` is the occluding instance of light ``j`` (``-1``
    unoccluded, ``-2`` light not facing, outside its cone, or the node is a miss).
    """

    node_ray: np.ndarray  # (Nn,) int32 input ray index
    node_parent: np.ndarray  # (Nn,) int32 parent row, -1 for roots
    node_path: np.ndarray  # (Nn,) int64 root 1, reflect child 2p, refract child 2p + 1
    node_inst: np.ndarray  # (Nn,) int32 instance hit, -1 = miss
    node_tri: np.ndarray  # (Nn,) int32 global triangle, -1 on miss
    node_origin: np.ndarray  # (Nn, 3) float64 segment start
    node_point: np.ndarray  # (Nn, 3) float64 hit point; far beyond the scene on a miss
    node_light_mask: np.ndarray  # (Nn, W) uint64 light j contributes (.light_bits)
    node_occluder: np.ndarray  # (Nn, L) int32


# ----------------------------------------------------------------------------- stages


def _as_hits(h: Hits) -> Hits:
    return Hits(np.ascontiguousarray(h.t, np.float64), np.ascontiguousarray(h.inst, np.int32),
                np.ascontiguousarray(h.prim, np.int32), np.ascontiguousarray(h.u, np.float64),
                np.ascontiguousarray(h.v, np.float64))


def surfaces(sa: SceneArrays, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
             hits: Hits) -> Surfaces:
    """The surface points of ``n`` rays ``o, d`` (n, 3) float64 with bounds ``tmax`` (n,)
    and their ``hits``: :class:`Surfaces` (the shadow-ray states of every light
    included)."""
    n = len(o)
    surf = Surfaces(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
                    np.empty(n, np.bool_), np.empty(n, np.int32), np.empty((n, 3)),
                    np.empty(n * len(sa.light_kind), np.int8))
    stripes.run(_surface_kernel, stripes.blocks_of(n), sa, o, d, tmax, _as_hits(hits), surf)
    return surf


def shadow_rays(sa: SceneArrays, surf: Surfaces):
    """The shadow rays of ``surf``: ``(todo (k,) int64, origins (k, 3), directions (k, 3),
    tmax (k,))``, ``todo`` their (point, light) rows ``i * L + j``."""
    todo = np.flatnonzero((surf.sh_state == _SH_TRACE) | (surf.sh_state == SH_FAR))
    k = len(todo)
    so, sd, st = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
    if k:
        _shadow_kernel(sa, surf.P, surf.NG, surf.Q, surf.sh_state, todo, so, sd, st)
    return todo, so, sd, st


def shade(sa: SceneArrays, hits: Hits, surf: Surfaces, vis: np.ndarray, weight: np.ndarray,
          spawn: bool, soft: SoftSamples | None = None, terms: bool = False,
          seeds: np.ndarray | None = None):
    """Direct light of ``surf`` (``vis`` (n L,) bool: light j visible from point i; ``soft``
    the samples of the lights with an extent and of the world, :func:`soft_direct`) times
    the path ``weight`` (n, 3), and the reflection and refraction rays when ``spawn``:
    ``(contrib (n, 3) float64, Spawned)``, point i's rays in slots ``2 i`` (reflection) and
    ``2 i + 1`` (refraction); with ``terms`` also the points' light terms ``(values (n, L +
    2, 3) float64, present (n, L + 2) bool)`` (see :func:`_shade_kernel`). Rough surfaces
    (:func:`~.glossy_rays.is_glossy`) draw their one reflected and refracted ray from the GGX
    lobe, seeded by ``seeds`` (n,) uint64, the points' node seeds (:func:`node_seeds`;
    required then). (The wavefront of :func:`trace` draws several at a path's first rough
    bounce.)"""
    if spawn and seeds is None and has_glossy(sa):
        raise ValueError("shade: rough materials draw glossy rays from the points' seeds: "
                         "give seeds")
    fresh = np.zeros(len(surf.P), np.bool_)
    res = _shade_level(sa, hits, surf, vis, weight, spawn, soft, terms, seeds, fresh, 1, None)
    return res[:-1]


def shade_paths(sa: SceneArrays, hits: Hits, surf: Surfaces, vis: np.ndarray,
                weight: np.ndarray, soft: SoftSamples | None, seeds: np.ndarray,
                fresh: np.ndarray, samples: int, lat=None):
    """:func:`shade` (spawning) for a wavefront that follows paths as :func:`trace` does:
    a rough point whose path has drawn no glossy samples yet (``fresh`` (n,) bool) draws
    ``samples`` ray pairs by its lobe (:func:`~.glossy_rays.glossy_counts`), any other one
    (docs/glossy.md). Returns ``(contrib (n, 3), Spawned, gstart, glossy)``: point i's ray
    pairs are ``gstart[i]:gstart[i + 1]`` (``gstart`` None: one pair each, slots ``2 i``,
    ``2 i + 1``), ``glossy`` (n,) bool which points drew from their lobe (None with
    ``gstart``); :func:`child_paths` gives the spawned rays' paths. ``lat``: a callable
    ``lat(glossy, counts) -> (n, 4)`` giving the glossy samples' lattices
    (:func:`~.glossy_strata.lattices`; None: each point's own)."""
    contrib, kids, plan = _shade_level(sa, hits, surf, vis, weight, True, soft, False, seeds,
                                       fresh, int(samples), lat)
    return contrib, kids, plan.gstart, plan.glossy


class _Plan(NamedTuple):
    """Where a level's spawned rays lie: point i's ray pairs ``gstart[i]:gstart[i + 1]``
    (None: one pair each, slots ``2 i``, ``2 i + 1``), ``glossy`` (n,) bool its rays are
    drawn from its lobe."""

    gstart: np.ndarray | None
    glossy: np.ndarray | None


def _shade_level(sa, hits, surf, vis, weight, spawn, soft, terms, seeds, fresh, samples, lat):
    """:func:`shade` for the wavefront: ``fresh`` (n,) bool the rays whose paths have not
    drawn glossy samples yet (they draw ``samples`` by lobe,
    :func:`~.glossy_rays.glossy_counts`, the others one); ``lat`` as
    :func:`shade_paths`. Returns ``(contrib, Spawned[, terms], _Plan)``."""
    n = len(surf.P)
    plan = _Plan(None, None)
    gseeds = np.zeros(0, np.uint64)
    gstart = np.arange(n + 1, dtype=np.int64)
    rows = no_strata(n)
    ediel = np.empty(n)  # (the Principled points' dielectric albedos, each stripe's at once)
    stripes.run(dielectric_albedos, stripes.blocks_of(n), surf.VD, surf.NS, surf.mat,
                sa.mat_model, sa.mat_roughness, sa.mat_specular_ior, sa.mat_diffuse, ediel)
    if spawn and seeds is not None and has_glossy(sa):
        counts, glossy = glossy_counts(sa, surf.mat, fresh, samples, ediel)
        gseeds = np.ascontiguousarray(seeds, np.uint64)
        if glossy.any():
            gstart = np.zeros(n + 1, np.int64)
            np.cumsum(counts, out=gstart[1:])
            plan = _Plan(gstart, glossy)
            if lat is not None:
                rows = lat(glossy, counts)
    m = 2 * int(gstart[-1])
    contrib = np.empty((n, 3))
    out = Spawned(np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty(m, np.bool_))
    c = len(sa.light_kind) + 2
    tv = np.empty((n if terms else 0, c, 3))
    tp = np.empty((n if terms else 0, c), np.bool_)
    stripes.run(_shade_kernel, stripes.blocks_of(n), sa, _as_hits(hits), surf, vis, weight,
                spawn, no_samples(n) if soft is None else soft, gstart, gseeds, rows, ediel,
                contrib, out, tv, tp)
    if plan.gstart is not None:  # the deeper rough bounces' weak rays
        roulette(plan.gstart, plan.glossy, fresh, gseeds, weight, out)
    if terms:
        return contrib, out, (tv, tp), plan
    return contrib, out, plan


# ----------------------------------------------------------------------------- driver


class _Front(NamedTuple):
    """The rays of one depth level and where they come from."""

    o: np.ndarray  # (nb, 3) float64
    d: np.ndarray  # (nb, 3) float64
    t0: np.ndarray  # (nb,) float64
    t1: np.ndarray  # (nb,) float64
    src: np.ndarray  # (nb,) int32 input ray
    weight: np.ndarray  # (nb, 3) float64 path weight
    parent: np.ndarray  # (nb,) int32 parent node row (-1: roots)
    path: np.ndarray  # (nb,) int64 root 1, reflect child 2p, refract child 2p + 1
    fresh: np.ndarray  # (nb,) bool the path has drawn no glossy samples yet
    tag: np.ndarray  # (nb,) uint64 hashed into the node seed below a glossy sample (else 0)
    sees: np.ndarray  # (nb,) int8 which lights the ray sees (seen_lights.SEEN_*)


def _count(counters: dict | None, key: str, n: int) -> None:
    if counters is not None:
        counters[key] = counters.get(key, 0) + int(n)


def _input_front(origins, directions, tmin, tmax, primary: Hits | None,
                 camera_lights: bool = True) -> _Front:
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    n = o.shape[0]
    if d.shape != o.shape:
        raise ValueError(f"trace: origins {o.shape} and directions {d.shape} differ")
    t0 = per_ray(tmin, n, np.float64)  # writeable: one numba type for every caller
    t1 = per_ray(tmax, n, np.float64)
    if primary is not None and len(primary.t) != n:
        raise ValueError(f"trace: primary hits for {len(primary.t)} rays, {n} rays given")
    return _Front(o, d, t0, t1, np.arange(n, dtype=np.int32), np.ones((n, 3)),
                  np.full(n, -1, np.int32), np.ones(n, np.int64), np.ones(n, np.bool_),
                  np.zeros(n, np.uint64),
                  np.full(n, SEEN_CAMERA if camera_lights else SEEN_NONE, np.int8))


def _next_front(front: _Front, kids: Spawned, rows: np.ndarray | None, plan: _Plan,
                nseeds: np.ndarray | None, mine=None, surf=None, counters=None):
    """The spawned rays, compacted, and what they skip (``own_reflections`` of ``mine``
    at ``surf``); ``rows``: the level's node rows (None: parents not followed); ``plan``:
    the slots' layout (:func:`_shade_level`), ``nseeds`` the node seeds (glossy samples)."""
    k, which, src, path, fresh, tag, sees, o, d, w = next_paths(
        kids.ok, plan.gstart, plan.glossy, front.src, front.path, front.fresh, front.tag,
        nseeds, kids.o, kids.d, kids.w, SEEN_NONE, SEEN_GLOSSY, SEEN_TRANSMISSION)
    # (mirror rays see lights as glossy rays, smooth refraction as transmission, rough
    # lobes none; path also seeds the soft lights' samples)
    parent = front.parent if rows is None else rows[which]
    skip = None if surf is None else own_reflections(mine, k, which, o, d, surf, counters)
    return _Front(o, d, np.zeros(len(k)), np.full(len(k), np.inf), src, w, parent, path,
                  fresh, tag, sees), skip


def _visibility(sa, accel, surf: Surfaces, occluders: bool, counters, mine=None):
    """Light visibility of the level's points, ``(vis (nb L,) bool, occ (nb L,) int32 or
    None, traced)``: ``occ`` (with ``occluders``, closest-hit shadow rays) names each
    light's occluder (``OCC_NONE``, ``OCC_NOT_FACING``); ``traced``: shadow rays were
    traced. ``mine`` (nb,) int32 or None: the instance a point's any-hit shadow rays leave
    out (:func:`~.shaft_skip.own_instances`: they leave as its soft samples do)."""
    todo, so, sd, st = shadow_rays(sa, surf)
    vis = np.zeros(len(surf.sh_state), np.bool_)
    occ_inst = None
    if len(todo):
        zero = np.zeros(len(todo))
        if links_shadows(sa):
            occ_inst = first_blocker(sa, accel, so, sd, st, todo % len(sa.light_kind))
            vis[todo] = occ_inst < 0
        elif occluders:
            occ_inst = accel.closest_hit(so, sd, zero, st).inst
            vis[todo] = occ_inst < 0
        else:
            skip = None if mine is None else mine[todo // max(len(sa.light_kind), 1)]
            vis[todo] = ~any_hit_shadows(accel, so, sd, st, skip)
        _count(counters, "shadow", len(todo))
    occ = None
    if occluders:
        occ = np.full(len(vis), OCC_NOT_FACING, np.int32)
        if len(todo):
            occ[todo] = np.where(occ_inst < 0, OCC_NONE, occ_inst).astype(np.int32)
    return vis, occ, len(todo) > 0


def _occluded_by(sa, accel):
    """``occluded(origins, directions, tmax, rows)`` of :func:`soft_direct`: by any hit
    (:func:`~.light_linking.any_hit_shadows`), or with shadow linking by the light's
    blockers (:mod:`.light_linking`)."""
    L = len(sa.light_kind)

    def occluded(o, d, tmax, rows, skip=None):  # (skip: any_hit's)
        if not links_shadows(sa):
            return any_hit_shadows(accel, o, d, tmax, skip)
        return linked_occluded(sa, accel, o, d, tmax, np.where(rows >= 0, rows % max(L, 1),
                                                                 -1))
    if not links_shadows(sa) and hasattr(accel, "occluded_samples"):
        # the plain any-hit query: soft_visibility may trace the samples where they lie
        occluded.samples = accel.occluded_samples
    return occluded


@njit(cache=True, nogil=True)
def _light_masks(sh_state, vis, L, traced, lit):
    """Per point: light j in ``traced`` when a shadow ray to it was traced, in ``lit`` when
    it is visible. sh_state, vis : (n L,); traced, lit : (n, W) uint64 outputs
    (:mod:`.light_bits`)."""
    for i in range(traced.shape[0]):
        for w in range(traced.shape[1]):
            a = np.uint64(0)
            b = np.uint64(0)
            for j in range(64 * w, min(L, 64 * w + 64)):
                bit = np.uint64(1) << np.uint64(j - 64 * w)
                st = sh_state[i * L + j]
                if st == _SH_TRACE or st == SH_SOFT or st == SH_FAR:
                    a |= bit
                if vis[i * L + j]:
                    b |= bit
            traced[i, w] = a
            lit[i, w] = b


def _segments(front: _Front, hits: Hits, surf: Surfaces, vis, L: int, saw) -> dict:
    """The level's compact ray-tree nodes for the pixel records (see :func:`trace`)."""
    nb = len(front.src)
    traced = np.empty((nb, words(L)), np.uint64)
    lit = np.empty((nb, words(L)), np.uint64)
    _light_masks(surf.sh_state, vis, L, traced, lit)
    return dict(ray=front.src, parent=front.parent, inst=hits.inst, point=surf.P,
                dir=surf.VD, traced=traced, lit=lit,
                seen=np.zeros(nb, np.bool_) if saw is None else saw)


def _light_terms(front: _Front, hits: Hits, surf: Surfaces, seeds, tvp) -> dict:
    """A level's nodes for :mod:`.light_records`: the path weight and light terms
    (:func:`shade`'s), the material (-1: a miss), and what shading one light again needs:
    the ray, its hit and the node's seed (:func:`surfaces` rebuilds the rest)."""
    return dict(weight=front.weight, t_val=tvp[0], t_on=tvp[1], mat=surf.mat, o=front.o,
                d=front.d, t=hits.t, inst=hits.inst, prim=hits.prim, u=hits.u, v=hits.v,
                seed=seeds)


def _tree_level(front: _Front, hits: Hits, surf: Surfaces, vis, occ, L: int) -> dict:
    nb = len(front.src)
    mask = np.empty((nb, words(L)), np.uint64)
    _light_masks(np.full(nb * L, _SH_TRACE, np.int8), vis, L, np.empty_like(mask), mask)
    return dict(ray=front.src, parent=front.parent, path=front.path, inst=hits.inst,
                tri=hits.prim, origin=front.o, point=surf.P, mask=mask,
                occ=occ.reshape(nb, L))


def _ray_tree(levels: list[dict], L: int) -> RayTree:
    cat = np.concatenate
    total = sum(len(lv["ray"]) for lv in levels)
    return RayTree(
        node_ray=cat([lv["ray"] for lv in levels]).astype(np.int32),
        node_parent=cat([lv["parent"] for lv in levels]).astype(np.int32),
        node_path=cat([lv["path"] for lv in levels]).astype(np.int64),
        node_inst=cat([lv["inst"] for lv in levels]).astype(np.int32),
        node_tri=cat([lv["tri"] for lv in levels]).astype(np.int32),
        node_origin=cat([lv["origin"] for lv in levels]).reshape(total, 3),
        node_point=cat([lv["point"] for lv in levels]).reshape(total, 3),
        node_light_mask=cat([lv["mask"] for lv in levels]).reshape(total, words(L)),
        node_occluder=cat([lv["occ"] for lv in levels]).reshape(total, L).astype(np.int32),
    )


def trace(sa: SceneArrays, accel, origins, directions, tmin, tmax, max_depth: int,
          record: bool = False, primary: Hits | None = None, counters: dict | None = None,
          segments: list | None = None, cancel=None, seeds: np.ndarray | None = None,
          light_samples: int = LIGHT_SAMPLES_DEFAULT, terms: bool = False,
          glossy_samples: int = GLOSSY_SAMPLES_DEFAULT, roots: str = "all",
          camera_lights: bool = True, skip_keys: np.ndarray | None = None,
          strata: Strata | None = None):
    """Whitted radiance of a batch of ``n`` rays, and optionally their ray trees.

    sa : the scene's :class:`~.geometry.scene.SceneArrays`; accel : an accelerator over
    it (:func:`~rstrace_engine.accel.accelerators.create_accelerator`).
    origins, directions : (n, 3) float64 (directions need not be unit); tmin, tmax : (n,)
    float64 (or scalars) bounds of the input rays. max_depth : reflection/refraction
    bounces (0: direct light only). record : also return the :class:`RayTree`.
    primary : optional :class:`~rstrace_engine.accel.accelerators.Hits` of the input rays (e.g.
    from ``intersect_object``), used instead of ``accel.closest_hit`` for the first level.
    counters : optional dict; ``primary``, ``secondary`` and ``shadow`` ray counts are added.
    segments : optional list; for every depth level a dict of arrays is appended, the compact
    ray-tree nodes the per-pixel records keep (:mod:`.pixel_records`): ``ray`` (input ray),
    ``parent`` (row of the parent node, rows numbered level after level, -1 for roots),
    ``inst`` (-1: a miss), ``point`` (hit point), ``dir`` (unit ray direction), ``traced``
    and ``lit`` (uint64 light bits: shadow ray traced / light visible), ``seen`` (bool: the
    ray saw a light's own surface). Cheaper than ``record`` (shadow rays stay any-hit
    queries).
    cancel : optional ``cancel() -> bool``, polled between the queries of every depth level:
    once it says stop, the rest is skipped and the result is incomplete (the caller polls
    ``cancel()`` itself and discards it; see :mod:`rstrace_engine.cancel`).
    seeds : (n,) uint64 seeds of the input rays for the samples of lights with an extent
    and of the world (:func:`~.soft_lights.sample_seeds` of their global sample ids; by
    default the rays' indices, which makes the samples depend on the batch);
    light_samples : shadow samples per such light and point. terms : with ``segments``, its
    dicts also hold each node's light terms and what re-shading one light needs
    (:func:`_light_terms`, for :mod:`.light_records`). glossy_samples : rays a path draws
    at its first rough reflection or refraction, by lobe (:func:`~.glossy_rays.glossy_counts`;
    deeper ones draw one; docs/glossy.md), seeded like the soft lights' samples.
    roots : which part of the radiance: ``"all"``; ``"own"``, a root on a rough surface
    spawns no rays (the root's own light, and what its mirror and refraction rays bring
    where it is not rough: the part radiance interpolants hold); ``"below"``, the roots'
    own light (emission, direct and world light) left out and their shadow rays not
    traced (what the rays they spawn bring: the rest, traced per pixel,
    :mod:`~..interpolants.glossy_term`). ``"own"`` plus ``"below"`` of a rough root is
    ``"all"``: the same rays, seeds and weights.
    camera_lights : the input rays are camera rays: they see the lights visible to the
    camera (:mod:`.seen_lights`; mirror and refraction rays below them see the lights
    visible to glossy and transmission rays whatever this says). False for rays that are
    not the camera's (the interpolants' lattice lines).
    skip_keys : (n,) int64 group keys of the input rays (their pixels' tiles): the shadow
    rays of lights proven fully visible per key and instance are skipped, the radiance the
    same bit for bit (:mod:`.shaft_skip`, which also says what ``counters`` gains).
    strata : the input rays' pixels and sample indices (:func:`~.glossy_strata.pixel_strata`):
    a pixel's rough points draw from one lattice per path and count
    (:mod:`.glossy_strata`); None: each point its own.

    Returns ``(radiance (n, 3) float64, RayTree or None)``.
    """
    front = _input_front(origins, directions, tmin, tmax, primary, camera_lights)
    max_depth = int(max_depth)
    if max_depth < 0:
        raise ValueError(f"trace: max_depth {max_depth} < 0")
    if roots not in ("all", "own", "below"):
        raise ValueError(f"trace: roots {roots!r} is not 'all', 'own' or 'below'")
    if roots == "below" and record:
        raise ValueError("trace: no ray trees of the part below the roots")
    L = len(sa.light_kind)
    radiance = np.zeros((len(front.src), 3))
    nodes = record or segments is not None  # ray-tree node rows are followed
    soft_on = has_soft_light(sa)
    seen_on = any_seen(sa, (SEEN_CAMERA,) if max_depth == 0 else
                       (SEEN_CAMERA, SEEN_GLOSSY, SEEN_TRANSMISSION))
    glossy_on = draws_glossy(sa, max_depth)
    terms = terms and segments is not None
    need_seeds = soft_on or terms or glossy_on
    if need_seeds:
        root = (sample_seeds(np.arange(len(front.src)), 0) if seeds is None
                else np.ascontiguousarray(seeds, np.uint64))
        if len(root) != len(front.src):
            raise ValueError(f"trace: {len(root)} seeds for {len(front.src)} rays")
    levels: list[dict] = []
    n_nodes = 0
    skip = None  # the front's rays' own instances (own_reflections)
    for level in range(max_depth + 1):
        nb = len(front.src)
        if nb == 0 or cancelled(cancel):
            break
        if level == 0 and primary is not None:
            hits = _as_hits(primary)
        else:
            hits = _as_hits(accel.closest_hit(front.o, front.d, front.t0, front.t1,
                                              *(() if skip is None else (skip,))))
        _count(counters, "primary" if level == 0 else "secondary", nb)
        surf = surfaces(sa, front.o, front.d, front.t1, hits)
        own = level > 0 or roots != "below"  # the roots' own light is wanted
        mine = (own_instances(sa, accel, surf, hits.inst, hits.prim) if (soft_on or glossy_on)
                and (own or level < max_depth) else None)
        if own:
            vis, occ, traced = _visibility(sa, accel, surf, record, counters, mine)
        else:
            vis, occ, traced = np.zeros(nb * L, np.bool_), None, False
        soft = None
        nseeds = None
        if need_seeds:
            nseeds = node_seeds(root, front.src, front.path)
            if glossy_on and level > 0:
                nseeds ^= front.tag
        if soft_on and own:
            proven = (proven_rows(sa, accel, surf, hits.inst, skip_keys, counters,
                                  hits.prim, mine)
                       if level == 0 else None)
            soft = soft_direct(sa, surf, nseeds, int(light_samples), vis,
                               _occluded_by(sa, accel), counters, occ, proven, mine)
            traced = traced or len(soft.w) > 0
        if traced and cancelled(cancel):
            break
        spawn = level < max_depth
        lat = None if strata is None else (
            lambda g, c, f=front: lattices(strata, f.src, f.path, f.fresh, g, c))
        shaded = _shade_level(sa, hits, surf, vis, front.weight, spawn, soft, terms, nseeds,
                              front.fresh, int(glossy_samples), lat)
        contrib, kids = shaded[0], shaded[1]
        if own:
            scatter_add(radiance, front.src, contrib)
        saw = None
        if seen_on and own:  # the lights' own surfaces the rays cross (after the shading)
            miss = hits.inst < 0
            lrad = seen(sa, front.o, front.d, front.t0, np.where(miss, front.t1, hits.t),
                        miss, front.sees, front.weight)
            saw = lrad.any(axis=1)
            if saw.any():
                scatter_add(radiance, front.src[saw], lrad[saw])
        if level == 0 and roots == "own" and glossy_on:
            _drop_rough_roots(kids, shaded[-1])
        if segments is not None:
            segments.append(_segments(front, hits, surf, vis, L, saw))
            if soft_on:  # the world's rays, for the pixel records to regenerate
                segments[-1].update(normal=surf.NS, seed=nseeds, n_soft=int(light_samples),
                                    n_lights=L)
                if soft is not None and soft.n[0] <= VIS_BITS_MAX:
                    # and the hits' soft samples' visibility (shadow_reshade.py)
                    bits = np.empty((nb, L + 1), np.uint64)
                    soft_bits(soft.start, soft.light, soft.vis, int(soft.n[0]), bits)
                    segments[-1]["soft_bits"] = bits
            if terms:
                segments[-1].update(_light_terms(front, hits, surf, nseeds, shaded[2]))
        if record:
            levels.append(_tree_level(front, hits, surf, vis, occ, L))
        if not spawn:
            break
        rows = np.arange(n_nodes, n_nodes + nb, dtype=np.int32) if nodes else None
        front, skip = _next_front(front, kids, rows, shaded[-1], nseeds, mine, surf,
                                  counters)
        n_nodes += nb
    return radiance, (_ray_tree(levels, L) if record else None)


def _drop_rough_roots(kids: Spawned, plan: _Plan) -> None:
    """The rays spawned by rough root points dropped (``trace(roots="own")``)."""
    if plan.gstart is None:
        return
    kids.ok[np.repeat(plan.glossy, 2 * np.diff(plan.gstart))] = False


def trace_pixels(sa: SceneArrays, accel, cp, pixels: np.ndarray, jitter: np.ndarray,
                 max_depth: int, cancel=None, counters: dict | None = None,
                 segments: list | None = None, gids: np.ndarray | None = None,
                 seed: int = 0, light_samples: int = LIGHT_SAMPLES_DEFAULT,
                 terms: bool = False, glossy_samples: int = GLOSSY_SAMPLES_DEFAULT,
                 spp: int | None = None):
    """Whitted radiance of the camera rays through ``pixels`` (k,) int64 at ``jitter``
    (k, 2) float64 (``cp``: the camera's :class:`~.geometry.cameras.CameraParams`), a
    frame's tile: small tiles run on one thread, and ``cancel`` is bound to ``accel``
    (:func:`trace` for ``counters``, ``segments`` and ``cancel``). Returns ``(radiance
    (k, 3) float64, primary instance (k,) int32)``. ``gids`` (k,) int64: the samples'
    global ids (``sample * width * height + pixel``; default: sample 0 of each pixel),
    which with ``seed`` seed the soft lights' samples (:func:`~.soft_lights.sample_seeds`);
    ``terms``: the segments keep the light terms too (:func:`trace`); ``spp``: the frame's
    samples per pixel, whose glossy samples are stratified per pixel
    (:func:`~.glossy_strata.pixel_strata`; None: per sample)."""
    if gids is None:
        gids = pixels
    with threads_for(len(pixels)), bound(accel, cancel):
        o, d, tmin, tmax = camera_rays(cp, pixels, jitter)
        hits = accel.closest_hit(o, d, tmin, tmax)
        rad, _ = trace(sa, accel, o, d, tmin, tmax, max_depth, primary=hits,
                       counters=counters, segments=segments, cancel=cancel,
                       seeds=sample_seeds(gids, seed), light_samples=light_samples,
                       terms=terms, glossy_samples=glossy_samples,
                       skip_keys=tile_keys(pixels, cp.width),
                       strata=None if spp is None else frame_strata(
                           sa, max_depth, gids, cp.width * cp.height, seed, spp))
    return rad, np.ascontiguousarray(hits.inst, np.int32)


def render(scene: Scene, settings: RenderSettings | None = None, accel=None, progress=None,
           cancel=None, records=None, pixels: np.ndarray | None = None,
           base: Frame | None = None) -> Frame:
    """Render ``scene``'s camera with the base tracer, in tiles of rows.

    settings : :class:`~rstrace_engine.frame.RenderSettings` (``max_depth``, ``samples``,
    ``seed``, ``accelerator`` are used; the mode is not looked at). accel : an accelerator
    over ``scene.arrays()``; built from ``settings.accelerator`` when omitted.
    progress(fraction, message) is called after every tile; cancel() -> bool is polled
    before every tile and between the queries within one, and a cancelled frame keeps the
    tiles completed before it (``stats["cancelled"]``; the tile in progress is dropped,
    and its records too). With a :class:`~rstrace_engine.cancel.CancelFlag` the BVH's
    traversal stops within a few dozen rays of it being set. Returns a
    :class:`~rstrace_engine.frame.Frame`: radiance (h, w, 3)
    float32, rows bottom-up; pixel_class ``CLASS_TRACED`` where a primary ray hit,
    ``CLASS_BACKGROUND`` elsewhere. Samples whose radiance is NaN, infinite or above
    ``tolerances.RADIANCE_MAX`` are left out of the pixel average and counted in
    ``stats["nonfinite_samples"]``.

    Incremental frames: with ``pixels`` ((h * w,) bool) only those pixels are traced (every
    sample, with the same jitter as a full frame, so they come out bit for bit as a full
    frame's) and the others are copied from ``base``, the previous frame of the same camera.
    records : optional :class:`~.pixel_records.PixelRecords` that receives the ray trees of
    every traced sample (then ``records.finish`` folds them in, replacing the old trees of
    the traced pixels).
    """
    settings = (settings or RenderSettings()).validated()
    heap.keep()  # a batch's arrays on pages already touched (heap.py)
    t_start = time.perf_counter()
    sa = scene.arrays()
    build_s = 0.0
    if accel is None:
        tb = time.perf_counter()
        accel = create_accelerator(settings.accelerator, sa, **settings.accelerator_options())
        build_s = time.perf_counter() - tb
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    depth = int(settings.max_depth)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    if pixels is not None:
        if base is None or base.radiance.shape[:2] != (h, w):
            raise ValueError("render: an incremental frame needs the previous frame of the "
                             "same camera as base")
        pixels = np.asarray(pixels, bool).reshape(h * w)
        image = base.radiance.reshape(h * w, 3).copy()
        pclass = base.pixel_class.reshape(h * w).copy()
    else:
        image = np.zeros((h * w, 3), np.float32)
        pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
    # per-light records kept (tracing.light_records; not when over their cap)
    terms = (records is not None and records.light is not None
             and records.light.overflow is None)
    counters: dict = {}
    bad_total = 0
    cancelled_ = False
    rows_done = 0
    traced_pixels = 0
    batches = frame_batches(w, h, spp, int(settings.seed), rows_per_tile, pixels)
    if pixels is not None and not pixels.any():  # nothing dirty (e.g. a relit frame)
        batches = iter(())
        rows_done = h
    for pix, jitter, y1 in batches:
        if cancelled(cancel):
            cancelled_ = True
            break
        npx = len(pix)
        if npx == 0:
            rows_done = y1
            continue
        segs = [] if records is not None else None
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h) + pix[None, :]).ravel()
        rad, inst = trace_pixels(sa, accel, cp, np.tile(pix, spp), jitter.reshape(-1, 2),
                                 depth, cancel, counters, segs, gids, int(settings.seed),
                                 int(settings.light_samples), terms,
                                 int(settings.glossy_samples), spp)
        if cancelled(cancel):  # the tile is incomplete: keep nothing of it
            cancelled_ = True
            break
        traced_pixels += npx
        with threads_for(npx * spp):
            if records is not None:
                records.add(gids, segs)
            out = np.empty((npx, 3), np.float32)
            pc = np.empty(npx, np.uint8)
            bad_total += accumulate(rad, inst, spp, out, pc)
        image[pix] = out
        pclass[pix] = pc
        rows_done = y1
        if progress is not None:
            progress(y1 / h, f"traced {y1}/{h} rows")
    elapsed = time.perf_counter() - t_start
    shadow = counters.get("shadow", 0)
    rays = counters.get("primary", 0) + counters.get("secondary", 0) + shadow
    if bad_total:
        log.warning("render: %d sample(s) with NaN/infinite radiance left out", bad_total)
    stats = dict(
        time_s=elapsed, accel_build_s=build_s, accelerator=getattr(accel, "name", "?"),
        rays_traced=rays, primary_rays=counters.get("primary", 0),
        secondary_rays=counters.get("secondary", 0), shadow_rays=shadow,
        shadow_rays_skipped=counters.get("shadow_skipped", 0), skip_s=counters.get("skip_s", 0.0),
        shadow_rays_own_skip=counters.get("shadow_own_skip", 0), skip_rows=counters.get(
            "skip_rows", 0), secondary_rays_own_skip=counters.get("secondary_own_skip", 0),
        skip_rows_proven=counters.get("skip_rows_proven", 0),
        rays_per_s=rays / elapsed if elapsed > 0 else 0.0,
        width=w, height=h, samples=spp, max_depth=depth, rows_done=rows_done,
        cancelled=cancelled_, nonfinite_samples=bad_total,
        triangles=scene.triangle_count, instances=scene.n_instances,
        degenerate_triangles=int(scene.stats.get("degenerate_triangles", 0)),
        warnings=list(scene.warnings), incremental=pixels is not None,
        traced_pixels=traced_pixels,
    )
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats)
