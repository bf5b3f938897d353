"""A light's power or colour change in INTERPOLANT mode rescales the interpolants it shades
(issue 21 item 4, ``interpolants/relight.py``) instead of invalidating them -- where the
radiance test still passes on the rescaled samples; a cell whose bound breaks is invalidated.

Every relit frame is held to the bound: its maximum display error against a fresh BASE frame
of the edited scene is at most epsilon, as is a fresh INTERPOLANT session's, and its traced
pixels are the base tracer's.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from bound_scenes import soft_penumbra

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
from rstrace_engine.geometry.edits import LightSet, WorldColor
from rstrace_engine.geometry.scene import SceneError
from rstrace_engine.interpolants import interpolant_cache
from rstrace_engine.interpolants.predicate import radiance_ok
from rstrace_engine.interpolants.relight import light_scale
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.session import Session
from rstrace_engine.tracing.world_samples import WorldSamples

EPS = 0.05
FLOAT_TOL = 1e-6  # float32 frames (see tests/test_interpolant_bound.py)


@pytest.fixture(autouse=True)
def cells_always(monkeypatch):
    """Cells are built wherever the predicate allows (no measured fallback), from few rays."""
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 12)


def _spheres():
    return SOAK_SCENES["spheres"](96, 72)


def _soft():
    return soft_penumbra("PERSP")


SCENES = {"spheres": (_spheres, "Key"), "soft_penumbra": (_soft, "Area")}


def settings(**kw) -> RenderSettings:
    return RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3, **kw)


def session(scene, terms: bool, **kw) -> Session:
    s = Session(scene.copy(), settings(**kw))
    s.light_terms = terms
    return s


def edit(sess: Session, key: str, power: float = 1.0, color=None) -> list:
    li = sess.scene.lights[sess.scene.light_slot(key)]
    return [LightSet(key, replace(li, power=li.power * power,
                                  color=li.color if color is None else color))]


def check_bound(frame, scene) -> float:
    """The frame and a fresh INTERPOLANT frame of ``scene`` within epsilon of its BASE
    frame (maximum display error), traced pixels exact; returns the frame's error."""
    base = Session(scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    fresh = Session(scene.copy(), settings()).render()
    errs = []
    for f in (frame, fresh):
        m = image.compare(f.radiance, base.radiance, EPS)
        assert m["max_error"] <= EPS + FLOAT_TOL, m
        traced = (f.pixel_class != CLASS_INTERPOLATED) & (f.pixel_class != CLASS_REBUILT)
        np.testing.assert_allclose(f.radiance[traced], base.radiance[traced], atol=1e-6)
        errs.append(m["max_error"])
    return errs[0]


def _cells(cache) -> dict:
    """Live interpolants by their cell (tree, depth, coord): their corner radiance."""
    a, p = cache.trees.arrays, cache.pool
    out = {}
    for q in np.flatnonzero(p.live):
        nd = p.node[q]
        out[(int(a.tree[nd]), int(a.depth[nd]), tuple(int(c) for c in a.coord[nd]))] = (
            p.rad[q].copy())
    return out


@pytest.mark.parametrize("name", sorted(SCENES))
def test_power_and_colour_rescale_interpolants(name):
    """Power, then colour: the light's interpolants are kept and rescaled (fewer rebuilt
    than the invalidation path, which a session without the shares still takes), their
    corners equal a fresh build's samples to float rounding, and both relit frames keep
    the bound."""
    make, key = SCENES[name]
    scene = make()
    new, old = session(scene, True), session(scene, False)
    f0 = new.render()
    old.render()
    assert (f0.pixel_class == CLASS_INTERPOLATED).mean() > 0.1
    assert f0.stats["interpolant_shares_mb"] > 0.0
    for step in (dict(power=0.6), dict(power=1.3, color=(1.0, 0.7, 0.45))):
        rep = new.apply(edit(new, key, **step))
        rep_old = old.apply(edit(old, key, **step))
        assert rep_old.rescaled_interpolants == 0 and rep_old.invalidated_interpolants > 0
        assert rep.rescaled_interpolants > 0  # the mechanism ran
        assert rep.invalidated_interpolants < rep_old.invalidated_interpolants
        frame = new.render()
        frame_old = old.render()
        if rep.invalidated_interpolants == 0:  # rescaled pixels are not shown as rebuilt
            assert not (frame.pixel_class == CLASS_REBUILT).any()
        assert (frame_old.pixel_class == CLASS_REBUILT).any()
        assert frame.stats["cells_built"] < frame_old.stats["cells_built"]
        check_bound(frame, new.scene)
        # a rescaled cell's corners are what a fresh build of the edited scene samples
        fresh = session(new.scene, True)
        fresh.render()
        kept, built = _cells(new.interpolants.cache), _cells(fresh.interpolants.cache)
        common = [k for k in kept if k in built]
        assert len(common) >= rep.rescaled_interpolants // 2
        for k in common:
            np.testing.assert_allclose(kept[k], built[k], rtol=1e-9, atol=1e-12)


def test_huge_power_increase_breaks_the_bound_and_invalidates():
    """Turned up 8 times, the key light takes some cells' interpolation error past the
    radiance test's margin (the display transform is not linear: the error of a rescaled
    cell is not the old one rescaled): those cells are invalidated, the others kept, and
    every kept cell passes the radiance test on its rescaled samples -- the test a fresh
    build runs. (Without the re-test these frames stayed within epsilon here, the test
    lines' half-epsilon margin and saturation hiding it: so the cells are checked.)"""
    scene = _spheres()
    sess = session(scene, True)
    sess.render()
    cache = sess.interpolants.cache
    rep = sess.apply(edit(sess, "Key", power=8.0))
    assert rep.rescale_invalidated > 0  # the bound broke for these
    assert rep.rescaled_interpolants > 0  # and held for others
    assert rep.invalidated_interpolants >= rep.rescale_invalidated
    assert cache.totals["rescaled"] == rep.rescaled_interpolants
    p, sm = cache.pool, cache.samples
    live = np.flatnonzero(p.live)
    assert len(live) == rep.rescaled_interpolants
    cs = np.concatenate([p.samples[live], p.tests[live]], axis=1)
    nsamp = (16 + np.count_nonzero(p.tests[live] >= 0, axis=1)).astype(np.int32)
    assert radiance_ok(sm.radiance(), cs, nsamp, EPS, sm.texture_terms(),
                       cache.tex_max).all()
    np.testing.assert_array_equal(p.rad[live], sm.radiance()[p.samples[live]])
    check_bound(sess.render(), sess.scene)


def test_shares_change_no_frame():
    """Keeping the shares traces the same rays: the frames are the same bit for bit."""
    scene = _soft()
    a = session(scene, True).render()
    b = session(scene, False).render()
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.pixel_class, b.pixel_class)


def test_shares_are_the_radiance_of_each_light():
    """A sample's radiance is its shares times the lights' intensities plus the rest
    (emission, the world): with every light at zero only the rest is left, so the shares
    reproduce a sample traced with one light alone."""
    scene = _spheres()
    scene.set_world_color((0.0, 0.0, 0.0))  # the mirror's misses add nothing then
    sess = session(scene, True)
    sess.render()
    c = sess.interpolants.cache
    share, shared = c.samples.shares()
    assert shared.mean() > 0.9
    sc = light_scale(c.sa)
    lit = np.einsum("nlc,lc->nc", share[shared], sc)
    rad = c.samples.radiance()[shared]
    # no emission, a black world: the lights are all of it
    np.testing.assert_allclose(lit, rad, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("cap_mb", [0.001, 0.0])
def test_shares_over_the_cap_fall_back_to_invalidation(cap_mb):
    """Over the cap (``relight_memory_mb``) cells are built without the shares, and said
    so; at 0 none are kept. A light's power then invalidates as before."""
    scene = _spheres()
    sess = session(scene, True, relight_memory_mb=cap_mb)
    f0 = sess.render()
    assert ("over the cap" if cap_mb else "is 0") in f0.stats["relight_off"]
    assert f0.stats["interpolant_shares_mb"] <= cap_mb
    rep = sess.apply(edit(sess, "Key", power=0.5))
    assert rep.rescaled_interpolants == 0 and rep.invalidated_interpolants > 0
    check_bound(sess.render(), sess.scene)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_a_moved_light_invalidates_by_its_shafts_and_relights_the_traced_pixels(name):
    """A moved (or resized) light keeps the cells its new place is proven on, the others
    are invalidated (``test_relight_interpolants_move.py``); the frame's traced samples
    shade that light again alone (as BASE's, ``light_reshade``), so their pixels are relit,
    not traced again -- a fresh BASE frame's bit for bit -- and the frame keeps the bound.
    A session without the records re-traces them."""
    make, key = SCENES[name]
    scene = make()
    new, old = session(scene, True), session(scene, False)
    new.render()
    old.render()
    for offset in ((0.4, 0.0, 0.0), (-0.2, 0.3, 0.1)):
        batch = []
        for sess in (new, old):
            li = sess.scene.lights[sess.scene.light_slot(key)]
            batch.append([LightSet(key, replace(
                li, position=tuple(np.asarray(li.position) + offset)))])
        rep, rep_old = new.apply(batch[0]), old.apply(batch[1])
        assert rep.relight and not rep_old.relight
        # (kept with its new term where it is proven, a light with an extent too)
        assert rep.rescaled_interpolants > 0
        assert rep.dirty_pixels < rep_old.dirty_pixels
        frame, frame_old = new.render(), old.render()
        assert frame.stats["relit"]
        assert frame.stats["relit_lights"] == [new.scene.light_slot(key)]
        assert frame.stats["relight_shadow_rays"] > 0
        assert frame.stats["traced_rays"] < frame_old.stats["traced_rays"]
        lr, rec = new.reuse.light_records, new.reuse.records
        relit = lr.relit_pixels(rec.spp, rec.n_pixels).reshape(frame.pixel_class.shape)
        assert relit.mean() > 0.1
        base = Session(new.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
        np.testing.assert_array_equal(frame.radiance[relit], base.radiance[relit])
        check_bound(frame, new.scene)
        check_bound(frame_old, old.scene)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_traced_pixels_are_relit_from_the_light_records(name):
    """A light's power or colour: the frame's traced pixels are recombined from the
    per-light records of its traced samples (as BASE relights), not traced again; only the
    pixels of its rescaled or invalidated interpolants and those with interpolated samples
    are rendered again. The relit pixels equal a fresh BASE frame's bit for bit, the frame
    keeps the bound."""
    make, key = SCENES[name]
    scene = make()
    new, old = session(scene, True), session(scene, False)
    new.render()
    old.render()
    for step in (dict(power=0.6), dict(power=1.3, color=(1.0, 0.7, 0.45))):
        rep, rep_old = new.apply(edit(new, key, **step)), old.apply(edit(old, key, **step))
        assert rep.relight and not rep_old.relight
        assert rep.dirty_pixels < rep_old.dirty_pixels
        frame, frame_old = new.render(), old.render()
        assert frame.stats["relit"] and frame.stats["relight_shadow_rays"] == 0
        assert frame.stats["traced_rays"] < frame_old.stats["traced_rays"]
        lr = new.reuse.light_records
        rec = new.reuse.records
        relit = lr.relit_pixels(rec.spp, rec.n_pixels).reshape(frame.pixel_class.shape)
        assert relit.mean() > 0.1
        base = Session(new.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
        np.testing.assert_array_equal(frame.radiance[relit], base.radiance[relit])
        check_bound(frame, new.scene)


# ----------------------------------------------------------------------------- the world


def _lit_world(make):
    """A bound test scene with a grey world that lights (its term left out of the
    interpolants and traced per interpolated pixel, docs/INTERPOLANTS.md)."""
    def build():
        s = make()
        s.set_world_color((0.2, 0.22, 0.25), lights=True)
        return s
    return build


WORLD_SCENES = {"spheres": _lit_world(_spheres), "soft_penumbra": _lit_world(_soft)}


def _world_edit(sess: Session, colour=None, strength: float = 1.0, lights=None) -> list:
    c = sess.scene.world_color if colour is None else np.asarray(colour)
    return [WorldColor(tuple(float(x) for x in np.asarray(c) * strength), lights)]


@pytest.mark.parametrize("name", sorted(WORLD_SCENES))
def test_world_colour_and_strength_recombine(name):
    """The world's colour, then its strength, changed while it lights: nothing is traced
    and nothing rebuilt -- the traced pixels are recombined from their light records (a
    fresh BASE frame's bit for bit), the interpolated ones from their interpolated part and
    their own world term rescaled (``R' + c * world``, the world term kept per sample) --
    and the frame equals a fresh INTERPOLANT frame within epsilon (maximum asserted)."""
    scene = WORLD_SCENES[name]()
    new, old = session(scene, True), session(scene, False)
    first = new.render()
    old.render()
    assert first.stats["interpolated_fraction"] > 0.2
    pool = new.interpolants.cache.pool
    shows_world = int(np.count_nonzero(pool.world & pool.live))
    for step in (dict(colour=(0.4, 0.3, 0.15)), dict(strength=2.5)):
        rep, rep_old = new.apply(_world_edit(new, **step)), old.apply(_world_edit(old, **step))
        assert rep.relight and not rep_old.relight
        # only interpolants whose trees show the world (a reflection of the sky) go
        assert rep.invalidated_interpolants == shows_world
        assert rep.dirty_pixels < rep_old.dirty_pixels
        frame, frame_old = new.render(), old.render()
        assert frame.stats["relit"] and frame.stats["relight_shadow_rays"] == 0
        if shows_world == 0:
            assert rep.dirty_pixels == 0
            assert frame.stats["traced_rays"] == 0 and frame.stats["shadow_rays"] == 0
            assert frame.stats["cells_built"] == 0
        assert frame.stats["traced_rays"] < frame_old.stats["traced_rays"]
        lr, rec = new.reuse.light_records, new.reuse.records
        traced = lr.relit_pixels(rec.spp, rec.n_pixels).reshape(frame.pixel_class.shape)
        world_kept = lr.relit_pixels(rec.spp, rec.n_pixels, world=True).reshape(
            frame.pixel_class.shape) & ~traced
        assert traced.mean() > 0.1 and world_kept.mean() > 0.1
        base = Session(new.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
        np.testing.assert_array_equal(frame.radiance[traced], base.radiance[traced])
        fresh = Session(new.scene.copy(), settings()).render()
        m = image.compare(frame.radiance, fresh.radiance, EPS)
        assert m["max_error"] <= EPS + FLOAT_TOL, m
        # without the records every pixel is rendered again, from the kept interpolants
        assert frame_old.stats["cells_built"] <= shows_world
        m = image.compare(frame_old.radiance, base.radiance, EPS)
        assert m["max_error"] <= EPS + FLOAT_TOL, m
        # (the same cells a fresh session builds: its interpolated part differs by float
        # rounding of R' = L - W only)
        np.testing.assert_allclose(frame.radiance[world_kept], fresh.radiance[world_kept],
                                   rtol=1e-5, atol=1e-6)
        check_bound(frame, new.scene)
        pool = new.interpolants.cache.pool
        shows_world = int(np.count_nonzero(pool.world & pool.live))


@pytest.mark.parametrize("step", ["black", "background", "black_to_lit", "background_to_lit"])
def test_world_that_starts_or_stops_lighting_rebuilds(step):
    """A world edit that changes whether the world lights (black <-> a colour, or its
    lights flag) changes what every interpolant holds (its term at the roots is left out
    of the samples only while it lights): every interpolant is invalidated and the frame
    rendered again (not relit), within epsilon, traced pixels exact."""
    scene = WORLD_SCENES["soft_penumbra"]()
    if step.endswith("_to_lit"):
        scene.set_world_color((0.0, 0.0, 0.0) if step.startswith("black") else
                              (0.2, 0.22, 0.25), lights=not step.startswith("background"))
    sess = session(scene, True)
    sess.render()
    live = sess.interpolants.cache.pool.n_live
    assert live > 0
    edit = {"black": [WorldColor((0.0, 0.0, 0.0))],
            "background": [WorldColor((0.2, 0.22, 0.25), lights=False)],
            "black_to_lit": [WorldColor((0.3, 0.3, 0.35), lights=True)],
            "background_to_lit": [WorldColor((0.2, 0.22, 0.25), lights=True)]}[step]
    rep = sess.apply(edit)
    assert not rep.relight
    assert rep.invalidated_interpolants == live
    frame = sess.render()
    assert not frame.stats.get("relit")
    check_bound(frame, sess.scene)
    # and the next world colour edit, lighting before and after, recombines again
    if step.endswith("_to_lit"):
        rep = sess.apply(_world_edit(sess, strength=0.5))
        assert rep.relight and rep.dirty_pixels == 0
        check_bound(sess.render(), sess.scene)


@pytest.mark.parametrize("bad", [(float("nan"), 0.2, 0.2), (0.2, float("inf"), 0.2),
                                 (0.2, -0.1, 0.2)])
def test_bad_world_colour_keeps_the_frame(bad):
    """A NaN, infinite or negative world colour (or strength) is refused naming the world;
    nothing is applied, no relight is pending and the next frame is the previous one."""
    sess = session(WORLD_SCENES["soft_penumbra"](), True)
    first = sess.render()
    key = "Area"
    with pytest.raises(SceneError, match="world"):
        sess.apply(edit(sess, key, power=0.5) + [WorldColor(bad)])
    assert not sess.reuse.relight_due
    assert sess.scene.lights[sess.scene.light_slot(key)].power == 350.0  # nothing applied
    again = sess.render()
    np.testing.assert_array_equal(again.radiance, first.radiance)


def test_random_edits_with_a_world_that_lights():
    """Seeded random edit batches (every kind, the light extents) on a scene whose world
    lights, a world colour edit after each: every frame within epsilon of a fresh BASE
    frame (and a fresh INTERPOLANT session's), traced pixels BASE's; the world edits that
    keep it lighting and follow a frame with records are relit."""
    gen = EditGenerator(WORLD_SCENES["soft_penumbra"](), seed=31, camera=False,
                        extra=EditGenerator.SOFT_KINDS)
    sess = session(gen.scene, True)
    sess.render()
    rng = np.random.default_rng(7)
    relit = 0
    for _ in range(5):
        for batch in (gen.step(), [WorldColor(tuple(rng.uniform(0.05, 0.4, 3)))]):
            rep = sess.apply(batch)
            relit += rep.relight and any(isinstance(e, WorldColor) for e in batch)
            check_bound(sess.render(), sess.scene)
    assert relit >= 3, relit


def test_world_samples_follow_the_rendered_samples():
    """The kept world terms (``tracing/world_samples.py``): samples rendered again replace
    theirs (or drop them), stale rows are compacted away, and the recombined radiance is
    ``rest + coef * world`` of each sample's latest entry."""
    rng = np.random.default_rng(3)
    ws = WorldSamples(4000)
    want = np.full((4000, 3), np.nan)
    for _ in range(12):
        rays = rng.choice(4000, 1500, replace=False)
        on = rays[rng.random(len(rays)) < 0.6]
        coef, rest = rng.random((len(on), 3)), rng.random((len(on), 3))
        ws.set(rays, on, coef, rest)
        want[rays] = np.nan
        want[on] = rest + coef * np.array([0.3, 0.2, 0.1])[None, :]
        assert ws.stale <= ws.n - ws.stale or ws.n == 0
    rad = np.full((4000, 3), np.nan)
    ws.apply(rad, np.array([0.3, 0.2, 0.1]))
    np.testing.assert_array_equal(ws.ok, ~np.isnan(want[:, 0]))
    np.testing.assert_array_equal(rad, want)
    assert ws.nbytes < 4000 * 4 + 2 * 48 * 4000


def test_world_terms_of_samples_traced_again_are_dropped(monkeypatch):
    """A sample interpolated with its world term kept (``rest + coef * world``), then traced
    again by the base tracer -- here the whole frame after a light's power edit, the measured
    fallback (``fallback.py``) having judged its cells not worth building, which is what
    studio at 640x480 did -- holds its light records from then on, not the kept world term
    of its interpolated past. A later world colour edit recombines it from those records:
    before, the stale world entry won and the pixels kept the light's old power (up to 0.19
    of display error on studio). The relit pixels equal a fresh BASE frame's bit for bit,
    the frame is within epsilon of it."""
    from rstrace_engine.interpolants import invalidation

    scene = WORLD_SCENES["soft_penumbra"]()
    sess = session(scene, True)
    sess.render()
    kept = sess.reuse.light_records.world.ok.copy()
    # (the kept cells' pixels rendered again, not given the term from their cells:
    # interpolants/term_pixels.py; the fallback's verdict is what traces them)
    monkeypatch.setattr(invalidation, "term_edit", lambda *a, **k: None)
    assert kept.mean() > 0.1
    # the fallback's verdict for the next frame: the base tracer's frame, no cell
    monkeypatch.setattr(sess.interpolants, "auto_fallback", True)
    monkeypatch.setattr(type(sess.interpolants.cache.fallback), "whole_frame_traced",
                        lambda self: True)
    rep = sess.apply(edit(sess, "Area", power=0.5))
    assert rep.relight
    frame = sess.render()
    assert frame.stats["interpolated_fraction"] == 0.0
    lr, rec = sess.reuse.light_records, sess.reuse.records
    again = kept & np.tile(sess.reuse.frame.pixel_class.reshape(-1) != CLASS_INTERPOLATED,
                           rec.spp) & lr.ok
    assert again.sum() > 0.05 * len(again)  # interpolated before, traced (with terms) now
    assert not (lr.world.ok & again).any()
    check_bound(frame, sess.scene)
    monkeypatch.undo()
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    rep = sess.apply(_world_edit(sess, colour=(0.4, 0.3, 0.15)))
    assert rep.relight
    frame = sess.render()
    assert frame.stats["relit"]
    relit = lr.relit_pixels(rec.spp, rec.n_pixels).reshape(frame.pixel_class.shape)
    assert again.reshape(rec.spp, -1).all(axis=0).reshape(relit.shape)[relit].any()
    base = Session(sess.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
    np.testing.assert_array_equal(frame.radiance[relit], base.radiance[relit])
    check_bound(frame, sess.scene)
