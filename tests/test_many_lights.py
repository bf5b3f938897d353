"""Scenes of more than 64 lights (issue 21's 100-light row): a set of lights is
``ceil(L / 64)`` uint64 words (:mod:`rstrace_engine.tracing.light_bits`) -- the per-pixel
records' traced and visible lights, the soft lights an object edit re-shades -- so light
slots past 63 render, relight and re-shade exactly as the first 64 do. Every BASE frame here
equals a fresh session's frame bit for bit; INTERPOLANT frames stay within epsilon."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator, soft_room
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
from rstrace_engine.geometry.edits import LightSet, ObjectTransform
from rstrace_engine.geometry.elements import MAX_LIGHTS
from rstrace_engine.geometry.scene import Light, Scene, SceneError
from rstrace_engine.interpolants import interpolant_cache
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.session import Session
from rstrace_engine.tracing.light_bits import column, mask_of, words
from rstrace_engine.tracing.light_nodes import RECORD_SLOTS

W, H = 24, 18
BASE = RenderSettings(mode="BASE", max_depth=3)


def many_room(n: int, width: int = W, height: int = H, soft: bool = False) -> Scene:
    """:func:`~rstrace_engine.bench.soak.soft_room` (area, sphere, sun, lit world) and
    point lights on a grid under the ceiling up to ``n`` lights, every ninth from the
    fifth a small area light and every ninth from the eighth a sphere light (lights with an
    extent in slots past 64 too); ``soft``: every other one an area light, the others
    sphere lights."""
    s = soft_room(width, height)
    k = 0
    while len(s.lights) < n:
        x, y = -3.0 + (k % 7), -3.0 + (k // 7) % 7
        if k % 9 == 4 or soft and k % 2 == 0:
            li = Light(f"G{k}", "AREA", power=40.0, position=(x, y, 3.6),
                       direction=(0.0, 0.0, -1.0), shape="SQUARE", size=(0.4, 0.4))
        elif k % 9 == 7 or soft:
            li = Light(f"G{k}", "POINT", power=40.0, position=(x, y, 3.6), radius=0.2)
        else:
            li = Light(f"G{k}", "POINT", power=30.0, position=(x, y, 3.0))
        s.add_light(li)
        k += 1
    return s


def fresh(sess, settings=BASE):
    return Session(sess.scene.copy(), settings).render()


def exact(sess) -> dict:
    frame = sess.render()
    ref = fresh(sess, sess.settings)
    np.testing.assert_array_equal(frame.radiance, ref.radiance)
    np.testing.assert_array_equal(frame.pixel_class, ref.pixel_class)
    return frame.stats


def light_edit(sess, slot: int, **kw) -> list:
    li = sess.scene.lights[slot]
    return [LightSet(li.name, replace(li, **kw))]


def test_light_sets_take_a_word_per_64_lights():
    assert [words(n) for n in (0, 1, 64, 65, 128, 129, MAX_LIGHTS)] == [
        1, 1, 1, 2, 2, 3, MAX_LIGHTS // 64]
    m = np.stack([mask_of([0, 63], 2), mask_of([64, 99], 2), mask_of([], 2)])
    assert m.tolist() == [[1 | 1 << 63, 0], [0, 1 | 1 << 35], [0, 0]]
    assert column(m, 99).tolist() == [False, True, False]
    assert column(m, 63).tolist() == [True, False, False]


def test_a_hundred_lights_render_relight_and_move_exactly():
    """Power, colour, a move of lights in slots past 64 (a point light, an area light, a
    sphere light): relit from the per-light records, each frame a fresh one's."""
    sess = Session(many_room(100), BASE)
    sess.light_terms = True
    first = sess.render()
    rec = sess.reuse.records
    assert rec.n_words == 2 and rec.light is not None and rec.light.overflow is None
    # lights past slot 64 light the frame's nodes, and are in their sets
    lit = rec.t_lit.astype(np.uint64)[rec.p_combo.astype(np.int64)]
    assert column(lit, 90).any() and column(lit, 67).any()
    slots = {sess.scene.lights[j].kind + str(sess.scene.lights[j].radius > 0): j
             for j in range(64, 100)}
    for j in (slots["POINTFalse"], slots["AREAFalse"], slots["POINTTrue"]):
        sess.apply(light_edit(sess, j, power=sess.scene.lights[j].power * 5.0,
                              color=(1.0, 0.4, 0.2)))
        st = exact(sess)
        assert st["relit"] and st["relight_shadow_rays"] == 0
        pos = np.asarray(sess.scene.lights[j].position) + (0.4, -0.3, -0.2)
        sess.apply(light_edit(sess, j, position=tuple(pos)))
        st = exact(sess)
        assert st["relit"] and st["relight_shadow_rays"] > 0
    assert not np.array_equal(sess.render().radiance, first.radiance)


def test_object_edits_reshade_the_soft_lights_past_slot_64():
    """A moved object: the lights with an extent whose shadow rays alone it may cross are
    re-shaded (shadow_reshade), light slots past 64 among them, bit for bit."""
    sess = Session(many_room(100, soft=True), RenderSettings(mode="BASE", max_depth=2,
                                                             light_samples=8))
    sess.light_terms = True
    sess.render()
    ext = [j for j in range(64, 100) if sess.scene.lights[j].kind == "AREA"
           or sess.scene.lights[j].radius > 0]
    high = 0
    for dx in (0.25, -0.4):
        m = sess.scene.instances[sess.scene.instance_slot("Small")]["matrix"].copy()
        m[0, 3] += dx
        sess.apply([ObjectTransform("Small", m)])
        r = sess.reuse
        assert r.reshade_lights is not None and r.reshade_lights.shape[1] == 2
        high += sum(int(column(r.reshade_lights, j).sum()) for j in ext)
        exact(sess)
    assert high > 0


def test_random_edit_sequences_with_more_than_64_lights_stay_exact():
    """Seeded random sequences of every edit kind (lights added, deleted, moved, powered,
    resized; objects; the world) on a scene of 70 lights: bit for bit a fresh frame."""
    gen = EditGenerator(many_room(70, 16, 12), seed=64, camera=False,
                        extra=EditGenerator.SOFT_KINDS)
    sess = Session(gen.scene.copy(), BASE)
    sess.render()
    relit = 0
    for _ in range(14):
        sess.apply(gen.step())
        relit += sess.reuse.relight_due
        exact(sess)
    assert len(sess.scene.lights) > 64 and relit >= 2, gen.kinds_done


def clustered_spheres(n: int) -> Scene:
    """The paper's three spheres, their key light split into ``n`` point lights around
    its place (the shadows stay where interpolants can cover them)."""
    s = SOAK_SCENES["spheres"](96, 72)
    key = s.lights[s.light_slot("Key")]
    s.set_light(s.light_slot("Key"), replace(key, power=key.power / n))
    for k in range(n - len(s.lights)):
        off = 0.05 * np.array([k % 5 - 2, (k // 5) % 5 - 2, k // 25])
        s.add_light(replace(key, name=f"Key{k}", power=key.power / n,
                            position=tuple(np.asarray(key.position) + off)))
    return s


def test_interpolant_bound_holds_with_lights_past_slot_64(monkeypatch):
    """INTERPOLANT frames of a 100-light scene after power / colour edits of lights past
    slot 64 (rescaled or invalidated cells): within epsilon of a fresh BASE frame, the
    traced pixels the base tracer's."""
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 12)
    eps = 0.05
    ip = RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=3)
    sess = Session(clustered_spheres(100), ip)
    sess.light_terms = True
    sess.render()
    assert len(sess.scene.lights) == 100
    for j, power in ((90, 30.0), (66, 0.0)):
        sess.apply(light_edit(sess, j, power=sess.scene.lights[j].power * power,
                              color=(0.3, 1.0, 0.5)))
        f = sess.render()
        base = Session(sess.scene.copy(), RenderSettings(mode="BASE", max_depth=3)).render()
        m = image.compare(f.radiance, base.radiance, eps)
        assert m["max_error"] <= eps + 1e-6, m
        traced = (f.pixel_class != CLASS_INTERPOLATED) & (f.pixel_class != CLASS_REBUILT)
        np.testing.assert_allclose(f.radiance[traced], base.radiance[traced], atol=1e-6)
        assert (f.pixel_class == CLASS_INTERPOLATED).sum() > 0.2 * f.pixel_class.size


def test_the_light_limit_names_its_setting():
    s = Scene()
    for k in range(MAX_LIGHTS):
        s.add_light(Light(f"L{k}", "POINT", power=1.0, position=(0.0, 0.0, 1.0)))
    with pytest.raises(SceneError, match=rf"'one more'.*at most {MAX_LIGHTS} \(MAX_LIGHTS\)"):
        s.add_light(Light("one more", "POINT", power=1.0, position=(0.0, 0.0, 1.0)))


def test_lights_past_the_records_slots_re_trace_and_say_so():
    """More light slots than the per-light records name (RECORD_SLOTS): no records, said in
    the frame's stats; a light edit re-traces its pixels, exactly."""
    sess = Session(many_room(RECORD_SLOTS + 2, 8, 6), RenderSettings(mode="BASE",
                                                                      max_depth=1))
    sess.light_terms = True
    f = sess.render()
    assert "light slots" in f.stats["relight_off"]
    assert "MAX_LIGHTS" in f.stats["relight_off"]
    j = RECORD_SLOTS + 1
    sess.apply(light_edit(sess, j, power=sess.scene.lights[j].power * 3.0))
    st = exact(sess)
    assert not st.get("relit")


def test_a_light_added_at_the_records_last_slot_re_traces():
    """Relit frames at RECORD_SLOTS lights, then one light more: the records cannot name
    it, so the add re-traces (said), exactly (it crashed: the relight ran on dropped
    records)."""
    sess = Session(many_room(RECORD_SLOTS, 8, 6), RenderSettings(mode="BASE", max_depth=1))
    sess.light_terms = True
    sess.render()
    sess.apply(light_edit(sess, 3, power=sess.scene.lights[3].power * 2.0))
    exact(sess)
    sess.apply(light_edit(sess, 3, power=sess.scene.lights[3].power * 3.0))
    assert exact(sess).get("relit")
    sess.apply([LightSet("extra", Light("extra", "POINT", power=50.0,
                                        position=(0.5, 0.5, 3.0)))])
    st = exact(sess)
    assert not st.get("relit") and "light slots" in st["relight_off"]


@pytest.mark.parametrize("light_terms", [False, True])
def test_edits_between_frames_past_the_records_light_words(light_terms):
    """A light with an extent added in slot 64 (the records' sets one word wide), then an
    object moved before the next frame: the records' sets widen for it (an index error
    before, and the kernels read past the sets)."""
    sess = Session(many_room(64, 16, 12), RenderSettings(mode="BASE", max_depth=2))
    sess.light_terms = light_terms
    sess.render()
    sess.apply([LightSet("X", Light("X", "POINT", power=300.0, position=(0.3, 0.2, 3.5),
                                    radius=0.2))])
    m = sess.scene.instances[sess.scene.instance_slot("Small")]["matrix"].copy()
    m[0, 3] += 0.25
    sess.apply([ObjectTransform("Small", m)])
    exact(sess)
