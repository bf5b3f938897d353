"""Radiance interpolants: the error predicate, bounded-error frames, memory cap, camera moves.

Images are small (64 x 48); every comparison is against the base tracer's frame of the same
scene and camera, in display space.
"""

from __future__ import annotations

import numpy as np
import pytest
from tracer_scenes import ortho_down, transformed

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import (
    CLASS_BACKGROUND,
    CLASS_FAIL_SHADOW,
    CLASS_INTERPOLATED,
    CLASS_TRACED,
    RenderSettings,
)
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_rays
from rstrace_engine.geometry.edits import CameraChange
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.interpolants import interpolant_cache
from rstrace_engine.interpolants.interpolant_cache import INTERP_BYTES, InterpolantCache
from rstrace_engine.interpolants.line_samples import front_hits
from rstrace_engine.interpolants.linetree import (
    LATTICE_DEPTH,
    corner_weights,
    lattice_lines,
    line_points,
)
from rstrace_engine.interpolants.render import InterpolantRenderer, render_frame
from rstrace_engine.interpolants.shafts import clip_polygon, hw_shaft, segment_in
from rstrace_engine.session import Session
from rstrace_engine.tracing import whitted

W, H = 64, 48
#: Display-space slack for float arithmetic (float32 frames, float64 sums): see
#: tests/test_interpolant_bound.py.
FLOAT_TOL = 1e-6


@pytest.fixture(autouse=True)
def small_cells(monkeypatch):
    """At 64 x 48 a cell covers few pixels: build cells from 6 rays on (default 48). The
    measured fallback (tests/test_interpolant_fallback.py) is off: these tests count what
    the cells do, which timings would make vary."""
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)


def settings(**kw) -> RenderSettings:
    return RenderSettings(mode="INTERPOLANT", **kw)


def render_pair(scene, accel=None, **kw):
    """(interpolant frame, base frame, renderer) for ``scene``'s camera."""
    accel = accel or create_accelerator("BVH", scene.arrays())
    st = settings(**kw)
    r = InterpolantRenderer()
    frame = r.render(scene, st, accel)
    base = whitted.render(scene, st, accel=accel)
    return frame, base, r


def display_error(a, b) -> np.ndarray:
    return np.abs(image.to_display(a) - image.to_display(b)).max(axis=-1)


@pytest.fixture(scope="module")
def spheres():
    sc = scenes.three_spheres(W, H, subdivisions=2)
    return sc, create_accelerator("BVH", sc.arrays())


# ----------------------------------------------------------------------------- frames


def test_epsilon_zero_renders_exactly_the_base_image(spheres):
    sc, accel = spheres
    frame, base, _ = render_pair(sc, accel, epsilon=0.0)
    np.testing.assert_array_equal(frame.radiance, base.radiance)
    np.testing.assert_array_equal(frame.pixel_class, base.pixel_class)
    assert frame.stats["interpolated_fraction"] == 0.0
    # with samples > 1 the rays and their averaging match the base tracer's too
    frame, base, _ = render_pair(sc, accel, epsilon=0.0, samples=3, seed=5)
    np.testing.assert_array_equal(frame.radiance, base.radiance)


def test_small_epsilon_bounds_the_error(spheres):
    sc, accel = spheres
    frame, base, _ = render_pair(sc, accel, epsilon=0.02, depth_cap=8)
    err = display_error(frame.radiance, base.radiance)
    interp = frame.pixel_class == CLASS_INTERPOLATED
    assert interp.mean() > 0.05
    assert err.max() <= 0.02 + FLOAT_TOL  # the bound holds for every pixel
    assert np.all(err[~interp] == 0.0)  # traced pixels are the base tracer's
    assert np.all((frame.pixel_class == CLASS_BACKGROUND) == (base.pixel_class == CLASS_BACKGROUND))


def test_huge_epsilon_is_finite_and_bounded(spheres):
    sc, accel = spheres
    frame, base, _ = render_pair(sc, accel, epsilon=1.0)
    assert np.all(np.isfinite(frame.radiance))
    assert frame.stats["interpolated_fraction"] > 0.15
    m = image.compare(frame.radiance, base.radiance)
    assert m["max_error"] < 0.25 and m["mean_error"] < 0.01, m


# ----------------------------------------------------------------------------- shadows


def _sun_plane(occluders, size=20.0):
    """A Lambertian plane under a sun (constant radiance where lit, 0 in shadow), seen from
    straight above, with box occluders floating over it: (centre, edge length) pairs."""
    s = Scene()
    white = s.add_material(Material("white", diffuse=(0.6, 0.6, 0.6)))
    s.add_instance(s.add_mesh(shapes.plane(size, name="floor")), np.eye(4), [white], "Floor")
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"))
    for k, (c, e) in enumerate(occluders):
        s.add_instance(cube, shapes.transform(c, e), [white], f"Occluder{k}")
    s.add_light(Light("Sun", "SUN", power=3.0, direction=(0.3, 0.2, -1.0)))
    s.set_camera(ortho_down(height=30.0, scale=size * 0.9, width=W, rows=H))
    return s


@pytest.mark.parametrize("occluders", [
    [((0.0, 0.0, 3.0), 3.0)],  # a large shadow with long straight boundaries
    [((1.3, -0.7, 2.0), 0.6), ((-2.1, 1.9, 0.5), 0.5)],  # shadows smaller than a cell
], ids=["large", "tiny"])
def test_a_shadow_boundary_is_never_interpolated_across(occluders):
    sc = _sun_plane(occluders)
    # epsilon = 1 switches the radiance test off: only the ray trees and the shafts stand
    # between the interpolants and the shadows
    frame, base, r = render_pair(sc, epsilon=1.0, depth_cap=10)
    floor = frame.pixel_class != CLASS_BACKGROUND
    lit = base.radiance[..., 0] > 0.05
    dark = floor & ~lit
    assert dark.sum() > 0 and lit.sum() > 0
    interp = frame.pixel_class == CLASS_INTERPOLATED
    assert interp.mean() > 0.5
    # a lit plane under a sun is constant, so interpolation is exact unless it crosses a
    # shadow boundary
    np.testing.assert_allclose(frame.radiance[interp], base.radiance[interp], rtol=1e-9,
                               atol=1e-12)
    assert np.any(frame.pixel_class == CLASS_FAIL_SHADOW)
    why = r.cache.frame_stats["reasons"]
    assert why.get("light_change", 0) > 0
    if len(occluders) > 1:
        # cells whose 16 corners are all lit but that hold a shadow: only the shaft sees it
        assert why.get("light_shaft", 0) > 0


# ----------------------------------------------------------------------------- guarantees


def _random_lines_in_valid_cells(cache, per_cell=6, seed=0):
    """Random lines inside each valid interpolant's cell: (interp id, inst, face, o, d)."""
    rng = np.random.default_rng(seed)
    p = cache.pool
    ids = np.flatnonzero(p.live)
    a = cache.trees.arrays
    rows = []
    for q in ids:
        nd = p.node[q]
        inst, face = divmod(int(a.tree[nd]), 6)
        lo = a.coord[nd] / 2.0 ** a.depth[nd]
        span = 1.0 / 2.0 ** a.depth[nd]
        for u in rng.random((per_cell, 4)):
            F = np.empty(3)
            B = np.empty(3)
            line_points(cache.box, inst, face, *(lo + u * span), F, B)
            rows.append((q, inst, face, F, B - F))
    q, inst, face, o, d = (np.array(x) for x in zip(*rows, strict=True))
    return q, inst.astype(np.int32), face, o, d


@pytest.mark.parametrize("name", ["tori", "three_spheres"])
def test_valid_cells_keep_their_geometric_and_light_guarantees(name):
    """Every line of a valid cell crosses its object inside the certified slab, on the
    certified surface class, and no light that was unoccluded at the corners is occluded
    (docs/INTERPOLANTS.md, what is guaranteed) -- non-convex tori included."""
    sc = scenes.build(name, W, H)
    frame, base, r = render_pair(sc, epsilon=0.05, depth_cap=8)
    cache = r.cache
    assert cache.pool.n_live > 20
    q, inst, face, o, d = _random_lines_in_valid_cells(cache)
    p = cache.pool
    k = face // 2
    L = cache.box[inst, 1, k] - cache.box[inst, 0, k]
    t0, t1 = p.zlo[q] / L, p.zhi[q] / L
    hits = cache.accel.intersect_object(inst, o, d, t0, t1)
    assert np.all(hits.inst == inst)  # a crossing inside the slab ...
    cls = cache.topo.tri_class[hits.prim]
    assert np.all(cls == p.cls[q])  # ... on the certified class ...
    tri = cache.sa.tris[hits.prim]
    v = cache.sa.verts
    n_obj = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    n_world = np.einsum("nij,nj->ni", cache.sa.inst_nmat[inst], n_obj)
    assert np.all(np.einsum("ni,ni->n", n_world, d) < 0)  # ... facing the line ...
    again = cache.accel.intersect_object(inst, o, d, hits.t * (1 + 1e-9) + 1e-12, t1)
    assert np.all(again.inst < 0)  # ... and the only one there
    # lights: traced ray trees of the interior lines against the cell's corners
    _, tree = whitted.trace(cache.sa, cache.accel, o, d, 0.0, 1.0, 0, record=True,
                            primary=hits)
    corner_occ = cache.samples.view().node_occ[cache.samples.view().node_start[
        p.samples[q, 0]]]
    occ = tree.node_occluder[:len(q)]
    lit = corner_occ == -1
    assert np.all(np.isin(occ[lit], (-1, -2)))  # never shadowed where the corners were lit
    blocked = corner_occ >= 0
    assert np.all((occ[blocked] == corner_occ[blocked]) | (occ[blocked] < 0))


def test_lines_on_cell_boundaries(spheres):
    """Lines exactly on the lower boundaries of valid cells belong to those cells and get
    their quadrilinear value; at the lower corner, the corner sample itself."""
    sc, accel = spheres
    frame, base, r = render_pair(sc, accel, epsilon=0.05)
    cache = r.cache
    p = cache.pool
    a = cache.trees.arrays
    rows = []
    for q in np.flatnonzero(p.live):
        nd = p.node[q]
        sh = LATTICE_DEPTH - int(a.depth[nd])
        half = 1 << (sh - 1)
        for frac in ((0, 0, 0, 0), (0, 1, 0, 1), (1, 0, 1, 0), (0, 1, 1, 0)):
            lat = (a.coord[nd].astype(np.int64) << sh) + np.array(frac) * half
            rows.append((q, a.tree[nd] // 6, a.tree[nd] % 6, lat, np.array(frac) * 0.5))
    q, inst, face, lat, u = (np.array(x) for x in zip(*rows, strict=True))
    inst = inst.astype(np.int32)
    face = face.astype(np.int8)
    o = np.empty((len(q), 3))
    d = np.empty((len(q), 3))
    lattice_lines(cache.box, inst, face, lat, o, d)
    hits = front_hits(cache.sa, cache.accel, inst, o, d)
    _, _, zp, clsp = cache.pixel_lines(hits, o, d)
    # the exact lattice coordinates (a parameterised ray may round to either side)
    abcd = lat / 2.0 ** LATTICE_DEPTH
    res = cache.resolve(inst, face, abcd, zp, clsp)
    assert res.interpolated.all()
    want = np.einsum("nk,nkc->nc", corner_weights(u), p.rad[q])
    np.testing.assert_allclose(res.radiance, want, rtol=1e-12, atol=1e-15)
    corner = (u == 0).all(axis=1)
    np.testing.assert_array_equal(res.radiance[corner], p.rad[q[corner], 0])
    # and within epsilon of the traced radiance there
    rad, _ = whitted.trace(cache.sa, accel, o, d, 0.0, 1.0, 5, primary=hits)
    assert display_error(res.radiance, rad).max() <= 0.05 + FLOAT_TOL


# ----------------------------------------------------------------------------- robustness


def test_rays_on_face_pair_boundaries_render(spheres):
    """An orthographic view along (1, 1, -1): every ray ties |dx| = |dy| = |dz|."""
    sc = scenes.three_spheres(W, H, subdivisions=2)
    cam = Camera(matrix=shapes.look_at((-6.0, -6.0, 6.0), (0.0, 0.0, 0.0)), kind="ORTHO",
                 ortho_scale=9.0, width=W, height=H)
    sc.set_camera(cam)
    from rstrace_engine.geometry.cameras import camera_rays

    _, d, _, _ = camera_rays(sc.camera)
    assert np.all(np.abs(d[:, 0]) == np.abs(d[:, 1])) and np.all(
        np.abs(d[:, 1]) == np.abs(d[:, 2]))
    frame, base, _ = render_pair(sc, epsilon=0.02)
    assert frame.stats["interpolated_fraction"] > 0.1
    err = display_error(frame.radiance, base.radiance)
    assert np.all(np.isfinite(frame.radiance)) and err.max() <= 0.02 + FLOAT_TOL


def test_zero_thickness_object():
    s = Scene()
    m = s.add_material(Material("m", diffuse=(0.7, 0.5, 0.3), specular=(0.2,) * 3))
    s.add_instance(s.add_mesh(shapes.plane(6.0)), shapes.transform((0, 0, 0), 1.0, 15.0, 0.0),
                   [m])
    s.add_light(Light("Lamp", "POINT", power=400.0, position=(1.0, -1.0, 3.0)))
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -6.0, 4.0), (0.0, 0.0, 0.0)), width=W,
                        height=H))
    frame, base, _ = render_pair(s, epsilon=0.02, depth_cap=8)
    assert frame.stats["interpolated_fraction"] > 0.3
    err = display_error(frame.radiance, base.radiance)
    assert err.max() <= 0.02 + FLOAT_TOL


def _sun_spheres() -> Scene:
    """Spheres on a plane under two suns (sun power does not change with scale)."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.55, 0.55, 0.5), specular=(0.1,) * 3))
    red = s.add_material(Material("red", diffuse=(0.7, 0.12, 0.1), specular=(0.25,) * 3,
                                  roughness=0.15))
    ball = s.add_mesh(shapes.icosphere(2))
    s.add_instance(s.add_mesh(shapes.plane(12.0)), np.eye(4), [floor])
    s.add_instance(ball, shapes.transform((-1.6, 0.4, 1.0)), [red])
    s.add_instance(ball, shapes.transform((1.2, -0.5, 0.8), 0.8), [red])
    s.add_light(Light("Sun", "SUN", power=2.0, direction=(-0.4, 0.5, -1.0)))
    s.add_light(Light("Sun2", "SUN", power=0.8, direction=(0.6, 0.2, -1.0)))
    s.set_world_color((0.05, 0.06, 0.08), lights=False)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -8.5, 3.6), (0.0, 0.3, 0.8)), lens=35.0,
                        width=W, height=H))
    return s


@pytest.mark.parametrize("scale", [1e-4, 1e5])
def test_scenes_at_extreme_scales_behave_like_unit_scale(scale):
    sc = _sun_spheres()
    unit, _, _ = render_pair(sc, epsilon=0.02)
    big = transformed(sc, scale=scale, offset=(3.0 * scale, -1.0 * scale, 0.5 * scale))
    frame, base, _ = render_pair(big, epsilon=0.02)
    err = display_error(frame.radiance, base.radiance)
    assert np.all(np.isfinite(frame.radiance)) and err.max() <= 0.02 + FLOAT_TOL
    a = unit.stats["interpolated_fraction"]
    b = frame.stats["interpolated_fraction"]
    assert b > 0.1 and abs(a - b) < 0.03, (a, b)
    assert np.mean(frame.pixel_class != unit.pixel_class) < 0.03


# ----------------------------------------------------------------------------- memory


def test_memory_cap_of_one_interpolant(spheres):
    sc, accel = spheres
    free, base, r0 = render_pair(sc, accel, epsilon=0.02)
    one = INTERP_BYTES + 16 * r0.cache.samples.memory_bytes / max(r0.cache.samples.n, 1)
    st = settings(epsilon=0.02, memory_cap_mb=one / 1e6)
    r = InterpolantRenderer()
    for _ in range(2):  # the second frame rebuilds what the cap evicted
        frame = r.render(sc, st, accel)
        assert r.cache.pool.n_live <= 1
        assert r.cache.interpolant_bytes <= one + 1
        np.testing.assert_array_equal(frame.pixel_class == CLASS_BACKGROUND,
                                      base.pixel_class == CLASS_BACKGROUND)
        err = display_error(frame.radiance, base.radiance)
        assert frame.stats["interpolated_fraction"] > 0.5 * free.stats["interpolated_fraction"]
        assert err.max() <= 0.02 + FLOAT_TOL
        assert frame.stats["cells_built"] > 0


def test_lru_evicts_the_least_recently_used(spheres):
    sc, accel = spheres
    cache = InterpolantCache(sc.arrays(), accel, 0.02, 6, 1e3, 5)
    render_frame(cache, sc, settings(epsilon=0.02))
    cache.compact_samples()
    live = np.flatnonzero(cache.pool.live)
    assert len(live) > 10
    cache.pool.stamp[live[: len(live) // 2]] = 0  # pretend half were not used lately
    old = set(live[: len(live) // 2].tolist())
    target = cache.interpolant_bytes * 0.6
    cache.set_memory_cap(target / 1e6)
    assert cache.interpolant_bytes <= target
    kept = set(np.flatnonzero(cache.pool.live).tolist())
    recent = set(live.tolist()) - old
    assert kept and kept <= set(live.tolist()) and len(kept) < len(live)
    assert not (kept & old) or recent <= kept  # no recent one goes while a stale one stays


# ----------------------------------------------------------------------------- sessions


def test_a_moved_camera_session_equals_a_fresh_session():
    sc = scenes.three_spheres(W, H, subdivisions=2)
    st = settings(epsilon=0.02)
    sess = Session(sc, st)  # the session keeps its own copy of the scene
    sess.render()
    totals = sess.interpolants.cache.totals
    built_first = totals["cells_built"]
    cam = sc.camera
    m = cam.matrix.copy()
    m[:3, 3] += 0.15 * -m[:3, 2]  # a step forward
    c, s_ = np.cos(np.radians(2.5)), np.sin(np.radians(2.5))
    m[:3, :3] = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]) @ m[:3, :3]  # and a pan
    moved_cam = Camera(matrix=m, lens=cam.lens, width=W, height=H)
    sc.set_camera(moved_cam)
    sess.apply([CameraChange(moved_cam)])
    moved = sess.render()
    assert sess.interpolants.cache.totals is totals
    assert 0 < totals["cells_built"] - built_first < built_first  # interpolants were reused
    fresh = Session(sc, st).render()
    base = Session(sc, RenderSettings()).render()
    err = display_error(moved.radiance, fresh.radiance)
    assert err.max() <= 2 * 0.02 + FLOAT_TOL  # both within epsilon of the base frame:
    for f in (moved, fresh):
        assert display_error(f.radiance, base.radiance).max() <= 0.02 + FLOAT_TOL


def test_session_keeps_interpolants_across_a_new_export_of_the_same_scene():
    st = settings(epsilon=0.02)
    sess = Session(scenes.three_spheres(W, H, subdivisions=2), st)
    sess.render()
    cache = sess.interpolants.cache
    built = cache.totals["cells_built"]
    sess.update_scene(scenes.three_spheres(W, H, subdivisions=2))  # same content
    again = sess.render()
    assert sess.interpolants.cache is cache and cache.totals["cells_built"] == built
    sess.update_settings(settings(epsilon=0.05))
    sess.render()
    assert sess.interpolants.cache is not cache
    assert again.stats["mode"] == "INTERPOLANT"
    assert np.all(np.isin(again.pixel_class, (CLASS_BACKGROUND, CLASS_TRACED,
                                              CLASS_INTERPOLATED, 3, 4, 5)))


# ----------------------------------------------------------------------------- shafts


def test_shaft_contains_both_boxes_and_clips_exactly():
    rng = np.random.default_rng(11)
    for _ in range(50):
        a = np.sort(rng.normal(size=(2, 3)), axis=0)
        b = np.sort(rng.normal(size=(2, 3)) + rng.normal(size=3) * 3, axis=0)
        if rng.random() < 0.3:
            b[1] = b[0]  # a point light
        pl = np.empty((18, 4))
        bb = np.empty(6)
        n = hw_shaft(a[0], a[1], b[0], b[1], 0.0, pl, bb)
        # every point of the segment between a point of A and a point of B is inside
        pa = a[0] + rng.random((200, 3)) * (a[1] - a[0])
        pb = b[0] + rng.random((200, 3)) * (b[1] - b[0])
        pts = pa + rng.random((200, 1)) * (pb - pa)
        inside = (pts @ pl[:n, :3].T + pl[:n, 3]) >= -1e-12
        assert inside.all()
        # a triangle clipped by the shaft keeps exactly its part inside (sampled check)
        tri = rng.normal(size=(3, 3)) * 2 + (a.mean(axis=0) + b.mean(axis=0)) / 2
        P = np.zeros((30, 3))
        Q = np.zeros((30, 3))
        P[:3] = tri
        m = clip_polygon(pl, 0, n, P, 3, Q)
        w = rng.dirichlet((1, 1, 1), 3000)
        sp = w @ tri
        ins = ((sp @ pl[:n, :3].T + pl[:n, 3]) >= 0).all(axis=1)
        assert (m > 0) == bool(ins.any()) or (m > 0 and not ins.any())
        e0, e1 = tri[0], tri[1]
        ts = np.linspace(0, 1, 2001)[:, None]
        seg_in = (((e0 + ts * (e1 - e0)) @ pl[:n, :3].T + pl[:n, 3]) >= 0).all(axis=1).any()
        if seg_in:
            assert segment_in(pl, n, *e0, *e1)


def test_saturated_samples_cannot_vouch_for_a_dip_below_one():
    from rstrace_engine.interpolants.predicate import extended_display

    x = np.array([0.0, 0.002, 0.5, 0.999, 1.0])
    np.testing.assert_array_equal(extended_display(x), image.to_display(x))
    # clamped, 2.5 and 0.85 look alike near the top; extended, they are far apart
    a, b = np.array([2.5]), np.array([0.85])
    assert abs(image.to_display(a) - image.to_display(b))[0] < 0.08
    assert abs(extended_display(a) - extended_display(b))[0] > 0.6
    assert np.all(np.diff(extended_display(np.linspace(0, 5, 200))) > 0)


def test_the_walk_does_not_depend_on_ray_order(spheres):
    """Rays reuse the leaf of the ray before them: any order gives the same pixels."""
    sc, accel = spheres
    cache = InterpolantCache(sc.arrays(), accel, 0.02, 10, 64.0, 5)
    render_frame(cache, sc, settings(epsilon=0.02))  # builds what this camera needs
    o, d, tmin, tmax = camera_rays(sc.camera)
    hits = accel.closest_hit(o, d, tmin, tmax)
    face, abcd, zp, clsp = cache.pixel_lines(hits, o, d)
    a = cache.resolve(hits.inst, face, abcd, zp, clsp)
    assert np.any(a.interpolated)
    perm = np.random.default_rng(3).permutation(len(o))
    b = cache.resolve(hits.inst[perm], face[perm], abcd[perm], zp[perm], clsp[perm])
    inv = np.argsort(perm)
    assert np.array_equal(a.interpolated, b.interpolated[inv])
    assert np.array_equal(a.pixel_class, b.pixel_class[inv])
    assert np.array_equal(a.radiance[a.interpolated], b.radiance[inv][a.interpolated])
