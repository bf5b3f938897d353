"""Base-mode shadow-ray skips (tracing/shaft_skip.py): every sample the proof skips is one
the tracer finds unoccluded, so frames with and without the skips are the same bit for
bit, and some samples are skipped."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.bench.soak import SOAK_SCENES
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_params, camera_rays
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.tracing import shaft_skip, whitted
from rstrace_engine.tracing.soft_lights import sample_seeds, soft_rays


def _down_light(name, kind, pos, rng, **kw):
    """A light at ``pos`` pointing roughly down (tilted at random)."""
    d = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), -1.0])
    d /= np.linalg.norm(d)
    a = np.cross(d, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    return Light(name, kind, position=tuple(pos), direction=tuple(d), axis=tuple(a), **kw)


def _random_scene(seed, w=48, h=36):
    """Objects of every kind (convex, non-convex, open, mirrored, tilted, touching the
    floor, a thin slab just above it) on a subdivided floor under random lights of every
    kind with an extent, and a world that lights."""
    rng = np.random.default_rng(seed)
    s = Scene()
    mats = [s.add_material(Material(f"m{k}", diffuse=tuple(rng.uniform(0.2, 0.8, 3))))
            for k in range(3)]
    mirror = s.add_material(Material("mirror", diffuse=(0.05,) * 3, mirror=(0.8,) * 3))
    s.add_instance(s.add_mesh(shapes.plane(12.0, divisions=3, name="floor")), np.eye(4),
                   [mats[0]], name="Floor")
    meshes = [shapes.box((0.6, 0.6, 0.6), name="box"), shapes.icosphere(2, 0.5, name="ico"),
              shapes.torus(0.5, 0.18, 24, 12, name="torus"),
              shapes.uv_sphere(16, 8, 0.4, name="uv"),
              shapes.revolve([0.0, 0.3, 0.4, 0.2, 0.0], [0.0, 0.05, 0.5, 0.9, 0.9], 16,
                             name="vase", closed=False)]
    ids = [s.add_mesh(m) for m in meshes]
    for k in range(7):
        m = ids[k % len(ids)]
        scale = rng.uniform(0.6, 1.4, 3) * (-1.0 if k == 3 else 1.0)  # one mirrored
        xf = shapes.transform((rng.uniform(-3, 3), rng.uniform(-2, 3), rng.uniform(0.3, 1.2)),
                              scale, rng.uniform(0, 360), rng.uniform(0, 60))
        mat = mirror if k == 5 else mats[k % 3]
        s.add_instance(m, xf, [mat], name=f"Obj{k}")
    # a box standing on the floor and a thin slab 1 mm above it
    s.add_instance(ids[0], shapes.transform((1.5, -1.5, 0.3)), [mats[1]], name="Standing")
    slab = s.add_mesh(shapes.box((1.0, 1.0, 1e-4), name="slab"))
    s.add_instance(slab, shapes.transform((-1.5, -1.5, 1e-3)), [mats[2]], name="Slab")
    s.add_light(_down_light("Area", "AREA", (rng.uniform(-1, 1), 0.0, 4.0), rng,
                            power=500.0, shape="RECTANGLE", size=(1.5, 0.8)))
    s.add_light(_down_light("Disk", "AREA", (2.0, 2.0, 3.0), rng, power=200.0,
                            shape="ELLIPSE", size=(0.8, 0.5), spread=math.radians(120)))
    s.add_light(Light("Bulb", "POINT", power=150.0, position=(-2.5, 1.0, 2.0), radius=0.3))
    s.add_light(Light("Hard", "POINT", power=50.0, position=(0.0, -2.0, 3.0),
                      radius=0.25, soft_falloff=False))
    s.add_light(Light("Spot", "SPOT", power=300.0, position=(0.5, -3.0, 3.0),
                      direction=(0.0, 0.6, -1.0), spot_size=math.radians(50), radius=0.1))
    s.add_light(Light("Sun", "SUN", power=2.0, direction=(0.3, 0.2, -1.0),
                      angle=math.radians(rng.uniform(1.0, 20.0))))
    s.set_world_color((0.04, 0.05, 0.06), lights=True)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -8.0, 5.0), (0.0, 0.5, 0.4)), lens=30.0,
                        width=w, height=h))
    return s


def _inside_scene(w=40, h=30):
    """A closed room seen from inside: a sun through a hole in its ceiling (a roof of two
    boxes with a gap), a sphere light whose ball crosses the floor, a point inside a
    sphere light."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6)))
    s.add_instance(s.add_mesh(shapes.box((8.0, 8.0, 4.0), name="room", inward=True)),
                   shapes.transform((0.0, 0.0, 2.0)), [grey], name="Room")
    roof = s.add_mesh(shapes.box((3.0, 8.0, 0.2), name="roof"))
    s.add_instance(roof, shapes.transform((-2.5, 0.0, 3.5)), [grey], name="RoofA")
    s.add_instance(roof, shapes.transform((2.5, 0.0, 3.5)), [grey], name="RoofB")
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(0.1, 0.05, -1.0),
                      angle=math.radians(4.0)))
    s.add_light(Light("Low", "POINT", power=40.0, position=(2.5, 2.5, 0.1), radius=0.3,
                      soft_falloff=False))
    s.add_light(Light("Big", "POINT", power=40.0, position=(-3.0, -3.0, 1.0), radius=1.2,
                      soft_falloff=False))
    s.add_light(Light("Panel", "AREA", power=80.0, position=(0.0, 3.9, 2.0),
                      direction=(0.0, -1.0, 0.0), axis=(1.0, 0.0, 0.0), shape="SQUARE",
                      size=1.0))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -3.8, 2.0), (0.0, 1.0, 1.2)), lens=14.0,
                        width=w, height=h))
    return s


def _render_both(scene, st, monkeypatch):
    monkeypatch.setattr(shaft_skip, "SHAFT_SKIP", True)
    on = whitted.render(scene, st)
    monkeypatch.setattr(shaft_skip, "SHAFT_SKIP", False)
    off = whitted.render(scene, st)
    return on, off


SCENES = {
    "random0": lambda: _random_scene(0),
    "random1": lambda: _random_scene(1),
    "inside": _inside_scene,
    "studio": lambda: scenes.studio(48, 36),
    "museum_soft": lambda: scenes.museum_soft(48, 36),
    "soft_room": lambda: SOAK_SCENES["soft_room"](40, 30),
}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_frames_with_and_without_skips_are_identical(name, monkeypatch):
    """Area (rectangle, ellipse with spread), sphere (soft falloff on and off, a point
    inside one), spot with a radius, sun with an angle, a world that lights, occluders
    partly in the shafts, mirrors below: the same image bit for bit; the skipped samples
    are exactly the shadow rays the frame without skips traced more."""
    st = RenderSettings(mode="BASE", max_depth=2, samples=2, light_samples=8, seed=3)
    on, off = _render_both(SCENES[name](), st, monkeypatch)
    assert np.array_equal(on.radiance, off.radiance)
    assert np.array_equal(on.pixel_class, off.pixel_class)
    skipped = on.stats["shadow_rays_skipped"]
    assert skipped > 0
    assert off.stats["shadow_rays_skipped"] == 0
    assert on.stats["shadow_rays"] + skipped == off.stats["shadow_rays"]
    assert 0 < on.stats["skip_rows_proven"] < on.stats["skip_rows"]


def primary_surfaces(scene, accelerator="BVH"):
    """``(arrays, accelerator, camera params, pixels, hits, surfaces)`` of one jittered
    camera ray per pixel (seed 0)."""
    sa = scene.arrays()
    accel = create_accelerator(accelerator, sa)
    cp = camera_params(scene.camera)
    pixels = np.arange(cp.width * cp.height, dtype=np.int64)
    rng = np.random.default_rng(0)
    o, d, tmin, tmax = camera_rays(cp, pixels, rng.uniform(0.0, 1.0, (len(pixels), 2)))
    hits = accel.closest_hit(o, d, tmin, tmax)
    return sa, accel, cp, pixels, hits, whitted.surfaces(sa, o, d, tmax, hits)


def _proofs(scene, light_samples=8, accelerator="BVH"):
    """``(proven samples, occluded among them, sampled samples)`` of the primary hits'
    lights with an extent, every sample traced."""
    sa, accel, cp, pixels, hits, surf = primary_surfaces(scene, accelerator)
    proven = shaft_skip.proven_rows(sa, accel, surf, hits.inst,
                                    shaft_skip.tile_keys(pixels, cp.width), prim=hits.prim)
    soft, so, st, rows = soft_rays(sa, surf, sample_seeds(pixels, 1), light_samples,
                                   surf.sh_state)
    r = np.repeat(rows, light_samples)
    live = soft.w > 0.0
    lit = r >= 0
    if proven is None:
        return 0, 0, int((live & lit).sum())
    mask = live & lit & proven[np.maximum(r, 0)]
    occ = accel.any_hit(so[mask], soft.d[mask], np.zeros(int(mask.sum())), st[mask])
    return int(mask.sum()), int(np.count_nonzero(occ)), int((live & lit).sum())


@pytest.mark.parametrize("seed", range(4))
def test_every_proven_sample_is_unoccluded(seed):
    """The proof itself, sample by sample (a black surface would hide a wrong proof from
    the image): every sample of a proven (point, light) row is unoccluded when traced,
    over random scenes; and a good share is proven."""
    proven, occluded, sampled = _proofs(_random_scene(10 + seed, 64, 48))
    assert occluded == 0
    assert proven > 0.2 * sampled


def test_inside_a_room_every_proven_sample_is_unoccluded():
    proven, occluded, sampled = _proofs(_inside_scene(64, 48))
    assert occluded == 0 and proven > 0.2 * sampled


def test_other_accelerators_trace_every_sample():
    """The proof reads the numba BVH's own trees; other accelerators trace everything."""
    assert _proofs(_inside_scene(), accelerator="BRUTE_FORCE")[0] == 0
    st = RenderSettings(mode="BASE", max_depth=0, light_samples=4,
                        accelerator="BRUTE_FORCE")
    assert whitted.render(_inside_scene(16, 12), st).stats["shadow_rays_skipped"] == 0


def test_the_world_alone_is_traced(monkeypatch):
    """The world's light has no extent to prove: nothing is skipped."""
    s = SOAK_SCENES["soft_room"](24, 18)
    for k, _ in list(s.live_lights()):
        s.delete_light(k)
    st = RenderSettings(mode="BASE", max_depth=1, light_samples=4)
    on, off = _render_both(s, st, monkeypatch)
    assert on.stats["shadow_rays_skipped"] == 0 and on.stats["skip_rows"] == 0
    assert np.array_equal(on.radiance, off.radiance)


def test_incremental_frames_skip_and_equal_fresh_ones():
    """An edit's incremental frame proves its dirty pixels' tiles again and equals a fresh
    frame bit for bit (the proofs are the frame's own: nothing is kept between frames)."""
    from rstrace_engine.geometry.edits import ObjectTransform
    from rstrace_engine.session import Session

    sc = _random_scene(2, 40, 30)
    st = RenderSettings(mode="BASE", max_depth=1, light_samples=4, seed=2)
    sess = Session(sc.copy(), st)
    sess.render()
    for k, pos in enumerate([(0.5, 0.5, 0.8), (-0.5, 1.0, 0.6)]):
        sess.apply([ObjectTransform(f"Obj{k}", shapes.transform(pos, 0.8))])
        frame = sess.render()
        fresh = Session(sess.scene.copy(), st).render()
        assert np.array_equal(frame.radiance, fresh.radiance)
        assert frame.stats["shadow_rays_skipped"] > 0
