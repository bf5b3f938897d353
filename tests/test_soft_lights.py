"""Soft light in the base tracer: closed forms on a Lambertian floor, convergence with the
light samples, determinism, hard lights unchanged, and bad input."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from tracer_scenes import ortho_down, plane_scene

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.errors import SceneError
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Light, Material, Scene
from rstrace_engine.tracing import whitted
from rstrace_engine.tracing.soft_lights import sample_seeds

RHO = 0.5


def _floor(lights, world=(0.0, 0.0, 0.0)):
    return plane_scene(Material("lambert", diffuse=(RHO, RHO, RHO)), lights,
                       camera=ortho_down(scale=6.0, width=16, rows=12), world=world,
                       world_lights=True)


def _radiance_at(scene, xy, n, seed=0):
    """Radiance leaving the floor at points ``xy`` (m, 2), seen from straight above."""
    sa = scene.arrays()
    accel = create_accelerator("BRUTE_FORCE", sa)
    m = len(xy)
    o = np.column_stack([xy, np.full(m, 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (m, 1))
    rad, _ = whitted.trace(sa, accel, o, d, 0.0, np.inf, 0,
                           seeds=sample_seeds(np.arange(m), seed), light_samples=n)
    return rad[:, 0]


def _grid(half=1.5, k=7):
    g = np.linspace(-half, half, k)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel()])


def _lambert_polygon(p, verts):
    """Irradiance factor of a polygon (vertices (k, 3)) above the +Z floor at ``p`` (3,):
    ``E / L`` by Lambert's formula."""
    tot = 0.0
    k = len(verts)
    for i in range(k):
        a = verts[i] - p
        b = verts[(i + 1) % k] - p
        a = a / np.linalg.norm(a)
        b = b / np.linalg.norm(b)
        beta = math.acos(min(1.0, max(-1.0, float(a @ b))))
        g = np.cross(a, b)
        tot += beta * g[2] / np.linalg.norm(g)
    return 0.5 * abs(tot)


def _rel_err(got, want):
    return float(np.max(np.abs(got - want) / np.max(want)))


# ----------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("shape,size", [("SQUARE", (1.2, 1.2)), ("RECTANGLE", (1.6, 0.6))])
def test_area_polygon_lambert_formula(shape, size):
    h, power = 1.5, 200.0
    light = Light("Area", "AREA", power=power, position=(0.2, -0.1, h),
                  direction=(0.0, 0.0, -1.0), shape=shape, size=size, axis=(1.0, 0.0, 0.0))
    sc = _floor([light])
    xy = _grid()
    su, sv = size
    c = np.array([0.2, -0.1, h])
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(-np.array([0.0, 0.0, -1.0]), u)
    verts = np.array([c + sx * su / 2 * u + sy * sv / 2 * v
                      for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    radiance = power / (math.pi * su * sv)  # Cycles: P / (pi A)
    want = np.array([RHO / math.pi * radiance * _lambert_polygon(np.array([x, y, 0.0]), verts)
                     for x, y in xy])
    assert _rel_err(_radiance_at(sc, xy, 16), want) < 0.05
    assert _rel_err(_radiance_at(sc, xy, 256), want) < 0.006


def test_disk_on_axis():
    h, power, dia = 1.0, 150.0, 1.0
    light = Light("Disk", "AREA", power=power, position=(0.0, 0.0, h),
                  direction=(0.0, 0.0, -1.0), shape="DISK", size=(dia, dia))
    sc = _floor([light])
    radiance = power / (math.pi * math.pi * dia * dia / 4.0)
    r = dia / 2
    want = RHO / math.pi * radiance * math.pi * r * r / (r * r + h * h)
    got = _radiance_at(sc, np.zeros((1, 2)), 256)
    assert abs(got[0] - want) / want < 0.003


def _area_quadrature(p, centre, u, v, su, sv, ellipse, radiance, spread=math.pi, n=400):
    """E at p (on the +Z floor) from an area light facing -Z: midpoint quadrature over its
    area, with Cycles' spread attenuation."""
    g = (np.arange(n) + 0.5) / n - 0.5
    x, y = np.meshgrid(g, g)
    x, y = x.ravel(), y.ravel()
    if ellipse:
        keep = (2 * x) ** 2 + (2 * y) ** 2 <= 1.0
        x, y = x[keep], y[keep]
    pts = centre + (x * su)[:, None] * u + (y * sv)[:, None] * v
    w = pts - p
    d2 = (w ** 2).sum(axis=1)
    wn = w / np.sqrt(d2)[:, None]
    cos_s = np.clip(wn[:, 2], 0.0, None)
    cos_l = np.clip(wn[:, 2], 0.0, None)  # the light faces -Z
    att = np.ones_like(cos_l)
    if spread < math.pi:
        h = spread / 2
        tan_a = np.sqrt(np.clip(1 - cos_l ** 2, 0, None)) / np.maximum(cos_l, 1e-300)
        att = np.clip((math.tan(h) - tan_a) / (math.tan(h) - h), 0.0, None)
    da = su * sv / n / n
    return float((radiance * att * cos_s * cos_l / d2).sum() * da)


@pytest.mark.parametrize("shape,spread", [("ELLIPSE", math.pi), ("SQUARE", math.radians(60)),
                                          ("DISK", math.radians(100))])
def test_area_ellipse_and_spread_by_quadrature(shape, spread):
    su, sv = (1.2, 0.6) if shape == "ELLIPSE" else (1.0, 1.0)
    power, h = 100.0, 1.0
    light = Light("A", "AREA", power=power, position=(0.0, 0.0, h),
                  direction=(0.0, 0.0, -1.0), shape=shape, size=(su, sv), spread=spread)
    sc = _floor([light])
    ellipse = shape in ("DISK", "ELLIPSE")
    area = su * sv * (math.pi / 4 if ellipse else 1.0)
    xy = np.array([[0.0, 0.0], [0.3, 0.2], [0.8, -0.4]])
    u, v = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    want = np.array([RHO / math.pi * _area_quadrature(
        np.array([x, y, 0.0]), np.array([0.0, 0.0, h]), u, v, su, sv, ellipse,
        power / (math.pi * area), spread) for x, y in xy])
    got = _radiance_at(sc, xy, 1024)
    assert _rel_err(got, want) < 0.01, (got, want)


@pytest.mark.parametrize("soft", [True, False])
def test_sphere_light_form_factor(soft):
    """Far enough for the sphere to stay above the horizon: with soft falloff the far
    field is ``P cos / (4 pi (d^2 + r^2))`` (Cycles), without it the point light's law."""
    r, h, power = 0.4, 1.5, 300.0
    light = Light("Sphere", "POINT", power=power, position=(0.0, 0.0, h), radius=r,
                  soft_falloff=soft)
    sc = _floor([light])
    xy = _grid(1.0, 5)
    p = np.column_stack([xy, np.zeros(len(xy))])
    dv = np.array([0.0, 0.0, h]) - p
    d2 = (dv ** 2).sum(axis=1)
    cos = dv[:, 2] / np.sqrt(d2)
    want = RHO / math.pi * power * cos / (4 * math.pi * (d2 + (r * r if soft else 0.0)))
    assert _rel_err(_radiance_at(sc, xy, 256), want) < 0.003


def test_spot_with_radius_keeps_the_cone():
    spot = Light("Spot", "SPOT", power=300.0, position=(0.0, 0.0, 2.0), radius=0.05,
                 direction=(0.0, 0.0, -1.0), spot_size=math.radians(60.0), spot_blend=0.0)
    sc = _floor([spot])
    got = _radiance_at(sc, np.array([[0.0, 0.0], [1.9, 0.0]]), 64)
    want0 = RHO / math.pi * 300.0 / (4 * math.pi * (4.0 + 0.05 ** 2))
    assert abs(got[0] - want0) / want0 < 0.002
    assert got[1] == 0.0  # well outside the cone


def test_sun_cone():
    d = np.array([0.3, -0.2, -1.0])
    sun = Light("Sun", "SUN", power=3.0, direction=tuple(d), angle=math.radians(10.0))
    sc = _floor([sun])
    cos = -d[2] / np.linalg.norm(d)
    got = _radiance_at(sc, _grid(), 64)
    want = RHO / math.pi * 3.0 * cos  # a cone fully above the horizon: S cos
    assert _rel_err(got, np.full(len(got), want)) < 2e-3


def test_uniform_world_lights_an_open_plane():
    world = (0.3, 0.4, 0.5)
    sc = _floor([], world=world)
    got = _radiance_at(sc, _grid(), 16)
    np.testing.assert_allclose(got, RHO * world[0], rtol=1e-12)  # rho L, no occluder


def test_black_world_costs_nothing():
    light = Light("Lamp", "POINT", power=100.0, position=(0.0, 0.0, 2.0))
    frame = whitted.render(_floor([light]), RenderSettings(max_depth=0))
    assert frame.stats["shadow_rays"] == 16 * 12  # one per pixel and point light


# ----------------------------------------------------------------------------- determinism


def _penumbra_scene():
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.6)))
    grey = s.add_material(Material("box", diffuse=(0.4, 0.5, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [floor],
                   name="Floor")
    bm = s.add_mesh(shapes.box((0.5, 0.5, 0.5), name="cube"))
    s.add_instance(bm, shapes.transform((0.0, 0.0, 0.6)), [grey], name="Blocker")
    s.add_instance(bm, shapes.transform((2.5, 2.0, 0.25)), [grey], name="Far")
    s.add_light(Light("Area", "AREA", power=400.0, position=(0.3, 0.2, 2.5),
                      direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(1.0, 0.6)))
    s.add_light(Light("Lamp", "POINT", power=200.0, position=(-2.0, 1.0, 3.0), radius=0.3))
    s.set_world_color((0.05, 0.05, 0.06))
    s.set_camera(ortho_down(scale=7.0, width=40, rows=30))
    return s


def test_same_seed_same_image_and_seeds_matter():
    sc = _penumbra_scene()
    st = RenderSettings(max_depth=1, samples=2, light_samples=8, seed=5)
    a = whitted.render(sc, st).radiance
    b = whitted.render(sc, st).radiance
    assert np.array_equal(a, b)
    c = whitted.render(sc, RenderSettings(max_depth=1, samples=2, light_samples=8,
                                          seed=6)).radiance
    assert not np.array_equal(a, c)


def test_samples_do_not_depend_on_the_batch():
    """A pixel's samples are seeded by its global sample id: traced alone or with the
    whole frame, it comes out the same."""
    sc = _penumbra_scene()
    st = RenderSettings(max_depth=1, samples=2, light_samples=8, seed=1)
    full = whitted.render(sc, st)
    pixels = np.zeros(40 * 30, bool)
    pixels[[37, 410, 411, 900]] = True
    base = full.__class__(np.zeros_like(full.radiance), full.pixel_class.copy(), {})
    part = whitted.render(sc, st, pixels=pixels, base=base)
    got = part.radiance.reshape(-1, 3)[pixels]
    assert np.array_equal(got, full.radiance.reshape(-1, 3)[pixels])


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("kw,needle", [
    (dict(kind="AREA", size=(0.0, 1.0), shape="RECTANGLE"), "size"),
    (dict(kind="AREA", size=(1.0, 0.0), shape="ELLIPSE"), "axis of the ellipse"),
    (dict(kind="AREA", size=(float("nan"), 1.0), shape="RECTANGLE"), "NaN"),
    (dict(kind="AREA", size=(float("inf"), 1.0), shape="RECTANGLE"), "NaN or infinite"),
    (dict(kind="AREA", shape="TRIANGLE"), "shape"),
    (dict(kind="AREA", spread=0.0), "spread 0"),
    (dict(kind="AREA", spread=4.0), "spread"),
    (dict(kind="AREA", axis=(0.0, 0.0, 1.0)), "orthogonal"),
    (dict(kind="AREA", axis=(0.0, 0.0, 0.0)), "axis"),
    (dict(kind="POINT", radius=-1.0), "radius"),
    (dict(kind="POINT", radius=float("nan")), "radius"),
    (dict(kind="SUN", angle=4.0), "angle"),
    (dict(kind="SUN", angle=float("inf")), "angle"),
])
def test_bad_soft_light_input_names_light_and_setting(kw, needle):
    s = Scene()
    with pytest.raises(SceneError) as exc:
        s.add_light(Light("Bad", direction=(0.0, 0.0, -1.0), **kw))
    assert "'Bad'" in str(exc.value) and needle in str(exc.value)


def test_light_samples_setting_is_validated():
    with pytest.raises(SceneError, match="light_samples"):
        RenderSettings(light_samples=0).validated()


def test_sun_at_its_maximum_angle_and_point_inside_a_sphere_are_finite():
    sun = Light("Sun", "SUN", power=2.0, direction=(0.0, 0.0, -1.0), angle=math.pi)
    lamp = Light("Lamp", "POINT", power=50.0, position=(0.0, 0.0, 0.2), radius=0.5,
                 soft_falloff=False)
    got = _radiance_at(_floor([sun, lamp]), _grid(0.3, 3), 16)
    assert np.all(np.isfinite(got)) and np.all(got > 0.0)


# ----------------------------------------------------------------------------- other modes


def test_incremental_equals_fresh_next_to_a_soft_shadow():
    """BASE: an edit next to a soft shadow re-renders the dirty pixels only, and the
    frame equals a fresh one bit for bit; the sphere light's shaft dirties the pixels
    whose penumbra the moved object reaches."""
    from rstrace_engine.geometry.edits import LightSet, ObjectTransform
    from rstrace_engine.session import Session

    sc = _penumbra_scene()
    sc.set_world_color((0.0, 0.0, 0.0))  # the world's light dirties every hit: kept apart
    st = RenderSettings(mode="BASE", max_depth=1, light_samples=8, seed=2)
    sess = Session(sc.copy(), st)
    sess.light_terms = True  # the light edit relights (by default from the second one)
    prev = sess.render()
    for edits in ([ObjectTransform("Far", shapes.transform((2.4, 1.8, 0.25)))],
                  [ObjectTransform("Blocker", shapes.transform((0.1, 0.0, 0.6)))],
                  [LightSet("Lamp", Light("Lamp", "POINT", power=200.0,
                                          position=(-2.0, 1.0, 3.0), radius=0.45))]):
        sess.apply(edits)
        dirty = sess.dirty_mask
        if dirty is not None:  # (and the kept pixels whose soft lights are shaded again)
            dirty = dirty | sess.reshade_mask
        relit = sess.reuse.relight_due  # light edits relight every kept pixel (issue 21)
        frame = sess.render()
        fresh = Session(sess.scene.copy(), st).render()
        assert np.array_equal(frame.radiance, fresh.radiance)
        assert relit == isinstance(edits[0], LightSet)
        if dirty is not None and not relit:
            changed = np.any(prev.radiance != fresh.radiance, axis=2)
            assert not (changed & ~dirty).any()
            assert dirty.mean() < 1.0
        prev = frame


def test_world_light_edit_is_exact():
    from rstrace_engine.geometry.edits import ObjectTransform, WorldColor
    from rstrace_engine.session import Session

    sc = _penumbra_scene()
    st = RenderSettings(mode="BASE", max_depth=1, light_samples=4, seed=2)
    sess = Session(sc.copy(), st)
    sess.render()
    for edits in ([WorldColor((0.2, 0.1, 0.0))], [WorldColor((0.0, 0.0, 0.0))],
                  [WorldColor((0.1, 0.1, 0.1))],
                  [ObjectTransform("Far", shapes.transform((2.0, 1.8, 0.25)))]):
        sess.apply(edits)
        frame = sess.render()
        fresh = Session(sess.scene.copy(), st).render()
        assert np.array_equal(frame.radiance, fresh.radiance)


@pytest.mark.parametrize("world", [(0.0, 0.0, 0.0), (0.2, 0.2, 0.25)])
def test_interpolants_keep_the_bound_under_soft_light(world, monkeypatch):
    """A penumbra across cells, a sphere light close to the floor, a sun's soft edge and a
    world-lit corner: the INTERPOLANT frame is within epsilon of BASE everywhere (cells
    where a light with an extent is proven fully visible and its value its closed form are
    interpolated, the rest traced; with the world lighting too, its term traced per
    pixel), and epsilon 0 gives the BASE frame."""
    from rstrace_engine import image
    from rstrace_engine.frame import CLASS_INTERPOLATED
    from rstrace_engine.interpolants import interpolant_cache
    from rstrace_engine.interpolants.render import InterpolantRenderer

    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    # cells wherever the rays need them (the measured fallback only traces: exact)
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.6, 0.6, 0.6)))
    grey = s.add_material(Material("box", diffuse=(0.4, 0.5, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="floor")), np.eye(4), [floor],
                   name="Floor")
    wall = s.add_mesh(shapes.plane(6.0, name="wall"))
    s.add_instance(wall, shapes.transform((-3.0, 0.0, 3.0), 1.0, 90, 90), [floor],
                   name="Wall")
    s.add_instance(s.add_mesh(shapes.box((0.5, 0.5, 0.5), name="cube")),
                   shapes.transform((-1.0, 0.0, 0.6)), [grey], name="Blocker")
    s.add_light(Light("Area", "AREA", power=300.0, position=(-0.8, 0.2, 2.0),
                      direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(0.8, 0.5)))
    s.add_light(Light("Near", "POINT", power=20.0, position=(1.5, -1.0, 0.3), radius=0.2))
    s.add_light(Light("Sun", "SUN", power=1.0, direction=(0.5, 0.2, -1.0), angle=0.2))
    s.add_light(Light("Hard", "POINT", power=200.0, position=(4.0, 3.0, 3.0)))
    s.set_world_color(world)
    s.set_camera(ortho_down(scale=8.0, width=64, rows=48))
    accel = create_accelerator("BVH", s.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.02, depth_cap=8, light_samples=8)
    frame = InterpolantRenderer().render(s, st, accel)
    base = whitted.render(s, st, accel=accel)
    err = np.abs(image.to_display(frame.radiance)
                 - image.to_display(base.radiance)).max(axis=-1)
    interp = frame.pixel_class == CLASS_INTERPOLATED
    assert np.all(err[~interp] == 0.0)  # traced pixels are the base tracer's, bit for bit
    assert err.max() <= 0.02 + 1e-6
    assert frame.stats["bound_notes"]  # says what is interpolated under soft light
    # with the world lighting, the other lights are interpolated and every interpolated
    # pixel traces the world's term at its own hit (world_term.py)
    assert interp.mean() > 0.2, interp.mean()
    if any(world):
        assert frame.stats["world_s"] > 0.0
    zero = InterpolantRenderer().render(s, RenderSettings(
        mode="INTERPOLANT", epsilon=0.0, light_samples=8), accel)
    assert np.array_equal(zero.radiance, base.radiance)  # epsilon 0 is BASE


def test_ri_tree_mode_gets_the_soft_lights():
    """RI_TREE shades through the base tracer's stages: soft shadows there too, close to
    BASE (its geometry is interpolated, so not bit for bit)."""
    from rstrace_engine.session import Session

    sc = _penumbra_scene()
    base = Session(sc.copy(), RenderSettings(mode="BASE", max_depth=1,
                                             light_samples=8)).render()
    ri = Session(sc.copy(), RenderSettings(mode="RI_TREE", max_depth=1,
                                           light_samples=8)).render()
    assert ri.stats["shadow_rays"] > 8 * 40 * 30  # sampled, not one ray per light
    diff = np.abs(ri.radiance - base.radiance).mean() / base.radiance.mean()
    assert diff < 0.05


def test_world_as_background_only():
    """``set_world_color(c, lights=False)``: misses see it, surfaces are not lit by it (and
    no shadow rays are spent); a WorldColor edit keeps the setting unless it names one."""
    from rstrace_engine.geometry.edits import WorldColor, apply_edits

    sc = _floor([], world=(0.3, 0.3, 0.3))
    sc.set_world_color((0.3, 0.3, 0.3), lights=False)
    assert np.all(_radiance_at(sc, _grid(), 16) == 0.0)
    new, _ = apply_edits(sc, [WorldColor((0.1, 0.2, 0.3))])
    assert not new.world_lights
    new, fx = apply_edits(new, [WorldColor((0.1, 0.2, 0.3), lights=True)])
    assert new.world_lights and fx.world_lights


def test_ratio_estimator_is_exact_where_the_light_is_fully_visible():
    """Heitz, Hill and McGuire's ratio estimator: on a diffuse floor with nothing in the
    way, a rectangle light, a sphere light and a sun's cone above the horizon give the
    closed form itself, whatever the number of samples (no noise at all)."""
    h = 1.5
    rect = Light("Area", "AREA", power=200.0, position=(0.2, -0.1, h),
                 direction=(0.0, 0.0, -1.0), shape="RECTANGLE", size=(1.6, 0.6))
    sphere = Light("Sphere", "POINT", power=300.0, position=(0.0, 0.0, h), radius=0.4)
    sun = Light("Sun", "SUN", power=3.0, direction=(0.3, -0.2, -1.0), angle=0.2)
    xy = _grid()
    for light in (rect, sphere, sun):
        one = _radiance_at(_floor([light]), xy, 1)
        many = _radiance_at(_floor([light]), xy, 64, seed=3)
        np.testing.assert_allclose(one, many, rtol=1e-9)


def test_random_extent_edits_base_exact():
    """Seeded random edits of every kind plus a light's extent (radius, soft falloff, sun
    angle, area size, shape, spread) on the soft-lit room: BASE incremental frames equal
    fresh ones bit for bit and no changed pixel is left clean."""
    from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
    from rstrace_engine.session import Session

    st = RenderSettings(mode="BASE", max_depth=2, light_samples=4)
    gen = EditGenerator(SOAK_SCENES["soft_room"](24, 18), seed=5,
                        extra=EditGenerator.SOFT_KINDS)
    sess = Session(gen.scene.copy(), st)
    prev = sess.render()
    for _ in range(24):
        sess.apply(gen.step())
        dirty = sess.dirty_mask
        if dirty is not None:  # (and the kept pixels whose soft lights are shaded again)
            dirty = dirty | sess.reshade_mask
        relit = sess.reuse.relight_due  # light edits relight every kept pixel (issue 21)
        frame = sess.render()
        fresh = Session(sess.scene.copy(), st).render()
        assert np.array_equal(frame.radiance, fresh.radiance)
        if dirty is not None and not relit:
            changed = np.any(prev.radiance != fresh.radiance, axis=2)
            assert not (changed & ~dirty).any()
        prev = frame
    assert set(gen.kinds_done) >= set(EditGenerator.SOFT_KINDS), gen.kinds_done


def test_tiny_extents_are_points_or_a_parallel_sun():
    """A radius or angle below float64's reach is the point light or the parallel sun (no
    overflow, no NaN); a small but real sun angle is still the sun's full irradiance."""
    lamp = Light("Lamp", "POINT", power=100.0, position=(0.0, 0.0, 2.0))
    xy = _grid()
    hard = _radiance_at(_floor([lamp]), xy, 4)
    tiny = _radiance_at(_floor([replace(lamp, radius=1e-200)]), xy, 4)
    assert np.array_equal(hard, tiny)
    sun = Light("Sun", "SUN", power=3.0, direction=(0.0, 0.0, -1.0), angle=1e-8)
    got = _radiance_at(_floor([sun]), xy, 4)
    np.testing.assert_allclose(got, RHO / math.pi * 3.0, rtol=1e-9)


def test_records_regenerate_the_tracers_samples():
    """The pixel records regenerate a point's world rays and its area light's and sun's
    samples from its node seed (tracing/sample_rays.py): the same directions and light
    points as the tracer's own samples (soft_lights.soft_rays)."""
    from numba import njit

    from rstrace_engine.tracing.soft_lights import (
        _sample_one,
        row_hash,
        row_uv,
        soft_rays,
        world_sample_dir,
    )

    @njit
    def regenerate(sa, seeds, ns, light, P, n, out):
        for i in range(seeds.shape[0]):
            for s in range(n):
                h = row_hash(seeds[i], light, sa.light_kind.shape[0])
                k = i * n + s
                if light == sa.light_kind.shape[0]:
                    out[k, 0], out[k, 1], out[k, 2] = world_sample_dir(
                        h, n, s, ns[i, 0], ns[i, 1], ns[i, 2])
                else:
                    u, v = row_uv(h, n, s)
                    dx, dy, dz, _, _ = _sample_one(sa, light, P[i, 0], P[i, 1], P[i, 2], u, v)
                    out[k, 0], out[k, 1], out[k, 2] = dx, dy, dz

    sc = _penumbra_scene()
    sc.add_light(Light("Sun", "SUN", power=1.0, direction=(0.3, 0.2, -1.0), angle=0.1))
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    m, n = 20, 8
    rng = np.random.default_rng(3)
    o = np.column_stack([rng.uniform(-2, 2, (m, 2)), np.full(m, 5.0)])
    d = np.tile([0.05, -0.02, -1.0], (m, 1))
    hits = accel.closest_hit(o, d, np.zeros(m), np.full(m, np.inf))
    surf = whitted.surfaces(sa, o, d, np.full(m, np.inf), hits)
    seeds = sample_seeds(np.arange(m), 9)
    L = len(sa.light_kind)
    for light in (0, L - 1, L):  # the area light, the sun, the world
        state = np.zeros(len(surf.sh_state), np.int8)
        if light < L:
            state[np.arange(m) * L + light] = 2  # SH_SOFT
        scene = sa._replace(world_light=np.zeros(3)) if light < L else sa  # one row each
        soft, _, _, rows = soft_rays(scene, surf, seeds, n, state)
        assert len(rows) == m
        got = np.empty((m * n, 3))
        regenerate(sa, seeds, surf.NS, light, surf.Q, n, got)
        np.testing.assert_allclose(got, soft.d, rtol=0, atol=1e-12)
