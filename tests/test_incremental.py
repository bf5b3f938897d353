"""Incremental frames after edits (fixed camera) against fresh sessions of the edited scene.

BASE: the incremental frame equals a fresh session's frame bit for bit (to 1e-6) and every
pixel whose radiance changed was marked dirty or relit (light edits, tests/test_relight.py).
INTERPOLANT: the session's frame and a fresh one both stay within epsilon of the BASE frame
of the edited scene (a stale interpolant would not), and every pixel whose BASE radiance
changed was marked dirty. A seeded generator runs random sequences of every edit kind mixed
with camera moves on several small scenes; the bench command runs the long soak
(``python -m rstrace_engine.bench edit --soak N``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_params
from rstrace_engine.geometry.edits import (
    MaterialSet,
    ObjectDelete,
    ObjectTransform,
    ObjectVisibility,
    apply_edits,
)
from rstrace_engine.geometry.scene import Material
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.session import Session

W, H = 32, 24


@pytest.fixture(autouse=True)
def cells_always(monkeypatch):
    """The INTERPOLANT sessions here count interpolated and rebuilt pixels: the measured
    fallback (decided from timings, tests/test_interpolant_fallback.py) is off."""
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)


def fresh_frame(scene, settings):
    return Session(scene.copy(), settings).render()


def check_base_step(sess, prev, settings):
    """The session's next frame against a fresh session's; returns (frame, dirty fraction).
    After light edits the kept pixels are relit (every one may change; none re-traced)."""
    dirty = sess.dirty_mask
    if dirty is not None:  # (soft lights shaded again at kept pixels: may change too)
        dirty = dirty | sess.reshade_mask
    relit = sess.reuse.relight_due
    starts = sess.starts_light_terms  # the first light edit: a full frame keeping them
    frame = sess.render()
    assert bool(frame.stats.get("relit")) == relit
    fresh = fresh_frame(sess.scene, settings)
    np.testing.assert_allclose(frame.radiance, fresh.radiance, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(frame.pixel_class, fresh.pixel_class)
    if relit:  # recombined, only the dirty pixels traced
        return frame, float(dirty.mean())
    if dirty is not None and prev is not None and not starts:
        assert frame.stats["incremental"]
        changed = np.any(prev.radiance != fresh.radiance, axis=2)
        missed = changed & ~dirty
        assert not missed.any(), f"{int(missed.sum())} changed pixels not marked dirty"
        return frame, float(dirty.mean())
    return frame, 1.0


@pytest.mark.parametrize("scene_name", sorted(SOAK_SCENES))
def test_random_edits_base_exact(scene_name):
    """Seeded random sequences of every edit kind and camera moves: BASE stays exact."""
    settings = RenderSettings(mode="BASE", max_depth=3)
    gen = EditGenerator(SOAK_SCENES[scene_name](W, H), seed=11)
    sess = Session(gen.scene.copy(), settings)
    prev = sess.render()
    fractions = []
    tinted = 0  # rough scenes: F82-tinted metals drawn (issue 23)
    for _ in range(36):
        edits = gen.step()
        tinted += sum(isinstance(e, MaterialSet) and tuple(e.material.metal_tint) != (1.0,) * 3
                      for e in edits)
        sess.apply(edits)
        prev, frac = check_base_step(sess, prev, settings)
        fractions.append(frac)
    assert set(gen.kinds_done) >= set(EditGenerator.KINDS), gen.kinds_done
    assert tinted > 0 or not gen.rough
    print(scene_name, np.round(fractions, 2))
    # most steps re-render a part of the frame only
    assert np.median(fractions) < 0.75, fractions


@pytest.mark.parametrize("accelerator", ["EMBREE", "BRUTE_FORCE", "VISIBILITY_FIELD"])
def test_random_edits_base_exact_other_accelerators(accelerator):
    if accelerator == "EMBREE":
        pytest.importorskip("embreex")
    settings = RenderSettings(mode="BASE", max_depth=3, accelerator=accelerator)
    gen = EditGenerator(SOAK_SCENES["room"](24, 18), seed=4)
    sess = Session(gen.scene.copy(), settings)
    prev = sess.render()
    for _ in range(14):
        sess.apply(gen.step())
        prev, _ = check_base_step(sess, prev, settings)


@pytest.mark.parametrize("memory_cap_mb", [256.0, 0.004])
def test_random_edits_interpolant_within_epsilon(memory_cap_mb):
    """Also under a memory cap so small that interpolants are evicted every frame (a kept
    pixel whose interpolant was evicted is no longer tracked by the RSTs)."""
    eps = 0.05
    settings = RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=3,
                              memory_cap_mb=memory_cap_mb)
    base_settings = RenderSettings(mode="BASE", max_depth=3)
    gen = EditGenerator(SOAK_SCENES["spheres"](128, 96), seed=5)  # big enough to interpolate
    sess = Session(gen.scene.copy(), settings)
    prev_base = fresh_frame(sess.scene, base_settings)
    sess.render()
    incremental = interpolated = 0
    for _ in range(10):
        sess.apply(gen.step())
        dirty = sess.dirty_mask
        relit = None
        if sess.reuse.relight_due:  # light edits: the traced pixels are recombined
            rec = sess.reuse.records
            relit = sess.reuse.light_records.relit_pixels(rec.spp, rec.n_pixels)
            # and the pixels of kept cells take the edit's term from them
            relit |= sess.reuse.term_mask.reshape(-1)
        frame = sess.render()
        assert bool(frame.stats.get("relit")) == (relit is not None)
        incremental += frame.stats["incremental"]
        interpolated += int(np.count_nonzero(frame.pixel_class == CLASS_INTERPOLATED))
        base = fresh_frame(sess.scene, base_settings)
        fresh = fresh_frame(sess.scene, settings)
        for f in (frame, fresh):
            m = image.compare(f.radiance, base.radiance, eps)
            assert m["max_error"] <= eps + 1e-6, m  # every pixel (float32 slack)
            traced = f.pixel_class != CLASS_INTERPOLATED
            traced &= f.pixel_class != CLASS_REBUILT  # rebuilt pixels are interpolated too
            np.testing.assert_allclose(f.radiance[traced], base.radiance[traced], atol=1e-6)
        if dirty is not None:
            changed = np.any(prev_base.radiance != base.radiance, axis=2)
            if relit is not None:
                changed &= ~relit.reshape(changed.shape)
            assert not (changed & ~dirty).any()
        prev_base = base
    assert incremental >= 4 and interpolated > 0


def test_moving_a_small_object_dirties_little():
    settings = RenderSettings(max_depth=3)
    scene = SOAK_SCENES["room"](64, 48)
    sess = Session(scene, settings)
    prev = sess.render()
    slot = scene.instance_slot("Small")
    m = scene.instances[slot]["matrix"].copy()
    m[0, 3] += 0.2
    rep = sess.apply([ObjectTransform("Small", m)])
    assert not rep.full_frame and 0 < rep.dirty_fraction < 0.25
    frame, _ = check_base_step(sess, prev, settings)
    assert frame.stats["traced_pixels"] == rep.dirty_pixels


def test_moving_a_small_object_under_a_world_that_lights():
    """Issue 20: the world's rays of every primary hit are regenerated from the records
    (tracing/world_rays.py), so moving a small object in a world-lit room dirties the
    pixels whose world rays, shadow rays or view may meet its old or new box -- not every
    hit (before; measured 20% of the pixels against 83% hits) -- and the frame equals a
    fresh one bit for bit."""
    settings = RenderSettings(max_depth=3, light_samples=8)
    scene = SOAK_SCENES["soft_room"](64, 48)
    assert scene.world_lights
    sess = Session(scene, settings)
    prev = sess.render()
    hits = float(np.mean(prev.pixel_class != 0))
    slot = scene.instance_slot("Small")
    m = scene.instances[slot]["matrix"].copy()
    for dx in (0.2, -0.1):
        m[0, 3] += dx
        rep = sess.apply([ObjectTransform("Small", m.copy())])
        assert not rep.full_frame and 0 < rep.dirty_fraction < 0.5 * hits, (
            rep.dirty_fraction, hits)
        prev, _ = check_base_step(sess, prev, settings)


@pytest.mark.parametrize("edit", ["move", "delete"])
def test_view_rays_are_dirty_only_where_objects_came(edit):
    """A ray that hit no edited object meets what it met unless geometry came into its way:
    the view and mirror segments are tested against where the edited objects are now (box
    and sphere), not the old box union new box. Moving or deleting the small box dirties
    fewer pixels than the boxes alone (before: the same), and the frame equals a fresh
    one bit for bit."""
    settings = RenderSettings(max_depth=3)
    scene = SOAK_SCENES["room"](64, 48)
    sess = Session(scene, settings)
    prev = sess.render()
    m = scene.instances[scene.instance_slot("Small")]["matrix"].copy()
    m[0, 3] += 0.3
    edits = [ObjectTransform("Small", m) if edit == "move" else ObjectDelete("Small")]
    rec, old_sa = sess.reuse.records, sess.scene.arrays()
    _, fx = apply_edits(sess.scene, edits)
    cp = camera_params(sess.scene.camera)
    dirty = rec.dirty_pixels(old_sa, cp, fx)
    boxes = rec.dirty_pixels(old_sa, cp, replace(fx, parts=[]))  # (every box, old and new)
    assert (dirty <= boxes).all()
    assert dirty.sum() < boxes.sum(), (int(dirty.sum()), int(boxes.sum()))
    rep = sess.apply(edits)
    assert rep.dirty_pixels == int(dirty.sum())
    frame, _ = check_base_step(sess, prev, settings)
    np.testing.assert_array_equal(frame.radiance, fresh_frame(sess.scene, settings).radiance)


@pytest.mark.parametrize("accelerator", ["EMBREE", "BVH", "BRUTE_FORCE", "VISIBILITY_FIELD"])
def test_hiding_an_object_keeps_every_other_hit(accelerator):
    """Hiding an object changes no hit its box does not hold, whatever the accelerator.

    A glass box resting on the floor (its bottom face coplanar with the floor): rays inside
    it end where the two faces coincide, and float32 Embree cannot order them. Which one it
    reported depended on its BVH, so on the other objects: hiding the glass ball changed
    three of these pixels (by up to 0.28), none marked dirty (found by the seeded random
    edits, seed 96 with mesh deletes)."""
    if accelerator == "EMBREE":
        pytest.importorskip("embreex")
    scene = SOAK_SCENES["room"](24, 18)
    scene.set_material(scene.material_id("red"),
                       Material("red", diffuse=(0.0,) * 3, transmission=(0.85,) * 3, ior=1.4))
    scene.set_instance_matrix(scene.instance_slot("Mirror"),
                              np.array([[10.0, 0.0, 0.0, 0.2171], [0.0, 0.0, -1.0, 3.6],
                                        [0.0, 4.0, 0.0, 2.3632], [0.0, 0.0, 0.0, 1.0]]))
    settings = RenderSettings(mode="BASE", max_depth=3, accelerator=accelerator)
    sess = Session(scene, settings)
    prev = sess.render()
    rep = sess.apply([ObjectVisibility("Glass", False)])
    assert not rep.full_frame and 0 < rep.dirty_fraction < 0.2
    frame, _ = check_base_step(sess, prev, settings)
    np.testing.assert_array_equal(frame.radiance, fresh_frame(sess.scene, settings).radiance)
    rep = sess.apply([ObjectVisibility("Glass", True)])  # and back
    frame, _ = check_base_step(sess, frame, settings)
    np.testing.assert_array_equal(frame.radiance, fresh_frame(sess.scene, settings).radiance)


def test_memory_stays_bounded_over_thousands_of_edits():
    settings = RenderSettings(mode="BASE", max_depth=2)
    gen = EditGenerator(SOAK_SCENES["room"](16, 12), seed=2, camera=False)
    sess = Session(gen.scene.copy(), settings)
    sess.render()
    sizes = []
    for k in range(2000):
        sess.apply(gen.step())
        if k % 50 == 49:
            sess.render()
            sizes.append(sess.records_bytes)
    assert len(sess.scene.instances) <= gen.max_objects + 2
    assert len(sess.scene.lights) <= gen.max_lights
    assert len(sess.scene.meshes) <= gen.max_meshes
    # the records of a 16x12 frame: bounded by the pixels, not by the edits
    assert max(sizes) < 16 * 12 * 64 + 65536, sizes
    assert sess.records.n_table <= 16 * 12 * 8


def test_cancelled_incremental_frame_falls_back_to_full():
    settings = RenderSettings(max_depth=2)
    scene = SOAK_SCENES["room"](32, 24)
    sess = Session(scene, settings)
    sess.render()
    m = scene.instances[scene.instance_slot("Small")]["matrix"].copy()
    m[1, 3] += 0.3
    sess.apply([ObjectTransform("Small", m)])
    part = sess.render(cancel=lambda: True)
    assert part.stats["cancelled"] and sess.dirty_mask is None
    full = sess.render()
    assert not full.stats["incremental"]
    np.testing.assert_array_equal(full.radiance, fresh_frame(sess.scene, settings).radiance)


def test_scene_box_change_renders_a_full_frame():
    settings = RenderSettings(max_depth=2)
    scene = SOAK_SCENES["room"](32, 24)
    sess = Session(scene, settings)
    sess.render()
    rep = sess.apply([ObjectTransform("Small", shapes.transform((0.0, 40.0, 0.3)))])
    assert rep.full_frame and any("bounding box" in m for m in rep.messages)
    frame = sess.render()
    np.testing.assert_array_equal(frame.radiance, fresh_frame(sess.scene, settings).radiance)


def test_rebuilt_pixels_are_magenta_and_camera_moves_invalidate_nothing():
    from rstrace_engine.geometry.edits import CameraChange, MaterialSet
    from rstrace_engine.geometry.scene import Camera, Material

    scene = SOAK_SCENES["spheres"](128, 96)
    settings = RenderSettings(mode="INTERPOLANT", epsilon=0.05, max_depth=3)
    sess = Session(scene, settings)
    first = sess.render()
    used = first.pixel_interpolant[first.pixel_class == CLASS_INTERPOLATED]
    assert len(used) > 0
    cache = sess.interpolants.cache
    live = cache.pool.n_live
    cam = scene.camera
    m = cam.matrix.copy()
    m[0, 3] += 0.05
    rep = sess.apply([CameraChange(Camera(m, width=cam.width, height=cam.height,
                                          lens=cam.lens))])
    assert rep.invalidated_interpolants == 0 and rep.full_frame
    assert sess.interpolants.cache is cache and cache.pool.n_live == live
    sess.render()
    assert not np.any(first.pixel_class == CLASS_REBUILT)
    # recolouring the floor invalidates the floor's interpolants: their pixels come back
    # "rebuilt after an edit" (magenta in the Interpolation pass)
    rep = sess.apply([MaterialSet("floor", Material("floor", diffuse=(0.3, 0.5, 0.3)))])
    assert rep.invalidated_interpolants > 0 and not rep.full_frame
    frame = sess.render()
    assert frame.stats["incremental"]
    assert np.count_nonzero(frame.pixel_class == CLASS_REBUILT) > 0
    # the statistic counts them as interpolated, also in the next frames that keep them
    # (it once left them out: 0% with 959 magenta pixels after an edit)
    for _ in range(2):
        both = (frame.pixel_class == CLASS_INTERPOLATED) | (frame.pixel_class == CLASS_REBUILT)
        assert frame.stats["interpolated_fraction"] == np.count_nonzero(both) / both.size
        sess.apply([MaterialSet("floor", Material("floor", diffuse=(0.3, 0.5, 0.3)))])
        frame = sess.render()
    base = fresh_frame(sess.scene, RenderSettings(max_depth=3))
    assert image.compare(frame.radiance, base.radiance, 0.05)["frac_over"] <= 0.01


def test_light_samples_change_renders_a_full_frame():
    """The kept frame depends on the soft lights' sample count: a new count is a new frame
    (it once reused the old samples' pixels)."""
    settings = RenderSettings(max_depth=1, light_samples=4)
    sess = Session(SOAK_SCENES["soft_room"](W, H), settings)
    sess.render()
    more = RenderSettings(max_depth=1, light_samples=9)
    sess.update_settings(more)
    frame = sess.render()
    assert not frame.stats["incremental"]
    np.testing.assert_array_equal(frame.radiance, fresh_frame(sess.scene, more).radiance)


def test_random_soft_edits_interpolant_within_epsilon(monkeypatch):
    """Issue 20 item 4: seeded random edits of every kind, light extents included (radius,
    soft falloff, sun angle, area size, shape, spread), in an INTERPOLANT session on the
    soft-lit room (its world a background) and the room: every frame within epsilon of a
    fresh BASE frame, traced pixels BASE's (the bench's ``edit --soak N --soak-mode
    INTERPOLANT`` runs it longer). Cells from 6 rays on (default 48): at 96 x 72 the mean
    interpolated share is 2.4% (edits add sampled lights, a world that lights, glossy
    materials, all of which are traced) and the largest error 0.0079."""
    from rstrace_engine.bench.soak import interpolant_soak
    from rstrace_engine.interpolants import interpolant_cache

    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    res = interpolant_soak(16, epsilon=0.02, width=96, height=72, log=lambda m: None)
    assert res["steps"] == 16 and res["max_error"] <= 0.02 + 1e-6
    assert res["mean_interpolated_fraction"] > 0.01, res
