"""The accelerator interface: BVH, visibility field and Embree against the brute-force
oracle."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import (
    AcceleratorUnavailable,
    Hits,
    create_accelerator,
)
from rstrace_engine.frame import CLASS_BACKGROUND, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_rays
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene, SceneError
from rstrace_engine.tolerances import FLOAT32_TNEAR_REL
from rstrace_engine.tracing.whitted import render


def mixed_scene() -> Scene:
    """Instanced, rotated, non-uniformly scaled closed meshes, a torus and a ground plane."""
    s = Scene()
    s.add_material(Material("m"))
    ico = s.add_mesh(shapes.icosphere(2))
    box = s.add_mesh(shapes.box((1.0, 0.6, 0.4)))
    tor = s.add_mesh(shapes.torus(0.8, 0.25, 24, 12))
    ground = s.add_mesh(shapes.plane(12.0, divisions=6))
    s.add_instance(ground, np.eye(4), [0], "Ground")
    s.add_instance(ico, shapes.transform((-2.0, 0.5, 1.0)), [0], "Ico1")
    s.add_instance(ico, shapes.transform((1.5, -1.0, 0.8), (0.6, 1.2, 0.8), 35, 20), [0], "Ico2")
    s.add_instance(box, shapes.transform((0.0, 2.0, 0.2), 1.5, 15), [0], "Box")
    s.add_instance(tor, shapes.transform((0.5, 0.5, 1.5), 1.0, 10, 70), [0], "Torus")
    s.add_instance(box, shapes.transform((-0.5, -2.0, 0.0), (2.0, 1.0, 0.1)), [0], "Slab")
    return s


@pytest.fixture(scope="module")
def scene_arrays():
    return mixed_scene().arrays()


@pytest.fixture(scope="module")
def oracle(scene_arrays):
    return create_accelerator("BRUTE_FORCE", scene_arrays)


@pytest.fixture(scope="module")
def bvh(scene_arrays):
    return create_accelerator("BVH", scene_arrays)


#: Accelerators held to the oracle by the tests below (Embree, float32, has its own).
EXACT = ("BVH", "VISIBILITY_FIELD")
#: Small visibility-field settings: the tests stay fast; exactness does not depend on them.
VF_OPTIONS = {"directions": 34, "tiles": 8}


@pytest.fixture(scope="module", params=EXACT)
def acc(request, scene_arrays):
    return create_accelerator(request.param, scene_arrays, **VF_OPTIONS)


def random_rays(sa, n: int, seed: int, scale_dirs: bool = True):
    """Origins in a box around the scene, random directions of random lengths."""
    rng = np.random.default_rng(seed)
    lo, hi = sa.scene_aabb
    o = rng.uniform(lo - 1.0, hi + 1.0, (n, 3))
    d = rng.normal(size=(n, 3))
    if scale_dirs:
        d *= rng.uniform(0.01, 100.0, (n, 1))  # distances are along d, not unit length
    return o, d, np.zeros(n), np.full(n, np.inf)


def adversarial_rays(sa, n_per: int = 1, seed: int = 0):
    """Rays aimed exactly at every vertex and edge midpoint of every instance (world space),
    from random origins, plus rays exactly along the axes and the diagonals."""
    rng = np.random.default_rng(seed)
    pts = []
    for i, m in enumerate(sa.inst_mesh):
        tris = sa.tris[sa.mesh_tri_start[m]:sa.mesh_tri_start[m + 1]]
        v = sa.verts[tris]
        local = np.concatenate([v.reshape(-1, 3), 0.5 * (v[:, 0] + v[:, 1])])
        x = sa.inst_xform[i]
        pts.append(local @ x[:3, :3].T + x[:3, 3])
    targets = np.repeat(np.concatenate(pts), n_per, axis=0)
    lo, hi = sa.scene_aabb
    o = rng.uniform(lo - 2.0, hi + 2.0, targets.shape)
    d = targets - o
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1],
                     [1, 1, 1], [1, -1, 1]], np.float64)
    axes = np.concatenate([axes, -axes])
    ao = rng.uniform(lo, hi, (len(axes) * 40, 3))
    ao[: len(ao) // 2] = np.round(ao[: len(ao) // 2] * 4) / 4  # on the grid lines of the plane
    ad = np.tile(axes, (40, 1))
    o, d = np.concatenate([o, ao]), np.concatenate([d, ad])
    return o, d, np.zeros(len(o)), np.full(len(o), np.inf)


def shares_vertex(sa, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether global triangles p and q (same-length int arrays) share a vertex position."""
    a = sa.verts[sa.tris[p]]
    b = sa.verts[sa.tris[q]]
    return np.any(np.all(a[:, :, None, :] == b[:, None, :, :], axis=-1), axis=(1, 2))


def assert_same_hits(sa, got: Hits, want: Hits, t_rtol: float = 1e-12):
    """Same instance and triangle; a different triangle only at a tie on a shared edge or
    vertex (same instance, same t, adjacent triangles)."""
    assert np.array_equal(got.inst >= 0, want.inst >= 0)
    hit = want.inst >= 0
    assert np.allclose(got.t[hit], want.t[hit], rtol=t_rtol, atol=0)
    assert np.all(np.isinf(got.t[~hit])) and np.all(got.prim[~hit] == -1)
    diff = hit & (got.prim != want.prim)
    assert np.array_equal(got.inst[diff], want.inst[diff])
    assert np.all(shares_vertex(sa, got.prim[diff], want.prim[diff]))
    same = hit & ~diff
    assert np.allclose(got.u[same], want.u[same], atol=1e-9)
    assert np.allclose(got.v[same], want.v[same], atol=1e-9)
    return diff


def check_hit_geometry(sa, o, d, h: Hits, atol: float):
    """The hit point from (u, v) on the reported triangle equals o + t d."""
    hit = np.flatnonzero(h.inst >= 0)
    x = sa.inst_xform[h.inst[hit]]
    v = sa.verts[sa.tris[h.prim[hit]]]
    local = ((1 - h.u[hit] - h.v[hit])[:, None] * v[:, 0] + h.u[hit][:, None] * v[:, 1]
             + h.v[hit][:, None] * v[:, 2])
    world = np.einsum("nij,nj->ni", x[:, :3, :3], local) + x[:, :3, 3]
    assert np.allclose(world, o[hit] + h.t[hit][:, None] * d[hit], atol=atol)
    # the triangle belongs to the instance's mesh
    m = sa.inst_mesh[h.inst[hit]]
    assert np.all((h.prim[hit] >= sa.mesh_tri_start[m]) & (h.prim[hit] < sa.mesh_tri_start[m + 1]))


# ----------------------------------------------------------------------------- factory


def test_create_by_name(scene_arrays):
    assert create_accelerator("bvh", scene_arrays).name == "BVH"
    assert create_accelerator("BRUTE_FORCE", scene_arrays).name == "BRUTE_FORCE"
    assert create_accelerator("VISIBILITY_FIELD", scene_arrays,
                              **VF_OPTIONS).name == "VISIBILITY_FIELD"
    with pytest.raises(AcceleratorUnavailable, match="unknown accelerator"):
        create_accelerator("KD_TREE", scene_arrays)
    assert issubclass(AcceleratorUnavailable, SceneError)


def test_bad_rays_rejected(bvh):
    o = np.zeros((2, 3))
    d = np.array([[1.0, 0, 0], [np.nan, 0, 0]])
    with pytest.raises(ValueError, match="NaN"):
        bvh.closest_hit(o, d, 0.0, np.inf)
    with pytest.raises(ValueError, match="must both be"):
        bvh.closest_hit(np.zeros((2, 2)), np.zeros((2, 2)), 0.0, np.inf)
    with pytest.raises(ValueError, match="out of range"):
        bvh.intersect_object(99, o[:1], d[:1], 0.0, np.inf)
    h = bvh.closest_hit(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    assert len(h.t) == 0 and h.inst.dtype == np.int32 and h.prim.dtype == np.int32


# ----------------------------------------------------------------------------- BVH vs oracle


def test_matches_brute_force_random(scene_arrays, oracle, acc):
    rays = random_rays(scene_arrays, 4000, seed=0)
    got, want = acc.closest_hit(*rays), oracle.closest_hit(*rays)
    assert np.mean(want.inst >= 0) > 0.3
    diff = assert_same_hits(scene_arrays, got, want)
    assert np.mean(diff) < 1e-3
    check_hit_geometry(scene_arrays, rays[0], rays[1], got, atol=1e-9)
    assert got.t.dtype == np.float64 and got.u.dtype == np.float64


def test_matches_brute_force_adversarial(scene_arrays, oracle, acc):
    rays = adversarial_rays(scene_arrays)
    got, want = acc.closest_hit(*rays), oracle.closest_hit(*rays)
    assert_same_hits(scene_arrays, got, want)


def test_any_hit_and_ray_interval(scene_arrays, oracle, acc):
    o, d, tmin, tmax = random_rays(scene_arrays, 3000, seed=1)
    first = acc.closest_hit(o, d, tmin, tmax)
    hit = first.inst >= 0
    for a in (acc, oracle):
        assert np.array_equal(a.any_hit(o, d, tmin, tmax), hit)
        # stopping just short of the closest hit: nothing
        short = np.where(hit, first.t * (1 - 1e-9), np.inf)
        assert not np.any(a.any_hit(o, d, tmin, short)[hit])
        assert np.all(a.closest_hit(o, d, tmin, short).inst[hit] == -1)
    # starting just past the closest hit: the next surface, as the oracle sees it
    start = np.where(hit, first.t * (1 + 1e-9), 0.0)
    nxt, want = acc.closest_hit(o, d, start, tmax), oracle.closest_hit(o, d, start, tmax)
    assert_same_hits(scene_arrays, nxt, want)
    assert np.all(nxt.t[hit & (nxt.inst >= 0)] > first.t[hit & (nxt.inst >= 0)])
    # an empty interval misses
    assert not np.any(acc.any_hit(o, d, np.full(len(o), 2.0), np.full(len(o), 1.0)))


def test_intersect_object_is_brute_force_restricted(scene_arrays, oracle, acc):
    o, d, tmin, tmax = random_rays(scene_arrays, 3000, seed=2)
    n_inst = len(scene_arrays.inst_mesh)
    for inst in range(n_inst):
        got = acc.intersect_object(inst, o, d, tmin, tmax)
        want = oracle.intersect_object(inst, o, d, tmin, tmax)
        assert np.all(got.inst[got.inst >= 0] == inst)
        assert_same_hits(scene_arrays, got, want)
    per_ray = np.random.default_rng(0).integers(0, n_inst, len(o)).astype(np.int32)
    got = acc.intersect_object(per_ray, o, d, tmin, tmax)
    assert_same_hits(scene_arrays, got, oracle.intersect_object(per_ray, o, d, tmin, tmax))
    assert np.all(got.inst[got.inst >= 0] == per_ray[got.inst >= 0])


@pytest.mark.parametrize("name", EXACT)
def test_on_grid_primary_rays(name):
    """The benchmark scene: every primary ray of a small grid camera agrees with the oracle."""
    s = scenes.grid(48, 36, subdivisions=2)
    sa = s.arrays()
    rays = camera_rays(s.camera)
    got = create_accelerator(name, sa, **VF_OPTIONS).closest_hit(*rays)
    want = create_accelerator("BRUTE_FORCE", sa).closest_hit(*rays)
    assert np.mean(want.inst >= 0) > 0.5
    assert_same_hits(sa, got, want)


# ----------------------------------------------------------------------------- Embree


@pytest.fixture(scope="module")
def embree(scene_arrays):
    pytest.importorskip("embreex")
    return create_accelerator("EMBREE", scene_arrays)


def float32_t_tolerance(sa, o, d, h: Hits):
    """Distance tolerance for float32 geometry: a few float32 ulps of the coordinates,
    divided by the cosine of incidence (grazing hits move far along the ray)."""
    hit = h.inst >= 0
    tri = sa.verts[sa.tris[np.where(hit, h.prim, 0)]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    x = sa.inst_nmat[np.where(hit, h.inst, 0)]
    n = np.einsum("nij,nj->ni", x, n)
    dn = np.linalg.norm(d, axis=1)
    cos = np.abs(np.einsum("ni,ni->n", n, d)) / (np.linalg.norm(n, axis=1) * dn)
    scale = np.abs(o).max(axis=1) + np.abs(sa.scene_aabb).max() + 1.0
    return 1e-5 * scale / (dn * np.maximum(cos, 1e-3))


def edge_distance(h: Hits) -> np.ndarray:
    """Smallest barycentric of each hit: 0 on an edge of the triangle hit."""
    return np.minimum(np.minimum(h.u, h.v), 1.0 - h.u - h.v)


def test_embree_matches_bvh(scene_arrays, embree, bvh):
    for rays, min_agree in ((random_rays(scene_arrays, 4000, seed=3), 0.999),
                            (adversarial_rays(scene_arrays, seed=4), 0.95)):
        o, d = rays[0], rays[1]
        got, want = embree.closest_hit(*rays), bvh.closest_hit(*rays)
        tol = float32_t_tolerance(scene_arrays, o, d, want)
        with np.errstate(invalid="ignore"):
            close = np.abs(got.t - want.t) <= tol  # inf - inf (both miss) is NaN: not close
        # the same: both miss, or the same triangle, or a tie (same distance; the scene has
        # coplanar overlaps such as the slab in the ground)
        same = ((got.inst == -1) & (want.inst == -1)) | close
        same |= (got.inst == want.inst) & (got.prim == want.prim) & (got.inst >= 0)
        # Embree does not report hits closer to the origin than its float32 resolution
        # (FLOAT32_TNEAR_REL of the coordinates): rays starting on a surface leave it
        near = (FLOAT32_TNEAR_REL * (np.abs(scene_arrays.scene_aabb).max() + np.abs(o).max(1))
                / np.abs(d).max(axis=1))
        same |= want.t <= near
        assert np.mean(same) > min_agree
        # where they differ (one hits, or they hit different surfaces), the ray grazes an
        # edge or vertex of what one of them hit (a silhouette): float32 vs float64 decides
        graze = (edge_distance(got) < 2e-3) & (got.inst >= 0)
        graze |= (edge_distance(want) < 1e-6) & (want.inst >= 0)
        assert np.all(graze[~same])
        both = np.flatnonzero((got.inst >= 0) & (got.prim == want.prim))
        assert np.all(np.abs(got.t[both] - want.t[both]) <= tol[both])
        check_hit_geometry(scene_arrays, o, d, got, atol=1e-3)
        assert np.array_equal(embree.any_hit(*rays), got.inst >= 0)


def test_embree_intersect_object_and_interval(scene_arrays, embree, bvh):
    o, d, tmin, tmax = random_rays(scene_arrays, 2000, seed=5)
    for inst in (1, 2, 4):
        got = embree.intersect_object(inst, o, d, tmin, tmax)
        want = bvh.intersect_object(inst, o, d, tmin, tmax)
        assert np.mean((got.inst >= 0) == (want.inst >= 0)) > 0.995
        both = (got.inst >= 0) & (want.inst >= 0)
        assert np.all(got.inst[got.inst >= 0] == inst)
        assert np.mean(got.prim[both] == want.prim[both]) > 0.99
    first = bvh.closest_hit(o, d, tmin, tmax)
    hit = first.inst >= 0
    start = np.where(hit, first.t + 1e-3 * np.abs(first.t), 0.0)
    got, want = embree.closest_hit(o, d, start, tmax), bvh.closest_hit(o, d, start, tmax)
    assert np.mean((got.inst >= 0) == (want.inst >= 0)) > 0.99
    both = (got.inst >= 0) & (want.inst >= 0)
    assert np.all(got.t[both] >= start[both] * (1 - 1e-6))


def test_embree_renders_the_bvh_image():
    """An accelerator must not change the image. Embree's float32 geometry once gave a ray
    spawned 1e-9 relative off a surface that same surface again (shadow acne): 29% of the
    pixels of this scene differed and 5,565 lit pixels were black against the BVH's 300."""
    pytest.importorskip("embreex")
    s = scenes.three_spheres(96, 72, subdivisions=3)
    settings = dict(samples=1, max_depth=2)
    a = render(s, RenderSettings(accelerator="BVH", **settings))
    b = render(s, RenderSettings(accelerator="EMBREE", **settings))
    assert np.array_equal(a.pixel_class, b.pixel_class)
    lit = a.pixel_class != CLASS_BACKGROUND
    black_a = int(np.count_nonzero((a.radiance.max(axis=-1) < 1e-3) & lit))
    black_b = int(np.count_nonzero((b.radiance.max(axis=-1) < 1e-3) & lit))
    assert abs(black_a - black_b) <= 2
    diff = np.abs(a.radiance - b.radiance).max(axis=-1)
    assert np.mean(diff > 1e-3) < 1e-3 and diff.max() < 0.05


@pytest.mark.parametrize("offset", [1e5, 1e6, 1e7])
def test_embree_far_from_the_origin_renders_the_bvh_image(offset):
    """Embree's float32 geometry is re-centred on the scene's box: in world float32 a scene
    1e6 from the origin had 1,122 of its 1,829 lit pixels wrong, and at 1e7 every primary
    ray missed (the image was background), without a word."""
    pytest.importorskip("embreex")
    from tracer_scenes import transformed

    base = scenes.three_spheres(64, 48, subdivisions=2)
    sc = transformed(base, 1.0, (offset, -offset, 0.5 * offset))
    st = RenderSettings(max_depth=3)
    a = render(sc, st, accel=create_accelerator("BVH", sc.arrays()))
    b = render(sc, st, accel=create_accelerator("EMBREE", sc.arrays()))
    assert np.array_equal(a.pixel_class, b.pixel_class)
    assert np.count_nonzero(a.pixel_class != CLASS_BACKGROUND) > 1000
    assert np.abs(a.radiance - b.radiance).max() <= 1e-6


def test_embree_shadow_rays_do_not_find_their_own_surface():
    """Shadow rays spawned off the small, finely tessellated objects of ``museum`` found
    their own object as occluder in Embree's float32 (4 pixels of this frame black or
    darker, up to 0.053; 37 at 320x240): occlusion is now checked by a closest-hit query
    whose float64 re-test rejects a hit behind the ray's start."""
    pytest.importorskip("embreex")
    sc = scenes.build("museum", 64, 48)
    st = RenderSettings(max_depth=3)
    a = render(sc, st, accel=create_accelerator("BVH", sc.arrays()))
    b = render(sc, st, accel=create_accelerator("EMBREE", sc.arrays()))
    assert np.array_equal(a.pixel_class, b.pixel_class)
    assert np.abs(a.radiance - b.radiance).max() <= 1e-6


@pytest.mark.parametrize("where", [(1.0, 1.0, 2.0), (1.0, 0.3, 2.0), (1.0, 0.3, 1.0)])
def test_embree_a_light_on_a_surface_is_not_its_own_occluder(where):
    """A point light exactly on a box's corner, edge or face: shadow rays end 1e-9 short of
    it, which float32 cannot resolve, and Embree reported the surface under the light as
    its occluder (up to 690 of 1,728 pixels dark that the oracle lights). A hit whose
    float64 distance lies past the ray's end is no hit."""
    pytest.importorskip("embreex")
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.5, 0.5, 0.5)))
    boxm = s.add_material(Material("box", diffuse=(0.6, 0.3, 0.2)))
    s.add_instance(s.add_mesh(shapes.plane(20.0)), np.eye(4), [floor], name="Floor")
    s.add_instance(s.add_mesh(shapes.box((2.0, 2.0, 2.0))), shapes.transform((0.0, 0.0, 1.0)),
                   [boxm], name="Box")
    s.add_light(Light("P", "POINT", power=1000.0, position=where))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -8.0, 5.0), (0.0, 0.0, 0.0)), lens=30.0,
                        width=48, height=36))
    st = RenderSettings(max_depth=3)
    a = render(s, st, accel=create_accelerator("BRUTE_FORCE", s.arrays()))
    b = render(s, st, accel=create_accelerator("EMBREE", s.arrays()))
    assert np.count_nonzero(a.radiance.max(axis=-1) > 0) > 300
    assert np.abs(a.radiance - b.radiance).max() <= 1e-6


def test_embree_builds_an_object_scene_for_every_object_of_a_large_scene():
    """Every per-object Embree scene had a device of its own and the process died
    (segfault) at about the 1,017th; ``museum`` has 2,002 objects, and a scene far from
    the origin sends most hits to the per-object tie tests. Run in a child process, so a
    crash is a failure and not the end of the test run."""
    pytest.importorskip("embreex")
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from rstrace_engine import scenes\n"
        "from rstrace_engine.accel.accelerators import create_accelerator\n"
        "sc = scenes.build('museum', 8, 6)\n"
        "sa = sc.arrays()\n"
        "acc = create_accelerator('EMBREE', sa)\n"
        "live = np.flatnonzero(sa.inst_alive)\n"
        "assert len(live) > 1100, len(live)\n"
        "c = 0.5 * (sa.inst_aabb[live, 0] + sa.inst_aabb[live, 1])\n"
        "o = c + np.array([0.0, 0.0, 50.0])\n"
        "d = np.tile([0.0, 0.0, -1.0], (len(live), 1))\n"
        "args = (live.astype(np.int32), o, d, np.zeros(len(live)), np.full(len(live), np.inf))\n"
        "h = acc.intersect_object(*args)\n"
        "ref = create_accelerator('BVH', sa).intersect_object(*args)\n"
        "close = np.isclose(h.t, ref.t, rtol=1e-9) | ((h.inst < 0) & (ref.inst < 0))\n"
        "same = int(np.count_nonzero((h.inst == ref.inst) & close))\n"
        "print('hits', int(np.count_nonzero(h.inst >= 0)), 'same', same, 'of', len(live))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    words = r.stdout.split()
    assert words[0] == "hits" and int(words[1]) > 1000
    # every ray: the BVH's object and distance (a ray down a box's diagonal edge may take
    # either triangle)
    assert int(words[3]) == int(words[5])


def resting_box_scene(n_others: int = 6) -> Scene:
    """A unit box resting on a floor (its bottom face coplanar with the floor) and a row of
    small boxes behind it."""
    s = Scene()
    s.add_material(Material("m"))
    floor = s.add_mesh(shapes.plane(10.0))
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0)))
    s.add_instance(floor, np.eye(4), [0], "Floor")
    s.add_instance(cube, shapes.transform((0.0, 0.0, 0.5)), [0], "Box")
    for k in range(n_others):
        s.add_instance(cube, shapes.transform((-3.0 + 1.2 * k, 2.5, 0.3), 0.3), [0], f"C{k}")
    return s


def rays_onto_the_box_bottom(n: int, seed: int):
    """Rays from inside the resting box down onto its bottom, where it meets the floor."""
    rng = np.random.default_rng(seed)
    o = np.column_stack([rng.uniform(-0.45, 0.45, n), rng.uniform(-0.45, 0.45, n),
                         rng.uniform(0.2, 0.8, n)])
    d = np.column_stack([rng.normal(0.0, 0.3, n), rng.normal(0.0, 0.3, n), -np.ones(n)])
    return o, d, np.zeros(n), np.full(n, np.inf)


@pytest.mark.parametrize("name", ["EMBREE", "BVH", "VISIBILITY_FIELD"])
def test_coplanar_faces_of_two_objects_hit_as_the_oracle(name):
    """Where two objects' faces coincide, the hit is the closest float64 one, equal distances
    going to the highest instance id (the oracle's rule), whatever the accelerator's own
    structure: Embree's float32 distances tie there, and which object it reported depended on
    its BVH, so on the other objects in the scene (an incremental frame after hiding one of
    them differed from a fresh frame in pixels nobody marked dirty)."""
    if name == "EMBREE":
        pytest.importorskip("embreex")
    s = resting_box_scene()
    rays = rays_onto_the_box_bottom(4000, seed=1)
    want = create_accelerator("BRUTE_FORCE", s.arrays()).closest_hit(*rays)
    assert np.all(want.inst >= 0) and set(np.unique(want.inst)) == {0, 1}  # both win ties
    for hidden in (None, "C0", "C3"):
        sc = s.copy()
        if hidden is not None:
            sc.set_instance_visible(sc.instance_slot(hidden), False)
        got = create_accelerator(name, sc.arrays(), **VF_OPTIONS).closest_hit(*rays)
        np.testing.assert_array_equal(got.inst, want.inst)
        np.testing.assert_array_equal(got.prim, want.prim)
        np.testing.assert_array_equal(got.t, want.t)
        np.testing.assert_array_equal(got.u, want.u)
        np.testing.assert_array_equal(got.v, want.v)


@pytest.mark.parametrize("name", ["EMBREE", "BVH"])
def test_duplicate_objects_and_far_origins_tie_as_the_oracle(name):
    """An exact duplicate of the resting box (every distance equal: the highest instance id
    wins), and rays starting 40 scene sizes away (Embree's tie window grows with the origin:
    the objects' own boxes are queried instead of the precomputed overlaps)."""
    if name == "EMBREE":
        pytest.importorskip("embreex")
    s = resting_box_scene(3)
    s.add_instance(s.instances[s.instance_slot("Box")]["mesh"],
                   shapes.transform((0.0, 0.0, 0.5)), [0], "Duplicate")
    o, d, tmin, tmax = rays_onto_the_box_bottom(2000, seed=2)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for rays in ((o, d, tmin, tmax), (o - 200.0 * d, d, tmin, tmax)):
        want = create_accelerator("BRUTE_FORCE", s.arrays()).closest_hit(*rays)
        got = create_accelerator(name, s.arrays()).closest_hit(*rays)
        assert np.count_nonzero(want.inst == s.instance_slot("Duplicate")) > 1000
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w)


def test_embree_update_follows_moves(embree):
    s = mixed_scene()
    s.set_instance_matrix(1, shapes.transform((3.0, 3.0, 1.0)))
    sa = s.arrays()
    embree.update(sa)
    bv = create_accelerator("BVH", sa)
    rays = random_rays(sa, 2000, seed=6)
    got, want = embree.closest_hit(*rays), bv.closest_hit(*rays)
    assert np.mean(got.inst == want.inst) > 0.99
    embree.update(mixed_scene().arrays())  # back, for the other tests of this module


# ----------------------------------------------------------------------------- bench


def test_bench_raycast_json():
    pytest.importorskip("embreex")
    from rstrace_engine.bench import raycast

    buf = io.StringIO()
    with redirect_stdout(buf):
        assert raycast.main(["--json", "--repeats", "1", "--random", "2000"]) == 0
    out = json.loads(buf.getvalue())
    names = {(w["name"], w["threads"]) for w in out["workloads"]}
    assert names == {("grid-primary", 1), ("grid-primary", 2), ("grid-random", 1),
                     ("grid-random", 2)}
    for w in out["workloads"]:
        assert w["numba_mrays"] > 0 and w["embree_mrays"] > 0
        # both speeds and the ratio are rounded to 3 decimals
        assert w["ratio"] == pytest.approx(w["numba_mrays"] / w["embree_mrays"], rel=1e-2,
                                           abs=1e-3)
