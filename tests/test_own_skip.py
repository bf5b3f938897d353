"""Soft shadow rays that leave their point's own convex instance out of the traversal
(tracing/shaft_skip.own_instances): the BVH's query without that instance (``any_hit``'s
``skip``; the kernel's ``only <= -2``) answers as the whole one for every such ray, so
frames with and without the skip are the same bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from test_shaft_skip import SCENES, _random_scene, primary_surfaces

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Light, Material, Scene
from rstrace_engine.tracing import shaft_skip, whitted
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


@pytest.mark.parametrize("name", sorted(OWN_SCENES))
def test_frames_with_and_without_the_own_skip_are_identical(name, monkeypatch):
    """Convex objects (mirrored and stretched ones too), non-convex ones, rough glass
    (its samples below the surface are not offered the skip), mirrors below, every light
    with an extent and a world that lights: the same image and the same shadow rays; rays
    leave their own instance out wherever a convex mesh of 32 triangles or more is hit
    (the room seen from inside has none, the rough room only its glass ball)."""
    st = RenderSettings(mode="BASE", max_depth=2, samples=2, light_samples=8, seed=3)
    scene = OWN_SCENES[name]()
    monkeypatch.setattr(shaft_skip, "OWN_SKIP", True)
    on = whitted.render(scene, st)
    monkeypatch.setattr(shaft_skip, "OWN_SKIP", False)
    off = whitted.render(scene, st)
    assert np.array_equal(on.radiance, off.radiance)
    assert np.array_equal(on.pixel_class, off.pixel_class)
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
