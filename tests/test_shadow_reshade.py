"""Object edits under soft light re-shade, at kept samples, only the lights whose shadow
rays they may cross (tracing/shadow_reshade.py, issue 20 item 5): BASE frames equal fresh
ones bit for bit, and the pixels that change without being traced again are exactly the
re-shaded ones (a term kept that should have changed would leave one of them wrong)."""

from __future__ import annotations

import numpy as np
import pytest

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
