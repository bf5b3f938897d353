"""What a light reaches, as Cycles says it: its diffuse and glossy ray visibility, the
elliptical cone of a non-uniformly scaled spot, light linking (receivers) and shadow linking
(blockers) -- geometry/lights.LightReach, tracing/shader, tracing/light_linking."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from tracer_scenes import ortho_down

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.errors import SceneError
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.lights import checked_light, link_mask
from rstrace_engine.geometry.scene import Light, Material, Scene
from rstrace_engine.tracing import whitted
from rstrace_engine.tracing.soft_lights import sample_seeds

GLOSSY = Material("plastic", diffuse=(0.6, 0.3, 0.2), specular=(0.5, 0.5, 0.5),
                  roughness=0.3, model="PRINCIPLED")


def _scene(lights, material=GLOSSY, ball=True, hide_ball=False):
    """A floor (z = 0) and a ball of radius 0.5 at height 1.2 over the origin."""
    s = Scene()
    mid = s.add_material(material)
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [mid],
                   name="Floor")
    if ball:
        m = np.eye(4)
        m[:3, 3] = (0.0, 0.0, 1.2)
        k = s.add_instance(s.add_mesh(shapes.uv_sphere(24, 12, 0.5, name="ball")), m, [mid],
                           name="Ball")
        if hide_ball:
            s.set_instance_visible(k, False)
    for li in lights:
        s.add_light(li)
    s.set_world_color((0.0, 0.0, 0.0), lights=False)
    s.set_camera(ortho_down(scale=6.0, width=16, rows=12))
    return s


def _radiance(scene, o, d, n=16):
    sa = scene.arrays()
    accel = create_accelerator("BVH", sa)
    m = len(o)
    rad, _ = whitted.trace(sa, accel, np.asarray(o, float), np.asarray(d, float), 0.0,
                           np.inf, 0, seeds=sample_seeds(np.arange(m), 3), light_samples=n)
    return rad, accel.closest_hit(np.asarray(o, float), np.asarray(d, float),
                                  np.zeros(m), np.full(m, np.inf)).inst


def _oblique_rays(k=9):
    """Rays from the side onto the floor around and under the ball, and onto the ball."""
    g = np.linspace(-1.5, 1.5, k)
    x, y = np.meshgrid(g, g)
    target = np.column_stack([x.ravel(), y.ravel(), np.zeros(k * k)])
    o = target + np.array([3.0, -2.0, 4.0])
    return o, target - o


POINT = Light("Key", "POINT", power=800.0, position=(0.4, 0.2, 4.0))
BULB = Light("Bulb", "POINT", power=800.0, position=(0.4, 0.2, 4.0), radius=0.3)
AREA = Light("Box", "AREA", power=800.0, position=(0.4, 0.2, 4.0), size=(1.0, 0.6))


@pytest.mark.parametrize("light", [POINT, BULB, AREA], ids=["point", "sphere", "area"])
def test_diffuse_and_glossy_parts_apart(light):
    o, d = _oblique_rays()
    full, _ = _radiance(_scene([light]), o, d)
    dif, _ = _radiance(_scene([replace(light, glossy=False)]), o, d)
    glo, _ = _radiance(_scene([replace(light, diffuse=False)]), o, d)
    none, _ = _radiance(_scene([replace(light, diffuse=False, glossy=False)]), o, d)
    assert full.max() > 0.0 and dif.max() > 0.0 and glo.max() > 0.0
    assert np.all(none == 0.0)
    np.testing.assert_allclose(dif + glo, full, rtol=1e-9, atol=1e-12)
    # diffuse off is the material without its diffuse base; glossy off without its layer
    no_base, _ = _radiance(_scene([light], replace(GLOSSY, diffuse=(0.0, 0.0, 0.0))), o, d)
    np.testing.assert_allclose(glo, no_base, rtol=1e-9, atol=1e-12)
    no_layer, _ = _radiance(_scene([light], replace(GLOSSY, specular=(0.0, 0.0, 0.0))), o, d)
    np.testing.assert_allclose(dif, no_layer, rtol=1e-9, atol=1e-12)


def _floor_rad(light, pts):
    o = np.column_stack([pts, np.full(len(pts), 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (len(pts), 1))
    lam = Material("lambert", diffuse=(0.5, 0.5, 0.5))
    return _radiance(_scene([light], lam, ball=False), o, d)[0][:, 0]


def test_scaled_spot_cone_is_elliptical():
    """A spot 1 m over the floor, half angle a, scaled 2 along X and 1 along Y and Z:
    Cycles' cone meets the floor in an ellipse of semi-axes 2 tan(a) and tan(a)."""
    a = math.radians(20.0)
    frame = np.diag([2.0, 1.0, 1.0])
    spot = Light("Spot", "SPOT", power=500.0, position=(0.0, 0.0, 1.0),
                 direction=(0.0, 0.0, -1.0), spot_size=2 * a, spot_blend=0.0,
                 spot_frame=tuple(frame.ravel()))
    t = math.tan(a)
    pts = np.array([[1.9 * t, 0.0], [2.1 * t, 0.0], [0.0, 0.95 * t], [0.0, 1.05 * t],
                    [1.3 * t, 0.7 * t], [1.5 * t, 0.8 * t]])
    got = _floor_rad(spot, pts)
    # inside: (x / 2t)^2 + (y / t)^2 < 1
    inside = (pts[:, 0] / (2 * t)) ** 2 + (pts[:, 1] / t) ** 2 < 1.0
    assert np.all(got[inside] > 0.0) and np.all(got[~inside] == 0.0)
    # lit points get the round spot's inverse-square light (blend 0: no falloff inside)
    round_ = _floor_rad(replace(spot, spot_frame=(), spot_size=math.pi), pts)
    np.testing.assert_allclose(got[inside], round_[inside], rtol=1e-12)


def test_uniformly_scaled_spot_is_round_and_bad_frames_are_named():
    li = Light("Spot", "SPOT", spot_frame=tuple((3.0 * np.eye(3)).ravel()))
    assert checked_light(li).spot_frame == ()
    with pytest.raises(SceneError, match="Spot.*9 finite"):
        checked_light(replace(li, spot_frame=(1.0, 2.0)))
    with pytest.raises(SceneError, match="Spot.*zero axis"):
        checked_light(replace(li, spot_frame=tuple(np.diag([1.0, 0.0, 1.0]).ravel())))


def test_link_mask_follows_blender():
    names = ["A", "B", "C"]
    assert link_mask((), names) is None
    assert link_mask((("A", True),), names).tolist() == [True, False, False]
    assert link_mask((("A", False),), names).tolist() == [False, True, True]
    assert link_mask((("A", True), ("B", False)), names).tolist() == [True, False, False]
    # instances go with their instancer
    assert link_mask((("A", True),), ["A/x", "B/A", None]).tolist() == [True, False, False]


def test_no_linking_carries_no_tables():
    sa = _scene([POINT]).arrays()
    assert sa.light_recv.shape == (0, 0) and sa.light_block.shape == (0, 0)
    sa = _scene([replace(POINT, receivers=(("Ball", True),))]).arrays()
    assert sa.light_recv.shape == (1, 2) and sa.light_recv.tolist() == [[0, 1]]


@pytest.mark.parametrize("light", [POINT, BULB], ids=["point", "sphere"])
def test_receivers(light):
    o, d = _oblique_rays()
    full, inst = _radiance(_scene([light]), o, d)
    for links in ((("Ball", True),), (("Floor", False),)):
        got, _ = _radiance(_scene([replace(light, receivers=links)]), o, d)
        ball = inst == 1
        assert ball.any() and (~ball).any()
        np.testing.assert_array_equal(got[ball], full[ball])
        assert np.all(got[~ball] == 0.0)
    # the other light still lights the floor
    fill = Light("Fill", "POINT", power=300.0, position=(-2.0, 1.0, 3.0))
    both, _ = _radiance(_scene([replace(light, receivers=(("Ball", True),)), fill]), o, d)
    only_fill, _ = _radiance(_scene([fill]), o, d)
    np.testing.assert_allclose(both[inst == 0], only_fill[inst == 0], rtol=1e-12)


@pytest.mark.parametrize("light", [POINT, BULB, AREA], ids=["point", "sphere", "area"])
def test_blockers(light):
    """The ball casts no shadow of a light whose blockers leave it out: the floor is lit
    as with the ball hidden, while the ball itself is shaded as before."""
    o, d = _oblique_rays(11)
    full, inst = _radiance(_scene([light]), o, d)
    hidden, _ = _radiance(_scene([light], hide_ball=True), o, d)
    floor = inst == 0
    assert np.any(full[floor, 0] < hidden[floor, 0] - 1e-6)  # a shadow to lose
    for links in ((("Floor", True),), (("Ball", False),)):
        got, _ = _radiance(_scene([replace(light, blockers=links)]), o, d)
        np.testing.assert_allclose(got[floor], hidden[floor], rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(got[~floor], full[~floor])
    # the ball among the blockers: its shadow as before
    got, _ = _radiance(_scene([replace(light, blockers=(("Ball", True),))]), o, d)
    np.testing.assert_array_equal(got, full)


def test_interpolant_cone_bound_holds_the_elliptical_cone():
    """The shafts' round cone of a reshaped spot holds every lit direction, and its inner
    cosine is NaN (never fully lit, never smooth)."""
    from rstrace_engine.interpolants.shafts import cone_bounds

    a = math.radians(25.0)
    frame = np.diag([1.0, 2.5, 0.8])
    spot = Light("Spot", "SPOT", power=500.0, position=(0.0, 0.0, 1.0),
                 direction=(0.0, 0.0, -1.0), spot_size=2 * a, spot_blend=0.3,
                 spot_frame=tuple(frame.ravel()))
    sa = _scene([spot, POINT], ball=False).arrays()
    co, ci = cone_bounds(sa)
    assert np.isnan(ci[0]) and ci[1] == sa.light_cos_inner[1] and co[1] == sa.light_cos_outer[1]
    rng = np.random.default_rng(1)
    ray = rng.normal(size=(20000, 3))
    ray /= np.linalg.norm(ray, axis=1)[:, None]
    f = sa.light_spot_frame[0]
    local = ray @ f.T
    lit = local[:, 2] / np.linalg.norm(local, axis=1) > math.cos(a)
    assert lit.sum() > 100
    assert np.all(ray[lit] @ sa.light_dir[0] > co[0])
