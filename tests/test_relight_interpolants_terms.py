"""The pixels of the cells a light edit keeps take its term from their cells, not rendered
again (issue 21 items 3 and 4 in INTERPOLANT mode, ``interpolants/term_pixels.py``): an
added light's term, a deleted light's, a power change's -- interpolated at each pixel's
line in its cell -- and an added light's cells that it leaves dark leave their pixels as
they are. Before, every pixel with an interpolated sample was rendered again.

Every frame is held to the bound (its maximum display error against a fresh BASE frame at
most epsilon, asserted) and equals, to float32 rounding, the frame that renders those
pixels again from the same cells (the old code's: ``term_edit`` switched off).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_relight_interpolants import (  # noqa: F401 (cells_always: the autouse fixture)
    EPS,
    FLOAT_TOL,
    SCENES,
    WORLD_SCENES,
    _world_edit,
    cells_always,
    check_bound,
    edit,
    session,
)
from test_relight_interpolants_add import _new_light

from rstrace_engine import image
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry.edits import LightDelete, LightSet, ObjectTransform
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Light
from rstrace_engine.interpolants import invalidation
from rstrace_engine.session import Session

ROUNDING = 1e-6  # float32 frames: a pixel's value plus its term, against the sum re-rendered


TERM_EDIT = invalidation.term_edit


def _run(monkeypatch, make, steps, old: bool, **kw):
    """Render ``make()``'s scene, then each list of batches of ``steps(sess)``, applied
    before one frame; ``old``: the old code's path (the kept cells' pixels rendered again,
    ``term_edit`` switched off). Returns ``[(dirty mask before the frame, frame), ...]``."""
    monkeypatch.setattr(invalidation, "term_edit", (lambda *a, **k: None) if old else TERM_EDIT)
    sess = session(make(), True, **kw)
    sess.render()
    out = []
    for frame_batches in steps(sess):
        for batch in frame_batches:
            sess.apply(batch)
        dirty = sess.dirty_mask.reshape(-1)
        f = sess.render()
        assert f.stats["incremental"] and f.stats["relit"]
        if kw:  # (against BASE with the same samples)
            base = Session(sess.scene.copy(), RenderSettings(mode="BASE", max_depth=3, **kw))
            err = image.compare(f.radiance, base.render().radiance, EPS)["max_error"]
            assert err <= EPS + FLOAT_TOL, err
        else:
            check_bound(f, sess.scene)
        out.append((dirty, f))
    return out


def _compare(monkeypatch, make, steps, **kw):
    """Both ways: the frames equal to float32 rounding; the new one renders none of the
    pixels the old one did not and leaves out those that took a term. Returns the new
    run's ``(dirty, frame)`` list."""
    new = _run(monkeypatch, make, steps, False, **kw)
    old = _run(monkeypatch, make, steps, True, **kw)
    for (d_new, f_new), (d_old, f_old) in zip(new, old, strict=True):
        np.testing.assert_allclose(f_new.radiance, f_old.radiance, rtol=ROUNDING,
                                   atol=ROUNDING)
        assert f_old.stats.get("term_pixels", 0) == 0
        assert not (d_new & ~d_old).any()  # (the old code's dirty pixels: a superset)
        assert d_new.sum() + f_new.stats["term_pixels"] <= d_old.sum()
        assert d_new.sum() < d_old.sum() or d_old.sum() == 0
    return new


@pytest.mark.parametrize("step", ["add_point", "add_spot", "delete", "power"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_kept_cells_pixels_take_the_term(monkeypatch, name, step):
    """An added light, a deleted one, a power change: the pixels of the cells that keep
    their interpolant are not rendered; the frame equals the one that renders them (to
    float32 rounding) and keeps the bound."""
    make, key = SCENES[name]

    def steps(sess):
        return [[{"add_point": [LightSet("Added", _new_light(sess, "POINT"))],
                  "add_spot": [LightSet("Added", _new_light(sess, "SPOT"))],
                  "delete": [LightDelete(key)],
                  "power": edit(sess, key, power=0.6)}[step]]]

    dirty, f = _compare(monkeypatch, make, steps)[0]
    pi = f.pixel_interpolant.reshape(-1)
    assert ((pi >= 0) & ~dirty).sum() >= f.stats["term_pixels"]
    if step != "add_spot":  # (the spot lights none of the kept cells: their pixels stay)
        assert f.stats["term_pixels"] > 0


def test_samples_of_a_pixel_take_their_own_terms(monkeypatch):
    """Four samples per pixel (jittered lines): each sample takes the term at its own line
    in the cell, the pixel their mean -- the old code's frame to rounding."""
    make, key = SCENES["spheres"]

    def steps(sess):
        return [[[LightSet("Added", _new_light(sess, "POINT"))]], [[LightDelete(key)]]]

    for _, f in _compare(monkeypatch, make, steps, samples=4):
        assert f.stats["term_pixels"] > 0


def test_cells_an_added_light_leaves_dark_keep_their_pixels(monkeypatch):
    """A light added under the floor (facing none of what the camera sees, its shadow
    everywhere else): the cells that keep their interpolant have unchanged corners, and
    their pixels are neither rendered nor changed -- the old code rendered every pixel
    with an interpolated sample again."""
    make, _ = SCENES["spheres"]
    sess = session(make(), True)
    f0 = sess.render()
    cache = sess.interpolants.cache
    live0 = np.flatnonzero(cache.pool.live)
    rad0 = cache.pool.rad[live0].copy()
    box = sess.scene.arrays().scene_aabb
    c = 0.5 * (box[0] + box[1])
    rep = sess.apply([LightSet("Under", Light("Under", "POINT", power=40.0, position=(
        c[0], c[1], box[0][2] - 1.0)))])
    pool = cache.pool
    same = live0[pool.live[live0] & np.all(pool.rad[live0] == rad0, axis=(1, 2))]
    pi = f0.pixel_interpolant.reshape(-1)
    quiet = np.isin(pi, same)
    assert quiet.sum() > 0.1 * (pi >= 0).sum()
    dirty = sess.dirty_mask.reshape(-1)
    assert not (dirty & quiet).any()
    assert rep.dirty_pixels == int(dirty.sum())
    f = sess.render()
    check_bound(f, sess.scene)
    assert np.array_equal(f.radiance.reshape(-1, 3)[quiet], f0.radiance.reshape(-1, 3)[quiet])


@pytest.mark.parametrize("name", sorted(WORLD_SCENES))
def test_terms_under_a_world_that_lights(monkeypatch, name):
    """While the world lights, a pixel's world term is kept apart with its interpolated
    part: an added light's term taken from the cell joins that part (``rest``), so a later
    world colour edit recombines the pixel with it; two batches before one frame (an add,
    then a power change and a delete) add their terms together."""
    make = WORLD_SCENES[name]
    key = SCENES[name][1]

    def steps(sess):
        return [[[LightSet("Added", _new_light(sess, "POINT"))]],
                [_world_edit(sess, colour=(0.35, 0.3, 0.2))],
                [[LightSet("Added2", _new_light(sess, "SPOT"))], edit(sess, key, power=0.7)],
                [[LightDelete("Added")]]]

    _compare(monkeypatch, make, steps)


def test_rough_roots_render_again():
    """A rough floor: its cells hold its own light, its glossy rays are traced per pixel
    (and see an added light): its pixels are rendered again, not given the term."""
    make, _ = SCENES["spheres"]
    scene = make()
    mat, _ = principled_material("floor", (0.6, 0.6, 0.55), metallic=1.0, roughness=0.35)
    scene.set_material(scene.material_id("floor"), mat)
    sess = session(scene, True)
    f0 = sess.render()
    cache = sess.interpolants.cache
    pi = f0.pixel_interpolant.reshape(-1)
    inst = cache.trees.arrays.tree[cache.pool.node[np.maximum(pi, 0)]] // 6
    floor_px = (pi >= 0) & (inst == sess.scene.instance_slot("Ground"))
    assert floor_px.sum() > 0.05 * len(pi)
    sess.apply([LightSet("Added", _new_light(sess, "POINT"))])
    dirty = sess.dirty_mask.reshape(-1)
    kept = np.isin(pi, np.flatnonzero(cache.pool.live))
    assert (floor_px & kept).any() and dirty[floor_px].all()
    check_bound(sess.render(), sess.scene)


def test_cells_freed_after_the_edit_render_their_pixels(monkeypatch):
    """A light added, then an object moved before the frame: the move frees some of the
    cells that took the added light's term (their sample ids may point past the compacted
    sample store). Their pixels are rendered; the frame and the next keep the bound and
    equal the old code's. (Review find: the term's corners were gathered over the freed
    cells too, an IndexError at this and every later render of the session.)"""
    make, key = SCENES["soft_penumbra"]

    def steps(sess):
        sl = sess.scene.instance_slot("Blocker")
        m = np.array(sess.scene.instances[sl]["matrix"], float).copy()
        m[:3, 3] += (0.2, 0.0, 0.0)
        return [[[LightSet("A", _new_light(sess, "POINT"))], [ObjectTransform("Blocker", m)]],
                [edit(sess, key, power=0.8)]]

    _compare_frames(monkeypatch, make, steps, samples=4)


def _compare_frames(monkeypatch, make, steps, **kw):
    """Both ways, the frames equal to float32 rounding (each within the bound: ``_run``)."""
    new = _run(monkeypatch, make, steps, False, **kw)
    old = _run(monkeypatch, make, steps, True, **kw)
    for (_, f_new), (_, f_old) in zip(new, old, strict=True):
        np.testing.assert_allclose(f_new.radiance, f_old.radiance, rtol=ROUNDING,
                                   atol=ROUNDING)
