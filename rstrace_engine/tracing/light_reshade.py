"""A light shaded again alone at the nodes of the per-light records
(:meth:`~.light_records.LightRecords.relight`): its states at the rebuilt surfaces, its
shadow rays (or samples) where it faces a node, the shade kernel with it alone -- the
tracer's own stages, so the term is the one a fresh frame computes.

A point, spot or sun light is shaded as the scene's only light (:func:`_one_light`: slot
``j`` alone as slot 0, the world not lighting, so the shade kernel performs the same
operations on the same operands without the other lights' columns), in one batch; a light
with an extent keeps the scene's own slots (its samples are seeded by its slot), in batches.

Light linking is honoured as the tracer does it: the light's state is -2 at the nodes on
instances it does not light (its receivers, read from the nodes' hit instance), and its
shadow rays (and samples) are stopped only by its blockers (:mod:`.light_linking`, the
same query the tracer makes).
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from .. import stripes
from ..accel.accelerators import Hits
from ..geometry.scene import LIGHT_POINT, LIGHT_SPOT, SceneArrays
from ..views import fields, view_type
from .batches import TILE_RAYS, threads_for
from .light_linking import occluded
from .shader import _SH_TRACE, Surfaces, light_state
from .shading import rough_interface
from .shaft_skip import ball_rows, proven_rows, tile_keys
from .soft_lights import soft_visibility
from .whitted import shade, shadow_rays

_ReshadeScene = view_type("_ReshadeScene", SceneArrays, (
    "light_bound", "light_cos_inner", "light_cos_outer", "light_dir", "light_ext",
    "light_half", "light_kind", "light_pos", "light_recv", "light_spot_frame",
    "light_spot_scaled", "mat_ior", "mat_model", "mat_roughness", "mat_transmission",
    "scene_extent"), __name__)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _one_light_states(sa, j, P, NG, NS, Q, MAT, INST, state, mat, first, step):
    """Shadow-ray state (:func:`~.shader.light_state`) of light ``j`` at surface points
    on instances ``INST`` (-2 where light linking says it does not light the instance, as
    :func:`~.shader.unlinked_lights`), and their materials where it faces them (-1
    elsewhere: shaded as misses, no term). Serial over share ``first`` of ``step`` of the
    points, without numba's reference counting (:func:`one_light_states` runs the
    stripes, :func:`~rstrace_engine.stripes.run`; a ``prange`` over ``SceneArrays``' fields
    cost three times the compile, docs/first-render.md)."""
    sa = _ReshadeScene(*fields(sa, _ReshadeScene))  # the fields its loop reads
    linked = sa.light_recv.shape[0] > 0
    n = P.shape[0]
    # a contiguous share of the points (stripes.run): every point costs about the same, and
    # blocks dealt in turn shared cache lines of ``state`` and ``mat`` between threads
    for i in range(n * first // step, n * (first + 1) // step):
        if linked and sa.light_recv[j, INST[i]] == 0:
            state[i] = -2
        else:
            state[i] = light_state(sa, j, P[i, 0], P[i, 1], P[i, 2], NG[i, 0], NG[i, 1],
                                   NG[i, 2], NS[i, 0], NS[i, 1], NS[i, 2], Q[i, 0], Q[i, 1],
                                   Q[i, 2], rough_interface(sa, MAT[i]))
        mat[i] = MAT[i] if state[i] != -2 else -1


def one_light_states(sa, j, P, NG, NS, Q, MAT, INST, state, mat) -> None:
    """:func:`_one_light_states` over the points on the calling thread's numba thread count
    (:func:`~rstrace_engine.stripes.run`, each thread a contiguous share of the points)."""
    stripes.run(_one_light_states, stripes.blocks_of(len(P)), sa, j, P, NG, NS, Q, MAT, INST,
                state, mat)


def _one_light(sa: SceneArrays, j: int) -> SceneArrays:
    """``sa`` with light slot ``j`` alone (as slot 0) and the world not lighting: what the
    shader computes for slot 0 there is what it computes for ``j`` in ``sa`` (the same
    operands), without the other lights' columns."""
    return sa._replace(world_light=np.zeros(3), **{
        f: getattr(sa, f)[j:j + 1] for f in sa._fields
        if f.startswith("light_") and getattr(sa, f).shape[0] > 0})


#: a rebuilt surface's bytes (kept while a light is dragged)
SURF_BYTES = 5 * 24 + 1 + 4


def relight_light(lr, sa: SceneArrays, accel, j: int, light_samples: int,
                  counters: dict | None = None, tiles: tuple | None = None):
    """:meth:`~.light_records.LightRecords.relight` (the records ``lr``, with geometry):
    light ``j`` shaded again at every node of its primary and secondary parts; returns
    their light bits ``(traced, lit)``. ``tiles``: ``(pixels, width)`` of the frame (its
    primary nodes are sample ``s`` of pixel ``g % pixels``): a dragged point or spot light
    skips the shadow rays of the nodes proven to see it (:func:`_drag_proof`), a light
    with an extent the samples of the primary nodes proven to see all of it, per tile and
    instance as the tracer proves them (:func:`~.shaft_skip.proven_rows`)."""
    split = {} if counters is None else counters.setdefault("split", {})
    bits = []
    for part in (lr.p, lr.s):
        t0 = time.perf_counter()
        n = len(part)
        rows = np.flatnonzero(part.hit)
        # the rebuilt surfaces are kept while they fit under the cap
        keep = lr.nbytes + len(rows) * SURF_BYTES <= lr.cap
        surf = part.surfaces(sa, keep)
        tick(split, "surfaces", t0)
        faced = np.zeros(n, bool)
        lit = np.zeros(n, bool)
        if len(rows) == 0:
            part.detach(j, rows, np.zeros((0, 1), bool), np.zeros((0, 1, 3)))
        elif sa.light_ext[j]:
            relight_sampled(sa, accel, j, light_samples, part, rows, surf, faced, lit,
                            counters, split, tiles if part is lr.p else None)
        else:
            relight_hard(sa, accel, j, part, rows, surf, faced, lit, counters, split,
                         _ones(len(rows)), tiles if part is lr.p else None)
        bits.append((faced, lit))
    return bits[0], bits[1]


#: A dragged point or spot light's *ball*: its radius over the scene's extent. From the
#: drag's second step on, the primary nodes proven to see every point of a ball ahead of
#: the light (:func:`~.shaft_skip.ball_rows`, per 8x8 tile and instance) trace no shadow
#: ray while it stays in the ball; leaving it proves a new one. Larger balls are proven
#: for fewer steps' cost but hold fewer nodes (on museum, 0.5% -- 0.25 m -- holds 86% of
#: the rows that trace a ray; 1%, which reaches the ceiling above the light, 40%).
DRAG_BALL_REL = 0.005
#: tests: trace the proven nodes' shadow rays too and fail if any is occluded
CHECK_PROOFS = False


class _Proof:
    """A part's proof for dragged light ``j`` (kept on the part, :attr:`_Part.proof`): the
    accelerator's trees ``sb`` it read, the ball (``center``, ``radius``), ``proven`` (k,)
    bool over the part's surface rows (None: no proof), the light's last position."""

    def __init__(self, j, sb, center, radius, proven, last) -> None:
        self.j, self.sb, self.center, self.radius = j, sb, center, radius
        self.proven, self.last = proven, last

    @property
    def nbytes(self) -> int:
        return 0 if self.proven is None else int(self.proven.nbytes)


def _drag_proof(part, sa1, accel, j, rows, sf, state, tiles, counters, split):
    """(k,) bool the part's surface rows whose shadow ray to light ``j`` (``sa1``: it
    alone, as slot 0; a point or spot) is proven unoccluded, or None: the part's ball
    proof (:data:`DRAG_BALL_REL`) while the light is in its ball; a new one when the light
    left it by a drag-sized step (shorter than the radius); none at the first step."""
    if tiles is None or sa1.light_kind[0] not in (LIGHT_POINT, LIGHT_SPOT):
        part.proof = None
        return None
    pos = np.array(sa1.light_pos[0], np.float64)
    sb = getattr(accel, "sb", None)
    pf = part.proof
    if pf is None or pf.j != j or pf.sb is not sb:
        part.proof = _Proof(j, sb, None, 0.0, None, pos)  # (the drag's first step)
        return None
    traced = state == _SH_TRACE
    if pf.proven is not None and np.linalg.norm(pos - pf.center) <= pf.radius:
        pf.last = pos
        proven = pf.proven & traced
    else:
        t0 = time.perf_counter()
        radius = DRAG_BALL_REL * float(sa1.scene_extent)
        step = pos - pf.last
        length = float(np.linalg.norm(step))
        proven = None
        if 0.0 < length < radius:
            center = pos + (0.9 * radius / length) * step  # ahead of the light
            n_pixels, width = tiles
            proven = ball_rows(sa1, accel, 0, center, radius, sf, traced,
                               part.geo["inst"], tile_keys(rows % n_pixels, width),
                               prim=part.geo["prim"])
            part.proof = _Proof(j, sb, center, radius, proven, pos)
        else:
            part.proof = _Proof(j, sb, None, 0.0, None, pos)
        tick(split, "proof", t0)
    if proven is not None and counters is not None:
        counters["shadow_skipped"] = counters.get("shadow_skipped", 0) + int(proven.sum())
    return proven


def _check_proof(sa1, accel, sf, proven) -> None:
    """:data:`CHECK_PROOFS`: every proven node's shadow ray, traced, is unoccluded."""
    todo, so, sd, stmax = shadow_rays(sa1, sf._replace(
        sh_state=np.where(proven, sf.sh_state, np.int8(-2))))
    if len(todo) != int(proven.sum()):
        raise AssertionError("drag proof: a proven node traces no shadow ray")
    hit = occluded(sa1, accel, so, sd, stmax, np.zeros(len(todo), np.int64))
    if hit.any():
        raise AssertionError(f"drag proof: {int(hit.sum())} proven shadow rays occluded")


_ONES = [np.ones((0, 3))]


def _ones(k: int) -> np.ndarray:
    """(k, 3) ones: the path weights of the shade kernel's nodes (kept between steps; the
    shade kernel only reads them)."""
    if len(_ONES[0]) < k:
        _ONES[0] = np.ones((k, 3))
    return _ONES[0][:k]


#: the stages of a light's re-shading (:meth:`LightRecords.relight`'s ``split``)
SPLIT = ("surfaces", "states", "proof", "shadow_rays", "shade", "terms")


def tick(split: dict, name: str, t0: float) -> None:
    split[name] = split.get(name, 0.0) + time.perf_counter() - t0


def relight_hard(sa, accel, j, part, rows, surf, faced, lit, counters, split, ones,
                 tiles=None):
    """A point, spot or sun light: shaded as the only light of the scene (slot ``j``
    alone, as slot 0: the shader's operations on the same operands), its shadow rays
    only where it faces a node, one batch."""
    t0 = time.perf_counter()
    k = len(rows)
    sa1 = _one_light(sa, j)
    state = np.empty(k, np.int8)
    mat = np.empty(k, np.int32)
    # the states and the shadow rays' set-up: a few operations per node, on one thread
    # (on a busy machine a parallel region waits for a descheduled thread longer than
    # this work takes: 45-90 ms against 5-15, docs/RELIGHT.md)
    with threads_for(0):
        # the nodes it does not face are shaded as misses (no material read, no term)
        one_light_states(sa1, 0, surf.P, surf.NG, surf.NS, surf.Q, surf.mat,
                         part.geo["inst"], state, mat)
    sf = Surfaces(*surf[:5], mat, surf.Q, state)
    tick(split, "states", t0)
    with threads_for(k):
        # the nodes proven to see the whole ball the dragged light is in trace no ray
        proven = _drag_proof(part, sa1, accel, j, rows, sf, state, tiles, counters, split)
    t0 = time.perf_counter()
    sf_rays = sf if proven is None else sf._replace(
        sh_state=np.where(proven, np.int8(-2), state))
    with threads_for(0):
        todo, so, sd, stmax = shadow_rays(sa1, sf_rays)
    tick(split, "states", t0)
    with threads_for(k):
        t0 = time.perf_counter()
        vis = np.zeros(k, np.bool_)
        if proven is not None:
            vis[proven] = True  # (the proof holds the rows that trace a ray alone)
            if CHECK_PROOFS:
                _check_proof(sa1, accel, sf, proven)
        if len(todo):
            # (shadow linking: only the light's blockers stop them, as the tracer's
            # whitted._visibility; sa1's tables hold the light's row alone, as light 0)
            vis[todo] = ~occluded(sa1, accel, so, sd, stmax, np.zeros(len(todo), np.int64))
            if counters is not None:
                counters["shadow"] = counters.get("shadow", 0) + len(todo)
        tick(split, "shadow_rays", t0)
        t0 = time.perf_counter()
        g = part.geo
        hits = Hits(g["t"], g["inst"], g["prim"], g["u"], g["v"])
        _, _, (tv, tp) = shade(sa1, hits, sf, vis, ones, False, None, True)
        tick(split, "shade", t0)
    t0 = time.perf_counter()
    part.detach(j, rows, tp, tv)
    faced[rows] = state != -2
    lit[rows] = vis
    tick(split, "terms", t0)


def relight_sampled(sa, accel, j, light_samples, part, rows, surf, faced, lit, counters,
                    split, tiles=None):
    """A light with an extent: its samples are seeded by its slot, so it is shaded in
    the scene's own slots, in batches of the surface rows. ``tiles``: ``(pixels, width)``
    of the frame, for the primary nodes: their samples proven unoccluded are not traced
    (the base tracer's shaft skip, :func:`~.shaft_skip.proven_rows`)."""
    t0 = time.perf_counter()
    state = np.empty(len(rows), np.int8)
    with threads_for(len(rows)):
        one_light_states(sa, j, surf.P, surf.NG, surf.NS, surf.Q, surf.mat,
                         part.geo["inst"], state, np.empty(len(rows), np.int32))
    tick(split, "states", t0)
    faced[rows] = state != -2
    on = np.zeros(len(rows), bool)
    nval = np.zeros((len(rows), 3))
    # contiguous batches of the surface rows (views, no copies) of the tracer's tile size:
    # their samples' arrays stay cache-sized (batches of 2^18 rows, 4 M samples, took
    # 0.75-0.9 s of a studio move against 0.55 s); the rows the light does not face trace
    # no shadow ray and get no term
    step = TILE_RAYS
    keys = None if tiles is None else tile_keys(rows % tiles[0], tiles[1])
    for a in range(0, len(rows), step):
        sub = slice(a, min(a + step, len(rows)))
        if not (state[sub] != -2).any():
            continue
        t0 = time.perf_counter()
        li, tp, tv = shade_one(sa, accel, j, light_samples, part.geo, surf, sub,
                               state[sub], counters, None if keys is None else keys[sub])
        tick(split, "shade", t0)
        lit[rows[sub]], on[sub], nval[sub] = li, tp, tv
    t0 = time.perf_counter()
    part.detach(j, rows, on.reshape(-1, 1), nval.reshape(-1, 1, 3))
    tick(split, "terms", t0)
def shade_one(sa, accel, j, light_samples, geo, surf, sub, state, counters, keys=None):
    """Light ``j``'s terms at the surface rows ``sub`` (a slice) of ``geo`` / ``surf``
    (its states ``state`` there), by the tracer's own stages: ``(visible, present,
    value)``. ``keys``: the rows' tiles, primary nodes: the samples of the rows proven
    to see all of the light are not traced (:func:`~.shaft_skip.proven_rows`)."""
    L = len(sa.light_kind)
    k = len(state)
    g = {key: geo[key][sub] for key in ("t", "inst", "prim", "u", "v", "seed")}
    sh_state = np.full((k, L), -2, np.int8)
    sh_state[:, j] = state
    sf = Surfaces(*(x[sub] for x in surf[:7]), sh_state.reshape(-1))
    hits = Hits(g["t"], g["inst"], g["prim"], g["u"], g["v"])
    with threads_for(k):
        todo, so, sd, stmax = shadow_rays(sa, sf)
        vis = np.zeros(k * L, np.bool_)
        if len(todo):
            vis[todo] = ~occluded(sa, accel, so, sd, stmax, todo % L)
            if counters is not None:
                counters["shadow"] = counters.get("shadow", 0) + len(todo)
        sa1 = sa._replace(world_light=np.zeros(3))  # the world's samples are not redone
        soft = None
        if sa.light_ext[j]:
            def blocked(o, dd, tmax, r):  # (as whitted._occluded_by: the light's blockers)
                return occluded(sa, accel, o, dd, tmax, np.where(r >= 0, r % L, -1))
            proven = (None if keys is None else
                      proven_rows(sa, accel, sf, g["inst"], keys, counters,
                                  g["prim"]))
            soft, srows, any_vis = soft_visibility(
                sa1, sf, g["seed"], int(light_samples), sf.sh_state, blocked, counters,
                proven)
            vis[srows[srows >= 0]] = any_vis[srows >= 0]
        _, _, (tv, tp) = shade(sa1, hits, sf, vis, np.ones((k, 3)), False, soft, True)
    return vis.reshape(k, L)[:, j], tp[:, j], tv[:, j]
