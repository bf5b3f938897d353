"""Lights seen directly (tracing/seen_lights.py): the radiance camera, mirror and refraction
rays gather from a light's own surface, as Cycles shows it (the values Cycles 5.0 renders
are checked in tests/blender/test_seen_lights.py), incremental frames after light edits,
and the interpolants' bound where rays can see a light."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from tracer_scenes import plane_scene

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.edits import LightSet
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.interpolants.samples import SEES_LIGHT, seen_flags
from rstrace_engine.session import Session
from rstrace_engine.tracing import whitted

GREY = Material("grey", diffuse=(0.5, 0.5, 0.5))
MIRROR = principled_material("mirror", (1.0, 1.0, 1.0), metallic=1.0, roughness=0.0)[0]
DOWN = np.array([0.0, 0.0, -1.0])


def _trace(scene, o, d, depth=0, **kw):
    sa = scene.arrays()
    acc = create_accelerator("BRUTE_FORCE", sa)
    o = np.asarray(o, np.float64).reshape(-1, 3)
    d = np.asarray(d, np.float64).reshape(-1, 3)
    return whitted.trace(sa, acc, o, d, 0.0, np.inf, depth, **kw)[0]


def _seen_part(light, o, d, depth=0, floor=GREY, **kw):
    """What rays ``o, d`` gather from ``light``'s surface: the radiance with the light as
    given minus with its camera, glossy and transmission visibility off (the floors here
    have no highlight the glossy visibility would also take)."""
    on = _trace(plane_scene(floor, [light]), o, d, depth, **kw)
    off = replace(light, camera=False, glossy=False, transmission=False)
    return on - _trace(plane_scene(floor, [off]), o, d, depth, **kw)


def test_area_light_rectangle_and_ellipse_from_the_front_only():
    p = 100.0
    for shape, area in (("RECTANGLE", 1.0 * 0.5), ("ELLIPSE", math.pi / 4 * 0.5)):
        li = Light("A", "AREA", power=p, position=(0.0, 0.0, 2.0), direction=(0.0, 0.0, 1.0),
                   shape=shape, size=(1.0, 0.5), camera=True, color=(1.0, 0.5, 0.25))
        # inside, near a corner (the ellipse misses it), outside along each axis
        o = [[0.1, 0.1, 5.0], [0.45, 0.2, 5.0], [0.55, 0.0, 5.0], [0.0, 0.3, 5.0]]
        got = _seen_part(li, o, np.tile(DOWN, (4, 1)))
        want = p / (math.pi * area) * np.array([1.0, 0.5, 0.25])
        np.testing.assert_allclose(got[0], want, rtol=1e-12)
        np.testing.assert_allclose(got[1], want if shape == "RECTANGLE" else 0.0, rtol=1e-12)
        assert np.all(got[2:] == 0.0)
        # from behind (rays going up through it): not seen; facing away from the camera
        back = _seen_part(li, [[0.1, 0.1, 1.0]], [[0.0, 0.0, 1.0]])
        assert np.all(back == 0.0)


def test_area_spread_attenuates_what_the_camera_sees():
    spread = math.radians(30.0)
    li = Light("A", "AREA", power=100.0, position=(0.0, 0.0, 2.0), direction=(0.0, 0.0, 1.0),
               size=(1.0, 1.0), spread=spread, camera=True)
    theta = math.radians(5.0)
    d = np.array([math.sin(theta), 0.0, -math.cos(theta)])
    got = _seen_part(li, [-3.0 * d], [d])[0, 0]
    half = spread / 2
    want = 100.0 / math.pi * (math.tan(half) - math.tan(theta)) / (math.tan(half) - half)
    assert got == pytest.approx(want, rel=1e-9)
    steep = math.radians(20.0)  # beyond the spread: dark
    d = np.array([math.sin(steep), 0.0, -math.cos(steep)])
    assert _seen_part(li, [-3.0 * d + [0, 0, 2.0]], [d])[0, 0] == 0.0


@pytest.mark.parametrize("soft", [False, True])
def test_sphere_light_ball_or_facing_disk(soft):
    r, dist = 0.5, 3.0
    li = Light("P", "POINT", power=100.0, position=(0.0, 0.0, 2.0), radius=r,
               soft_falloff=soft, camera=True)
    o = np.array([0.0, 0.0, 2.0 + dist])
    want = 100.0 / (4.0 * math.pi ** 2 * r * r)
    # the centre, and a direction between the disk's and the ball's angular radius
    between = 0.5 * (math.atan(r / dist) + math.asin(r / dist))
    dirs = np.array([DOWN, [math.sin(between), 0.0, -math.cos(between)]])
    got = _seen_part(li, np.tile(o, (2, 1)), dirs)[:, 0]
    assert got[0] == pytest.approx(want, rel=1e-12)
    assert got[1] == (0.0 if soft else pytest.approx(want, rel=1e-12))


def test_soft_falloff_disk_faces_the_rays_start():
    """Cycles faces the disk to ``ray->P``, which for a camera ray is on the clip-start
    plane: the disk faces ``o + t0 d``, not ``o`` (1.2 m from a 0.6 m light, clip start
    0.1 m: 1004 lit pixels in Cycles where facing the eye gives 1044)."""
    from rstrace_engine.tracing.seen_lights import SEEN_CAMERA, seen

    r, c = 0.6, np.array([0.0, 0.0, 2.0])
    li = Light("P", "POINT", power=100.0, position=tuple(c), radius=r, soft_falloff=True,
               camera=True)
    sa = plane_scene(GREY, [li]).arrays()
    o = c + [0.0, 0.0, 1.2]
    ang = np.radians(np.linspace(25.0, 28.0, 61))  # edges: 25.97 (start), 26.57 (eye)
    d = np.stack([np.sin(ang), np.zeros_like(ang), -np.cos(ang)], axis=1)
    n = len(d)
    t0 = np.full(n, 0.1 / np.cos(ang))  # the clip-start plane, 0.1 along the view axis

    def hits(start):  # the disk of radius r through c facing ``start``, met by each ray
        nrm = (start - c) / np.linalg.norm(start - c, axis=1)[:, None]
        t = (nrm @ (c - o)) / np.einsum("ij,ij->i", d, nrm)
        return np.linalg.norm(o + t[:, None] * d - c, axis=1) <= r

    want = hits(o + t0[:, None] * d)
    assert (want != hits(np.tile(o, (n, 1)))).sum() >= 5  # the two differ on these rays
    got = seen(sa, np.tile(o, (n, 1)), d, t0, np.full(n, 10.0), np.ones(n, np.bool_),
               np.full(n, SEEN_CAMERA, np.int8), np.ones((n, 3)))[:, 0]
    radiance = 100.0 / (4.0 * math.pi ** 2 * r * r)
    assert np.array_equal(got > 0.0, want)
    assert got[want] == pytest.approx(radiance, rel=1e-12)


def test_spot_seen_through_its_cone_toward_it_only():
    size, blend = math.radians(60.0), 0.3
    li = Light("S", "SPOT", power=100.0, position=(0.0, 0.0, 2.0), direction=(0.0, 0.0, 1.0),
               radius=0.25, soft_falloff=False, spot_size=size, spot_blend=blend,
               camera=True)
    want = 100.0 / (4.0 * math.pi ** 2 * 0.25 ** 2)
    assert _seen_part(li, [[0.0, 0.0, 5.0]], [DOWN])[0, 0] == pytest.approx(want, rel=1e-12)
    a = math.radians(27.0)  # in the blend: Cycles' smoothstep of the cone
    o = np.array([0.0, 0.0, 2.0]) + 3.0 * np.array([math.sin(a), 0.0, math.cos(a)])
    cos_out = math.cos(size / 2)
    x = (math.cos(a) - cos_out) / ((1.0 - cos_out) * blend)
    got = _seen_part(li, [o], [np.array([0.0, 0.0, 2.0]) - o])[0, 0]
    assert got == pytest.approx(want * x * x * (3.0 - 2.0 * x), rel=1e-9)
    down = replace(li, direction=(0.0, 0.0, -1.0))  # pointing away from the camera
    assert _seen_part(down, [[0.0, 0.0, 5.0]], [DOWN])[0, 0] == 0.0


def test_sun_disc_on_rays_that_hit_nothing():
    angle = math.radians(10.0)
    li = Light("Sun", "SUN", power=3.0, direction=(0.0, 0.0, -1.0), angle=angle, camera=True)
    want = 3.0 / (math.pi * math.sin(angle / 2) ** 2)
    tilt = math.radians(4.0)
    dirs = [[0.0, 0.0, 1.0], [math.sin(tilt), 0.0, math.cos(tilt)],
            [math.sin(2 * tilt), 0.0, math.cos(2 * tilt)], DOWN]
    got = _seen_part(li, np.tile([0.0, 0.0, 1.0], (4, 1)), dirs)[:, 0]
    np.testing.assert_allclose(got, [want, want, 0.0, 0.0], rtol=1e-12)


def test_lights_are_not_opaque_and_visibility_says_who_sees():
    """A light adds to what is behind it (Cycles' rays pass on through lights); camera
    visibility off: camera rays do not see it."""
    li = Light("P", "POINT", power=100.0, position=(0.0, 0.0, 2.0), radius=0.5,
               soft_falloff=False)
    lit = Light("K", "POINT", power=500.0, position=(3.0, 0.0, 4.0))
    o, d = [[0.0, 0.0, 5.0]], [DOWN]
    unseen = _trace(plane_scene(GREY, [lit, li]), o, d)
    both = _trace(plane_scene(GREY, [lit, replace(li, camera=True)]), o, d)
    want = 100.0 / (4.0 * math.pi ** 2 * 0.25)
    assert unseen[0, 0] > 0.0  # the floor behind it, lit by both lights
    assert both[0, 0] == pytest.approx(unseen[0, 0] + want, rel=1e-12)


def _mirror_rays():
    """Rays from beside the light down onto the mirror floor, reflected into the light."""
    target = np.array([0.0, 0.0, 0.0])
    o = np.array([-2.0, 0.0, 2.0])
    return o[None], (target - o)[None]


def test_mirror_shows_the_light_glossy_visibility_off_hides_it():
    li = Light("P", "POINT", power=100.0, position=(2.0, 0.0, 2.0), radius=0.4,
               soft_falloff=False)
    o, d = _mirror_rays()
    want = 100.0 / (4.0 * math.pi ** 2 * 0.16)
    got = _seen_part(li, o, d, depth=1, floor=MIRROR)[0]
    np.testing.assert_allclose(got, want, rtol=1e-12)  # a white metal: Fresnel 1
    assert np.all(_seen_part(li, o, d, depth=0, floor=MIRROR) == 0.0)  # no bounce
    hidden = replace(li, glossy=False, camera=True, transmission=True)
    assert np.all(_seen_part(hidden, o, d, depth=1, floor=MIRROR) == 0.0)


def test_glass_shows_the_light_to_refraction_rays():
    li = Light("P", "POINT", power=100.0, position=(0.0, 0.0, -2.0), radius=0.4,
               soft_falloff=False)
    # IOR 1: straight through
    glass = principled_material("glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0,
                                ior=1.0)[0]
    o, d = [[0.0, 0.0, 3.0]], [DOWN]
    got = _seen_part(li, o, d, depth=2, floor=glass)[0, 0]
    assert got == pytest.approx(100.0 / (4.0 * math.pi ** 2 * 0.16), rel=1e-9)
    assert np.all(_seen_part(replace(li, transmission=False), o, d, depth=2,
                             floor=glass) == 0.0)


def test_rough_lobe_rays_see_no_light():
    """A rough surface's glossy rays do not see lights (the light is its direct light, from
    the lights' samples): no node below it is marked seen."""
    li = Light("P", "POINT", power=100.0, position=(2.0, 0.0, 2.0), radius=0.4,
               soft_falloff=False)
    rough = principled_material("rough", (1.0, 1.0, 1.0), metallic=1.0, roughness=0.4)[0]
    o, d = _mirror_rays()
    segs: list = []
    _trace(plane_scene(rough, [li]), np.tile(o, (64, 1)), np.tile(d, (64, 1)), depth=1,
           segments=segs, seeds=np.arange(64, dtype=np.uint64))
    assert len(segs) == 2 and len(segs[1]["inst"]) > 0
    assert not any(s["seen"].any() for s in segs)
    segs = []
    _trace(plane_scene(MIRROR, [li]), o, d, depth=1, segments=segs)
    assert segs[1]["seen"].all()


# ----------------------------------------------------------------------------- frames


def _stage(camera_seen=True, world=(0.0, 0.0, 0.0)):
    """A grey floor, a mirror ball, an area light the camera sees and a sphere light seen
    in the ball."""
    s = Scene()
    grey = s.add_material(GREY)
    mirror = s.add_material(MIRROR)
    s.add_instance(s.add_mesh(shapes.plane(12.0, name="floor")), np.eye(4), [grey],
                   name="Floor")
    m = np.eye(4)
    m[:3, 3] = (0.8, 0.5, 1.0)
    s.add_instance(s.add_mesh(shapes.uv_sphere(24, 12, 1.0, name="ball")), m, [mirror],
                   name="Ball")
    s.add_light(Light("Panel", "AREA", power=60.0, position=(-1.5, 0.5, 1.2),
                      direction=(0.0, -1.0, 0.0), axis=(1.0, 0.0, 0.0), size=(0.8, 0.5),
                      shape="RECTANGLE",
                      camera=camera_seen), key="Panel")
    s.add_light(Light("Bulb", "POINT", power=300.0, position=(1.5, -2.5, 2.5), radius=0.3,
                      soft_falloff=False), key="Bulb")
    s.set_world_color(world, lights=False)
    cam = np.eye(4)
    ang = math.radians(75.0)
    cam[:3, :3] = [[1.0, 0.0, 0.0], [0.0, math.cos(ang), -math.sin(ang)],
                   [0.0, math.sin(ang), math.cos(ang)]]
    cam[:3, 3] = (0.0, -6.0, 2.2)
    s.set_camera(Camera(matrix=cam, lens=30.0, width=48, height=36))
    return s


def test_frames_show_the_lights_camera_and_mirror():
    s = _stage()
    f = Session(s.copy(), RenderSettings(mode="BASE", max_depth=2, samples=2)).render()
    off = _stage(camera_seen=False)
    for j, li in off.live_lights():
        off.set_light(j, replace(li, glossy=False))
    g = Session(off, RenderSettings(mode="BASE", max_depth=2, samples=2)).render()
    diff = (f.radiance - g.radiance).max(axis=2)
    # the panel's pixels (its radiance 60 / (pi 0.4)), and the bulb in the ball
    assert (diff > 40.0).sum() >= 10, np.sort(diff.ravel())[-20:]
    assert np.all(diff >= -1e-3)


def _fresh(scene, settings):
    return Session(scene.copy(), settings).render()


@pytest.mark.parametrize("edit", ["move", "power", "hide", "bulb"])
def test_light_edits_redraw_the_pixels_that_see_it(edit):
    """BASE: after an edit of a seen light the incremental frame (relit or re-traced) is a
    fresh session's, bit for bit, and the pixels that saw or see the light were re-traced."""
    settings = RenderSettings(mode="BASE", max_depth=2, samples=1)
    sess = Session(_stage(), settings)
    sess.render()
    bulb = sess.scene.lights[sess.scene.light_slot("Bulb")]
    sess.apply([LightSet("Bulb", replace(bulb, power=310.0))])
    sess.render()  # (the first light edit: a full frame, its light terms kept from here)
    panel = sess.scene.lights[sess.scene.light_slot("Panel")]
    bulb = sess.scene.lights[sess.scene.light_slot("Bulb")]
    li = {"move": ("Panel", replace(panel, position=(-1.0, 0.5, 1.5))),
          "power": ("Panel", replace(panel, power=120.0)),
          "hide": ("Panel", replace(panel, camera=False)),
          "bulb": ("Bulb", replace(bulb, position=(1.2, -2.5, 2.8)))}[edit]
    sess.apply([LightSet(*li)])
    frame = sess.render()
    fresh = _fresh(sess.scene, settings)
    assert frame.stats["incremental"], frame.stats
    np.testing.assert_allclose(frame.radiance, fresh.radiance, rtol=0, atol=1e-6)
    print(edit, "relit", frame.stats.get("relit"), "traced pixels", frame.stats["traced_pixels"])


def test_view_segments_dirty_only_where_the_camera_sees_the_light():
    """BASE, a power edit of an area light: the pixels whose camera ray crosses its box are
    re-traced only where camera rays see it (issue 21: studio's soft box, hidden from the
    camera, re-traced every background pixel, 33% of the frame, on each power or colour
    edit); mirror rays still see it: the ball's pixels whose mirror rays cross its box are
    re-traced. Every frame a fresh session's, bit for bit."""
    settings = RenderSettings(mode="BASE", max_depth=2, samples=1)
    dirty = {}
    for camera_seen in (True, False):
        sess = Session(_stage(camera_seen), settings)
        sess.light_terms = True
        first = sess.render()
        panel = sess.scene.lights[sess.scene.light_slot("Panel")]
        rep = sess.apply([LightSet("Panel", replace(panel, power=120.0))])
        assert rep.relight
        dirty[camera_seen] = sess.dirty_mask
        frame = sess.render()
        np.testing.assert_array_equal(frame.radiance, _fresh(sess.scene, settings).radiance)
        if camera_seen:  # the pixels that show the panel changed, and were re-traced
            shown = np.abs(frame.radiance - first.radiance).max(axis=2) > 1.0
            assert shown.sum() >= 10 and dirty[camera_seen][shown].all()
    assert 0 < dirty[False].sum() < dirty[True].sum() / 2, (dirty[False].sum(),
                                                            dirty[True].sum())


def _panel_scene(glossy=True):
    """three_spheres and, between the camera and them, a panel facing the camera (it lights
    nothing the camera sees: everything is behind it)."""
    s = scenes.three_spheres(96, 72)
    s.add_light(Light("Panel", "AREA", power=20.0, position=(-0.5, -5.0, 2.0),
                      direction=(0.0, -0.8, 0.6), axis=(1.0, 0.0, 0.0), size=(0.8, 0.5),
                      shape="RECTANGLE", camera=True, glossy=glossy, transmission=glossy))
    return s


def test_interpolants_trace_the_pixels_that_see_a_light(monkeypatch):
    """INTERPOLANT: pixels whose camera ray may cross a light the camera sees are traced:
    the frame stays within epsilon of BASE's, the panel's pixels are never interpolated
    and the rest interpolates as much as without the panel."""
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    eps = 0.05
    counts = []
    for panel in (False, True):
        s = _panel_scene() if panel else scenes.three_spheres(96, 72)
        base = Session(s.copy(), RenderSettings(mode="BASE", max_depth=2)).render()
        f = Session(s.copy(), RenderSettings(mode="INTERPOLANT", max_depth=2,
                                             epsilon=eps)).render()
        err = np.abs(f.radiance - base.radiance).max(axis=2) / np.maximum(
            np.abs(base.radiance).max(axis=2), 1e-3)
        interp = f.pixel_class == CLASS_INTERPOLATED
        seen = base.radiance.max(axis=2) > 10.0  # the panel's radiance: 20 / (0.4 pi)
        assert (seen.sum() > 100) == panel
        assert not (interp & seen).any()
        assert err.max() <= eps, err.max()
        counts.append(int(interp.sum()))
    assert counts[1] == counts[0] > 300, counts


def test_samples_below_a_mirror_are_flagged_where_mirrors_see_lights():
    """A lattice line whose tree reflects fails its cell (``tunnel_light``) while mirror
    rays may see a light; its root alone does not."""
    for glossy in (True, False):
        s = _panel_scene(glossy)
        sa = s.arrays()
        acc = create_accelerator("BRUTE_FORCE", sa)
        # one ray onto the mirror sphere (reflects), one onto the floor
        o = np.array([[0.0, -8.5, 3.6]] * 2)
        d = np.array([[0.6, -0.9, 1.0], [-3.0, -1.0, 0.0]]) - o
        _, tree = whitted.trace(sa, acc, o, d, 0.0, np.inf, 2, record=True,
                                camera_lights=False)
        flags = seen_flags(sa, tree, 2)
        assert list(flags) == ([SEES_LIGHT, 0] if glossy else [0, 0])
