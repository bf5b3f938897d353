"""A moved hard light keeps the interpolants its new place is proven on (issue 21 item 3 in
INTERPOLANT mode, ``interpolants/moved_light.py``): its old term dropped, the new one
shaded at the kept samples, each cell checked for it as a fresh build checks it (predicate
and radiance test), the cell's old tunnels and membership entries replaced by the new
ones, and the kept cells' pixels given the difference of their corners (``term_pixels``).
Before, every interpolant with a state for the light (every cell with a hit) was
invalidated and rebuilt or traced.

Every frame is held to the bound: its maximum display error against a fresh BASE frame of
the edited scene at most epsilon (asserted, ``check_bound``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from bound_scenes import soft_sun
from test_relight_interpolants import (  # noqa: F401 (cells_always: the autouse fixture)
    EPS,
    SCENES,
    cells_always,
    check_bound,
    edit,
    session,
)
from test_relight_interpolants_terms import _compare, _run

from rstrace_engine.bench.soak import SOAK_SCENES, soft_room_unlit_world
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry.edits import LightSet
from rstrace_engine.geometry.scene import Light, Material
from rstrace_engine.interpolants import invalidation
from rstrace_engine.interpolants.invalidation import _members, affected
from rstrace_engine.interpolants.membership import _entry_keys
from rstrace_engine.interpolants.predicate import radiance_ok
from rstrace_engine.interpolants.samples import hit_materials
from rstrace_engine.interpolants.shafts import glossy_materials
from rstrace_engine.session import Session
from rstrace_engine.tracing.soft_lights import OCC_SOFT

MOVABLE = invalidation.movable_lights
MOVE_TERMS = invalidation.move_terms


def _room():
    return SOAK_SCENES["room"](96, 72)


def _soft_room():
    return soft_room_unlit_world(96, 72)


MAKE = {"spheres": SCENES["spheres"][0], "room": _room,
        "soft_penumbra": SCENES["soft_penumbra"][0], "soft_room": _soft_room,
        "soft_sun": lambda: soft_sun("PERSP")}


def _moved(sess: Session, key: str, step: str) -> list:
    """The edit batch of ``step`` on light ``key``: moved, a spot turned or re-coned, the
    sun turned."""
    li = sess.scene.lights[sess.scene.light_slot(key)]
    if step == "move":
        new = replace(li, position=tuple(np.asarray(li.position) + (0.6, 0.4, -0.2)))
    elif step == "rotate":
        new = replace(li, direction=tuple(np.asarray(li.direction) + (0.15, -0.1, 0.0)))
    elif step == "cone":
        new = replace(li, spot_size=0.8 * li.spot_size)
    elif step == "lift":  # (a sphere light close to the floor: up, away from its horizon)
        new = replace(li, position=tuple(np.asarray(li.position) + (0.3, 0.2, 0.3)))
    elif step == "size":  # an area light resized
        new = replace(li, size=(1.3 * li.size[0], 1.15 * li.size[1]))
    elif step == "radius":  # a sphere light resized
        new = replace(li, radius=0.7 * li.radius)
    elif step == "angle":  # a sun's angle
        new = replace(li, angle=1.5 * li.angle)
    else:  # "sun"
        new = replace(li, direction=tuple(np.asarray(li.direction) + (0.1, 0.05, 0.0)))
    return [LightSet(key, new)]


def _cells(cache) -> dict:
    a, p = cache.trees.arrays, cache.pool
    return {(int(a.tree[p.node[q]]), int(a.depth[p.node[q]]),
             tuple(int(c) for c in a.coord[p.node[q]])): p.rad[q].copy()
            for q in np.flatnonzero(p.live)}


def _live_keys(index, pool) -> dict:
    """Live interpolant id -> the set of keys its live entries in membership ``index``
    hold."""
    a = index.arrays
    keys = np.empty(len(a.nxt), np.int64)
    _entry_keys(a, keys)
    out: dict = {}
    for e in range(index.n):
        q = int(a.q[e])
        if pool.live[q] and pool.serial[q] == a.serial[e]:
            out.setdefault(q, set()).add(int(keys[e]))
    return out


def _live_entries(index, pool) -> int:
    """Live entries of membership ``index`` (a key listed twice for a cell counts twice)."""
    a = index.arrays
    return sum(1 for e in range(index.n)
               if pool.live[a.q[e]] and pool.serial[a.q[e]] == a.serial[e])


CASES = [("spheres", "Key", "move"), ("room", "Lamp", "move"), ("room", "Spot", "rotate"),
         ("room", "Spot", "cone"), ("room", "Sun", "sun")]
#: lights with an extent: moved, resized (their sampled terms per pixel, their proof the
#: soft-light shaft to the whole extent)
SOFT_CASES = [("soft_penumbra", "Area", "move"), ("soft_penumbra", "Area", "size"),
              ("soft_penumbra", "Near", "lift"), ("soft_penumbra", "Near", "radius"),
              ("soft_room", "Lamp", "move"), ("soft_room", "Sun", "angle"),
              ("soft_room", "Sun", "sun"), ("soft_room", "Area", "size")]


@pytest.mark.parametrize(("name", "key", "step"), CASES + SOFT_CASES)
def test_a_moved_light_keeps_the_cells_it_is_proven_on(monkeypatch, name, key, step):
    """The same edit with and without the move path (``movable_lights`` switched off: the
    old code's invalidation): fewer cells invalidated and built, fewer pixels rendered;
    the kept cells pass their radiance test, their corners are a fresh build's samples,
    their membership entries are exactly those of their trees now (the old light's gone)
    and the new shaft finds them; the frame keeps the bound."""
    make = MAKE[name]
    new, old = session(make(), True), session(make(), True)
    f0 = new.render()
    old.render()
    assert (f0.pixel_class == CLASS_INTERPOLATED).mean() > 0.1
    cache = new.interpolants.cache
    live0 = cache.pool.n_live
    rep = new.apply(_moved(new, key, step))
    monkeypatch.setattr(invalidation, "movable_lights", lambda *a: [])
    rep_old = old.apply(_moved(old, key, step))
    monkeypatch.setattr(invalidation, "movable_lights", MOVABLE)
    assert new.interpolants.cache is cache
    kept = np.flatnonzero(cache.pool.live)
    assert len(kept) > 0 and len(kept) + rep.invalidated_interpolants == live0
    assert rep.invalidated_interpolants < rep_old.invalidated_interpolants
    assert cache.totals["terms_moved"] == len(kept)
    d_new, d_old = new.dirty_mask.sum(), old.dirty_mask.sum()
    assert d_new < d_old
    frame, frame_old = new.render(), old.render()
    assert frame.stats["relit"] and frame.stats["incremental"]
    assert frame.stats["cells_built"] < frame_old.stats["cells_built"]
    err = check_bound(frame, new.scene)
    assert err <= EPS
    p, sm = cache.pool, cache.samples
    live = np.flatnonzero(p.live)
    cs = np.concatenate([p.samples[live], p.tests[live]], axis=1)
    ns = (16 + np.count_nonzero(p.tests[live] >= 0, axis=1)).astype(np.int32)
    assert radiance_ok(sm.radiance(), cs, ns, EPS, sm.texture_terms(), cache.tex_max).all()
    # the corners of a kept cell are what a fresh build of the edited scene samples
    fresh = Session(new.scene.copy(), RenderSettings(mode="INTERPOLANT", epsilon=EPS,
                                                     max_depth=3))
    fresh.light_terms = True
    fresh.render()
    a, b = _cells(cache), _cells(fresh.interpolants.cache)
    common = set(a) & set(b)
    assert common
    for k in common:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=1e-12)
    # every kept cell's membership entries are those of its trees now (no old occluder)
    okeys, oc, lkeys, lc, _ = _members(sm.view(), np.ascontiguousarray(cs, np.int32), ns)
    objs, lights = _live_keys(cache.deps.objects, p), _live_keys(cache.deps.lights, p)
    o0, l0 = np.concatenate([[0], np.cumsum(oc)]), np.concatenate([[0], np.cumsum(lc)])
    for i, q in enumerate(live.tolist()):
        assert objs.get(q, set()) == set(okeys[o0[i]:o0[i + 1]].tolist())
        assert lights.get(q, set()) == set(lkeys[l0[i]:l0[i + 1]].tolist())
    # ... and its tunnels and entries are as many as recording the kept cells afresh makes
    # (the old light's shafts and entries are gone, not left beside the new ones)
    ref = invalidation.Dependencies(cache.sa)
    ref._set_domain(cache.deps.domain)
    ref.rst = invalidation.RaySegmentTrees(ref.domain, ref.slack)
    a_ = cache.trees.arrays
    tree = a_.tree[p.node[live]].astype(np.int64)
    ref.add(cache, live.astype(np.int32), tree // 6, tree % 6, a_.depth[p.node[live]],
            a_.coord[p.node[live]], p.zlo[live], p.zhi[live], cs, ns)
    assert cache.deps.rst.live_count(p.serial, p.live) == ref.rst.live_count(p.serial, p.live)
    for idx in ("objects", "lights"):
        assert (sum(map(len, _live_keys(getattr(cache.deps, idx), p).values()))
                == _live_entries(getattr(cache.deps, idx), p)
                == _live_entries(getattr(ref, idx), p))
    # an object put in the moved light's new shaft from a lit kept cell finds it
    j = new.scene.light_slot(key)
    if step in ("move", "lift"):
        for q in live:
            s0 = p.samples[q, 0]
            if sm._nocc[sm._nstart[s0], j] not in (-1, OCC_SOFT):  # (lit at its root)
                continue
            root = sm._npoint[sm._nstart[s0]]
            mid = 0.5 * (root + np.asarray(new.scene.arrays().light_pos[j]))
            box = np.stack([mid - 1e-3, mid + 1e-3])[None]
            assert q in set(affected(cache, box).ids.tolist())
            break
        else:
            pytest.fail("no kept cell lit by the moved light")


@pytest.mark.parametrize(("name", "key", "step"), [
    CASES[0], CASES[1], CASES[4], SOFT_CASES[0], SOFT_CASES[4], ("soft_sun", "Soft", "move")])
def test_moved_light_pixels_take_the_term(monkeypatch, name, key, step):
    """The kept cells' pixels take the difference of their corners: the frame equals the
    one that renders them again from the same cells (``term_edit`` off), to float32
    rounding, and renders fewer pixels. (The room's spot, turned or re-coned, changes no
    kept cell's corners: the cells it lights fail on its cone's edge or were traced.) A
    light with an extent: no kept cell of these scenes is on a glossy root (soft_sun's
    ball keeps none); those are
    ``test_a_moved_light_with_an_extent_renders_its_glossy_cells_pixels``'s."""
    def steps(sess):
        return [[_moved(sess, key, step)]]

    monkeypatch.setitem(SCENES, "room", (_room, key))
    dirty, f = _compare(monkeypatch, MAKE[name], steps)[0]
    assert f.stats["term_pixels"] > 0


def test_a_light_dragged_and_relit_in_batches(monkeypatch):
    """A drag: the key light moved three times, a frame after each, then a power change
    and a move in two batches before one frame (the power change's corner terms are taken
    with the shares before the move: taken at the frame, they would use the moved
    light's), then a move back: each frame within the bound and equal to the one that
    renders the kept cells' pixels again."""
    term_edit = invalidation.term_edit

    def run(old):
        monkeypatch.setattr(invalidation, "term_edit",
                            (lambda *a, **k: None) if old else term_edit)
        sess = session(MAKE["spheres"](), True)
        sess.render()
        frames = []
        def move():
            return _moved(sess, "Key", "move")

        for batches in ([move], [move], [move], [lambda: edit(sess, "Key", power=0.7), move]):
            for b in batches:
                sess.apply(b())  # (each move from where the last one left the light)
            f = sess.render()
            assert f.stats["incremental"] and f.stats["relit"]
            check_bound(f, sess.scene)
            frames.append(f)
        return sess, frames

    sess, new = run(False)
    _, old = run(True)
    for f_new, f_old in zip(new, old, strict=True):
        np.testing.assert_allclose(f_new.radiance, f_old.radiance, rtol=1e-6, atol=1e-6)
    assert all(f.stats["term_pixels"] > 0 for f in new)
    assert sess.interpolants.cache.totals["terms_moved"] > 0


def _spot_penumbra():
    """The soft penumbra with a spot with a radius over the floor: a light without a closed
    form (its whole term is sampled, per pixel, :mod:`~rstrace_engine.interpolants.
    sampled_term`)."""
    s = MAKE["soft_penumbra"]()
    s.add_light(Light("Cone", "SPOT", power=300.0, position=(1.2, 0.5, 2.5),
                      direction=(0.0, 0.0, -1.0), spot_size=1.0, radius=0.15))
    return s


def test_a_moved_light_without_a_closed_form_renders_its_cells_pixels(monkeypatch):
    """A spot with a radius moved: the cells its new place is proven on (fully visible over
    them) are kept, but its term at their pixels is sampled per pixel (none of it is in the
    corners): those pixels are rendered again, not given the corners' difference -- given
    it, they would keep the spot's old light (the frame out of the bound). Each frame
    within the bound, equal to the one that renders every kept cell's pixels again."""
    kept = []

    def move_terms(*a):
        r = MOVE_TERMS(*a)
        kept.append(len(r.kept))
        return r

    monkeypatch.setattr(invalidation, "move_terms", move_terms)

    def steps(sess):  # (each move from where the last one left the spot)
        for _ in range(2):
            yield [_moved(sess, "Cone", "move")]

    new = _run(monkeypatch, _spot_penumbra, steps, False)
    assert len(kept) == 2 and min(kept) > 0
    old = _run(monkeypatch, _spot_penumbra, steps, True)
    for (d_new, f_new), (d_old, f_old) in zip(new, old, strict=True):
        assert f_new.stats["term_pixels"] == 0
        np.testing.assert_array_equal(d_new, d_old)
        np.testing.assert_allclose(f_new.radiance, f_old.radiance, rtol=1e-6, atol=1e-6)


def _glossy_floor():
    """soft_sun with a Ward floor (a glossy lobe, no glossy rays: not a rough root): the
    sphere light's highlight on it is its sampled term, per pixel, under kept cells."""
    s = soft_sun("PERSP")
    slot = s.instance_slot("Floor")
    s.set_instance_materials(slot, [s.add_material(Material(
        "ward", diffuse=(0.55, 0.55, 0.5), specular=(0.2,) * 3, roughness=0.3))])
    return s


def test_a_moved_light_with_an_extent_renders_its_glossy_cells_pixels(monkeypatch):
    """A sphere light moved over a glossy (not rough) floor: cells are kept there, but the
    light's glossy lobe is its sampled term, per pixel: their pixels are rendered again
    (given the corners' difference alone they would keep the old highlight); each frame
    within the bound, equal to the one that renders every kept cell's pixels again."""
    glossy = []

    def move_terms(cache, old_sa, sa, accel, slots):
        r = MOVE_TERMS(cache, old_sa, sa, accel, slots)
        inst = (cache.trees.arrays.tree[cache.pool.node[r.kept]] // 6).astype(np.int64)
        m = hit_materials(sa, inst, cache.pool.cls[r.kept])
        glossy.append(int(np.count_nonzero(glossy_materials(sa)[np.maximum(m, 0)])))
        return r

    monkeypatch.setattr(invalidation, "move_terms", move_terms)

    def steps(sess):
        return [[_moved(sess, "Soft", "move")]]

    new = _run(monkeypatch, _glossy_floor, steps, False)  # (each frame within the bound)
    assert glossy and min(glossy) > 0  # (kept cells on the glossy floor)
    # their corners hold the closed form alone, as a fresh build's (the light's sampled
    # term taken off its new shares: else the pixels would add it twice)
    sess = session(_glossy_floor(), True)
    sess.render()
    sess.apply(steps(sess)[0][0])
    sess.render()
    fresh = Session(sess.scene.copy(), RenderSettings(mode="INTERPOLANT", epsilon=EPS,
                                                      max_depth=3))
    fresh.light_terms = True
    fresh.render()
    a, b = _cells(sess.interpolants.cache), _cells(fresh.interpolants.cache)
    common = set(a) & set(b)
    assert len(common) >= min(glossy)
    for k in common:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=1e-12)
    old = _run(monkeypatch, _glossy_floor, steps, True)
    for (_, f_new), (_, f_old) in zip(new, old, strict=True):
        np.testing.assert_allclose(f_new.radiance, f_old.radiance, rtol=1e-6, atol=1e-6)
