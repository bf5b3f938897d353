"""The soft samples' shadow rays traced where they were drawn (accel/bvh_occlusion.py):
the BVH's any-hit answer bit for bit, per sample, with a row's instance left out, proven
rows and samples without weight; and a frame traced so equals the frame traced through the
gathered any-hit query, image and counters."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import whitted


def _rays(sa, n_rows, n, rng):
    """Rays from points inside the scene's box in random directions, ``n`` a row, some
    bounded short of the scene, some without weight, some rows leaving an instance out."""
    lo, hi = np.asarray(sa.scene_aabb, np.float64)
    k = n_rows * n
    o = lo + (hi - lo) * rng.random((k, 3))
    d = rng.normal(size=(k, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tmax = np.where(rng.random(k) < 0.3, rng.random(k) * 2.0, np.inf)
    w = np.where(rng.random(k) < 0.1, 0.0, 1.0)
    n_inst = len(sa.inst_mesh)
    skip = np.where(rng.random(n_rows) < 0.4, rng.integers(0, n_inst, n_rows), -1)
    proven = rng.random(n_rows) < 0.1
    return o, d, tmax, w, skip.astype(np.int32), proven


@pytest.mark.parametrize("threads", [1, 2])
def test_occluded_samples_is_any_hit(threads):
    s = scenes.studio(32, 24)
    sa = s.arrays()
    acc = create_accelerator("BVH", sa)
    rng = np.random.default_rng(5)
    n = 16
    o, d, tmax, w, skip, proven = _rays(sa, 700, n, rng)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        vis, counts = acc.occluded_samples(o, d, tmax, w, n, skip, proven)
    finally:
        numba.set_num_threads(old)
    row = np.arange(len(o)) // n
    go = (w > 0) & ~proven[row]
    blocked = acc.any_hit(o[go], d[go], np.zeros(go.sum()), tmax[go], skip[row[go]])
    want = np.zeros(len(o), np.bool_)
    want[go] = ~blocked
    want[(w > 0) & proven[row]] = True
    assert 0.1 < blocked.mean() < 0.9  # both outcomes exercised
    np.testing.assert_array_equal(vis, want)
    assert counts[0] == go.sum()
    assert counts[1] == ((w > 0) & proven[row]).sum()
    assert counts[2] == (go & (skip[row] >= 0)).sum()


def test_occluded_samples_refuses_a_non_finite_ray():
    sa = scenes.studio(32, 24).arrays()
    acc = create_accelerator("BVH", sa)
    o = np.zeros((4, 3))
    d = np.tile([0.0, 0.0, 1.0], (4, 1))
    d[2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or infinite"):
        acc.occluded_samples(o, d, np.full(4, np.inf), np.ones(4), 2,
                             np.full(2, -1, np.int32), np.zeros(2, np.bool_))


@pytest.mark.parametrize("name", ["studio", "museum_soft"])
def test_frame_traced_in_place_equals_the_gathered_query(name, monkeypatch):
    """The base frame (world, area, sphere, spot and sun samples; proven rows and own
    instances left out) with the samples traced in place equals, bit for bit, the frame
    whose samples go through the accelerator's any-hit query."""
    s = getattr(scenes, name)(48, 36)
    st = RenderSettings(max_depth=3)
    fast = whitted.render(s, st, accel=create_accelerator("BVH", s.arrays()))
    plain = whitted._occluded_by

    def gathered(sa, accel):
        f = plain(sa, accel)
        assert hasattr(f, "samples")  # the fast path was taken above
        del f.samples
        return f

    monkeypatch.setattr(whitted, "_occluded_by", gathered)
    slow = whitted.render(s, st, accel=create_accelerator("BVH", s.arrays()))
    assert np.array_equal(fast.radiance, slow.radiance)
    for key in ("shadow_rays", "shadow_rays_skipped", "shadow_rays_own_skip", "rays_traced"):
        assert fast.stats[key] == slow.stats[key], key
    assert fast.stats["shadow_rays_own_skip"] > 0


@pytest.mark.parametrize("name", ["studio", "museum_soft"])
def test_a_ray_ending_at_its_hit_is_answered_as_any_hit(name):
    """Rays whose far end lies on (or a few ulps past) the surface they meet: a box is
    entered within :func:`.bvh._cull` of ``tmax`` there, as any_hit (and occludes_object,
    the shadow re-shade's per-object test) enters it; a box test against ``tmax`` itself
    lost hits at ``t == tmax`` (1-2% of these rays answered visible)."""
    sa = getattr(scenes, name)(32, 24).arrays()
    acc = create_accelerator("BVH", sa)
    rng = np.random.default_rng(1)
    lo, hi = np.asarray(sa.scene_aabb, np.float64)
    k = 20000
    o = lo + (hi - lo) * rng.random((k, 3))
    d = rng.normal(size=(k, 3))
    ax = rng.random(k) < 0.3  # axis-aligned directions: faces lying on box planes
    d[ax] = np.eye(3)[rng.integers(0, 3, ax.sum())] * rng.choice([-1.0, 1.0], (ax.sum(), 1))
    d /= np.linalg.norm(d, axis=1)[:, None]
    h = acc.closest_hit(o, d, np.zeros(k), np.full(k, np.inf))
    o, d, t = o[h.inst >= 0], d[h.inst >= 0], h.t[h.inst >= 0]
    m = len(o)
    for ulps in (0, 2, 8):
        tmax = t.copy()
        for _ in range(ulps):
            tmax = np.nextafter(tmax, np.inf)
        blocked = acc.any_hit(o, d, np.zeros(m), tmax)
        vis, _ = acc.occluded_samples(o, d, tmax, np.ones(m), 1, np.full(m, -1, np.int32),
                                      np.zeros(m, np.bool_))
        assert blocked.mean() > 0.9
        np.testing.assert_array_equal(vis, ~blocked)


def _instanced_scene():
    """Shared meshes under non-uniform, mirrored and rotated transforms, small meshes (a
    box: fewer than ``shaft_skip.OWN_MIN_TRIS`` triangles) and a large one."""
    from rstrace_engine.geometry import shapes
    from rstrace_engine.geometry.scene import Material, Scene

    s = Scene()
    a = s.add_material(Material("a"))
    s.add_instance(s.add_mesh(shapes.plane(10.0, name="ground")), np.eye(4), [a])
    sph = s.add_mesh(shapes.icosphere(3, name="sphere"))
    box = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="box"))
    tor = s.add_mesh(shapes.torus(0.6, 0.2, 48, 24, name="torus"))
    s.add_instance(sph, shapes.transform((-1.5, 0.0, 0.6), (1.6, 0.5, 0.9), 30, 20), [a])
    s.add_instance(sph, shapes.transform((1.2, 0.5, 0.5), (-0.7, 0.7, 0.7), 15), [a])
    s.add_instance(tor, shapes.transform((0.0, 1.5, 0.4), (1.0, -1.3, 0.6), 40, 70), [a])
    s.add_instance(box, shapes.transform((0.3, -1.0, 0.3), (0.6, 1.4, 0.6), 25), [a])
    s.add_instance(box, shapes.transform((-0.2, 2.8, 1.0), (3.0, 0.2, 2.0)), [a])
    return s


def _hard_rays(sa, acc, k, rng):
    """``k`` rays: origins on the surfaces they left, axis-aligned directions and
    directions with a zero component, far ends on (or an ulp or two past) a surface or
    infinite."""
    lo, hi = np.asarray(sa.scene_aabb, np.float64)
    o = lo + (hi - lo) * rng.random((k, 3))
    d = rng.normal(size=(k, 3))
    ax = rng.random(k) < 0.3
    d[ax] = np.eye(3)[rng.integers(0, 3, ax.sum())] * rng.choice([-1.0, 1.0], (ax.sum(), 1))
    z = (rng.random(k) < 0.1) & ~ax
    d[z, rng.integers(0, 3, z.sum())] = 0.0
    d /= np.linalg.norm(d, axis=1)[:, None]
    h = acc.closest_hit(o, d, np.zeros(k), np.full(k, np.inf))
    on = (h.inst >= 0) & (rng.random(k) < 0.5)  # start on the surface met, leave anywhere
    o[on] += d[on] * h.t[on, None]
    d2 = rng.normal(size=(k, 3))
    d[on] = d2[on] / np.linalg.norm(d2[on], axis=1)[:, None]
    h = acc.closest_hit(o, d, np.zeros(k), np.full(k, np.inf))
    tmax = np.where(rng.random(k) < 0.5, np.inf, np.where(h.inst >= 0, h.t, 1.0))
    up = rng.integers(0, 3, k)
    for i in range(2):
        tmax = np.where(up > i, np.nextafter(tmax, np.inf), tmax)
    return o, d, tmax


def test_hard_rays_through_mirrored_and_squashed_instances():
    """Origins on the surfaces they left, axis-aligned directions and directions with a
    zero component, far ends on (or an ulp or two past) a surface, an instance left out per
    row: the any-hit answer, ray for ray."""
    sa = _instanced_scene().arrays()
    acc = create_accelerator("BVH", sa)
    rng = np.random.default_rng(7)
    k, n = 40000, 8
    o, d, tmax = _hard_rays(sa, acc, k, rng)
    skip = np.where(rng.random(k // n) < 0.5, rng.integers(0, len(sa.inst_mesh), k // n), -1)
    skip = skip.astype(np.int32)
    vis, counts = acc.occluded_samples(o, d, tmax, np.ones(k), n, skip,
                                       np.zeros(k // n, np.bool_))
    blocked = acc.any_hit(o, d, np.zeros(k), tmax, np.repeat(skip, n))
    assert 0.1 < blocked.mean() < 0.9 and counts[0] == k
    np.testing.assert_array_equal(vis, ~blocked)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name", ["instanced", "studio"])
def test_hard_shadow_query_is_any_hit(name, threads):
    """The hard lights' shadow query (:meth:`BVHAccelerator.occluded`, the occlusion
    kernel, one ray a row) answers as :meth:`any_hit` from ``tmin = 0``, ray for ray: through
    mirrored and squashed instances, far ends on a surface, an instance left out per ray
    or none."""
    sa = (_instanced_scene() if name == "instanced" else scenes.studio(32, 24)).arrays()
    acc = create_accelerator("BVH", sa)
    rng = np.random.default_rng(11)
    k = 30000
    o, d, tmax = _hard_rays(sa, acc, k, rng)
    skip = np.where(rng.random(k) < 0.5, rng.integers(0, len(sa.inst_mesh), k), -1)
    skip = skip.astype(np.int32)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        got = acc.occluded(o, d, tmax, skip)
        got_all = acc.occluded(o, d, tmax)
    finally:
        numba.set_num_threads(old)
    want = acc.any_hit(o, d, np.zeros(k), tmax, skip)
    want_all = acc.any_hit(o, d, np.zeros(k), tmax)
    assert 0.1 < want.mean() < 0.9 and (want != want_all).any()
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got_all, want_all)


def _plain_any_hit(accel, o, d, tmax, skip=None):
    extra = () if skip is None else (skip,)
    return np.asarray(accel.any_hit(o, d, np.zeros(len(o)), tmax, *extra), np.bool_)


def _count_occluded(monkeypatch) -> list:
    """The batch sizes of every :meth:`BVHAccelerator.occluded` call from now on."""
    from rstrace_engine.accel.accelerators import BVHAccelerator

    calls = []
    query = BVHAccelerator.occluded

    def counted(self, o, d, tmax, skip=None):
        calls.append(len(o))
        return query(self, o, d, tmax, skip)

    monkeypatch.setattr(BVHAccelerator, "occluded", counted)
    return calls


@pytest.mark.parametrize("name", ["rough_materials", "three_spheres"])
def test_hard_lit_frame_takes_the_occlusion_query(name, monkeypatch):
    """A hard-lit base frame (a point light at camera hits and at every level of the rough
    paths) traces its shadow rays through :meth:`BVHAccelerator.occluded`, every one of
    them, and equals bit for bit the frame whose shadow rays go through ``any_hit``."""

    s = scenes.build(name, 40, 30)
    st = RenderSettings(max_depth=5, samples=2, glossy_samples=4)
    calls = _count_occluded(monkeypatch)
    fast = whitted.render(s, st, accel=create_accelerator("BVH", s.arrays()))
    assert len(calls) > 1 and sum(calls) == fast.stats["shadow_rays"] > 0
    monkeypatch.setattr(whitted, "any_hit_shadows", _plain_any_hit)
    calls.clear()
    slow = whitted.render(s, st, accel=create_accelerator("BVH", s.arrays()))
    assert not calls
    assert np.array_equal(fast.radiance, slow.radiance)
    for key in ("shadow_rays", "rays_traced"):
        assert fast.stats[key] == slow.stats[key], key


def test_ri_tree_frame_takes_the_occlusion_query(monkeypatch):
    """The RI_TREE frame's shadow rays from traced points go through the occlusion query,
    and its image is the one through ``any_hit``."""
    from rstrace_engine.ri_tree import render as ri_render
    from rstrace_engine.session import Session

    s = scenes.build("three_spheres", 40, 30)
    calls = _count_occluded(monkeypatch)
    fast = Session(s, RenderSettings(mode="RI_TREE")).render()
    assert sum(calls) > 0
    monkeypatch.setattr(ri_render, "any_hit_shadows", _plain_any_hit)
    monkeypatch.setattr(whitted, "any_hit_shadows", _plain_any_hit)
    slow = Session(s, RenderSettings(mode="RI_TREE")).render()
    assert np.array_equal(fast.radiance, slow.radiance)


def test_hard_shadow_query_takes_any_hits_bounds():
    """``occluded`` takes ``tmax`` as :meth:`any_hit` does: a scalar, or a read-only
    array, answered as ``any_hit`` answers them, and a read-only ``tmax`` compiles no
    second signature of the occlusion kernel (``per_ray``'s copy, as ``check_rays``)."""
    from rstrace_engine.accel import bvh_occlusion

    sa = _instanced_scene().arrays()
    acc = create_accelerator("BVH", sa)
    rng = np.random.default_rng(3)
    o, d, tmax = _hard_rays(sa, acc, 2000, rng)
    acc.occluded(o, d, tmax)
    sigs = len(bvh_occlusion.occluded_kernel.signatures)
    frozen = tmax.copy()
    frozen.setflags(write=False)
    np.testing.assert_array_equal(acc.occluded(o, d, frozen),
                                  acc.any_hit(o, d, np.zeros(len(o)), frozen))
    assert len(bvh_occlusion.occluded_kernel.signatures) == sigs
    for t in (0.5, np.inf, 0.0):
        np.testing.assert_array_equal(acc.occluded(o, d, t),
                                      acc.any_hit(o, d, np.zeros(len(o)), t))


def test_hard_shadow_query_refuses_nan_bounds_as_any_hit():
    """A NaN ``tmax`` is refused by ``occluded`` with ``any_hit``'s message (the kernel
    alone would answer such a ray visible: a silently lit pixel)."""
    sa = _instanced_scene().arrays()
    acc = create_accelerator("BVH", sa)
    o, d, tmax = _hard_rays(sa, acc, 50, np.random.default_rng(5))
    tmax[7] = np.nan
    with pytest.raises(ValueError, match="NaN tmin or tmax") as want:
        acc.any_hit(o, d, np.zeros(len(o)), tmax)
    with pytest.raises(ValueError, match="NaN tmin or tmax") as got:
        acc.occluded(o, d, tmax)
    assert str(got.value) == str(want.value)
    with pytest.raises(ValueError, match="NaN tmin or tmax"):
        acc.occluded(o, d, np.nan)
