"""The base Whitted tracer against closed forms, its ray trees, render() and the Session."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from tracer_scenes import ortho_down, plane_scene, point_intensity

from rstrace_engine import image, scenes
from rstrace_engine.__main__ import main as cli_main
from rstrace_engine.accel.accelerators import Hits, create_accelerator
from rstrace_engine.frame import CLASS_BACKGROUND, CLASS_TRACED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_rays
from rstrace_engine.geometry.scene import Light, Material, Scene, SceneError
from rstrace_engine.session import Session
from rstrace_engine.tracing import whitted


def brute(scene: Scene):
    return create_accelerator("BRUTE_FORCE", scene.arrays())


def trace1(scene, origin, direction, depth=0, record=False, accel=None):
    """Trace a single ray; returns (rgb (3,), RayTree | None)."""
    sa = scene.arrays()
    rad, tree = whitted.trace(sa, accel or brute(scene), np.array([origin], float),
                              np.array([direction], float), 0.0, np.inf, depth, record=record)
    return rad[0], tree


def floor_hits(scene):
    """Primary hit points of the (orthographic, straight down) camera on the z = 0 floor."""
    o, d, _, _ = camera_rays(scene.camera)
    return o - d * (o[:, 2:3] / d[:, 2:3])


# ----------------------------------------------------------------------------- closed forms


def test_lambertian_plane_under_point_light():
    rho = np.array([0.6, 0.5, 0.3])
    light = Light("Lamp", "POINT", color=(1.0, 0.5, 0.25), power=800.0,
                  position=(0.3, -0.2, 2.0))
    sc = plane_scene(Material("lambert", diffuse=tuple(rho)), [light])
    frame = whitted.render(sc, RenderSettings(max_depth=0), accel=brute(sc))
    p = floor_hits(sc)
    v = np.asarray(light.position) - p
    r2 = np.einsum("ij,ij->i", v, v)
    cos = v[:, 2] / np.sqrt(r2)
    want = rho / math.pi * point_intensity(light) * (cos / r2)[:, None]
    got = frame.radiance.reshape(-1, 3)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert np.all(frame.pixel_class == CLASS_TRACED)


def test_lambertian_plane_under_sun_and_max_depth_has_no_effect():
    rho = np.array([0.5, 0.5, 0.5])
    d = np.array([0.3, -0.4, -1.0])
    sun = Light("Sun", "SUN", color=(1.0, 0.9, 0.8), power=3.0, direction=tuple(d))
    sc = plane_scene(Material("lambert", diffuse=tuple(rho)), [sun])
    cos = -d[2] / np.linalg.norm(d)
    want = rho / math.pi * np.array(sun.color) * sun.power * cos
    for depth in (0, 3):
        frame = whitted.render(sc, RenderSettings(max_depth=depth), accel=brute(sc))
        np.testing.assert_allclose(frame.radiance.reshape(-1, 3), np.broadcast_to(want,
                                   (32 * 24, 3)), rtol=1e-6)


def test_ward_specular_peak_through_the_tracer():
    rho_s, alpha = 0.5, 0.2
    light = Light("Lamp", "POINT", power=1000.0, position=(1.0, 0.0, 1.0))
    sc = plane_scene(Material("glossy", diffuse=(0.0,) * 3, specular=(rho_s,) * 3,
                              roughness=alpha), [light])
    rad, _ = trace1(sc, (-1.0, 0.0, 1.0), (1.0, 0.0, -1.0))
    # mirror configuration: f = rho_s / (4 pi a^2 cos45), E = I cos45 / r^2, r^2 = 2
    want = rho_s / (4 * math.pi * alpha ** 2) * point_intensity(light) / 2.0
    np.testing.assert_allclose(rad, want, rtol=1e-9)


def test_spot_cone_and_blend():
    size, blend = math.radians(60.0), 0.3
    spot = Light("Spot", "SPOT", power=500.0, position=(0.0, 0.0, 3.0),
                 direction=(0.0, 0.0, -1.0), spot_size=size, spot_blend=blend)
    sc = plane_scene(Material("lambert", diffuse=(0.8, 0.8, 0.8)), [spot],
                     camera=ortho_down(scale=8.0, width=48, rows=48))
    frame = whitted.render(sc, RenderSettings(max_depth=0), accel=brute(sc))
    p = floor_hits(sc)
    v = np.asarray(spot.position) - p
    r = np.linalg.norm(v, axis=1)
    cos = v[:, 2] / r  # angle to the normal equals angle to the spot axis here
    half = size / 2
    c_out = math.cos(half)
    c_in = c_out + (1 - c_out) * blend  # Cycles blends in cosine space
    x = np.clip((cos - c_out) / (c_in - c_out), 0.0, 1.0)
    fall = np.where(cos > c_out, x * x * (3 - 2 * x), 0.0)
    want = 0.8 / math.pi * point_intensity(spot)[0] * cos / r ** 2 * fall
    got = frame.radiance.reshape(-1, 3)[:, 0]
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12)
    assert np.count_nonzero(want == 0.0) > 100  # outside the cone: dark
    assert np.count_nonzero(fall == 1.0) > 50  # inner cone: full
    assert np.count_nonzero((fall > 0.0) & (fall < 1.0)) > 50  # blend ring


def _shadow_scene():
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.5, 0.5, 0.5)))
    grey = s.add_material(Material("box", diffuse=(0.5, 0.5, 0.5)))
    pm = s.add_mesh(shapes.plane(20.0, name="floor"))
    bm = s.add_mesh(shapes.box((0.5, 0.5, 0.5), name="cube"))
    s.add_instance(pm, np.eye(4), [floor], name="Floor")
    s.add_instance(bm, shapes.transform((0.0, 0.0, 1.0)), [grey], name="Blocker")
    s.add_light(Light("Lamp", "POINT", power=1000.0, position=(0.0, 0.0, 4.0)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(ortho_down())
    return s


@pytest.mark.parametrize("record", [False, True])
def test_hard_shadow_present_and_absent(record):
    sc = _shadow_scene()
    light = sc.lights[0]
    # oblique rays reach the floor under the blocker and beside it, passing below the blocker
    rad_in, tree_in = trace1(sc, (-5.0, 0.0, 5.0), (1.0, 0.0, -1.0), record=record)
    rad_out, tree_out = trace1(sc, (-3.0, 0.0, 5.0), (1.0, 0.0, -1.0), record=record)
    assert np.all(rad_in == 0.0)
    p = np.array([2.0, 0.0, 0.0])
    v = np.asarray(light.position) - p
    want = 0.5 / math.pi * point_intensity(light) * v[2] / np.linalg.norm(v) ** 3
    np.testing.assert_allclose(rad_out, want, rtol=1e-9)
    if record:
        assert tree_in.node_inst[0] == 0 and tree_out.node_inst[0] == 0
        assert tree_in.node_occluder[0, 0] == 1  # the Blocker
        assert tree_in.node_light_mask[0, 0] == 0
        assert tree_out.node_occluder[0, 0] == whitted.OCC_NONE
        assert tree_out.node_light_mask[0, 0] == 1
    else:
        assert tree_in is None


def test_light_behind_surface_contributes_nothing():
    # the light is below the floor; the shading normal must not let it leak through
    light = Light("Under", "POINT", power=1000.0, position=(0.0, 0.0, -1.0))
    sc = plane_scene(Material("lambert", diffuse=(0.8,) * 3), [light])
    rad, tree = trace1(sc, (0.3, 0.2, 5.0), (0.0, 0.0, -1.0), record=True)
    assert np.all(rad == 0.0)
    assert tree.node_occluder[0, 0] == whitted.OCC_NOT_FACING


def test_emission_and_world_colour():
    sc = plane_scene(Material("glow", diffuse=(0.0,) * 3, emission=(2.0, 1.0, 0.5)),
                     world=(0.1, 0.2, 0.3))
    rad, _ = trace1(sc, (0.0, 0.0, 5.0), (0.0, 0.0, -1.0))
    np.testing.assert_allclose(rad, (2.0, 1.0, 0.5))
    rad, tree = trace1(sc, (0.0, 0.0, 5.0), (0.0, 0.3, 1.0), record=True)
    np.testing.assert_allclose(rad, (0.1, 0.2, 0.3))
    assert tree.node_inst[0] == -1 and tree.node_tri[0] == -1
    # a miss's segment end lies beyond the scene box along the ray
    seg = tree.node_point[0] - tree.node_origin[0]
    assert np.linalg.norm(seg) > sc.arrays().scene_extent
    np.testing.assert_allclose(seg / np.linalg.norm(seg), np.array([0, 0.3, 1]) / math.hypot(
        0.3, 1.0), atol=1e-12)


def _mirror_wall_scene(mirror=(1.0, 1.0, 1.0)):
    s = Scene()
    mir = s.add_material(Material("mirror", diffuse=(0.0,) * 3, mirror=mirror))
    glow = s.add_material(Material("glow", diffuse=(0.0,) * 3, emission=(2.0, 1.0, 0.5)))
    pm = s.add_mesh(shapes.plane(20.0, name="plane"))
    s.add_instance(pm, np.eye(4), [mir], name="MirrorFloor")
    wall = np.eye(4)
    wall[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # +Z normal -> -X
    wall[:3, 3] = (3.0, 0.0, 2.0)
    s.add_instance(pm, wall, [glow], name="GlowWall")
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(ortho_down())
    return s


def test_mirror_reflection_and_ray_tree():
    mirror = (0.5, 0.7, 0.9)
    sc = _mirror_wall_scene(mirror)
    o, d = (0.0, 0.0, 1.0), (1.0, 0.0, -1.0)
    rad0, _ = trace1(sc, o, d, depth=0)
    assert np.all(rad0 == 0.0)
    rad, tree = trace1(sc, o, d, depth=3, record=True)
    np.testing.assert_allclose(rad, np.array(mirror) * (2.0, 1.0, 0.5), rtol=1e-12)
    assert list(tree.node_path) == [1, 2]
    assert list(tree.node_inst) == [0, 1]
    assert list(tree.node_parent) == [-1, 0]
    assert list(tree.node_ray) == [0, 0]
    np.testing.assert_allclose(tree.node_point[0], (1.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(tree.node_origin[1], (1.0, 0.0, 0.0), atol=1e-8)
    np.testing.assert_allclose(tree.node_point[1], (3.0, 0.0, 2.0), atol=1e-8)


def _slab_scene(depth_z=2.0, thickness=0.5, ior=1.5):
    s = Scene()
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(1.0,) * 3,
                                    ior=ior))
    glow = s.add_material(Material("glow", diffuse=(0.0,) * 3, emission=(1.0, 2.0, 3.0)))
    bm = s.add_mesh(shapes.box((40.0, 40.0, thickness), name="slab"))
    pm = s.add_mesh(shapes.plane(100.0, name="floor"))
    s.add_instance(pm, np.eye(4), [glow], name="GlowFloor")
    s.add_instance(bm, shapes.transform((0.0, 0.0, depth_z)), [glass], name="Slab")
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(ortho_down())
    return s


@pytest.mark.parametrize("depth", [1, 2, 3, 4, 6])
def test_refraction_through_slab_normal_incidence(depth):
    sc = _slab_scene()
    rad, _ = trace1(sc, (0.3, 0.1, 5.0), (0.0, 0.0, -1.0), depth=depth)
    f = ((1.5 - 1) / (1.5 + 1)) ** 2
    # paths to the floor: T (F F)^k T, reaching it at depth 2 + 2k
    series = sum(f ** (2 * k) for k in range(10) if 2 + 2 * k <= depth)
    np.testing.assert_allclose(rad, np.array([1.0, 2.0, 3.0]) * (1 - f) ** 2 * series,
                               rtol=1e-12, atol=1e-300)


def test_refraction_direction_follows_snell():
    sc = _slab_scene()
    th = math.radians(30.0)
    d = (math.sin(th), 0.0, -math.cos(th))
    _, tree = trace1(sc, (0.0, 0.0, 5.0), d, depth=2, record=True)
    by_path = {int(p): k for k, p in enumerate(tree.node_path)}
    assert {1, 2, 3, 7} <= set(by_path)
    inside = tree.node_point[by_path[3]] - tree.node_origin[by_path[3]]
    inside /= np.linalg.norm(inside)
    assert inside[0] == pytest.approx(math.sin(th) / 1.5, abs=1e-9)
    assert tree.node_inst[by_path[3]] == 1  # leaves through the slab's other face
    out = tree.node_point[by_path[7]] - tree.node_origin[by_path[7]]
    np.testing.assert_allclose(out / np.linalg.norm(out), d, atol=1e-9)  # parallel faces
    assert tree.node_inst[by_path[7]] == 0
    refl = tree.node_point[by_path[2]] - tree.node_origin[by_path[2]]
    np.testing.assert_allclose(refl / np.linalg.norm(refl), (d[0], 0.0, -d[2]), atol=1e-9)


@pytest.mark.parametrize("deg,tir", [(30.0, False), (41.0, False), (43.0, True), (60.0, True)])
def test_total_internal_reflection(deg, tir):
    s = Scene()
    glass = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(1.0,) * 3,
                                    ior=1.5))
    bm = s.add_mesh(shapes.box((40.0, 40.0, 4.0), name="block"))  # top face hit first
    s.add_instance(bm, np.eye(4), [glass], name="Block")
    s.set_camera(ortho_down())
    th = math.radians(deg)
    d = (math.sin(th), 0.0, math.cos(th))
    _, tree = trace1(s, (0.0, 0.0, 0.0), d, depth=1, record=True)
    paths = set(int(p) for p in tree.node_path)
    assert 2 in paths  # the internal reflection
    assert (3 not in paths) == tir
    if not tir:
        k = list(tree.node_path).index(3)
        seg = tree.node_point[k] - tree.node_origin[k]
        assert seg[0] / np.linalg.norm(seg) == pytest.approx(1.5 * math.sin(th), abs=1e-9)


# ----------------------------------------------------------------------------- ray trees


@pytest.fixture(scope="module")
def spheres_traced():
    sc = scenes.three_spheres(64, 48, subdivisions=2)
    sa = sc.arrays()
    acc = create_accelerator("BVH", sa)
    o, d, t0, t1 = camera_rays(sc.camera)
    rad, tree = whitted.trace(sa, acc, o, d, t0, t1, 3, record=True)
    return sc, sa, acc, rad, tree


def test_ray_tree_structure(spheres_traced):
    sc, sa, acc, rad, tree = spheres_traced
    n = len(rad)
    assert np.array_equal(tree.node_ray[:n], np.arange(n))
    assert np.all(tree.node_parent[:n] == -1) and np.all(tree.node_path[:n] == 1)
    kids = np.flatnonzero(tree.node_parent >= 0)
    assert len(kids) > 0
    par = tree.node_parent[kids]
    assert np.all(par < kids)
    assert np.array_equal(tree.node_path[kids] // 2, tree.node_path[par])
    assert np.array_equal(tree.node_ray[kids], tree.node_ray[par])
    assert np.all(tree.node_inst[par] >= 0)  # only hits spawn children
    # a child starts where its parent hit (up to the spawn offset)
    gap = np.abs(tree.node_origin[kids] - tree.node_point[par]).max(axis=1)
    assert gap.max() < 1e-6
    # radiance matches the untraced-tree run
    rad2, none = whitted.trace(sa, acc, *camera_rays(sc.camera), 3)
    assert none is None
    np.testing.assert_allclose(rad2, rad, rtol=1e-12, atol=1e-15)
    assert tree.node_occluder.shape == (len(tree.node_ray), len(sc.lights))


def test_ray_tree_mirror_sees_reflected_object(spheres_traced):
    sc, sa, acc, rad, tree = spheres_traced
    names = [i["name"] for i in sc.instances]
    mirror, red = names.index("MirrorSphere"), names.index("RedSphere")
    n = len(rad)
    kids = np.flatnonzero((tree.node_parent >= 0) & (tree.node_path == 2))
    on_mirror = kids[(tree.node_parent[kids] < n) & (tree.node_inst[tree.node_parent[kids]]
                                                     == mirror)]
    assert len(on_mirror) > 5
    sees_red = on_mirror[tree.node_inst[on_mirror] == red]
    assert len(sees_red) > 0
    # independently: the reflected direction about the sphere's true normal sees the same
    centre = sa.inst_xform[mirror][:3, 3]
    for k in sees_red[:10]:
        p = tree.node_point[tree.node_parent[k]]
        d = p - tree.node_origin[tree.node_parent[k]]
        d /= np.linalg.norm(d)
        nrm = (p - centre) / np.linalg.norm(p - centre)
        r = d - 2 * (d @ nrm) * nrm
        seg = tree.node_point[k] - tree.node_origin[k]
        seg /= np.linalg.norm(seg)
        assert math.acos(min(1.0, float(seg @ r))) < 0.08  # tessellation of a 320-face sphere
        h = acc.closest_hit(tree.node_origin[k][None], seg[None], np.zeros(1),
                            np.full(1, np.inf))
        assert h.inst[0] == red


def test_ray_tree_shadowed_floor(spheres_traced):
    sc, sa, acc, rad, tree = spheres_traced
    ground = [i["name"] for i in sc.instances].index("Ground")
    n = len(rad)
    roots = np.arange(n)
    on_floor = roots[tree.node_inst[:n] == ground]
    occ = tree.node_occluder[on_floor]
    shadowed = on_floor[(occ >= 0).any(axis=1)]
    assert len(shadowed) > 0
    bits = np.arange(len(sc.lights), dtype=np.uint64)
    mask_bits = (tree.node_light_mask[on_floor, 0, None] >> bits) & np.uint64(1)
    assert np.array_equal(mask_bits.astype(bool), occ == whitted.OCC_NONE)
    for k in shadowed[:20]:
        j = int(np.flatnonzero(tree.node_occluder[k] >= 0)[0])
        p = tree.node_point[k] + np.array([0, 0, 1e-6])
        v = sa.light_pos[j] - p
        h = acc.closest_hit(p[None], v[None], np.zeros(1), np.ones(1))
        assert h.inst[0] == tree.node_occluder[k, j]
        assert h.inst[0] != ground


# ----------------------------------------------------------------------------- render, session


def test_render_classes_and_stats():
    sc = scenes.three_spheres(48, 36, subdivisions=2)
    acc = create_accelerator("BVH", sc.arrays())
    frame = whitted.render(sc, RenderSettings(max_depth=2), accel=acc)
    o, d, t0, t1 = camera_rays(sc.camera)
    hit = (acc.closest_hit(o, d, t0, t1).inst >= 0).reshape(36, 48)
    assert np.array_equal(frame.pixel_class == CLASS_TRACED, hit)
    assert np.array_equal(frame.pixel_class == CLASS_BACKGROUND, ~hit)
    assert 0 < hit.mean() < 1
    bg = frame.radiance[~hit]
    np.testing.assert_allclose(bg, np.broadcast_to(sc.world_color, bg.shape), rtol=1e-6)
    st = frame.stats
    assert st["primary_rays"] == 48 * 36
    assert st["rays_traced"] == st["primary_rays"] + st["secondary_rays"] + st["shadow_rays"]
    assert st["secondary_rays"] > 0 and st["shadow_rays"] > 0
    assert st["triangles"] == sc.triangle_count and st["instances"] == 4
    assert st["rays_per_s"] > 0 and st["nonfinite_samples"] == 0
    assert frame.radiance.dtype == np.float32 and frame.radiance.shape == (36, 48, 3)


def test_render_bottom_up_rows():
    # light only the upper half of the image (+Y): row 0 (bottom) must be dark
    sc = plane_scene(Material("lambert", diffuse=(0.8,) * 3),
                     [Light("Spot", "SPOT", power=1000.0, position=(0.0, 1.5, 1.0),
                            direction=(0.0, 0.0, -1.0), spot_size=math.radians(90))])
    frame = whitted.render(sc, RenderSettings(max_depth=0), accel=brute(sc))
    assert frame.radiance[0].max() == 0.0
    assert frame.radiance[-1].max() > 0.0


def test_samples_average_jittered_rays():
    sc = scenes.three_spheres(32, 24, subdivisions=2)
    acc = create_accelerator("BVH", sc.arrays())
    one = whitted.render(sc, RenderSettings(max_depth=1, samples=1), accel=acc)
    four = whitted.render(sc, RenderSettings(max_depth=1, samples=4), accel=acc)
    assert four.stats["primary_rays"] == 4 * 32 * 24
    m = image.compare(four.radiance, one.radiance, epsilon=0.05)
    assert m["mean_error"] < 0.05  # the same picture ...
    assert m["max_error"] > 0.0  # ... antialiased at the edges


class _CorruptingAccel:
    """Wraps an accelerator and turns some closest-hit distances into NaN."""

    def __init__(self, inner):
        self.inner = inner
        self.name = "CORRUPT"

    def closest_hit(self, o, d, t0, t1):
        h = self.inner.closest_hit(o, d, t0, t1)
        t = h.t.copy()
        t[::7] = np.where(h.inst[::7] >= 0, np.nan, t[::7])
        return Hits(t, h.inst, h.prim, h.u, h.v)

    def any_hit(self, o, d, t0, t1):
        return self.inner.any_hit(o, d, t0, t1)


def test_broken_hits_do_not_break_the_image():
    sc = plane_scene(Material("lambert", diffuse=(0.8,) * 3),
                     [Light("Lamp", "POINT", power=100.0, position=(0.0, 0.0, 2.0))])
    frame = whitted.render(sc, RenderSettings(max_depth=2), accel=_CorruptingAccel(brute(sc)))
    assert np.isfinite(frame.radiance).all()


def test_infinite_radiance_never_reaches_the_image():
    # valid input whose sum overflows: emission 1e308 plus a mirror of a 1e308 world
    big = 1e308
    s = plane_scene(Material("hot", diffuse=(0.0,) * 3, mirror=(1.0,) * 3,
                             emission=(big,) * 3), world=(big,) * 3,
                    camera=ortho_down(scale=40.0))  # some pixels miss the 20 m plane
    frame = whitted.render(s, RenderSettings(max_depth=1), accel=brute(s))
    n_hit = int(np.count_nonzero(frame.pixel_class == CLASS_TRACED))
    assert 0 < n_hit < 32 * 24
    assert frame.stats["nonfinite_samples"] == 32 * 24  # the world colour itself is > 1e30
    assert np.all(frame.radiance == 0.0)


def test_progress_and_cancel(monkeypatch):
    sc = plane_scene(Material("lambert", diffuse=(0.8,) * 3),
                     [Light("Lamp", "POINT", power=100.0, position=(0.0, 0.0, 2.0))])
    monkeypatch.setattr(whitted, "TILE_RAYS", 32 * 6)  # 6 rows per tile, 4 tiles
    acc = brute(sc)
    seen = []
    full = whitted.render(sc, RenderSettings(max_depth=0), accel=acc,
                          progress=lambda f, msg: seen.append(f))
    assert seen == pytest.approx([0.25, 0.5, 0.75, 1.0])
    assert not full.stats["cancelled"]
    tiles = []  # cancel() is polled before and within every tile: stop after two tiles
    part = whitted.render(sc, RenderSettings(max_depth=0), accel=acc,
                          progress=lambda f, msg: tiles.append(f),
                          cancel=lambda: len(tiles) >= 2)
    assert part.stats["cancelled"] and part.stats["rows_done"] == 12
    np.testing.assert_array_equal(part.radiance[:12], full.radiance[:12])
    assert np.all(part.radiance[12:] == 0.0)


def test_session_base_mode_update_and_modes():
    sc = scenes.three_spheres(32, 24, subdivisions=2)
    settings = RenderSettings(max_depth=2)
    sess = Session(sc, settings)
    frame = sess.render()
    ref = whitted.render(sc, settings, accel=brute(sc))
    assert image.compare(frame.radiance, ref.radiance)["n_over"] <= 2
    assert sess.stats["rays_traced"] == frame.stats["rays_traced"] > 0
    # move the red sphere: the session's update matches a fresh session on the moved scene
    moved = scenes.three_spheres(32, 24, subdivisions=2)
    moved.set_instance_matrix(1, shapes.transform((-1.0, 1.5, 1.0)))
    accel = sess.accel
    sess.update_scene(moved)
    assert sess.accel is accel
    after = sess.render()
    fresh = Session(moved, settings).render()
    np.testing.assert_array_equal(after.radiance, fresh.radiance)
    assert image.compare(after.radiance, frame.radiance)["n_over"] > 10
    from rstrace_engine.session import AVAILABLE_MODES

    for mode in ("INTERPOLANT", "RI_TREE"):
        if mode in AVAILABLE_MODES:
            continue
        sess.update_settings(RenderSettings(mode=mode))
        with pytest.raises(SceneError, match="not available"):
            sess.render()


def test_cli_render_writes_png_and_stats(tmp_path):
    out = tmp_path / "img.png"
    rc = cli_main(["render", "three_spheres", "--out", str(out), "--width", "24", "--height",
                   "18", "--depth", "1"])
    assert rc == 0
    px = image.read_png(out)
    assert px.shape == (18, 24, 3) and px.max() > 0
    stats = json.loads(out.with_suffix(".json").read_text())
    assert stats["scene"] == "three_spheres" and stats["rays_traced"] > 24 * 18


def test_diffuse_texture_through_uvs():
    rng = np.random.default_rng(11)
    tex = rng.random((3, 5, 3)).astype(np.float32)
    size = 4.0
    sun = Light("Sun", "SUN", power=2.0, direction=(0.0, 0.0, -1.0))
    sc = plane_scene(Material("tiles", diffuse=(0.5, 0.6, 0.7), texture=tex), [sun],
                     size=size)
    frame = whitted.render(sc, RenderSettings(max_depth=0), accel=brute(sc))
    p = floor_hits(sc)
    u = (p[:, 0] + size / 2) / size  # shapes.plane's uvs span [0, 1] over the plane
    v = (p[:, 1] + size / 2) / size
    # bilinear, repeating reference lookup (texel centres at (i + 0.5) / w), row 0 at v = 0
    h, w = tex.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]

    def texel(i, j):
        return tex[j % h, i % w].astype(np.float64)

    ref = ((1 - fx) * (1 - fy) * texel(x0, y0) + fx * (1 - fy) * texel(x0 + 1, y0)
           + (1 - fx) * fy * texel(x0, y0 + 1) + fx * fy * texel(x0 + 1, y0 + 1))
    want = np.array([0.5, 0.6, 0.7]) * ref / math.pi * 2.0
    np.testing.assert_allclose(frame.radiance.reshape(-1, 3), want, rtol=1e-5)


def test_bench_frame_runs_and_reports(tmp_path):
    from rstrace_engine.bench import frame as bench_frame

    res = bench_frame.run(["three_spheres"], width=24, height=18, depth=1, out=tmp_path)
    row = res["frames"][0]
    assert row["scene"] == "three_spheres" and row["rays"] > 24 * 18
    assert row["time_s"] > 0 and row["mrays_per_s"] > 0
    assert (tmp_path / "three_spheres_rstrace.png").exists()
    pytest.importorskip("mitsuba")
    assert row["mitsuba_s"] > 0 and row["ratio"] > 0
    mit = image.read_png(tmp_path / "three_spheres_mitsuba.png")
    assert mit.shape == (18, 24, 3) and mit.max() > 0  # the same camera sees lit geometry


def test_session_keeps_its_settings_when_an_accelerator_is_unavailable():
    from rstrace_engine.scenes import three_spheres
    from rstrace_engine.session import Session

    sess = Session(three_spheres(16, 12), RenderSettings(max_depth=1))
    # a visibility field of 2050 x 1024^2 tiles: over its memory cap, refused before building
    with pytest.raises(SceneError, match="visibility field: .* over the cap"):
        sess.update_settings(RenderSettings(accelerator="VISIBILITY_FIELD",
                                            vf_directions=2050, vf_tiles=1024))
    assert sess.settings.accelerator == "BVH" and sess.accel.name == "BVH"
    assert sess.render().radiance.shape == (12, 16, 3)
