"""A light added or deleted in INTERPOLANT mode adds or drops one term (issue 21 items 3 and
4, ``interpolants/added_light.py``, ``interpolants/relight.py``): the interpolant cache is
kept, each cell takes the added light's term where the predicate proves it for that light
and the radiance test still passes (else it is invalidated), a deleted light's term is
rescaled to zero; the frame's traced pixels are relit as BASE's.

Every frame is held to the bound: its maximum display error against a fresh BASE frame of
the edited scene is at most epsilon, and its traced pixels are the base tracer's.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_relight_interpolants import (  # noqa: F401 (cells_always: the autouse fixture)
    EPS,
    SCENES,
    cells_always,
    check_bound,
    session,
    settings,
)

from rstrace_engine.frame import CLASS_INTERPOLATED
from rstrace_engine.geometry.edits import LightDelete, LightSet
from rstrace_engine.geometry.scene import Light
from rstrace_engine.interpolants.invalidation import affected
from rstrace_engine.interpolants.predicate import radiance_ok
from rstrace_engine.session import Session


def _new_light(sess: Session, kind: str) -> Light:
    box = sess.scene.arrays().scene_aabb
    c = 0.5 * (box[0] + box[1])
    top = (c[0] + 0.2 * (box[1][0] - box[0][0]), c[1], box[0][2] + 0.8 * (box[1][2] - box[0][2]))
    if kind == "AREA":
        return Light("Added", "AREA", power=40.0, position=top, direction=(0.0, 0.0, -1.0),
                     size=(0.4, 0.4), glossy=False, transmission=False)  # (not seen)
    return Light("Added", kind, power=2.0 if kind == "SUN" else 40.0, position=top,
                 direction=(0.2, 0.1, -1.0))


def _live(cache) -> dict:
    """Live interpolant id -> (serial, corner radiance)."""
    p = cache.pool
    return {int(q): (int(p.serial[q]), p.rad[q].copy()) for q in np.flatnonzero(p.live)}


def _cells(cache) -> dict:
    a, p = cache.trees.arrays, cache.pool
    return {(int(a.tree[p.node[q]]), int(a.depth[p.node[q]]),
             tuple(int(c) for c in a.coord[p.node[q]])): p.rad[q].copy()
            for q in np.flatnonzero(p.live)}


@pytest.mark.parametrize("kind", ["POINT", "SPOT", "SUN"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_an_added_light_adds_its_term(name, kind):
    """The cache is kept (the old code started a new one: every interpolant gone, a full
    frame); interpolants the light reaches take its term, their corners equal to a fresh
    build's samples; the frame relights and keeps the bound; the kept cells pass their
    radiance test and are found by a later edit of the added light (its membership entries
    and shafts were added)."""
    make, _ = SCENES[name]
    sess = session(make(), True)
    f0 = sess.render()
    assert (f0.pixel_class == CLASS_INTERPOLATED).mean() > 0.1
    cache = sess.interpolants.cache
    before = _live(cache)
    rep = sess.apply([LightSet("Added", _new_light(sess, kind))])
    assert sess.interpolants.cache is cache, "the cache started over"
    assert not any("started over" in m for m in rep.messages)
    after = _live(cache)
    kept = [q for q, (s, _) in after.items() if q in before and before[q][0] == s]
    changed = [q for q in kept if not np.array_equal(after[q][1], before[q][1])]
    assert len(kept) > 0 and len(kept) + rep.invalidated_interpolants == len(before)
    assert rep.rescaled_interpolants == len(changed)
    frame = sess.render()
    assert frame.stats["relit"] and frame.stats["incremental"]
    assert frame.stats["dirty_fraction"] < 1.0
    check_bound(frame, sess.scene)
    fresh = Session(sess.scene.copy(), settings())
    fresh.light_terms = True
    fresh.render()
    check_kept_cells(sess, fresh.interpolants.cache, changed, kind)


def check_kept_cells(sess, fresh_cache, changed, kind):
    """After an added light: every kept cell passes its radiance test on its samples (with
    the new term); the corners of a kept cell are what a fresh build of the edited scene
    (``fresh_cache``) samples; a later edit of the added light finds the cells that took
    its term (``changed``), and so does an object put in its shaft from such a cell (its
    tunnels were added; not a sun's)."""
    cache = sess.interpolants.cache
    p, sm = cache.pool, cache.samples
    live = np.flatnonzero(p.live)
    cs = np.concatenate([p.samples[live], p.tests[live]], axis=1)
    ns = (16 + np.count_nonzero(p.tests[live] >= 0, axis=1)).astype(np.int32)
    assert radiance_ok(sm.radiance(), cs, ns, EPS, sm.texture_terms(), cache.tex_max).all()
    a, b = _cells(cache), _cells(fresh_cache)
    common = set(a) & set(b)
    assert common
    for key in common:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-12)
    j = sess.scene.light_slot("Added")
    hit = set(affected(cache, np.zeros((0, 2, 3)), lights=(j,)).ids.tolist())
    assert {q for q in changed if p.live[q]} <= hit
    lit = [q for q in changed if p.live[q] and kind != "SUN"]
    if lit:
        q = lit[0]
        root = sm._npoint[sm._nstart[p.samples[q, 0]]]
        mid = 0.5 * (root + np.asarray(sess.scene.arrays().light_pos[j]))
        box = np.stack([mid - 1e-3, mid + 1e-3])[None]
        assert q in set(affected(cache, box).ids.tolist())


@pytest.mark.parametrize("name", sorted(SCENES))
def test_a_deleted_light_drops_its_term(name):
    """Deleting a light rescales what it shaded to zero (the old code invalidated every
    interpolant it shaded: all rebuilt); fewer cells invalidated and built than a session
    without the shares, and the frame keeps the bound. Then a light added, then deleted
    again (its slot a tombstone)."""
    make, _ = SCENES[name]
    new, old = session(make(), True), session(make(), False)
    new.render()
    old.render()
    key = [li.name for li in new.scene.lights if li is not None][-1]
    rep = new.apply([LightDelete(key)])
    rep_old = old.apply([LightDelete(key)])
    assert rep_old.rescaled_interpolants == 0 and rep_old.invalidated_interpolants > 0
    assert rep.rescaled_interpolants > 0
    assert rep.invalidated_interpolants < rep_old.invalidated_interpolants
    frame, frame_old = new.render(), old.render()
    assert frame.stats["cells_built"] < frame_old.stats["cells_built"]
    check_bound(frame, new.scene)
    new.apply([LightSet("Added", _new_light(new, "POINT"))])  # (into the tombstone slot)
    check_bound(new.render(), new.scene)
    rep = new.apply([LightDelete("Added")])
    assert rep.rescaled_interpolants > 0
    check_bound(new.render(), new.scene)


def _with_and_without(monkeypatch, counted, switch, impls, make_scene, steps,
                      first_interpolated=None, bound=False):
    """Render ``steps(sess)``'s edit batches incrementally twice, with ``switch`` (module,
    name) set to ``impls[0]`` (the kept terms reused) then ``impls[1]`` (traced again);
    ``counted`` (module, name): the term kernel whose rows traced are counted. The frames
    must be equal bit for bit (and, ``bound``, within it); returns the traced rows per
    step, reused first."""
    traced = []
    module, name = counted
    orig = getattr(module, name)

    def count(sa, accel, o, *a, **k):
        traced.append(len(o))
        return orig(sa, accel, o, *a, **k)

    monkeypatch.setattr(module, name, count)
    frames, rows = [], []
    for impl in impls:
        monkeypatch.setattr(*switch, impl)
        sess = session(make_scene(), True)
        f0 = sess.render()
        if first_interpolated is not None:
            assert f0.stats["interpolated_fraction"] > first_interpolated
        out, n = [], []
        for edits in steps(sess):
            sess.apply(edits)
            traced.clear()
            f = sess.render()
            assert f.stats["incremental"]
            if bound:
                check_bound(f, sess.scene)
            out.append(f.radiance)
            n.append(sum(traced))
        frames.append(out)
        rows.append(n)
    for a, b in zip(*frames, strict=True):
        assert np.array_equal(a, b)
    return rows


def _render_again(monkeypatch) -> None:
    """The pixels of the cells a light edit keeps are rendered again, as before
    ``interpolants/term_pixels.py`` let them take the edit's term from their cells (as a
    rough root's pixels still are): what the kept world and sampled terms are for."""
    from rstrace_engine.interpolants import invalidation

    monkeypatch.setattr(invalidation, "term_edit", lambda *a, **k: None)


def test_pixels_rendered_again_keep_their_world_terms(monkeypatch):
    """While the world lights, an interpolated pixel a light edit renders again takes its
    world term from the one the records keep (``world_term.kept_world_term``: ``coef *
    world``, no world sample traced again) -- the frame bit for bit the one that traces
    them (the old code) -- while a pixel an object edit makes dirty traces them again."""
    from test_relight_interpolants import WORLD_SCENES

    from rstrace_engine.geometry.edits import ObjectTransform
    from rstrace_engine.interpolants import render, world_term

    kept = render.kept_world_term
    _render_again(monkeypatch)

    def steps(sess):
        m = sess.scene.instances[sess.scene.instance_slot("Blocker")]["matrix"].copy()
        m[0, 3] += 0.05  # (inside the scene's box: an incremental frame)
        return ([LightSet("Added", _new_light(sess, "POINT"))], [ObjectTransform("Blocker", m)],
                [LightSet("Added2", _new_light(sess, "SPOT"))])

    rows = _with_and_without(monkeypatch, (world_term, "world_term"),
                             (render, "kept_world_term"),
                             (kept, lambda lrec, *a: kept(None, *a)),
                             lambda: WORLD_SCENES["soft_penumbra"](), steps)
    assert rows[0][0] < rows[1][0] and rows[0][2] < rows[1][2]  # kept after a light edit
    assert rows[0][1] == rows[1][1]  # the object edit's dirty pixels traced again


def test_an_added_light_without_the_shares_invalidates():
    """A session that keeps no light terms (its cells keep no test lines): the cache is
    kept, every interpolant invalidated (their radiance test cannot be run again), and the
    frame keeps the bound."""
    make, _ = SCENES["spheres"]
    sess = session(make(), False)
    sess.render()
    cache = sess.interpolants.cache
    n = cache.pool.n_live
    rep = sess.apply([LightSet("Added", _new_light(sess, "POINT"))])
    assert sess.interpolants.cache is cache and rep.invalidated_interpolants == n
    check_bound(sess.render(), sess.scene)


def _spread_penumbra():
    """The soft penumbra with its area light given a spread: no closed form, so its
    sampled term is traced per interpolated pixel (``sampled_term.sampled_possible``)."""
    from dataclasses import replace

    scene = SCENES["soft_penumbra"][0]()
    j = scene.light_slot("Area")
    scene.set_light(j, replace(scene.lights[j], spread=1.2))
    return scene


def test_pixels_rendered_again_keep_their_sampled_terms(monkeypatch):
    """The sampled terms of lights with an extent, per interpolated pixel, are kept as the
    world term is (``sampled_term.add_sampled_terms`` with the records): a pixel a hard
    light's edit renders again takes its kept term -- the frame bit for bit the one that
    traces them all -- while an object edit's dirty pixels and an edit of the area light
    (its power: every kept term dropped) trace them again."""
    from dataclasses import replace

    from rstrace_engine.geometry.edits import ObjectTransform
    from rstrace_engine.interpolants import render, sampled_term

    kept = render.add_sampled_terms
    _render_again(monkeypatch)

    def steps(sess):
        m = sess.scene.instances[sess.scene.instance_slot("Blocker")]["matrix"].copy()
        m[0, 3] += 0.05
        area = sess.scene.lights[sess.scene.light_slot("Area")]
        return ([LightSet("Added", _new_light(sess, "POINT"))], [ObjectTransform("Blocker", m)],
                [LightSet("Added2", _new_light(sess, "SPOT"))],
                [LightSet("Area", replace(area, power=area.power * 1.5))],
                [LightDelete("Added")])

    rows = _with_and_without(monkeypatch, (sampled_term, "sampled_term"),
                             (render, "add_sampled_terms"),
                             (kept, lambda *a: kept(*a[:-1], None)), _spread_penumbra,
                             steps, first_interpolated=0.3, bound=True)
    assert rows[0][0] < rows[1][0] and rows[0][2] < rows[1][2] and rows[0][4] < rows[1][4]
    assert rows[0][1] == rows[1][1] and rows[0][3] == rows[1][3]  # traced again
