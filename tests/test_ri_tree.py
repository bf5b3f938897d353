"""The RI-tree (seed 004): interpolated attributes against traced and analytic ones, error
falling with the thresholds, patch classes, the cache cap, invalidation, frames and the
thickness view against the base tracer."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.attributes import slots_of
from rstrace_engine.geometry.edits import ObjectTransform, apply_edits
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene, SceneError
from rstrace_engine.ri_tree import tree_cache as ri_cache
from rstrace_engine.ri_tree.patches import ST_HIT
from rstrace_engine.ri_tree.render import RITreeRenderer, render_thickness_exact
from rstrace_engine.ri_tree.tree_cache import RITreeCache
from rstrace_engine.session import Session
from rstrace_engine.tracing.whitted import render


@pytest.fixture(autouse=True)
def _keep_trees(monkeypatch):
    """These tests follow the trees over frames: the measured fallback (which may decide, on
    this machine's timings, that a small test tree does not pay) is tested on its own in
    tests/test_ri_fallback.py."""
    monkeypatch.setattr(RITreeRenderer, "auto_fallback", False)
    # the cost rule's counts for these small frames (the defaults, tuned on the paper's
    # sizes, would leave a 64x48 frame's leaves unevaluated)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES", 8)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES_MIXED", 32)


def _scene(glass=True, w=64, h=48, obj="sphere", ior=1.5) -> Scene:
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.5, 0.5, 0.5)))
    if glass:
        m = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.95,) * 3,
                                    ior=ior))
    else:
        m = s.add_material(Material("chrome", diffuse=(0.05,) * 3, mirror=(0.9,) * 3))
    mesh = shapes.icosphere(4) if obj == "sphere" else shapes.torus(1.0, 0.4, 96, 48)
    s.add_instance(s.add_mesh(shapes.plane(10.0)), np.eye(4), [floor], name="Floor")
    s.add_instance(s.add_mesh(mesh), shapes.transform((0.0, 0.0, 1.2), 1.0, 0.0, 20.0),
                   [m], name="Obj")
    s.add_light(Light("Key", "POINT", power=1500.0, position=(-3.0, -4.0, 6.0)))
    s.set_world_color((0.3, 0.35, 0.4), lights=False)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -6.0, 2.5), (0.0, 0.0, 1.0)), lens=40.0,
                        width=w, height=h))
    return s


def _rays_at(center, radius, n, seed=0):
    """Rays from far outside aimed at points near a sphere of ``radius`` at ``center``."""
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    target = center + rng.uniform(-1, 1, (n, 3)) * radius * 0.9
    return target - 8.0 * radius * dirs, dirs


def _cache(sc, dist=0.05, ang=30.0, depth=28, cache_mb=100.0, thickness=False, plain=True):
    """A cache over ``sc``; ``plain``: the paper's lazy subdivision without the cost rule
    (every leaf a query reaches is refined to FINAL: these tests query scattered rays)."""
    sa = sc.arrays()
    n = 1 if plain else None
    return RITreeCache(sa, create_accelerator("BVH", sa), dist, ang, depth, cache_mb,
                       thickness, split_queries=n, split_queries_mixed=n), sa


def test_sphere_attributes_match_analytic_and_error_falls_with_threshold():
    sc = _scene(glass=True)
    c = np.array([0.0, 0.0, 1.2])
    o, d = _rays_at(c, 1.0, 3000)
    errs, perr = [], []
    for dist in (0.25, 0.02):
        cache, sa = _cache(sc, dist=dist)
        q = cache.query(np.ones(len(o), np.int32), o, d)
        hit = q.status == ST_HIT
        assert hit.mean() > 0.5
        # analytic: the hit lies on the sphere, the normal is radial
        P = q.P[hit]
        radial = (P - c) / np.linalg.norm(P - c, axis=1, keepdims=True)
        off = np.abs(np.linalg.norm(P - c, axis=1) - 1.0)
        assert off.max() < 0.06
        perr.append(off.mean())
        cosn = np.einsum("ij,ij->i", q.NS[hit], radial)
        assert cosn.min() > np.cos(np.radians(3.0))
        # analytic exit ray of a glass sphere: it leaves the sphere on its surface, and
        # by symmetry the exit direction makes the same angle with the outward normal
        # there as the incoming ray with the entry normal
        X = q.OP[hit]
        assert np.abs(np.linalg.norm(X - c, axis=1) - 1.0).max() < 0.06
        nx = (X - c) / np.linalg.norm(X - c, axis=1, keepdims=True)
        cin = -np.einsum("ij,ij->i", d[hit], radial)
        cout = np.einsum("ij,ij->i", q.OD[hit], nx)
        ok = q.nint[hit] == 1  # direct exits (no total internal reflection)
        errs.append(np.abs(np.degrees(np.arccos(np.clip(cin[ok], -1, 1)))
                           - np.degrees(np.arccos(np.clip(cout[ok], -1, 1)))).mean())
        assert errs[-1] < 5.0
    assert errs[1] < errs[0], f"exit-angle error did not fall: {errs}"
    assert perr[1] < perr[0], f"hit-point error did not fall: {perr}"


def test_torus_attributes_match_traced_ones():
    sc = _scene(glass=False, obj="torus")
    cache, sa = _cache(sc, dist=0.02, cache_mb=2000.0)  # plain scheme: deep silhouettes
    rng = np.random.default_rng(3)
    o, d = _rays_at(np.array([0.0, 0.0, 1.2]), 1.3, 4000, seed=3)
    q = cache.query(np.ones(len(o), np.int32), o, d)
    hit = np.flatnonzero(q.status == ST_HIT)
    assert len(hit) > 500
    h = cache.accel.intersect_object(1, o[hit], d[hit], 0.0, np.inf)
    good = h.inst >= 0
    assert good.mean() > 0.99  # an interpolated hit is a real hit
    P = o[hit] + d[hit] * h.t[:, None]
    err = np.linalg.norm(q.P[hit] - P, axis=1)[good]
    assert np.percentile(err, 99) < 0.05 and err.mean() < 0.01
    del rng


def test_patch_classes_never_cross_sharp_edges_or_material_borders():
    s = Scene()
    mirror = s.add_material(Material("m", diffuse=(0.1,) * 3, mirror=(0.8,) * 3))
    glass = s.add_material(Material("g", diffuse=(0.0,) * 3, transmission=(0.9,) * 3))
    box = shapes.box((2.0, 2.0, 2.0))
    s.add_instance(s.add_mesh(box), np.eye(4), [mirror], name="Box")
    sph = shapes.icosphere(4)
    tri_z = sph.vertices[sph.triangles].mean(axis=1)[:, 2]
    sph.slots = (tri_z > 0).astype(np.int32)
    s.add_instance(s.add_mesh(sph), shapes.transform((4.0, 0.0, 0.0)), [mirror, glass],
                   name="TwoMaterials")
    s.set_camera(Camera())
    cache, sa = _cache(s, dist=0.25)
    cache_box_normals = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1],
                                  [0, 0, -1]], float)
    o, d = _rays_at(np.zeros(3), 1.2, 3000, seed=5)
    # the box has 12 triangles: force it into the tree by querying it directly
    q = cache.query(np.zeros(len(o), np.int32), o, d)
    hit = q.status == ST_HIT
    assert hit.sum() > 200
    # interpolated only inside one face: the normal is exactly that face's
    dots = np.abs(q.NS[hit] @ cache_box_normals.T).max(axis=1)
    assert dots.min() > 1.0 - 1e-9
    o2, d2 = _rays_at(np.array([4.0, 0.0, 0.0]), 1.0, 3000, seed=6)
    q2 = cache.query(np.ones(len(o2), np.int32), o2, d2)
    hit2 = np.flatnonzero(q2.status == ST_HIT)
    assert len(hit2) > 200
    h = cache.accel.intersect_object(1, o2[hit2], d2[hit2], 0.0, np.inf)
    ok = h.inst >= 0
    slot = slots_of(sa, sa.inst_mesh[np.maximum(h.inst, 0)], np.maximum(h.prim, 0))
    exact_mat = np.where(slot == 1, glass, mirror)
    assert np.array_equal(q2.mat[hit2][ok], exact_mat[ok])


def test_frame_close_to_base_and_cache_reused():
    sc = _scene(glass=True, w=64, h=48)
    # the paper's tests (this is about the trees kept across frames; at 64x48 the
    # exit-ray test leaves too few queries per leaf for the growth asserted below: its
    # bound is tests/test_ri_tree_bounds.py's)
    st = RenderSettings(mode="RI_TREE", max_depth=4, ri_dist_thresh=0.05, ri_probe_angle=0.0)
    sess = Session(sc, st)
    base = render(sc, replace(st, mode="BASE"), accel=sess.accel)
    frames = [sess.render() for _ in range(4)]
    f = frames[0]
    assert f.stats["mode"] == "RI_TREE" and f.stats["ri_objects"] == 1
    interp = [(g.pixel_class == CLASS_INTERPOLATED).mean() for g in frames]
    samples = [g.stats["samples_traced"] for g in frames]
    # the trees are kept across frames: later frames of the same view refine only the
    # leaves their rays have by now visited often enough to pay for (the cost rule), so
    # fewer samples are traced and more pixels are interpolated
    assert interp[0] > 0.0 and interp[-1] > 1.5 * interp[0], interp
    assert samples[-1] < 0.5 * samples[0], samples
    for g in frames:
        assert np.isfinite(g.radiance).all()
        m = image.compare(g.radiance, base.radiance, 0.05)
        assert m["mean_error"] < 0.02, m


def test_tiny_cache_cap_is_honoured():
    sc = _scene(glass=True, w=64, h=48)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    cap = 0.05
    st = RenderSettings(mode="RI_TREE", max_depth=3, ri_cache_mb=cap)
    r = RITreeRenderer()
    f = r.render(sc, st, accel)
    assert f.stats["prunes"] > 0
    assert f.stats["memory_mb"] <= cap
    # within every query batch too (peak: after every allocation, midpoints included)
    assert f.stats["peak_memory_mb"] <= cap
    big = RITreeRenderer().render(sc, replace(st, ri_cache_mb=100.0), accel)
    assert np.isfinite(f.radiance).all()
    assert image.compare(f.radiance, big.radiance, 0.05)["mean_error"] < 0.02


def test_edit_invalidates_only_the_edited_objects_tree():
    sc = _scene(glass=True, w=48, h=36)
    sc.add_instance(sc.add_mesh(shapes.icosphere(3)), shapes.transform((2.0, 1.0, 1.0), 0.6),
                    [1], name="Second")
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    st = RenderSettings(mode="RI_TREE", max_depth=3)
    r = RITreeRenderer()
    r.render(sc, st, accel)
    cache = r.caches[False]
    assert (cache.forest.roots[1] >= 0).any() and (cache.forest.roots[2] >= 0).any()
    new, fx = apply_edits(sc, [ObjectTransform("Second",
                                               shapes.transform((1.8, 1.2, 1.0), 0.6))])
    accel.update(new.arrays())
    assert r.take_edits(fx, sa, new.arrays()) > 0  # the edits machinery's call
    sc = new
    f = r.render(sc, st, accel)
    fresh = RITreeRenderer().render(sc, st, accel)
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    # the kept tree goes on refining where the first frame's rays made it worth it (the
    # cost rule), so the frame is not the fresh one bit for bit; a stale tree of the moved
    # object would put it where it was
    assert image.compare(f.radiance, fresh.radiance, 0.05)["mean_error"] < 0.002
    assert image.compare(f.radiance, base.radiance, 0.05)["mean_error"] < 0.02
    assert 0 < f.stats["samples_traced"] < fresh.stats["samples_traced"]
    # the explicit call of the edits machinery
    assert r.invalidate([1]) > 0
    assert (r.caches[False].forest.roots[1] < 0).all()


def test_thickness_view_exact_and_interpolated():
    w, h = 96, 72
    sc = _scene(glass=True, w=w, h=h)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    st = RenderSettings(mode="BASE", thickness_view=True, thickness_distance=1.0)
    exact = render_thickness_exact(sc, st, accel)
    # the centre pixel looks at the sphere: its chord is close to a diameter
    cy, cx = h // 2, w // 2
    assert exact.radiance[cy, cx, 0] < np.exp(-1.5)
    r = RITreeRenderer()
    f = r.render(sc, replace(st, mode="RI_TREE"), accel)
    assert f.stats["view"] == "THICKNESS"
    assert (f.pixel_class == CLASS_INTERPOLATED).mean() > 0.05
    assert image.compare(f.radiance, exact.radiance, 0.05)["mean_error"] < 0.02


@pytest.mark.parametrize("field,value", [("ri_dist_thresh", 0.0), ("ri_dist_thresh", np.nan),
                                         ("ri_ang_thresh", 500.0), ("ri_depth", 0),
                                         ("ri_depth", 1000), ("ri_cache_mb", -1.0),
                                         ("thickness_distance", -2.0)])
def test_absurd_ri_settings_are_rejected(field, value):
    with pytest.raises(SceneError, match=field):
        replace(RenderSettings(), **{field: value}).validated()


def test_session_edit_matches_a_fresh_session_of_the_edited_scene():
    """Moving the mirror object through Session.apply drops its RI-tree and only its (the
    glass's tree survives, its box padding frozen): the next RI_TREE frame matches a fresh
    session's frame of the edited scene. Not bit for bit: the kept glass tree was refined by
    the first frame's queries (measured: max display error 7e-4, 0.5% of pixels off by more
    than 1e-5), so the bound is the mode's own tolerance against the base tracer in
    test_frame_close_to_base_and_cache_reused (mean display error < 0.02), and no pixel
    over 0.05."""
    from rstrace_engine.geometry.edits import ObjectTransform

    sc = _scene(glass=False, w=48, h=36)
    glass = sc.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.95,) * 3,
                                      ior=1.5))
    sc.add_instance(sc.add_mesh(shapes.icosphere(3)), shapes.transform((1.3, -1.0, 0.8), 0.5),
                    [glass], name="Glass")
    st = RenderSettings(mode="RI_TREE", max_depth=3)
    sess = Session(sc, st)
    sess.render()
    forest = sess.ri_tree.caches[False].forest
    assert (forest.roots[1] >= 0).any() and (forest.roots[2] >= 0).any()
    moved = shapes.transform((0.2, 0.2, 1.3), 1.0, 0.0, 35.0)
    sess.apply([ObjectTransform("Obj", moved)])
    assert (forest.roots[1] < 0).all() and (forest.roots[2] >= 0).any()
    assert sess.stats["ri_trees_invalidated"] > 0
    f = sess.render()
    assert not f.stats["incremental"] and sess.ri_tree.caches[False].forest is forest
    edited = sc.copy()
    edited.set_instance_matrix(1, moved)
    fresh = Session(edited, st).render()
    assert f.stats["samples_traced"] < fresh.stats["samples_traced"]  # the glass tree kept
    m = image.compare(f.radiance, fresh.radiance, 0.05)
    assert m["mean_error"] < 0.02 and m["n_over"] == 0, m
    # the moved object is drawn where the fresh frame draws it
    assert (f.pixel_class != fresh.pixel_class).mean() < 0.01


def test_cost_rule_without_demand_traces_every_ray_exactly(monkeypatch):
    """With no leaf ever worth refining, every query is traced: the frame is the base
    tracer's (the traced fallback of sparse leaves adds nothing of its own)."""
    import rstrace_engine.ri_tree.tree_cache as ri_cache

    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES", 10 ** 9)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES_MIXED", 10 ** 9)
    sc = _scene(glass=True, w=48, h=36)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    st = RenderSettings(mode="RI_TREE", max_depth=4)
    f = RITreeRenderer().render(sc, st, accel)
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    assert f.stats["cells_split"] == 0
    assert f.stats["samples_traced"] <= 6 * 16  # the roots' corners only
    assert not (f.pixel_class == CLASS_INTERPOLATED).any()
    np.testing.assert_allclose(f.radiance, base.radiance, rtol=1e-6, atol=1e-6)


def test_cost_rule_refines_dense_demand_and_traces_scattered_rays():
    """Rays from one eye (a camera's bundle: dense in line space) get refined leaves and
    are interpolated; as many rays scattered over all of line space do not pay for
    samples: they stay in sparse leaves and are traced, for far fewer samples than the
    plain lazy scheme spends on them."""
    from rstrace_engine.ri_tree.patches import ST_SPARSE

    sc = _scene(glass=False)
    c = np.array([0.0, 0.0, 1.2])
    n = 4000
    rng = np.random.default_rng(8)
    eye = c + np.array([0.0, -6.0, 1.0])
    tgt = c + rng.uniform(-0.6, 0.6, (n, 3))
    d_eye = (tgt - eye) / np.linalg.norm(tgt - eye, axis=1, keepdims=True)
    o_eye = np.repeat(eye[None], n, axis=0)
    dense, _ = _cache(sc, dist=0.05, plain=False)
    q = dense.query(np.ones(n, np.int32), o_eye, d_eye)
    assert (q.status == ST_HIT).mean() > 0.6
    o, d = _rays_at(c, 1.0, n, seed=2)
    cost, _ = _cache(sc, dist=0.05, plain=False)
    qs = cost.query(np.ones(n, np.int32), o, d)
    plain, _ = _cache(sc, dist=0.05, plain=True)
    qp = plain.query(np.ones(n, np.int32), o, d)
    assert (qs.status == ST_SPARSE).mean() > 0.5
    # the plain scheme answers every ray but those in cells at the depth constraint whose
    # corners all miss while their lines can meet the box (traced: the corners cannot say)
    assert (qp.status == ST_SPARSE).mean() < 0.15
    assert cost.counters["samples_traced"] < 0.25 * plain.counters["samples_traced"]
    # a sparse answer is never an interpolated one
    assert np.isinf(qs.t[qs.status == ST_SPARSE]).all()


def _exact_queries(monkeypatch):
    """Every interpolated attribute of a query replaced by the traced sample of the query's
    own line."""
    from rstrace_engine.interpolants.linetree import parameterize
    from rstrace_engine.ri_tree import tree_cache as ri_cache
    from rstrace_engine.ri_tree.sampling import trace_samples

    orig = ri_cache.RITreeCache.query

    def exact(self, inst, o, d):
        q = orig(self, inst, o, d)
        inst = np.ascontiguousarray(inst, np.int32)
        face = np.empty(len(inst), np.int8)
        abcd = np.empty((len(inst), 4))
        parameterize(self.box, inst, np.ascontiguousarray(o, np.float64),
                     np.ascontiguousarray(d, np.float64), face, abcd)
        s = trace_samples(self.sa, self.accel, self.tri_class, self.box, inst, face, abcd,
                          False)
        hit = np.flatnonzero(q.status == ST_HIT)
        for name in ("P", "NS", "NG", "OP", "OD", "gain", "nint", "mat", "RP", "RD", "rgain"):
            getattr(q, name)[hit] = getattr(s, name)[hit]
        return q

    monkeypatch.setattr(ri_cache.RITreeCache, "query", exact)


def test_exact_attributes_give_the_base_frame(monkeypatch):
    """With exact attributes (:func:`_exact_queries`), an RI_TREE frame of a glass object
    is the base tracer's: the exit ray, its path weight and the internal reflection split
    off where the path refracts out (which a single exit ray leaves out) are all the
    renderer needs (measured without that reflection: mean display error 0.09 on the
    interpolated pixels of the random volumes)."""
    _exact_queries(monkeypatch)
    sc = _scene(glass=True, w=64, h=48)
    accel = create_accelerator("BVH", sc.arrays())
    # coarse, the paper's tests alone: as many interpolated pixels as a 64x48 frame allows
    st = RenderSettings(mode="RI_TREE", max_depth=5, ri_dist_thresh=0.25, ri_probe_angle=0.0)
    r = RITreeRenderer()
    for _ in range(3):  # later frames interpolate more
        f = r.render(sc, st, accel)
    assert (f.pixel_class == CLASS_INTERPOLATED).mean() > 0.05
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    np.testing.assert_allclose(f.radiance, base.radiance, rtol=1e-5, atol=1e-5)


def test_rough_surfaces_sample_as_the_base_frame(monkeypatch):
    """Rough surfaces in a frame with trees draw the base tracer's glossy samples (issue
    22): with exact attributes the RI_TREE frame of a scene whose rough floor, rough metal
    ball (with a tree, interpolated) and their glossy rays meet a glass ball (with a tree) is
    the base frame, at Glossy Samples 8 (8 ray pairs at a path's first rough bounce, one
    deeper, the same seeds), not a noisier frame of one ray pair per rough point."""
    from rstrace_engine.geometry.principled import principled_material

    _exact_queries(monkeypatch)
    sc = _scene(glass=True, w=64, h=48)
    rough, _ = principled_material("rough_floor", (0.5, 0.5, 0.5), roughness=0.4)
    metal, _ = principled_material("rough_metal", (0.9, 0.7, 0.4), metallic=1.0,
                                   roughness=0.3)
    sc.set_material(sc.material_id("floor"), rough)
    sc.add_instance(sc.add_mesh(shapes.icosphere(3)), shapes.transform((1.6, 0.6, 0.7), 0.6),
                    [sc.add_material(metal)], name="Metal")
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="RI_TREE", max_depth=4, glossy_samples=8, ri_dist_thresh=0.25,
                        ri_probe_angle=0.0)
    r = RITreeRenderer()
    r.auto_fallback = False
    for _ in range(3):  # later frames interpolate more
        f = r.render(sc, st, accel)
    assert (f.pixel_class == CLASS_INTERPOLATED).mean() > 0.05
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    np.testing.assert_allclose(f.radiance, base.radiance, rtol=1e-5, atol=1e-5)
    one = render(sc, replace(st, mode="BASE", glossy_samples=1), accel=accel)
    assert np.abs(one.radiance - base.radiance).max() > 0.05  # the samples matter here


def test_tiny_cap_within_a_batch_keeps_the_pools_consistent():
    """One large query batch per call under a cap far below what the batch wants: the cache
    never holds more than the cap (pruning older batches' nodes mid-batch, tracing what does
    not fit), and no sample a live node or a held midpoint uses is ever freed twice or
    handed out while in use."""
    from rstrace_engine.ri_tree.kdtree import DEAD
    from rstrace_engine.ri_tree.patches import ST_SPARSE

    sc = _scene(glass=True)
    cap = 0.5
    cache, _ = _cache(sc, dist=0.05, cache_mb=cap, plain=False)
    big, _ = _cache(sc, dist=0.05, cache_mb=1000.0, plain=False)
    c = np.array([0.0, 0.0, 1.2])
    rng = np.random.default_rng(4)
    for k in range(4):
        # bundles from four eyes around the sphere (dense in line space)
        a = 0.5 * np.pi * k
        eye = c + 6.0 * np.array([np.cos(a), np.sin(a), 0.3])
        tgt = c + rng.uniform(-0.8, 0.8, (20000, 3))
        d = (tgt - eye) / np.linalg.norm(tgt - eye, axis=1, keepdims=True)
        o = np.repeat(eye[None], len(d), axis=0)
        q = cache.query(np.ones(len(o), np.int32), o, d)
        assert cache.peak_bytes <= cap * 1e6
        f = cache.forest
        free = np.asarray(f._free_samples, np.int64)
        assert len(np.unique(free)) == len(free)
        live = f.nodes.state[:f.n_nodes] != DEAD
        used = f.nodes.corner[:f.n_nodes][live].reshape(-1)
        assert not np.isin(used[used >= 0], free).any()
        qb = big.query(np.ones(len(o), np.int32), o, d)
        # what fitted is interpolated as with room to spare; the rest is traced
        both = (q.status == ST_HIT) & (qb.status == ST_HIT)
        assert (q.status == ST_SPARSE).sum() > (qb.status == ST_SPARSE).sum()
        assert both.sum() > 100
        np.testing.assert_allclose(q.NS[both], qb.NS[both], atol=0.2)
    assert cache.counters["prunes"] > 0


def test_error_falls_with_the_distance_threshold_under_the_cost_rule():
    """The cost rule decides which leaves are worth refining, not how far: with dense
    demand (one eye's bundle) a lower distance threshold still gives a finer tree and a
    smaller exit-ray error against the traced exit rays of the same lines."""
    from rstrace_engine.interpolants.linetree import parameterize
    from rstrace_engine.ri_tree.sampling import trace_samples

    sc = _scene(glass=True)
    c = np.array([0.0, 0.0, 1.2])
    rng = np.random.default_rng(12)
    eye = c + np.array([0.5, -6.0, 1.5])
    tgt = c + rng.uniform(-0.9, 0.9, (30000, 3))
    d = (tgt - eye) / np.linalg.norm(tgt - eye, axis=1, keepdims=True)
    o = np.repeat(eye[None], len(d), axis=0)
    inst = np.ones(len(d), np.int32)
    errs, samples = [], []
    for dist in (0.25, 0.02):
        cache, _ = _cache(sc, dist=dist, plain=False)
        cache.query(inst, o, d)  # the first batch builds; the second reads the tree
        q = cache.query(inst, o, d)
        hit = np.flatnonzero((q.status == ST_HIT) & (q.nint >= 0))
        assert len(hit) > 1000
        face = np.empty(len(hit), np.int8)
        abcd = np.empty((len(hit), 4))
        parameterize(cache.box, inst[hit], o[hit], d[hit], face, abcd)
        s = trace_samples(cache.sa, cache.accel, cache.tri_class, cache.box, inst[hit], face,
                          abcd, False)
        ok = s.nint == q.nint[hit]
        cosang = np.clip(np.einsum("ij,ij->i", q.OD[hit][ok], s.OD[ok]), -1.0, 1.0)
        errs.append(np.degrees(np.arccos(cosang)).mean())
        samples.append(cache.counters["samples_traced"])
    assert errs[1] < errs[0], errs
    assert samples[1] > samples[0], samples


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_cells_whose_corners_all_miss_are_traced_at_a_shallow_depth_constraint(depth):
    """At the depth constraint a cell whose 16 corners all miss was final and declared
    every ray through it a miss: at depth 1-2 the chrome torus between the corners vanished
    (432 of 3,072 pixels off, up to 0.73 display error, none marked interpolated). Such a
    cell is traced unless none of its lines can meet the object's box."""
    sc = _scene(glass=False, obj="torus")
    st = RenderSettings(mode="RI_TREE", max_depth=4, ri_depth=depth).validated()
    sess = Session(sc, st)
    frame = sess.render()
    base = render(sc, replace(st, mode="BASE"), accel=sess.accel)
    err = np.abs(image.to_display(frame.radiance) - image.to_display(base.radiance)).max()
    assert err < 1e-3


def test_thickness_counts_closed_objects_only_and_adds_overlaps():
    """The thickness walk: an open ground plane has no inside (its "entry" once swallowed
    the chord of a sphere sunk into it: length 0), and overlapping objects add up, as the
    RI-tree's per-object lengths do (the whole-scene walk counted an overlap once: BASE and
    RI_TREE thickness views differed by up to 0.37)."""
    from rstrace_engine.ri_tree.thickness import walk

    s = Scene()
    m = s.add_material(Material("m", diffuse=(0.5, 0.5, 0.5)))
    s.add_instance(s.add_mesh(shapes.plane(10.0)), np.eye(4), [m], name="Ground")
    ball = s.add_mesh(shapes.icosphere(4))
    s.add_instance(ball, shapes.transform((0.0, 0.0, 0.5)), [m], name="Sunk")
    s.add_instance(ball, shapes.transform((4.0, 0.0, 2.0)), [m], name="A")
    s.add_instance(ball, shapes.transform((4.5, 0.0, 2.0)), [m], name="B")
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -5.0, 3.0), (0.0, 0.0, 0.0))))
    sa = s.arrays()
    acc = create_accelerator("BVH", sa)

    def scene_hits(o, d, lo, hi, rows):
        return acc.closest_hit(o, d, lo, hi)

    # straight down through the sunk sphere's poles: its whole diameter, the plane nothing
    o = np.array([[0.0, 0.0, 5.0], [0.0, -5.0, 2.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    down = walk(sa, scene_hits, o[:1], d[:1], 0.0, np.inf)
    assert down[0] == pytest.approx(2.0, rel=2e-3)
    # along x through the overlapping pair: the sum of both chords, as per-object walks
    ox, dx = np.array([[0.0, 0.0, 2.0]]), np.array([[1.0, 0.0, 0.0]])
    both = walk(sa, scene_hits, ox, dx, 0.0, np.inf)[0]
    each = 0.0
    for k in (2, 3):
        def one(oo, dd, lo, hi, rows, k=k):
            return acc.intersect_object(np.full(len(oo), k, np.int32), oo, dd, lo, hi)
        each += walk(sa, one, ox, dx, 0.0, np.inf)[0]
    assert both == pytest.approx(4.0, rel=2e-3) and both == pytest.approx(each, rel=1e-9)
    # a ray starting inside the sunk sphere counts from its origin
    inside = walk(sa, scene_hits, np.array([[0.0, 0.0, 0.5]]), d[:1], 0.0, np.inf)
    assert inside[0] == pytest.approx(1.0, rel=2e-3)


def test_a_pixels_samples_do_not_depend_on_the_tiling():
    """A pixel's jitter is its own (seed, pixel, sample), not its tile's: the RI-tree's 4x
    larger tiles, the dirty pixels of an incremental frame and the base frame's tiles all
    trace the same rays (with the tile's first row seeding it, an RI_TREE frame of the
    random volumes at 9 samples per pixel was off the base frame by 0.47 on traced pixels)."""
    from rstrace_engine.tracing.batches import frame_batches, row_tiles

    w, h, spp = 40, 30, 9

    def jitter_of(batches):
        out = np.empty((spp, w * h, 2))
        for pix, jit, _ in batches:
            out[:, pix] = jit
        return out

    a = jitter_of(row_tiles(w, h, spp, 7, 1))
    for rows in (4, 13, 30):
        np.testing.assert_array_equal(jitter_of(row_tiles(w, h, spp, 7, rows)), a)
    mask = np.zeros(w * h, np.bool_)
    mask[::7] = True
    part = jitter_of(frame_batches(w, h, spp, 7, 5, mask))
    np.testing.assert_array_equal(part[:, mask], a[:, mask])
    # stratified (the first 8 of a pixel's samples: one in each eighth of it in x, and in
    # y), in [0, 1), and another seed draws others
    assert (a >= 0).all() and (a < 1).all()
    for axis in (0, 1):
        cells = np.sort(np.floor(a[:8, :, axis] * 8).astype(int), axis=0)
        assert (cells == np.arange(8)[:, None]).all()
    assert not np.array_equal(jitter_of(row_tiles(w, h, spp, 8, 1)), a)


def test_an_all_traced_frame_with_several_samples_is_the_base_frame():
    """Every object traced (its tree fallen back), 4 samples per pixel over more rows than
    one base tile holds: the RI_TREE frame is the base frame bit for bit."""
    sc = _scene(glass=True, w=128, h=96)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="RI_TREE", max_depth=5, samples=4)
    r = RITreeRenderer()
    r.auto_fallback = False
    r.render(sc, st, accel)
    r.fall_back(False, r.ri[False], sc, None)
    f = r.render(sc, st, accel)
    assert f.stats["ri_objects"] == 0
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    np.testing.assert_array_equal(f.radiance, base.radiance)


def test_the_exit_ray_through_an_object_that_does_not_refract_is_the_ray():
    """IOR 1 (a wrap, a pane as a sheet): the exit ray continues the entering ray exactly,
    its origin on the ray (an interpolation of the corners' directions was 0.003 degrees off
    on the tomatoes' wrap, enough for a bowl's rim a unit behind to flip pixels); with IOR
    1.5 the exit rays bend."""
    sc = _scene(glass=True, ior=1.0)
    c = np.array([0.0, 0.0, 1.2])
    o, d = _rays_at(c, 1.0, 2000)
    cache, sa = _cache(sc, dist=0.25)
    assert cache.straight.tolist() == [False, True]  # the floor's material has IOR 1.45
    q = cache.query(np.ones(len(o), np.int32), o, d)
    ok = np.flatnonzero((q.status == ST_HIT) & (q.nint >= 0))
    assert len(ok) > 100
    np.testing.assert_allclose(q.OD[ok], d[ok] / np.linalg.norm(d[ok], axis=1)[:, None],
                               rtol=0, atol=1e-15)
    off = np.cross(q.OP[ok] - o[ok], d[ok])
    assert np.abs(off).max() < 1e-9
    cache, _ = _cache(_scene(glass=True), dist=0.25)
    q = cache.query(np.ones(len(o), np.int32), o, d)
    ok = np.flatnonzero((q.status == ST_HIT) & (q.nint >= 0))
    assert np.abs(q.OD[ok] - d[ok] / np.linalg.norm(d[ok], axis=1)[:, None]).max() > 0.1
