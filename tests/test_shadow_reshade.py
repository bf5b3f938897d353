"""Object edits under soft light re-shade, at kept samples, only the lights whose shadow
rays they may cross (tracing/shadow_reshade.py, issue 20 item 5): BASE frames equal fresh
ones bit for bit, and the pixels that change without being traced again are exactly the
re-shaded ones (a term kept that should have changed would leave one of them wrong)."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.edits import ObjectAdd, ObjectDelete, ObjectTransform
from rstrace_engine.session import Session

W, H = 48, 36


def fresh(sess):
    return Session(sess.scene.copy(), sess.settings).render()


def step(sess, prev, edits):
    """Apply, render; the frame equals a fresh one bit for bit and every changed pixel was
    traced again or re-shaded. Returns the frame and the pixels changed by re-shading."""
    rep = sess.apply(edits)
    assert not rep.full_frame
    dirty = sess.dirty_mask.copy()
    shaded = sess.reshade_mask.copy()
    assert not (dirty & shaded).any()
    assert rep.reshade_pixels == int(shaded.sum())
    frame = sess.render()
    ref = fresh(sess)
    np.testing.assert_array_equal(frame.radiance, ref.radiance)
    np.testing.assert_array_equal(frame.pixel_class, ref.pixel_class)
    assert frame.stats["traced_pixels"] == int(dirty.sum())
    changed = np.any(prev.radiance != ref.radiance, axis=2)
    assert not (changed & ~dirty & ~shaded).any()
    return frame, changed & shaded


@pytest.mark.parametrize("depth", [3, 0])
def test_object_edits_under_soft_light_reshade_exactly(depth):
    """soft_room: an area light, a sphere light, a sun with an angle, a world that lights.
    Moving, adding and deleting objects: some pixels change through their soft shadow
    rays alone, are re-shaded (not traced) and equal a fresh frame's."""
    settings = RenderSettings(mode="BASE", max_depth=depth, light_samples=8, samples=2)
    scene = SOAK_SCENES["soft_room"](W, H)
    assert scene.world_lights
    kinds = {li.kind for li in scene.lights if li is not None}
    assert {"AREA", "SUN"} <= kinds, kinds
    sess = Session(scene, settings)
    sess.light_terms = True
    prev = sess.render()
    slot = scene.instance_slot("Small")
    m = scene.instances[slot]["matrix"].copy()
    shaded_changed = 0
    batches = []
    for dx in (0.25, -0.15):
        m[0, 3] += dx
        batches.append([ObjectTransform("Small", m.copy())])
    batches.append([ObjectAdd("Extra", "ball", shapes.transform((0.4, 0.3, 0.25), 0.2),
                              ("red",))])
    batches.append([ObjectDelete("Extra")])
    for edits in batches:
        prev, changed = step(sess, prev, edits)
        shaded_changed += int(changed.sum())
    # the path was taken, and it changed pixels (a kept term would have left them wrong)
    assert shaded_changed > 0


def test_pending_reshade_then_light_edit_is_exact():
    """An object edit whose soft shadows are to be re-shaded, then a light edit in the
    next batch before any frame: the pending pixels are traced again instead."""
    settings = RenderSettings(mode="BASE", max_depth=2, light_samples=8)
    scene = SOAK_SCENES["soft_room"](W, H)
    sess = Session(scene, settings)
    sess.light_terms = True
    sess.render()
    slot = scene.instance_slot("Small")
    m = scene.instances[slot]["matrix"].copy()
    m[0, 3] += 0.2
    sess.apply([ObjectTransform("Small", m)])
    assert sess.reshade_mask.any()
    lamp = next(li for li in sess.scene.lights if li is not None)
    from dataclasses import replace

    from rstrace_engine.geometry.edits import LightSet
    sess.apply([LightSet(lamp.name, replace(lamp, power=lamp.power * 0.5))])
    assert not sess.reshade_mask.any()
    frame = sess.render()
    np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)


def test_random_soft_edits_with_light_terms_exact():
    """Seeded random sequences of every edit kind (soft kinds too) on soft_room with the
    per-light records from the first frame: every frame equals a fresh one."""
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=4)
    gen = EditGenerator(SOAK_SCENES["soft_room"](32, 24), seed=23,
                        extra=EditGenerator.EXTRA_KINDS + EditGenerator.SOFT_KINDS)
    sess = Session(gen.scene.copy(), settings)
    sess.light_terms = True
    prev = sess.render()
    shaded = 0
    for _ in range(30):
        sess.apply(gen.step())
        dirty = sess.dirty_mask
        mask = sess.reshade_mask
        frame = sess.render()
        ref = fresh(sess)
        np.testing.assert_array_equal(frame.radiance, ref.radiance)
        if dirty is not None and not frame.stats.get("relit"):
            changed = np.any(prev.radiance != ref.radiance, axis=2)
            assert not (changed & ~dirty & ~mask).any()
            shaded += int(mask.sum())
        prev = frame
    assert shaded > 0


def test_moving_an_object_behind_rough_glass_reshades_its_far_side_samples():
    """A rough glass pane lit through its far side by an area light (its samples below the
    surface traced from the far side, tracing/soft_lights.py): a small box moved between
    the pane and the light changes the pane's pixels through those samples alone. The
    re-shade must draw them as the tracer does (below the surface, from the far side),
    else their kept visibility bits leave the pane as it was."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_rough_glass_light import _TURN, _pane

    from rstrace_engine.geometry.principled import principled_material

    scene = _pane(0.5, "area", n=W)
    dark, _ = principled_material("dark", (0.1, 0.1, 0.1), specular_level=0.0)
    m = _TURN.copy()
    m[:3, 3] = (-0.3, 0.5, 0.0)
    scene.add_instance(scene.add_mesh(shapes.box((0.3, 0.05, 0.3), name="chip")), m,
                       [scene.add_material(dark)], name="Chip")
    settings = RenderSettings(mode="BASE", max_depth=2, light_samples=8)
    sess = Session(scene, settings)
    sess.light_terms = True
    prev = sess.render()
    shaded_changed = 0
    for x in (0.0, 0.25):
        m[0, 3] = x
        prev, changed = step(sess, prev, [ObjectTransform("Chip", m.copy())])
        shaded_changed += int(changed.sum())
    assert shaded_changed > 0


def test_parts_bound_the_edited_objects_old_and_new():
    """A moved object's effects hold its old and its new place apart (EditEffects.parts),
    each a box and a sphere that contain every vertex of the object there."""
    from rstrace_engine.geometry.edits import PART_NEW, PART_OLD, apply_edits

    scene = SOAK_SCENES["soft_room"](W, H)
    slot = scene.instance_slot("Small")
    inst = scene.instances[slot]
    verts = scene.meshes[inst["mesh"]]["verts"]
    m0 = inst["matrix"].copy()
    m1 = m0.copy()
    m1[:3, :3] = m1[:3, :3] @ np.diag([1.5, 0.7, 1.0])  # (the sphere scales by the most)
    m1[0, 3] += 0.3
    _, fx = apply_edits(scene, [ObjectTransform("Small", m1)])
    lo, hi, c, r, tag = fx.part_arrays()
    assert len(lo) == 2 and len(fx.regions) == 1
    assert list(tag) == [PART_OLD, PART_NEW]
    for k, m in enumerate((m0, m1)):
        w = verts @ m[:3, :3].T + m[:3, 3]
        assert (w >= lo[k] - 1e-12).all() and (w <= hi[k] + 1e-12).all()
        assert (np.linalg.norm(w - c[k], axis=1) <= r[k] * (1 + 1e-12)).all()
        box_r = 0.5 * np.linalg.norm(hi[k] - lo[k])
        assert r[k] <= box_r
    # the union box the other structures use holds both
    box = fx.region_array()[0]
    assert (box[0] <= lo).all() and (box[1] >= hi).all()


def test_crossing_windows_drop_no_sample():
    """crossing_rows skips samples whose (u, v) puts their direction outside every
    region's cone before drawing them: on every point of a soft_room frame, for every
    light and the world, against regions around and between the objects, it finds
    exactly the samples it finds drawing them all."""
    from rstrace_engine.tracing.sample_rays import ALL, crossing_rows
    from rstrace_engine.tracing.shadow_reshade import _surfaces

    settings = RenderSettings(mode="BASE", max_depth=1, light_samples=16)
    scene = SOAK_SCENES["soft_room"](64, 48)
    sess = Session(scene, settings)
    sess.light_terms = True
    sess.render()
    sa = sess.scene.arrays()
    p = sess.reuse.light_records.p
    geo = p.geo
    surf = _surfaces(sa, geo)
    k = len(geo["t"])
    L = len(sa.light_kind)
    pt = np.repeat(np.arange(k), L + 1)
    lj = np.tile(np.arange(L + 1), k)
    rng = np.random.default_rng(5)
    box = sa.scene_aabb
    found = 0
    for _ in range(4):
        c = rng.uniform(box[0], box[1], size=(3, 3))
        half = rng.uniform(0.05, 0.6, size=(3, 3))
        lo, hi = c - half, c + half
        cen = c + rng.uniform(-0.2, 0.2, size=(3, 3)) * half
        rad = np.linalg.norm(half, axis=1) * rng.uniform(0.4, 1.2, size=3)
        tag = rng.integers(1, 4, size=3).astype(np.int8)
        old = rng.integers(0, 2**63, size=len(pt), dtype=np.uint64)
        out = []
        for windows in (True, False):
            mask = np.empty(len(pt), np.uint64)
            count = np.empty(len(pt), np.int64)
            crossing_rows(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat,
                          np.ascontiguousarray(geo["seed"], np.uint64), pt, lj, 16, lo, hi,
                          cen, rad, tag, old, np.full(len(pt), ALL), windows, mask,
                          count)
            out.append((mask, count))
        np.testing.assert_array_equal(out[0][0], out[1][0])
        np.testing.assert_array_equal(out[0][1], out[1][1])
        found += int(out[0][1].sum())
    assert found > 0


@pytest.mark.parametrize("form", [1, 2])
def test_sample_windows_hold_every_direction_in_the_cone(form):
    """The (u, v) windows (sample_rays._windows): every sample whose direction (drawn
    cosine-weighted about an axis, form 1, or uniform in a cone about it, form 2) lies in a
    region's cone is inside its window, and the windows leave most samples out when the
    cone is small."""
    from rstrace_engine.tracing.sample_rays import _in_window, _windows
    from rstrace_engine.tracing.soft_lights import _cone_dir, _cosine_dir

    rng = np.random.default_rng(11 + form)
    skipped = total = 0
    for _ in range(40):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        omc = rng.uniform(0.05, 1.0) if form == 2 else 0.0
        cv = np.empty((2, 4))
        hs = []
        for q in range(2):
            w = rng.normal(size=3)
            w /= np.linalg.norm(w)
            if q == 0:  # (near the axis: the cone holds it)
                w = a + 0.1 * w
                w /= np.linalg.norm(w)
            dist = rng.uniform(0.5, 5.0)
            h = rng.uniform(0.01, 0.4)
            hs.append((w, h))
            cv[q, :3] = w * dist
            cv[q, 3] = np.cos(h) * dist
        win = np.empty((2, 4))
        _windows(form, *a, omc, cv, win, np.full(2, 3, np.int8), 3)
        for u, v in rng.uniform(0.0, 1.0, size=(500, 2)):
            d = np.array(_cosine_dir(*a, u, v) if form == 1 else _cone_dir(*a, omc, u, v))
            inside = any(d @ w >= np.cos(h) for w, h in hs)
            ok = _in_window(win, u, v)
            assert ok or not inside, (u, v, win)
            skipped += not ok
            total += 1
    assert skipped > total // 4


def test_soft_lit_sessions_keep_light_terms_from_the_first_frame():
    """By default (Session.light_terms None) a BASE session over a soft-lit scene keeps
    the per-light terms from its first frame, so its first object edit re-shades soft
    shadows instead of tracing those pixels; a hard-lit scene's does not pay for them."""
    settings = RenderSettings(mode="BASE", max_depth=2, light_samples=8)
    sess = Session(SOAK_SCENES["soft_room"](W, H), settings)
    assert sess.light_terms is None
    prev = sess.render()
    assert prev.stats["light_records_mb"] > 0.0
    slot = sess.scene.instance_slot("Small")
    m = sess.scene.instances[slot]["matrix"].copy()
    m[0, 3] += 0.25
    _, changed = step(sess, prev, [ObjectTransform("Small", m)])
    assert changed.any()
    hard = Session(SOAK_SCENES["room"](W, H), settings)
    assert hard.render().stats["light_records_mb"] == 0.0


@pytest.mark.parametrize("edit", ["add", "move"])
def test_mirror_hits_soft_shadows_reshade_exactly(edit):
    """studio's mirror ball reflects the floor around it: a ball added beside it, or the
    box moved, crosses the soft samples (area light, sphere light, world) of those
    reflected floor points but not the reflection rays. The records keep the secondary
    hits' normals, seeds and samples' visibility too, so those mirror pixels are re-shaded
    at their reflected hits (not traced again: before, any edited box made every pixel
    with a reflected hit dirty while the world lights) and equal a fresh frame's."""
    scene = scenes.studio(96, 72)
    settings = RenderSettings(mode="BASE", max_depth=3, light_samples=8)
    sess = Session(scene, settings)
    sess.light_terms = True
    prev = sess.render()
    rec = sess.reuse.records
    s_hit = rec.t_inst[rec.s_combo.astype(np.int64)] >= 0
    mirror = np.zeros(rec.n_rays, bool)  # pixels whose sample has a reflected hit
    mirror[rec.secondary_rays()[s_hit]] = True
    mirror = mirror.reshape(rec.spp, -1).any(axis=0).reshape(prev.pixel_class.shape)
    assert mirror.sum() > 20
    if edit == "add":
        edits = [ObjectAdd("NewBall", "sphere", shapes.transform((0.3, -1.9, 0.15), 0.15),
                           ("blue",))]
    else:
        m = scene.instances[scene.instance_slot("Cube")]["matrix"].copy()
        m[0, 3] += 0.15
        edits = [ObjectTransform("Cube", m)]
    frame, changed = step(sess, prev, edits)
    # mirror pixels re-shaded, not traced, that changed: their reflected hits' terms were
    # shaded again (step compares every pixel with a fresh frame, bit for bit)
    assert (changed & mirror).sum() >= 3, int((changed & mirror).sum())


def test_blocked_samples_ask_the_scene_without_the_placed_object(monkeypatch):
    """A kept sample that was blocked and that the moved object does not block now is asked
    of the whole scene (its blocker may have been the object's old place), with that object
    left out of the query: it was just tested against it alone (shadow_reshade._blocked;
    the mirror ball's tree is not walked again by rays that pass close by it). The frame
    equals a fresh one bit for bit."""
    from rstrace_engine.tracing import shadow_reshade

    asked = []
    occluded_by = shadow_reshade._occluded_by

    def spy(sa, accel):
        occluded = occluded_by(sa, accel)

        def query(o, d, tmax, rows, skip=None):
            asked.append((len(o), None if skip is None else set(skip.tolist())))
            return occluded(o, d, tmax, rows, skip)
        return query

    monkeypatch.setattr(shadow_reshade, "_occluded_by", spy)
    scene = scenes.studio(64, 48)
    sess = Session(scene, RenderSettings(mode="BASE", max_depth=3, light_samples=8))
    sess.light_terms = True
    prev = sess.render()
    slot = scene.instance_slot("MirrorBall")
    m = scene.instances[slot]["matrix"].copy()
    m[0, 3] += 0.1
    step(sess, prev, [ObjectTransform("MirrorBall", m)])
    assert sum(n for n, _ in asked) > 0
    assert all(skip == {slot} for n, skip in asked if n)
