"""Light edits without re-tracing (BASE, issue 21): the per-light records
(:mod:`rstrace_engine.tracing.light_records`).

A light's power or colour and the world's colour recombine the frame from its light terms
(no ray traced); a moved, resized, added or deleted light is shaded again alone. Every
relit frame equals a fresh session's frame of the edited scene bit for bit; batches the
terms cannot follow, and records over their cap, take the per-pixel records' path.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_params
from rstrace_engine.geometry.edits import (
    EditEffects,
    LightDelete,
    LightSet,
    MeshSet,
    ObjectTransform,
    WorldColor,
)
from rstrace_engine.geometry.elements import MAX_LIGHT_POWER
from rstrace_engine.geometry.lights import seen_extent
from rstrace_engine.geometry.scene import Light, SceneError
from rstrace_engine.session import RELIGHT_OFF, Session
from rstrace_engine.tracing import light_records, shaft_skip

W, H = 32, 24
SETTINGS = RenderSettings(mode="BASE", max_depth=3, samples=2)


@pytest.fixture(autouse=True)
def _light_terms_from_the_first_frame(monkeypatch):
    """These tests edit lights from the first frame on: the sessions keep the light terms
    at once (by default they start at the first light edit, tested below)."""
    monkeypatch.setattr(Session, "light_terms", True)


def fresh(sess):
    return Session(sess.scene.copy(), sess.settings).render()


def step(sess, edits, relit=True, frame_relit=None):
    """Apply ``edits``, render; the frame must equal a fresh one bit for bit. ``relit``:
    the batch relights; ``frame_relit``: the frame does (default: ``relit``)."""
    rep = sess.apply(edits)
    assert rep.relight == relit
    frame = sess.render()
    assert bool(frame.stats.get("relit")) == (relit if frame_relit is None else frame_relit)
    ref = fresh(sess)
    np.testing.assert_array_equal(frame.radiance, ref.radiance)
    np.testing.assert_array_equal(frame.pixel_class, ref.pixel_class)
    return frame


def seen_pixels(sess, *lights) -> int:
    """Pixels of the kept frame an edit of a light from the first of ``lights`` to the last
    traces again: those whose samples saw a light's own surface, or whose view or mirror
    rays cross its boxes where rays see it (tracing/seen_lights.py: that radiance is in no
    light term; the view rays only where the camera sees it)."""
    boxes = [(seen_extent(li), li.camera) for li in lights]
    regions = [(b, c) for b, c in boxes if b is not None and b is not True]
    fx = EditEffects(seen_regions=[b for b, _ in regions], seen_camera=[c for _, c in regions],
                     seen_sky=any(b is True for b, _ in boxes))
    rec = sess.reuse.records
    return int(rec.dirty_pixels(sess.scene.arrays(), camera_params(sess.scene.camera),
                                fx).sum())


def light(sess, key):
    return sess.scene.lights[sess.scene.light_slot(key)]


@pytest.mark.parametrize("scene_name", ["room", "soft_room"])
def test_power_colour_and_world_recombine_without_rays(scene_name):
    sess = Session(SOAK_SCENES[scene_name](W, H), SETTINGS)
    first = sess.render()
    assert sess.reuse.light_records_bytes > 0
    for key in list(sess.scene.light_keys.slot):
        li = light(sess, key)
        seen = seen_pixels(sess, li)
        frame = step(sess, [LightSet(key, replace(li, power=li.power * 0.4,
                                                  color=(1.0, 0.6, 0.3)))])
        # recombined: no shadow ray, no pixel traced but those that see the light's own
        # surface (or may: their rays cross its box)
        assert frame.stats["traced_pixels"] == seen
        assert frame.stats["rays_traced"] == 0 or seen
        assert frame.stats["relight_shadow_rays"] == 0
        assert not np.array_equal(frame.radiance, first.radiance)
    # the world: no shadow ray either; only the pixels the records always trace again
    # (FLAG_ALWAYS: a node that saw a light's own surface, in no light term, or left the
    # records' grid; here two pixels' reflections of the area light, since the pixel
    # sampler became a Sobol sequence)
    seen = seen_pixels(sess)
    frame = step(sess, [WorldColor((0.12, 0.2, 0.05))])
    assert frame.stats["traced_pixels"] == seen
    assert frame.stats["rays_traced"] == 0 or seen
    assert frame.stats["relight_shadow_rays"] == 0


@pytest.mark.parametrize("scene_name", ["room", "soft_room"])
def test_moved_lights_are_shaded_again_alone(scene_name):
    sess = Session(SOAK_SCENES[scene_name](W, H), SETTINGS)
    sess.render()
    for key in list(sess.scene.light_keys.slot):
        li = light(sess, key)
        if li.kind == "SUN":
            moved = replace(li, direction=(0.1, -0.4, -1.0), angle=li.angle * 1.5)
        else:
            moved = replace(li, position=tuple(np.asarray(li.position) + (0.7, -0.3, 0.2)))
        seen = seen_pixels(sess, li, moved)
        frame = step(sess, [LightSet(key, moved)])
        assert frame.stats["relit_lights"] == [sess.scene.light_slot(key)]
        assert frame.stats["relight_shadow_rays"] > 0
        assert frame.stats["traced_pixels"] == seen  # (those that may see it, above)
        assert frame.stats["primary_rays"] == 0 or seen
    if scene_name == "soft_room":  # an area light resized, reshaped and spread
        area = light(sess, "Area")
        step(sess, [LightSet("Area", replace(area, shape="ELLIPSE", size=(1.2, 0.6),
                                             spread=1.2))])
        lamp = light(sess, "Lamp")
        step(sess, [LightSet("Lamp", replace(lamp, radius=0.0))])  # soft to hard
        step(sess, [LightSet("Lamp", replace(lamp, radius=0.4))])  # and back


def test_a_resized_area_light_skips_the_samples_proven_visible(monkeypatch):
    """A light with an extent shaded again skips, at the primary nodes, the samples the base
    tracer's shaft proofs show unoccluded (per 8x8 tile and instance,
    ``shaft_skip.proven_rows``; a resized soft box on studio traced 3.1 M samples, slower
    than a fresh frame): the frame is a fresh one's bit for bit, the same as with the
    proofs off, which traces every skipped sample."""
    frames = {}
    for skip in (True, False):
        monkeypatch.setattr(shaft_skip, "SHAFT_SKIP", skip)
        sess = Session(SOAK_SCENES["soft_room"](64, 48), SETTINGS)
        sess.render()
        area = light(sess, "Area")
        for size in ((1.2, 0.6), (0.5, 0.9)):
            frame = step(sess, [LightSet("Area", replace(area, size=size))])
            assert frame.stats["relit_lights"] == [sess.scene.light_slot("Area")]
            frames[skip, size] = frame
    for size in ((1.2, 0.6), (0.5, 0.9)):
        on, off = frames[True, size].stats, frames[False, size].stats
        np.testing.assert_array_equal(frames[True, size].radiance, frames[False, size].radiance)
        assert on["relight_shadow_skipped"] > 0.2 * off["relight_shadow_rays"]
        assert off["relight_shadow_skipped"] == 0
        assert (on["relight_shadow_rays"] + on["relight_shadow_skipped"]
                == off["relight_shadow_rays"])


@pytest.mark.parametrize("scene_name", ["room", "rough_room"])
def test_a_lights_diffuse_or_glossy_visibility_is_shaded_again(scene_name):
    """A light's term holds both lobes: turning its diffuse or glossy visibility off or on
    re-shades that light alone (a rescale would keep the lobe), bit for bit a fresh frame
    (found by the seeded sequences once they toggled ray visibility)."""
    sess = Session(SOAK_SCENES[scene_name](W, H), SETTINGS)
    sess.render()
    key = "Lamp"
    li = light(sess, key)
    for flags in (dict(glossy=False), dict(diffuse=False), dict(diffuse=True, glossy=True)):
        li = replace(li, **flags)
        frame = step(sess, [LightSet(key, li)])
        assert frame.stats["relit_lights"] == [sess.scene.light_slot(key)]


@pytest.mark.parametrize("scene_name", ["room", "soft_room"])
def test_linked_lights_are_relit_with_their_links(scene_name):
    """Under light and shadow linking a light's power or colour recombines (its terms were
    shaded with its links), and moving, resizing or relinking it shades it again alone
    with its links -- only its receivers get its term, only its blockers stop its shadow
    rays (or samples) -- bit for bit a fresh frame, no primary ray traced. Shadow linking
    turned on or off (every light's shadow query changes) re-traces what it reaches."""
    sess = Session(SOAK_SCENES[scene_name](W, H), SETTINGS)
    sess.render()
    slot = sess.scene.light_slot("Lamp")

    def relit(li, **kw):
        seen = seen_pixels(sess, light(sess, "Lamp"), li)
        frame = step(sess, [LightSet("Lamp", li)], **kw)
        if kw.get("relit", True):
            assert frame.stats["relit_lights"] == [slot]
            assert frame.stats["traced_pixels"] == seen
            assert frame.stats["primary_rays"] == 0 or seen
        return frame

    def moved(li, dx):
        return replace(li, position=tuple(np.asarray(li.position) + dx))

    # light linking: the Lamp lights the ball and the floor only
    li = replace(light(sess, "Lamp"), receivers=(("Ball", True), ("Floor", True)))
    relit(li)
    relit(li := moved(li, (0.5, -0.2, 0.1)))
    frame = relit(li := replace(li, radius=li.radius * 1.5 + 0.05))
    assert frame.stats["relight_shadow_rays"] > 0
    relit(li := replace(li, receivers=(("Box", False),)))  # relinked: all but the box
    # shadow linking turned on: every light's shadow rays change their query (re-traced)
    frame = relit(li := replace(li, blockers=(("Box", False),)), relit=False)
    assert frame.stats["traced_pixels"] > 0
    # with blockers set: moved, resized, its blockers changed -- relit
    relit(li := moved(li, (-0.6, 0.3, -0.1)))
    relit(li := replace(li, radius=li.radius * 0.5))
    relit(li := replace(li, blockers=(("Ball", False),), receivers=()))
    brighter = replace(li, power=li.power * 0.6, color=(1.0, 0.7, 0.4))
    seen = seen_pixels(sess, li)  # (its own surface seen: in no term)
    frame = step(sess, [LightSet("Lamp", li := brighter)])
    assert frame.stats["relight_shadow_rays"] == 0
    assert frame.stats["traced_pixels"] == seen
    frame = relit(li := replace(li, blockers=()), relit=False)  # shadow linking off
    assert frame.stats["traced_pixels"] > 0


def test_linked_light_terms_follow_the_links():
    """The relit term of a linked light is its links' term: a receiver set that leaves
    out every object relights a frame without the light, and blockers of nothing a frame
    without its shadows (each equal to a fresh frame, asserted by ``step``)."""
    sess = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    sess.render()
    li = light(sess, "Lamp")
    names = [inst["name"] for inst in sess.scene.instances]
    no_lamp = step(sess, [LightSet("Lamp", replace(li, power=0.0))])
    step(sess, [LightSet("Lamp", li)])
    off = step(sess, [LightSet("Lamp", replace(li, receivers=tuple(
        (n, False) for n in names)))])
    np.testing.assert_array_equal(off.radiance, no_lamp.radiance)
    assert off.stats["relit_lights"] == [sess.scene.light_slot("Lamp")]
    assert off.stats["relight_shadow_rays"] == 0  # (it faces no receiver: no shadow ray)
    with_blockers = step(sess, [LightSet("Lamp", replace(li, receivers=(),
                                                         blockers=(("Box", False),)))],
                         relit=False)
    unblocked = step(sess, [LightSet("Lamp", replace(li, blockers=tuple(
        (n, False) for n in names)))])
    assert not np.array_equal(unblocked.radiance, with_blockers.radiance)


def test_added_and_deleted_lights():
    scene = SOAK_SCENES["room"](W, H)
    scene.set_world_color((0.05, 0.05, 0.06), lights=False)
    sess = Session(scene, SETTINGS)
    sess.render()
    step(sess, [LightDelete("Lamp")])
    step(sess, [LightSet("New", Light("New", "POINT", power=700.0,
                                      position=(0.5, -1.0, 3.0)))])  # the freed slot
    step(sess, [LightSet("Newer", Light("Newer", "SPOT", power=900.0,
                                        position=(-1.0, 1.0, 3.0), radius=0.2,
                                        direction=(0.2, -0.2, -1.0)))])  # a new slot
    step(sess, [LightDelete("Spot"), LightDelete("New")])


def test_world_light_needs_its_samples():
    """A world that starts to light changes the world's samples: that batch re-traces
    (exactly). A light slot added or deleted while it lights keeps them (the world's row
    is seeded by a fixed id, not by the number of slots, soft_lights.row_hash): relit, no
    pixel re-traced."""
    scene = SOAK_SCENES["room"](W, H)
    scene.set_world_color((0.05, 0.05, 0.06), lights=False)
    sess = Session(scene, SETTINGS)
    sess.render()
    step(sess, [WorldColor((0.1, 0.1, 0.12), lights=True)], relit=False)
    step(sess, [WorldColor((0.2, 0.1, 0.12))])  # now it lights: its terms are kept
    extra = Light("Extra", "POINT", power=300.0, position=(1.0, 1.0, 3.0))
    panel = Light("Panel", "AREA", power=200.0, position=(-1.0, 0.5, 2.8),
                  direction=(0.0, 0.0, -1.0), axis=(1.0, 0.0, 0.0), size=(0.6, 0.4),
                  shape="RECTANGLE")
    for li, edit in ((extra, LightSet("Extra", extra)), (panel, LightSet("Panel", panel)),
                     (extra, LightDelete("Extra"))):
        seen = seen_pixels(sess, li)  # (its own surface: in no light term)
        frame = step(sess, [edit])
        assert frame.stats["traced_pixels"] == seen < W * H // 10, edit
    step(sess, [WorldColor((0.1, 0.2, 0.12))])  # the world's terms kept through the slots


def test_mixed_batches_and_later_object_edits():
    """Light edits with object edits, a relit moved light followed by an object moving into
    its new shadow shafts: the pixel records' light bits follow the relit light."""
    sess = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    sess.render()
    lamp = light(sess, "Lamp")
    key = next(k for k, i in sess.scene.live_instances() if i["name"] != "Floor")
    name_key = sess.scene.instance_keys
    obj = next(k for k, v in name_key.slot.items() if v == key)
    m = sess.scene.instances[key]["matrix"].copy()
    m[0, 3] += 0.2
    step(sess, [LightSet("Lamp", replace(lamp, power=lamp.power * 2.0)),
                ObjectTransform(obj, m)], relit=False)
    step(sess, [LightSet("Lamp", replace(lamp, position=(1.5, 1.5, 3.0)))])
    # two batches before one frame: a light moved, then an object
    sess.apply([LightSet("Lamp", replace(lamp, position=(-1.0, 2.0, 2.5)))])
    m[1, 3] -= 0.3
    frame = step(sess, [ObjectTransform(obj, m)], relit=False, frame_relit=True)
    assert 0 < frame.stats["traced_pixels"] < W * H
    m[:3, 3] = (-0.5, 1.2, 1.0)  # into the lamp's new shafts
    step(sess, [ObjectTransform(obj, shapes.transform(m[:3, 3], 0.5))], relit=False)


def test_a_light_moved_before_a_mesh_is_added_renders_in_full():
    """Two batches before one frame: a light moved (to be shaded again), then a mesh added,
    which renumbers the triangles and drops the light records' geometry: the moved light
    cannot be relit, so the frame is traced in full, == fresh (it raised before)."""
    sess = Session(SOAK_SCENES["soft_room"](W, H), SETTINGS)
    sess.render()
    spot = light(sess, "Spot")
    assert sess.apply([LightSet("Spot", replace(spot, position=(2.5, -3.0, 3.0)))]).relight
    rep = sess.apply([MeshSet("newmesh", shapes.box((0.5, 0.5, 0.5), name="newmesh"))])
    assert rep.full_frame and any("could not be relit" in m for m in rep.messages)
    frame = sess.render()
    assert frame.stats["traced_pixels"] == W * H
    np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)


def test_random_light_edit_sequences_stay_exact():
    """Seeded random sequences of every edit kind (light power, colour, moves, adds,
    deletes, extents and the world among them): bit for bit a fresh frame."""
    gen = EditGenerator(SOAK_SCENES["soft_room"](24, 18), seed=21, camera=False,
                        extra=EditGenerator.SOFT_KINDS)
    sess = Session(gen.scene.copy(), RenderSettings(mode="BASE", max_depth=3))
    sess.render()
    relit = 0
    for _ in range(30):
        sess.apply(gen.step())
        due = sess.reuse.relight_due
        frame = sess.render()
        relit += due
        np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)
    assert relit >= 5, gen.kinds_done


def _records(cap_mb=1e6):
    """A rendered room session with the light records under ``cap_mb``, and their parts."""
    sess = Session(SOAK_SCENES["room"](W, H), replace(SETTINGS, relight_memory_mb=cap_mb))
    return sess, sess.render()


def test_record_cap():
    """Over the cap the geometry goes first (moved lights re-trace, said in the frame's
    stats and the edit's messages; power still relights); then everything (light edits
    re-trace); a cap of zero is refused, naming the setting."""
    sess, _ = _records()
    lr = sess.reuse.light_records
    full = lr.nbytes
    geo = lr.p.geo_bytes + lr.s.geo_bytes
    assert 0 < geo < full
    # between the terms alone and everything: no geometry
    sess, first = _records((full - geo / 2) / 1e6)
    assert "relight_memory_mb" in first.stats["relight_moves_off"]
    assert "relight_off" not in first.stats
    assert 0 < sess.reuse.light_records_bytes <= full - geo
    li = light(sess, "Lamp")
    step(sess, [LightSet("Lamp", replace(li, power=li.power * 0.5))])
    rep = sess.apply([LightSet("Lamp", replace(light(sess, "Lamp"),
                                               position=(-1.7, -2.1, 3.4)))])
    assert not rep.relight and any("re-traced, not relit" in m for m in rep.messages)
    frame = sess.render()
    assert not frame.stats.get("relit") and frame.stats["traced_pixels"] > 0
    np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)
    # under the terms alone: nothing kept
    sess, first = _records((full - geo) / 2e6)
    assert "relight_memory_mb" in first.stats["relight_off"]
    assert sess.reuse.light_records_bytes == 0
    li = light(sess, "Lamp")
    step(sess, [LightSet("Lamp", replace(li, power=li.power * 0.5))], relit=False)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(SceneError, match="relight_memory_mb"):
            sess.update_settings(replace(SETTINGS, relight_memory_mb=bad))
    assert sess.settings.relight_memory_mb == (full - geo) / 2e6  # nothing half-applied


def test_record_cap_zero_keeps_no_records():
    """A cap of 0: no records, said in the frame's stats; light edits re-trace (equal to a
    fresh frame) and the frames cost nothing for the terms."""
    sess, first = _records(0.0)
    assert first.stats["relight_off"] == RELIGHT_OFF and "relight_memory_mb" in RELIGHT_OFF
    assert sess.reuse.light_records_bytes == 0 and sess.records.light is None
    li = light(sess, "Lamp")
    frame = step(sess, [LightSet("Lamp", replace(li, power=li.power * 0.5))], relit=False)
    assert frame.stats["incremental"] and frame.stats["relight_off"] == RELIGHT_OFF
    # raised again: the next full frame keeps them
    sess.update_settings(replace(SETTINGS, relight_memory_mb=100.0))
    frame = sess.render()
    assert "relight_off" not in frame.stats and sess.reuse.light_records_bytes > 0
    step(sess, [LightSet("Lamp", replace(li, power=li.power * 0.3))])


def test_records_are_sparse():
    """A node keeps only the terms the shader added: fewer entries than nodes times slots,
    and 9 bytes + 88 per surface node + 24 per secondary node + 25 per term."""
    sess, _ = _records()
    lr = sess.reuse.light_records
    p, s = lr.p, lr.s
    n_nodes = len(p) + len(s)
    entries = len(p.slot) + len(s.slot)
    assert entries < n_nodes * (lr.L + 2)
    hits = int(p.hit.sum() + s.hit.sum())
    expect = (n_nodes * light_records.NODE_BYTES + 8 * 2 + hits * light_records.GEO_BYTES
              + len(s) * light_records.WEIGHT_BYTES + entries * light_records.ENTRY_BYTES)
    assert lr.nbytes == expect


@pytest.mark.parametrize("bad", [dict(power=float("nan")), dict(power=-5.0),
                                 dict(power=float("inf")), dict(color=(1.0, float("nan"), 0.0)),
                                 dict(position=(0.0, float("inf"), 1.0)),
                                 dict(power=10.0 * MAX_LIGHT_POWER), dict(color=(1.0, -0.5, 0.0)),
                                 dict(radius=-0.1), dict(radius=float("nan")),
                                 dict(kind="LASER")])
def test_bad_light_edits_keep_the_frame(bad):
    sess = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    first = sess.render()
    li = light(sess, "Lamp")
    with pytest.raises(SceneError, match="Lamp"):
        sess.apply([LightSet("Spot", replace(light(sess, "Spot"), power=10.0)),
                    LightSet("Lamp", replace(li, **bad))])
    assert not sess.reuse.relight_due
    assert light(sess, "Spot").power != 10.0  # nothing half-applied
    again = sess.render()
    np.testing.assert_array_equal(again.radiance, first.radiance)


def test_light_terms_start_at_the_first_light_edit(monkeypatch):
    """By default a session keeps no light terms until a light or the world is edited (they
    cost every full frame): the frame after the first light edit is a full one that keeps
    them, and the next light edit relights; each frame equals a fresh one."""
    monkeypatch.setattr(Session, "light_terms", None)
    sess = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    first = sess.render()
    assert first.stats["light_records_mb"] == 0.0
    lamp = next(li for li in sess.scene.lights if li.kind == "POINT")
    rep = sess.apply([LightSet(lamp.name, replace(lamp, power=lamp.power * 0.7))])
    assert not rep.relight
    frame = sess.render()
    assert not frame.stats["incremental"] and frame.stats["light_records_mb"] > 0.0
    np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)
    step(sess, [LightSet(lamp.name, replace(lamp, power=lamp.power * 0.5))])
    # an object edit alone does not start them
    other = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    other.render()
    m = other.scene.instances[other.scene.instance_slot("Small")]["matrix"].copy()
    m[1, 3] += 0.2
    other.apply([ObjectTransform("Small", m)])
    assert other.render().stats["light_records_mb"] == 0.0


def test_light_deleted_while_a_relit_frame_is_in_flight():
    """A viewport worker relighting a moved light while the light is deleted: the deletion
    waits for its turn (the session applies queued edits between frames), the next frame
    drops the light's term, and the image equals a fresh render without it; deleting it
    again is refused naming the light, the frame kept."""
    import threading

    from rstrace_engine.interactive import ViewportWorker

    sess = Session(SOAK_SCENES["room"](W, H), replace(SETTINGS, samples=1))
    worker = ViewportWorker(threading.Lock(), samples=1)
    try:
        worker.submit(session=sess, camera=sess.scene.camera, settings=sess.settings)
        assert worker.wait_idle(300)
        li = light(sess, "Lamp")
        sess.submit([LightSet("Lamp", replace(li, position=(-1.8, -2.0, 3.5)))])
        worker.submit()
        sess.submit([LightDelete("Lamp")])  # while that frame may be in flight
        worker.submit()
        assert worker.wait_idle(300)
        assert "Lamp" not in sess.scene.light_keys.slot
        frame = worker.last_frame
        np.testing.assert_array_equal(frame.radiance, fresh(sess).radiance)
        with pytest.raises(SceneError, match="Lamp"):
            sess.apply([LightDelete("Lamp")])
        sess.submit([LightSet("Spot", replace(light(sess, "Spot"), power=700.0)),
                     LightDelete("Lamp")])
        worker.submit()
        assert worker.wait_idle(300)
        assert worker.error is not None and "Lamp" in worker.error, worker.error
        assert light(sess, "Spot").power != 700.0  # nothing half-applied
        np.testing.assert_array_equal(worker.last_frame.radiance, frame.radiance)
    finally:
        worker.stop()


def test_a_drag_keeps_the_light_term_apart():
    """A light moved step after step (a drag) keeps its term apart from the sparse entries
    (replaced in place each step); another light's edit keeps it apart, a move of another
    light folds it back (and keeps that light's apart). An object edit in the middle of a
    drag keeps it apart too: the frame that traces the dirty pixels splices their new nodes
    into the records (:mod:`~rstrace_engine.tracing.light_nodes`), the new nodes' term of
    the dragged light taken from their entries. Every frame equals a fresh one bit for bit.
    The Lamp is made unseen by mirror and refraction rays: the pixels that see a light are
    traced again at every light edit (:mod:`~rstrace_engine.tracing.seen_lights`)."""
    sess = Session(SOAK_SCENES["soft_room"](W, H), SETTINGS)
    sess.apply([LightSet("Lamp", replace(light(sess, "Lamp"), glossy=False,
                                         transmission=False))])
    sess.render()
    lamp, spot = light(sess, "Lamp"), light(sess, "Spot")
    j = sess.scene.light_slot("Lamp")
    for k in range(3):
        step(sess, [LightSet("Lamp", replace(lamp, position=tuple(
            np.asarray(lamp.position) + (0.05 * (k + 1), 0.0, 0.0))))])
        lr = sess.reuse.light_records
        assert lr.p.dj == j and lr.s.dj in (j, -1)
    step(sess, [LightSet("Spot", replace(spot, power=spot.power * 3.0))])
    assert sess.reuse.light_records.p.dj == j  # (recombined with the term apart)
    step(sess, [LightSet("Spot", replace(spot, position=(0.3, 0.2, 2.8)))])
    assert sess.reuse.light_records.p.dj == sess.scene.light_slot("Spot")
    step(sess, [LightSet("Lamp", replace(light(sess, "Lamp"), power=lamp.power * 0.5))])
    step(sess, [LightDelete("Spot")])
    step(sess, [LightSet("Lamp", replace(light(sess, "Lamp"), position=(0.35, -0.2, 2.9)))])
    assert sess.reuse.light_records.p.dj == j
    obj = next(k for k, v in sess.scene.instance_keys.slot.items()
               if sess.scene.instances[v]["name"] != "Floor")
    for k in range(2):
        m = sess.scene.instances[sess.scene.instance_slot(obj)]["matrix"].copy()
        m[0, 3] += 0.2
        step(sess, [ObjectTransform(obj, m)], relit=False)
        lr = sess.reuse.light_records
        assert lr.p.dj == j and lr.s.dj in (j, -1)  # (spliced, not folded)
        step(sess, [LightSet("Lamp", replace(light(sess, "Lamp"), position=(
            0.4 + 0.05 * k, -0.2, 2.9)))])
        assert sess.reuse.light_records.p.dj == j


def test_light_edits_repack_only_the_lights():
    """A batch of light and world edits packs the lights and the world again and keeps
    the rest of the packing: equal to packing the edited scene from scratch."""
    sess = Session(SOAK_SCENES["soft_room"](W, H), SETTINGS)
    old = sess.scene.arrays()
    sess.render()
    top = sess.accel.sb  # (the BVH's top level)
    lamp = light(sess, "Lamp")
    sess.apply([LightSet("Lamp", replace(lamp, position=(0.1, 0.2, 2.7), power=90.0)),
                LightSet("Extra", Light("Extra", "SPOT", power=300.0, position=(1, 1, 3),
                                        direction=(0.0, 0.0, -1.0))),
                LightDelete("Spot"), WorldColor((0.2, 0.1, 0.05), lights=True)])
    sa = sess.scene.arrays()
    assert sa.verts is old.verts and sa.inst_xform is old.inst_xform  # (kept, not packed)
    # the accelerator keeps its top level (the same instances) and traces the new packing
    assert sess.accel.sb is top and sess.accel.sa is sa
    np.testing.assert_array_equal(sess.render().radiance, fresh(sess).radiance)
    scratch = sess.scene.copy()
    scratch._arrays = None
    ref = scratch.arrays()
    for name in ref._fields:
        a, b = getattr(sa, name), getattr(ref, name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape, name
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            assert a == b, name
    m = sess.scene.instances[sess.scene.instance_slot("Small")]["matrix"].copy()
    m[0, 3] += 0.1
    sess.apply([ObjectTransform("Small", m)])
    assert sess.accel.sb is not top  # (an object moved: rebuilt)
    np.testing.assert_array_equal(sess.render().radiance, fresh(sess).radiance)


@pytest.mark.parametrize("key", ["Lamp", "Spot"])
def test_a_drag_skips_the_shadow_rays_its_ball_proves(monkeypatch, key):
    """From a point or spot light's second drag step on, the primary nodes proven to see
    every point of a ball ahead of it (light_reshade.DRAG_BALL_REL; per tile and instance,
    the shaft skips' proof) trace no shadow ray while it stays in the ball. Every proven
    ray, traced anyway (CHECK_PROOFS), is unoccluded, and every frame equals a fresh one
    bit for bit. An object edit mid-drag drops the proof (new trees, new nodes)."""
    from rstrace_engine.tracing import light_reshade

    monkeypatch.setattr(light_reshade, "CHECK_PROOFS", True)
    monkeypatch.setattr(light_reshade, "DRAG_BALL_REL", 0.02)  # (0.35 m in the room)
    sess = Session(SOAK_SCENES["room"](W, H), SETTINGS)
    sess.render()

    def drag(n):
        out = []
        for _ in range(n):
            li = light(sess, key)
            frame = step(sess, [LightSet(key, replace(li, position=tuple(
                np.asarray(li.position) + (0.05, 0.02, 0.0))))])
            out.append(frame.stats["relight_shadow_skipped"])
        return out

    skipped = drag(8)
    assert skipped[0] == 0 and all(s > 0 for s in skipped[1:]), skipped
    lr = sess.reuse.light_records
    assert lr.p.proof is not None and lr.p.proof.proven.any()
    # a proof holds while the light is in its ball: a new one is made after it left
    centers = {tuple(lr.p.proof.center)}
    skipped = drag(12)
    centers.add(tuple(sess.reuse.light_records.p.proof.center))
    assert len(centers) == 2 and all(s > 0 for s in skipped)
    m = sess.scene.instances[sess.scene.instance_slot("Box")]["matrix"].copy()
    m[0, 3] += 0.2
    step(sess, [ObjectTransform("Box", m)], relit=False)
    skipped = drag(3)
    assert skipped[0] == 0 and skipped[1] > 0
    # a jump (longer than the ball) proves nothing; power edits keep the proof
    li = light(sess, key)
    frame = step(sess, [LightSet(key, replace(li, position=tuple(
        np.asarray(li.position) + (-1.0, 0.0, 0.0))))])
    assert frame.stats["relight_shadow_skipped"] == 0
    step(sess, [LightSet(key, replace(light(sess, key), power=li.power * 2.0))])
    assert drag(2)[1] > 0


def test_a_ball_proof_holds_everywhere_in_the_ball():
    """shaft_skip.ball_rows: from every point of the ball (random points, its surface
    included) every proven node's shadow ray is unoccluded; the proof is not empty, and
    a ball moved to where the Box shadows the floor proves fewer nodes."""
    from rstrace_engine.tracing.light_linking import occluded
    from rstrace_engine.tracing.light_reshade import _one_light, one_light_states
    from rstrace_engine.tracing.shaft_skip import ball_rows, tile_keys
    from rstrace_engine.tracing.whitted import shadow_rays

    w, h = 64, 48
    sess = Session(SOAK_SCENES["room"](w, h), replace(SETTINGS, samples=1))
    sess.render()
    sa = sess.scene.arrays()
    p = sess.reuse.light_records.p
    rows = np.flatnonzero(p.hit)
    surf = p.surfaces(sa, False)
    inst = p.geo["inst"]
    keys = tile_keys(rows % (w * h), w)
    sa1 = _one_light(sa, sess.scene.light_slot("Lamp"))
    rng = np.random.default_rng(3)
    radius = 0.4
    counts = []
    for center in (np.asarray(sa1.light_pos[0]), np.asarray(sa1.light_pos[0]) + (0, 0, -1.5)):
        state = np.empty(len(rows), np.int8)
        mat = np.empty(len(rows), np.int32)
        one_light_states(sa1._replace(light_pos=center.reshape(1, 3)), 0, surf.P, surf.NG,
                         surf.NS, surf.Q, surf.mat, inst, state, mat)
        traced = state == 1
        proven = ball_rows(sa1, sess.accel, 0, center, radius, surf, traced, inst, keys)
        assert proven is not None and proven.any() and not (proven & ~traced).any()
        counts.append(int(proven.sum()))
        for _ in range(12):
            u = rng.normal(size=3)
            pos = center + radius * rng.random() ** (1 / 3) * u / np.linalg.norm(u)
            sa_p = sa1._replace(light_pos=pos.reshape(1, 3))
            st = np.empty(len(rows), np.int8)
            one_light_states(sa_p, 0, surf.P, surf.NG, surf.NS, surf.Q, surf.mat, inst,
                             st, mat)
            # the proven nodes the light faces from there: their rays are unoccluded
            todo, so, sd, tmax = shadow_rays(sa_p, surf._replace(
                sh_state=np.where(proven & (st == 1), st, np.int8(-2))))
            assert len(todo) and not occluded(sa_p, sess.accel, so, sd, tmax,
                                              np.zeros(len(todo), np.int64)).any()
    assert counts[1] != counts[0]
