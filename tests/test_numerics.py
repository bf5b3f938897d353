"""Numerical robustness of the base tracer, and the display-space metrics.

* The same scene scaled by 1e-4 and 1e5, or translated by 1e6, renders the same image.
* Grazing rays, rays exactly along axes and diagonals, zero-thickness surfaces.
* No self-shadowing (acne) on curved surfaces at any scale.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from tracer_scenes import ortho_down, plane_scene, point_intensity, transformed

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_rays
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.tracing import whitted

ACCELS = ["BRUTE_FORCE", "BVH"]


def trace_rays(scene, origins, directions, depth=0, record=False, accel="BRUTE_FORCE"):
    sa = scene.arrays()
    acc = create_accelerator(accel, sa)
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    return whitted.trace(sa, acc, o, d, 0.0, np.inf, depth, record=record)


# ----------------------------------------------------------------------------- scale invariance


@pytest.mark.parametrize("name", ["museum_1999", "tori"])
def test_touching_objects_far_from_the_origin_keep_their_shadows(name):
    """1e7 from the origin the spawn offset (relative to the coordinates) once reached 1 cm:
    shadow rays started beyond the gaps between stacked slabs and next to contacts, and
    light leaked (museum_1999: 18 pixels of 64x48 off, up to 0.82; tori: 11, up to 0.57)."""
    base = scenes.build(name, 64, 48)
    st = RenderSettings(max_depth=3)
    ref = whitted.render(base, st, accel=create_accelerator("BVH", base.arrays()))
    sc = transformed(base, 1.0, (1e7, -1e7, 0.5e7))
    frame = whitted.render(sc, st, accel=create_accelerator("BVH", sc.arrays()))
    assert np.array_equal(frame.pixel_class, ref.pixel_class)
    m = image.compare(frame.radiance, ref.radiance, epsilon=1e-3)
    assert m["n_over"] == 0 and m["max_error"] < 1e-3


@pytest.fixture(scope="module")
def spheres_reference():
    base = scenes.three_spheres(64, 48, subdivisions=2)
    frames = {a: whitted.render(base, RenderSettings(max_depth=3),
                                accel=create_accelerator(a, base.arrays())) for a in ACCELS}
    return base, frames


@pytest.mark.parametrize("accel", ACCELS)
@pytest.mark.parametrize("scale,offset", [(1e-4, 0.0), (1e5, 0.0), (1.0, 1e6),
                                          (1.0, 1e7), (1e5, -1e9)])
def test_scaled_and_translated_scene_renders_the_same(spheres_reference, accel, scale, offset):
    """Same image at 1e-4 / 1e5 scale and 1e6 away from the origin.

    Primary hits are float64-exact up to ~1e-16 of the coordinate magnitude, so only the
    spawn offset (1e-9 of the magnitude: 1e-3 m at 1e6 m, i.e. 1e-4 of this 10 m scene)
    moves anything: it shifts secondary rays by that much, which shows only where the
    mirror sphere reflects a steep radiance gradient (highlights, silhouettes). Hence: the
    same pixel classes, a tiny mean error, and at most a handful of pixels over 1e-3.
    """
    base, frames = spheres_reference
    gain = 1e-2 if scale > 1 else 1.0  # keeps point-light powers within the 1e12 W limit
    sc = transformed(base, scale, (offset, -offset, 0.5 * offset), gain=gain)
    frame = whitted.render(sc, RenderSettings(max_depth=3),
                           accel=create_accelerator(accel, sc.arrays()))
    ref = frames[accel]
    assert np.array_equal(frame.pixel_class, ref.pixel_class)
    m = image.compare(frame.radiance / gain, ref.radiance, epsilon=1e-3)
    assert m["mean_error"] < 1e-5
    assert m["n_over"] <= 5  # of 3,072 pixels
    assert m["max_error"] < 5e-3
    if offset == 0.0:  # pure scaling changes no offsets relative to the scene
        assert m["max_error"] < 1e-4


@pytest.mark.parametrize("scale,offset", [(1.0, 0.0), (1e-4, 0.0), (1e5, 0.0), (1.0, 1e6)])
def test_no_self_shadowing_on_curved_surfaces(scale, offset):
    s = Scene()
    mat = s.add_material(Material("white", diffuse=(0.8,) * 3))
    sph = s.add_mesh(shapes.icosphere(2, name="ball"))
    s.add_instance(sph, np.eye(4), [mat], name="Ball")
    s.add_light(Light("Sun", "SUN", power=2.0, direction=(0.3, 0.5, -1.0)))
    s.add_light(Light("Lamp", "POINT", power=300.0, position=(-3.0, 1.0, 2.0)))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -5.0, 1.5), (0.0, 0.0, 0.0)), width=32,
                        height=24))
    sc = transformed(s, scale, (offset, offset, offset), gain=1e-2 if scale > 1 else 1.0)
    sa = sc.arrays()
    o, d, t0, t1 = camera_rays(sc.camera)
    _, tree = whitted.trace(sa, create_accelerator("BVH", sa), o, d, t0, t1, 0, record=True)
    hit = tree.node_inst >= 0
    assert hit.sum() > 200
    # a convex object cannot shadow itself: every light facing a hit point reaches it
    assert np.all(tree.node_occluder[hit] != 0)
    assert np.count_nonzero(tree.node_light_mask[hit].any(axis=1)) > 0.5 * hit.sum()


# ----------------------------------------------------------------------------- grazing rays


@pytest.mark.parametrize("angle", [1e-2, 1e-4, 1e-6])
def test_grazing_view_of_a_lambertian_plane(angle):
    """A Lambertian plane looks the same from any angle, grazing ones included."""
    light = Light("Lamp", "POINT", power=500.0, position=(0.2, 0.1, 1.5))
    sc = plane_scene(Material("lambert", diffuse=(0.7,) * 3), [light], size=2e7)
    targets = np.array([[0.0, 0.0, 0.0], [0.37, -0.21, 0.0], [-0.5, 0.5, 0.0]])
    d = np.array([math.cos(angle), 0.0, -math.sin(angle)])
    origins = targets - 1e3 * d
    rad, tree = trace_rays(sc, origins, np.broadcast_to(d, targets.shape), record=True)
    assert np.all(tree.node_inst == 0)
    np.testing.assert_allclose(tree.node_point, targets, atol=1e-9)
    v = np.asarray(light.position) - targets
    r2 = np.einsum("ij,ij->i", v, v)
    want = 0.7 / math.pi * point_intensity(light)[0] * v[:, 2] / r2 ** 1.5
    np.testing.assert_allclose(rad[:, 0], want, rtol=1e-6)


@pytest.mark.parametrize("angle", [1e-2, 1e-4, 1e-6])
def test_grazing_reflection_does_not_self_intersect(angle):
    sc = plane_scene(Material("mirror", diffuse=(0.0,) * 3, mirror=(0.9,) * 3),
                     world=(0.2, 0.3, 0.4), size=2e7)
    d = np.array([math.cos(angle), 0.0, -math.sin(angle)])
    origins = np.array([[0.0, 0.0, 0.0], [3.3, 1.1, 0.0]]) - 10.0 * d
    rad, tree = trace_rays(sc, origins, np.broadcast_to(d, origins.shape), depth=4,
                           record=True)
    np.testing.assert_allclose(rad, np.broadcast_to([0.18, 0.27, 0.36], rad.shape), rtol=1e-12)
    kids = tree.node_parent >= 0
    assert np.all(tree.node_inst[kids] == -1)  # the reflection escapes to the sky
    assert np.all(tree.node_path[kids] == 2)


def test_grazing_light():
    """A light almost in the plane gives a tiny, correct, finite irradiance."""
    for h in (1e-3, 1e-6):
        light = Light("Low", "POINT", power=1e3, position=(100.0, 0.0, h))
        sc = plane_scene(Material("lambert", diffuse=(1.0,) * 3), [light], size=1e3)
        rad, _ = trace_rays(sc, [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]])
        r = math.hypot(100.0, h)
        want = 1.0 / math.pi * point_intensity(light)[0] * (h / r) / r ** 2
        assert rad[0, 0] == pytest.approx(want, rel=1e-6)


# ----------------------------------------------------------------------------- axes, diagonals


def _cube_scene(material=None, world=(0.0, 0.0, 0.0)):
    s = Scene()
    mat = s.add_material(material or Material("white", diffuse=(0.8,) * 3))
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"))
    s.add_instance(cube, np.eye(4), [mat], name="Cube")
    s.add_light(Light("Sun", "SUN", power=2.0, direction=(0.0, 0.0, -1.0)))  # along an axis
    s.add_light(Light("Diag", "SUN", power=1.0, direction=(-1.0, -1.0, -1.0)))
    s.set_world_color(world, lights=False)
    s.set_camera(ortho_down())
    return s


@pytest.mark.parametrize("accel", ACCELS)
def test_rays_along_axes_hit_edges_and_vertices(accel):
    sc = _cube_scene()
    xs = np.array([-0.5, -0.25, 0.0, 0.25, 0.5])  # includes the cube's edges and vertices
    X, Y = np.meshgrid(xs, xs)
    origins = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 5.0)], 1)
    rad, tree = trace_rays(sc, origins, np.broadcast_to([0.0, 0.0, -1.0], origins.shape),
                           record=True, accel=accel)
    assert np.all(tree.node_inst == 0)  # no leaks through edges or vertices
    np.testing.assert_allclose(tree.node_point[:, 2], 0.5, atol=1e-12)
    # the top face, lit head-on by the axis sun and at cos = 1/sqrt(3) by the diagonal one
    want = 0.8 / math.pi * (2.0 + 1.0 / math.sqrt(3.0))
    np.testing.assert_allclose(rad[:, 0], want, rtol=1e-9)
    # just outside: misses
    out = origins[:5] + [0.0, -1e-9, 0.0]
    out[:, 1] = -0.5 - 1e-9
    _, t2 = trace_rays(sc, out, np.broadcast_to([0.0, 0.0, -1.0], out.shape), record=True,
                       accel=accel)
    assert np.all(t2.node_inst == -1)


@pytest.mark.parametrize("accel", ACCELS)
def test_rays_along_diagonals(accel):
    sc = _cube_scene()
    dirs = np.array([[1, 1, 1], [-1, 1, 1], [1, -1, -1], [1, 1, 0], [0, 1, -1]], float)
    origins = -5.0 * dirs  # straight at the centre: through a vertex or along an edge
    rad, tree = trace_rays(sc, origins, dirs, record=True, accel=accel)
    assert np.all(tree.node_inst == 0)
    assert np.all(np.isfinite(rad)) and np.all(rad >= 0.0)
    # the hit is the vertex / edge midpoint the ray aims at
    np.testing.assert_allclose(tree.node_point, -0.5 * dirs, atol=1e-12)


def test_axis_aligned_mirror_reflection_is_exact():
    sc = _cube_scene(Material("mirror", diffuse=(0.0,) * 3, mirror=(0.5,) * 3),
                     world=(0.2, 0.4, 0.6))
    rad, tree = trace_rays(sc, [[0.1, 0.2, 5.0], [5.0, 0.0, 0.0]],
                           [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]], depth=3, record=True)
    np.testing.assert_allclose(rad, [[0.1, 0.2, 0.3]] * 2, rtol=1e-15)
    kids = np.flatnonzero(tree.node_parent >= 0)
    seg = tree.node_point[kids] - tree.node_origin[kids]
    np.testing.assert_array_equal(seg[:, :2][0], [0.0, 0.0])  # straight back up, exactly


# ----------------------------------------------------------------------------- thin surfaces


def test_zero_thickness_plane_lit_from_both_sides():
    above = Light("Above", "POINT", color=(1.0, 0.0, 0.0), power=500.0,
                  position=(0.3, 0.0, 2.0))
    below = Light("Below", "POINT", color=(0.0, 0.0, 1.0), power=300.0,
                  position=(-0.2, 0.1, -1.0))
    sc = plane_scene(Material("paper", diffuse=(0.6,) * 3), [above, below])
    p = np.array([0.1, -0.1, 0.0])
    rad, tree = trace_rays(sc, [p + [0, 0, 3.0], p - [0, 0, 3.0]],
                           [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]], record=True)

    def lambert(light):
        v = np.asarray(light.position) - p
        return 0.6 / math.pi * point_intensity(light) * abs(v[2]) / np.linalg.norm(v) ** 3

    np.testing.assert_allclose(rad[0], lambert(above), rtol=1e-9, atol=0)
    np.testing.assert_allclose(rad[1], lambert(below), rtol=1e-9, atol=0)
    assert list(tree.node_occluder[0]) == [whitted.OCC_NONE, whitted.OCC_NOT_FACING]
    assert list(tree.node_occluder[1]) == [whitted.OCC_NOT_FACING, whitted.OCC_NONE]
    assert tree.node_light_mask.tolist() == [[1], [2]]  # (one word: light_bits)


def test_zero_thickness_plane_casts_a_shadow():
    s = Scene()
    mat = s.add_material(Material("grey", diffuse=(0.5,) * 3))
    pm = s.add_mesh(shapes.plane(1.0, name="card"))
    fm = s.add_mesh(shapes.plane(20.0, name="floor"))
    s.add_instance(fm, np.eye(4), [mat], name="Floor")
    s.add_instance(pm, shapes.transform((0.0, 0.0, 1.0)), [mat], name="Card")
    s.add_light(Light("Lamp", "POINT", power=500.0, position=(0.0, 0.0, 3.0)))
    s.set_camera(ortho_down())
    rad, tree = trace_rays(s, [[-3.0, 0.0, 3.0], [3.0, 0.0, 3.0]],
                           [[1.0, 0.0, -1.0], [1.0, 0.0, -1.0]], record=True)
    assert list(tree.node_inst) == [0, 0]
    assert tree.node_occluder[0, 0] == 1 and np.all(rad[0] == 0.0)
    assert tree.node_occluder[1, 0] == whitted.OCC_NONE and rad[1, 0] > 0.0


# ----------------------------------------------------------------------------- display metrics


def test_display_transform():
    lin = np.array([[0.0, 0.0031308, 0.5], [1.0, 2.0, -1.0], [np.nan, np.inf, 0.18]])
    out = image.to_display(lin)
    want = [[0.0, 0.04045, 1.055 * 0.5 ** (1 / 2.4) - 0.055], [1.0, 1.0, 0.0],
            [0.0, 1.0, 1.055 * 0.18 ** (1 / 2.4) - 0.055]]
    np.testing.assert_allclose(out, want, atol=1e-6)
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(image.srgb_decode(image.srgb_encode(x)), x, atol=1e-12)


def test_compare_metrics():
    a = np.full((4, 5, 3), 0.5, np.float32)
    same = image.compare(a, a)
    assert same["max_error"] == 0.0 and same["psnr"] == math.inf and same["n_over"] == 0
    b = a.copy()
    b[0, 0, 1] = 1.0  # display 0.7354 -> 1.0
    m = image.compare(b, a, epsilon=0.1)
    d = 1.0 - image.to_display(np.float64(0.5))
    assert m["max_error"] == pytest.approx(d, rel=1e-6)
    assert m["mean_error"] == pytest.approx(d / 60, rel=1e-6)
    assert m["n_over"] == 1 and m["frac_over"] == pytest.approx(1 / 20)
    assert m["psnr"] == pytest.approx(10 * math.log10(60 / d ** 2), rel=1e-6)
    with pytest.raises(ValueError):
        image.compare(a, a[:2])


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    rad = rng.random((7, 9, 3)) * 1.2
    path = image.write_render_png(tmp_path / "x.png", rad)
    back = image.read_png(path)
    np.testing.assert_array_equal(back, image.to_uint8(image.to_display(rad)))
    raw = image.read_png(path, bottom_up=False)
    np.testing.assert_array_equal(raw, back[::-1])
    rgba = rng.integers(0, 256, (3, 4, 4), dtype=np.uint8)
    np.testing.assert_array_equal(image.read_png(image.write_png(tmp_path / "a.png", rgba)),
                                  rgba)
    image.save_npy(tmp_path / "x.npy", rad)
    np.testing.assert_array_equal(image.load_npy(tmp_path / "x.npy"), rad)
