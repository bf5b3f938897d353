"""Object edits under soft light, at the level of rays (BASE, issue 20 item 5).

A point lit by a light with an extent or by the world shoots ``n`` shadow rays per such
light (:mod:`.soft_lights`); an object moved, added or deleted near it may cross a few of
them. The per-pixel records find, per sample, *which* of its rays may cross an edited box
(:meth:`~.pixel_records.PixelRecords.dirty_split`): a sample whose primary ray, secondary
nodes and hard lights' shadow rays are untouched, and only some lights' (or the world's)
shadow rays at its primary hit may change, is not traced again. Its primary node's terms of
those lights are shaded again (:func:`reshade`), the others kept, and the frame is
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
"""

from __future__ import annotations

import time

import numpy as np

from ..accel.accelerators import Hits
from .batches import threads_for
from .light_nodes import WORLD, term_of
from .light_reshade import _one_light_states, tick
from .shader import Surfaces
from .soft_lights import soft_visibility
from .whitted import _occluded_by, shade, surfaces


def _surfaces(sa, geo: dict) -> Surfaces:
    """The nodes' surfaces, rebuilt by the tracer's surface stage from their rays and hits
    (as :meth:`~.light_records._Part.surfaces`)."""
    k = len(geo["t"])
    hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
    no_lights = sa._replace(light_kind=np.empty(0, sa.light_kind.dtype))
    with threads_for(k):
        return surfaces(no_lights, geo["o"], geo["d"], np.full(k, np.inf), hits)


def _light_term(sa, accel, j: int, n: int, geo: dict, surf: Surfaces, counters):
    """Light ``j``'s (an extent's) terms at the nodes: ``(present (k,), value (k, 3), lit
    (k,))``."""
    k = len(geo["t"])
    L = len(sa.light_kind)
    state = np.empty(k, np.int8)
    with threads_for(k):
        _one_light_states(sa, j, surf.P, surf.NG, surf.NS, surf.Q, surf.mat, state,
                          np.empty(k, np.int32))
        sh_state = np.full((k, L), -2, np.int8)
        sh_state[:, j] = state
        sf = Surfaces(*surf[:7], sh_state.reshape(-1))
        sa1 = sa._replace(world_light=np.zeros(3))  # (the world's term is not this one)
        soft, rows, any_vis = soft_visibility(sa1, sf, geo["seed"], n, sf.sh_state,
                                              _occluded_by(sa, accel), counters)
        vis = np.zeros(k * L, np.bool_)
        vis[rows[rows >= 0]] = any_vis[rows >= 0]
        hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
        _, _, (tv, tp) = shade(sa1, hits, sf, vis, np.ones((k, 3)), False, soft, True)
    return tp[:, j], tv[:, j], vis.reshape(k, L)[:, j]


def _world_term(sa, accel, n: int, spawn: bool, geo: dict, surf: Surfaces, counters):
    """The world's terms at the nodes: ``(present (k,), value (k, 3))``. ``spawn``: the
    level spawns rays (a rough point's world samples then light its diffuse part only)."""
    k = len(geo["t"])
    L = len(sa.light_kind)
    with threads_for(k):
        sh_state = np.full(k * L, -2, np.int8)
        sf = Surfaces(*surf[:7], sh_state)
        soft, _, _ = soft_visibility(sa, sf, geo["seed"], n, sh_state,
                                     _occluded_by(sa, accel), counters)
        hits = Hits(geo["t"], geo["inst"], geo["prim"], geo["u"], geo["v"])
        _, _, (tv, tp) = shade(sa, hits, sf, np.zeros(k * L, np.bool_), np.ones((k, 3)),
                               spawn, soft, True, seeds=geo["seed"])
    return tp[:, L], tv[:, L]


def reshade(lr, sa, accel, lights: np.ndarray, world: np.ndarray, light_samples: int,
            spawn: bool, counters: dict | None = None) -> dict:
    """Shade again, at the primary nodes of the per-light records ``lr`` (with geometry),
    the lights with an extent whose bits ``lights`` (n_rays,) uint64 name and the world's
    light where ``world`` (n_rays,) bool, through ``accel`` over the edited scene ``sa``;
    their entries replaced, every other term kept. Returns ``{j: (rows, lit)}``: each
    light's nodes and its visibility bit there (for the pixel records). ``spawn``: primary
    nodes spawn rays (ray depth > 0). ``counters``: adds ``shadow`` and ``split`` seconds."""
    split = {} if counters is None else counters.setdefault("split", {})
    t0 = time.perf_counter()
    p = lr.p
    rows = np.flatnonzero(((lights != 0) | world) & p.hit)  # (a miss has no shadow ray)
    out: dict = {}
    if len(rows) == 0:
        return out
    sub = p.take(rows)  # (the nodes, their terms and geometry; a dragged light's folded)
    sub.fold()
    geo = sub.geo
    surf = _surfaces(sa, geo)
    tick(split, "surfaces", t0)
    n = int(light_samples)
    L = len(sa.light_kind)
    changes = []
    for j in range(L):
        sel = np.flatnonzero((lights[rows] >> np.uint64(j)) & np.uint64(1))
        if len(sel) == 0:
            continue
        t0 = time.perf_counter()
        g = {key: x[sel] for key, x in geo.items()}
        s = Surfaces(*(x[sel] for x in surf[:7]), surf.sh_state)
        on, val, lit = _light_term(sa, accel, j, n, g, s, counters)
        changes.append((j, sel, on, val))
        out[j] = (rows[sel], lit)
        tick(split, "shade", t0)
    sel = np.flatnonzero(world[rows])
    if len(sel):
        t0 = time.perf_counter()
        g = {key: x[sel] for key, x in geo.items()}
        s = Surfaces(*(x[sel] for x in surf[:7]), surf.sh_state)
        on, val = _world_term(sa, accel, n, spawn, g, s, counters)
        changes.append((WORLD, sel, on, val))
        tick(split, "shade", t0)
    t0 = time.perf_counter()
    for c, sel, on, val in changes:
        d_on, d_val = term_of(sub.start, sub.slot, sub.val, c)
        d_on[sel] = on
        d_val[sel] = val
        sub.replace_slot(c, d_on, d_val)
    lr.p = p.splice(rows, sub)
    tick(split, "terms", t0)
    return out
