"""Soft shadow rays that leave their point's own convex instance out of the traversal
(tracing/shaft_skip.own_instances): the BVH's query without that instance (``any_hit``'s
``skip``; the kernel's ``only <= -2``) answers as the whole one for every such ray, so
frames with and without the skip are the same bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from test_shaft_skip import SCENES, _random_scene, primary_surfaces

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Light, Material, Scene
from rstrace_engine.tracing import shaft_skip, whitted
from rstrace_engine.tracing.glossy_rays import interface_materials
from rstrace_engine.tracing.soft_lights import sample_seeds, soft_rays


def _rough_balls(w=40, h=30):
    """The soak's room under soft light with a rough glass ball (its samples below the
    surface leave from the far side: not offered the skip) and, of the same mesh, an
    opaque ball stretched and mirrored."""
    s = SOAK_SCENES["rough_soft_room"](w, h)
    s.add_instance(s.mesh_id("ball"), shapes.transform((-1.2, 0.8, 0.7), (0.8, -1.1, 0.9),
                                                       20.0, 10.0),
                   [s.material_id("red")], name="Opaque")
    return s


OWN_SCENES = dict(SCENES, rough_soft_room=lambda: SOAK_SCENES["rough_soft_room"](40, 30),
                  rough_balls=_rough_balls)


def _on_and_off(scene, st, monkeypatch) -> tuple:
    """``scene``'s frames with the own-instance skip on and off: the same image and pixel
    classes (asserted)."""
    monkeypatch.setattr(shaft_skip, "OWN_SKIP", True)
    on = whitted.render(scene, st)
    monkeypatch.setattr(shaft_skip, "OWN_SKIP", False)
    off = whitted.render(scene, st)
    assert np.array_equal(on.radiance, off.radiance)
    assert np.array_equal(on.pixel_class, off.pixel_class)
    return on, off


@pytest.mark.parametrize("name", sorted(OWN_SCENES))
def test_frames_with_and_without_the_own_skip_are_identical(name, monkeypatch):
    """Convex objects (mirrored and stretched ones too), non-convex ones, rough glass
    (its samples below the surface are not offered the skip), mirrors below, every light
    with an extent and a world that lights: the same image and the same shadow rays; rays
    leave their own instance out wherever a convex mesh of 32 triangles or more is hit
    (the room seen from inside has none, the rough room only its glass ball)."""
    st = RenderSettings(mode="BASE", max_depth=2, samples=2, light_samples=8, seed=3)
    on, off = _on_and_off(OWN_SCENES[name](), st, monkeypatch)
    assert on.stats["shadow_rays"] == off.stats["shadow_rays"]
    assert on.stats["shadow_rays_skipped"] == off.stats["shadow_rays_skipped"]
    assert off.stats["shadow_rays_own_skip"] == 0
    if name in ("inside", "rough_soft_room"):
        assert on.stats["shadow_rays_own_skip"] == 0
    else:
        assert 0 < on.stats["shadow_rays_own_skip"] < on.stats["shadow_rays"]


def _own_rays(scene, light_samples=8, depth_hits=None):
    """The soft samples the tracer traces from the primary hits (every light with an
    extent and the world) and the instance each leaves out (-1: none)."""
    sa, accel, cp, pixels, hits, surf = primary_surfaces(scene)
    own = shaft_skip.own_instances(sa, accel, surf, hits.inst, hits.prim)
    soft, so, st, rows = soft_rays(sa, surf, sample_seeds(pixels, 1), light_samples,
                                   surf.sh_state)
    r = np.repeat(rows, light_samples)
    L = max(len(sa.light_kind), 1)
    skip = own[np.where(r >= 0, r // L, -1 - r)]
    live = soft.w > 0.0
    return accel, so[live], soft.d[live], st[live], skip[live]


@pytest.mark.parametrize("seed", range(4))
def test_no_skipped_ray_meets_its_own_instance(seed):
    """The proof itself, ray by ray (another blocker could hide a wrong skip from the
    image): no soft sample offered the skip meets its own instance when that instance
    alone is traced, and the whole scene's answer is the same with the skip; a good share
    of the rays is offered it (the objects are small in these frames)."""
    scene = _random_scene(20 + seed, 64, 48)
    accel, o, d, tmax, skip = _own_rays(scene)
    mine = np.flatnonzero(skip >= 0)
    assert len(mine) > 0.01 * len(skip)
    zero = np.zeros(len(mine))
    assert not accel.occludes_object(skip[mine], o[mine], d[mine], zero, tmax[mine]).any()
    assert np.array_equal(accel.any_hit(o, d, np.zeros(len(o)), tmax, skip),
                          accel.any_hit(o, d, np.zeros(len(o)), tmax))


def test_any_hit_leaves_the_skipped_instance_out():
    """``skip`` takes the instance out of that ray's query alone: a ray through two balls
    is blocked whichever is skipped, a ray through one is not blocked when it is skipped;
    other accelerators answer the whole query (the skip is the caller's proven hint)."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.5, 0.5, 0.5)))
    ball = s.add_mesh(shapes.icosphere(2, 0.5, name="ball"))
    a = s.add_instance(ball, shapes.transform((0.0, 0.0, 0.0)), [grey], name="A")
    b = s.add_instance(ball, shapes.transform((0.0, 3.0, 0.0)), [grey], name="B")
    s.add_light(Light("Lamp", "POINT", power=10.0, position=(0.0, 0.0, 5.0)))
    o = np.array([[0.0, -5.0, 0.0], [0.0, -5.0, 0.0], [0.0, -5.0, 0.0], [5.0, 0.0, 0.0],
                  [5.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    d = np.array([[0.0, 1.0, 0.0]] * 3 + [[-1.0, 0.0, 0.0]] * 3)
    skip = np.array([-1, a, b, -1, a, b], np.int32)
    t0, t1 = np.zeros(6), np.full(6, np.inf)
    bvh = create_accelerator("BVH", s.arrays())
    assert bvh.any_hit(o, d, t0, t1, skip).tolist() == [True, True, True, True, False, True]
    brute = create_accelerator("BRUTE_FORCE", s.arrays())
    assert brute.any_hit(o, d, t0, t1, skip).all()
    # the closest hits are the kernel's without a skip
    assert bvh.closest_hit(o, d, t0, t1).inst.tolist() == [a, a, a, a, a, a]


def _rough_random(seed, w=48, h=36):
    """The random scene of every kind of object (convex, non-convex, open, mirrored,
    stretched) with its materials made rough metals, rough plastics and mirrors, and a
    point light beside its lights with an extent."""
    s = _random_scene(seed, w, h)
    for mid, m in enumerate(s.materials):
        if m is not None and mid % 3 != 2:
            rough, _ = principled_material(m.name, m.diffuse, metallic=float(mid % 3 == 0),
                                           roughness=0.3 + 0.1 * (mid % 4))
            s.set_material(mid, rough)
        elif m is not None:
            s.set_material(mid, Material(m.name, diffuse=(0.1,) * 3, mirror=(0.8,) * 3))
    s.add_light(Light("Key", "POINT", power=300.0, position=(1.5, -2.0, 4.0)))
    return s


REFLECT_SCENES = {
    "rough_materials": lambda: scenes.rough_materials(48, 36),
    "glossy": lambda: scenes.glossy(48, 36),
    "studio": lambda: scenes.studio(48, 36),
    "three_spheres": lambda: scenes.three_spheres(48, 36),
    "rough_random0": lambda: _rough_random(0),
    "rough_random1": lambda: _rough_random(1),
}


@pytest.mark.parametrize("name", sorted(REFLECT_SCENES))
def test_reflections_and_hard_shadow_rays_leave_their_own_instance_out(name, monkeypatch):
    """Mirror and glossy reflections of points on a convex instance (their closest-hit
    query, ``own_reflections``) and the hard lights' shadow rays from them leave that
    instance out where the scene has rough surfaces or lights with an extent: the same
    image, pixel classes and rays with and without, and rays are offered the skip (all of
    studio's: its only reflections are its mirror ball's). A scene with neither
    (three_spheres) computes no own instances: nothing offered, as before."""
    st = RenderSettings(mode="BASE", max_depth=3, samples=2, light_samples=4,
                        glossy_samples=4, seed=5)
    on, off = _on_and_off(REFLECT_SCENES[name](), st, monkeypatch)
    for k in ("primary_rays", "secondary_rays", "shadow_rays"):
        assert on.stats[k] == off.stats[k]
    assert off.stats["secondary_rays_own_skip"] == 0
    if name == "three_spheres":
        assert on.stats["secondary_rays_own_skip"] == 0
    else:
        assert 0 < on.stats["secondary_rays_own_skip"] <= on.stats["secondary_rays"]


@pytest.mark.parametrize("name", ["rough_materials", "rough_random0", "rough_random1",
                                  "studio"])
def test_no_skipped_reflection_meets_its_own_instance(name, monkeypatch):
    """The proof ray by ray, at every level: no reflected ray offered the skip meets its
    own instance traced alone, and the scene's closest hits (instance, triangle, distance,
    barycentrics) are the same with and without the skip; mirror and glossy reflections
    off convex meshes are offered it, refractions never."""
    scene = REFLECT_SCENES[name]()
    sa = scene.arrays()
    accel = create_accelerator("BVH", sa)
    seen = []

    def keep(mine, slots, which, o, d, surf, counters=None):
        out = own(mine, slots, which, o, d, surf, counters)
        seen.append((slots.copy(), o.copy(), d.copy(), out))
        return out

    own = whitted.own_reflections
    monkeypatch.setattr(whitted, "own_reflections", keep)
    whitted.render(scene, RenderSettings(mode="BASE", max_depth=3, light_samples=4,
                                         glossy_samples=4, seed=2), accel=accel)
    offered = 0
    for slots, o, d, skip in seen:
        mine = np.flatnonzero(skip >= 0)
        offered += len(mine)
        assert not (slots[mine] & 1).any()
        n = len(o)
        zero, inf = np.zeros(n), np.full(n, np.inf)
        alone = accel.intersect_object(skip[mine], o[mine], d[mine], zero[mine], inf[mine])
        assert (alone.inst < 0).all()
        a, b = accel.closest_hit(o, d, zero, inf, skip), accel.closest_hit(o, d, zero, inf)
        for f in ("inst", "prim", "t", "u", "v"):
            assert np.array_equal(getattr(a, f), getattr(b, f))
    assert offered > 0


def test_closest_hit_leaves_the_skipped_instance_out():
    """``closest_hit``'s ``skip`` as ``any_hit``'s: a ray through two balls hits the far
    one when the near one is skipped, misses when its only ball is skipped."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.5, 0.5, 0.5)))
    ball = s.add_mesh(shapes.icosphere(2, 0.5, name="ball"))
    a = s.add_instance(ball, shapes.transform((0.0, 0.0, 0.0)), [grey], name="A")
    b = s.add_instance(ball, shapes.transform((0.0, 3.0, 0.0)), [grey], name="B")
    o = np.array([[0.0, -5.0, 0.0]] * 3 + [[5.0, 0.0, 0.0]] * 2)
    d = np.array([[0.0, 1.0, 0.0]] * 3 + [[-1.0, 0.0, 0.0]] * 2)
    skip = np.array([-1, a, b, -1, a], np.int32)
    bvh = create_accelerator("BVH", s.arrays())
    h = bvh.closest_hit(o, d, np.zeros(5), np.full(5, np.inf), skip)
    assert h.inst.tolist() == [a, b, a, a, -1]


def test_own_instances_looks_at_the_points_own_clear_would():
    """``own_instances`` hands ``own_clear`` only the hits on meshes of ``OWN_MIN_TRIS``
    triangles or more away from rough interfaces (session 42: a few passes over the level
    instead of own_clear's filter over every hit): the answer is own_clear's over every
    hit, point for point (misses, the floor's few triangles and the rough glass included)."""
    sa, accel, _, _, hits, surf = primary_surfaces(_rough_balls(64, 48))
    mine = shaft_skip.own_instances(sa, accel, surf, hits.inst, hits.prim)
    inst = np.asarray(hits.inst, np.int64)
    pts = np.flatnonzero(inst >= 0)
    pts = pts[~interface_materials(sa)[surf.mat[pts]]]
    out = np.zeros(len(inst), np.bool_)
    shaft_skip.own_clear(accel.sa, np.ascontiguousarray(accel.sa.inst_xform), surf.Q,
                         surf.NG, inst, np.asarray(hits.prim, np.int64), pts, out)
    assert mine.dtype == np.int32
    assert np.array_equal(mine, np.where(out, inst, -1))
    assert (mine >= 0).any() and (mine < 0).any()
    assert (inst < 0).any() and (inst[mine < 0] >= 0).any()


def test_own_instances_keeps_its_per_packing_data_across_levels(monkeypatch):
    """``own_clear``'s per-instance stretches (a singular value decomposition) and its
    per-mesh flags are computed once per packing, not at every depth level (session 42,
    wave2): a second level over the same geometry decomposes nothing; a packing that
    moved an instance (new matrices) computes them again, and the answer is the one
    fresh caches give."""
    calls = []
    svd = np.linalg.svd
    monkeypatch.setattr(np.linalg, "svd", lambda *a, **k: calls.append(1) or svd(*a, **k))
    scene = _rough_balls(48, 36)
    sa, accel, _, _, hits, surf = primary_surfaces(scene)
    first = shaft_skip.own_instances(sa, accel, surf, hits.inst, hits.prim)
    n = len(calls)
    again = shaft_skip.own_instances(sa, accel, surf, hits.inst, hits.prim)
    assert np.array_equal(first, again)
    assert len(calls) == n  # nothing decomposed again
    # the edit: the opaque ball moved and stretched (new arrays, as every edit gives)
    k = scene.instance_slot("Opaque")
    scene.set_instance_matrix(k, shapes.transform((-1.0, 0.9, 0.6), (0.3, -1.0, 0.2), 35.0,
                                                  5.0))
    sa2, accel2, _, _, hits2, surf2 = primary_surfaces(scene)
    assert accel2.sa.inst_xform is not accel.sa.inst_xform
    moved = shaft_skip.own_instances(sa2, accel2, surf2, hits2.inst, hits2.prim)
    assert len(calls) > n
    monkeypatch.setattr(shaft_skip, "_OWN_BOUNDS", shaft_skip._OwnBounds())
    monkeypatch.setattr(shaft_skip, "_OWN_MESHES", shaft_skip.Memo(
        ("mesh_tri_start", "inst_mesh"), shaft_skip._own_meshes))
    assert np.array_equal(moved, shaft_skip.own_instances(sa2, accel2, surf2, hits2.inst,
                                                          hits2.prim))


def test_material_flags_follow_an_edit_of_the_materials():
    """``has_glossy`` and the glossy counts read per-materials flags kept per set of
    material arrays (:class:`~rstrace_engine.tracing.memo.Memo`): materials edited (new
    arrays) are read anew."""
    from rstrace_engine.tracing import glossy_rays

    sa = _rough_balls(16, 12).arrays()
    assert glossy_rays.has_glossy(sa)
    flat = sa._replace(mat_roughness=np.zeros_like(sa.mat_roughness))
    assert not glossy_rays.has_glossy(flat)
    nm = len(sa.mat_model)
    counts, glossy = glossy_rays.glossy_counts(flat, np.arange(nm), np.ones(nm, np.bool_), 4,
                                               np.zeros(nm))
    assert not glossy.any() and (counts == 1).all()
    assert glossy_rays.has_glossy(sa)
    assert glossy_rays.MATERIAL_FLAGS.get(sa)[0][:-1].tolist() == (
        glossy_rays.glossy_materials(sa).tolist())


@pytest.mark.parametrize("which", ["CONVEX", "BALLS"])
def test_per_mesh_slots_never_hand_one_packing_another_packings_value(monkeypatch, which):
    """``object_rays.CONVEX`` / ``BALLS`` (read by ``own_clear``'s per-packing bounds,
    session 42 wave2) keep one packing's per-mesh values: a call for another packing made
    while one computes (what a second thread does between two bytecodes) must not leave
    that packing's dict holding the first packing's value. (Its references and its dict
    were two attributes set one after the other: the first call's value landed in the
    second packing's dict, which then answered with it.)"""
    from collections import namedtuple

    from rstrace_engine.tracing import object_rays

    P = namedtuple("P", "verts tris mesh_tri_start")

    def packing(scale):
        mesh = shapes.icosphere(1)
        v = np.asarray(mesh.vertices, np.float64) * scale
        t = np.asarray(mesh.triangles, np.int32)
        return P(v, t, np.array([0, len(t)], np.int32))

    small, large = packing(1.0), packing(3.0)
    slot = type(getattr(object_rays, which))()  # (a fresh slot: nothing kept)
    monkeypatch.setattr(object_rays, which, slot)
    name = "convexity" if which == "CONVEX" else "solid_ball"
    fn = getattr(object_rays, name)
    inner = []

    def interleaved(verts, tris):
        if not inner:  # the other thread's call, between this one's look and its store
            inner.append(None)
            inner[0] = slot.get(large, 0)
        return fn(verts, tris)

    monkeypatch.setattr(object_rays, name, interleaved)
    got_small = slot.get(small, 0)
    monkeypatch.setattr(object_rays, name, fn)

    def flat(value):
        return np.concatenate([np.ravel(np.asarray(x, np.float64)) for x in value])

    assert np.array_equal(flat(got_small), flat(fn(small.verts, small.tris)))
    assert np.array_equal(flat(inner[0]), flat(fn(large.verts, large.tris)))
    # the large packing asked again: its own value, not the small one's
    assert np.array_equal(flat(slot.get(large, 0)), flat(fn(large.verts, large.tris)))
