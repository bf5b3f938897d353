"""The RI_TREE mode's fallback (issue 9): an object whose tree does not pay is traced from
the next frame on. The decision is tested with given costs, not with timings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.scene import Camera, Light, Material, Scene
from rstrace_engine.ri_tree import fallback
from rstrace_engine.ri_tree import tree_cache as ri_cache
from rstrace_engine.ri_tree.fallback import FrameCosts, object_costs, tree_pays
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render


def _scene(w, h) -> Scene:
    """A glass sphere on a floor (as tests/test_ri_tree.py's)."""
    s = Scene()
    floor = s.add_material(Material("floor", diffuse=(0.5, 0.5, 0.5)))
    m = s.add_material(Material("glass", diffuse=(0.0,) * 3, transmission=(0.95,) * 3,
                                ior=1.5))
    s.add_instance(s.add_mesh(shapes.plane(10.0)), np.eye(4), [floor], name="Floor")
    s.add_instance(s.add_mesh(shapes.icosphere(4)),
                   shapes.transform((0.0, 0.0, 1.2), 1.0, 0.0, 20.0), [m], name="Obj")
    s.add_light(Light("Key", "POINT", power=1500.0, position=(-3.0, -4.0, 6.0)))
    s.set_world_color((0.3, 0.35, 0.4), lights=False)
    s.set_camera(Camera(matrix=shapes.look_at((0.0, -6.0, 2.5), (0.0, 0.0, 1.0)), lens=40.0,
                        width=w, height=h))
    return s


def _costs(queries, failed, skipped, samples, lookup_s, sample_s, obj_ray_s, ray_s):
    a = lambda x: np.asarray(x, np.int64)  # noqa: E731
    return FrameCosts(a(queries), a(failed), a(skipped), a(samples), lookup_s, sample_s,
                      obj_ray_s, ray_s)


def test_decision_from_given_costs():
    # object 0: no tree; object 1: cheap lookups, glass paths skipped (pays);
    # object 2: lookups dearer than its rays and many traced anyway (does not pay);
    # object 3: too few queries to judge
    c = _costs([0, 10000, 10000, 100], [0, 500, 6000, 100], [0, 10000, 0, 0],
               [0, 4000, 4000, 0], lookup_s=0.05, sample_s=0.04, obj_ray_s=2e-6, ray_s=4e-6)
    tree, traced = object_costs(c)
    # lookups split by queries (0.05 * 10000 / 20100), samples by count over SAMPLE_FRAMES
    q = 10000 / 20100
    assert np.isclose(tree[1], 0.05 * q + 0.02 / fallback.SAMPLE_FRAMES + 500 * 2e-6)
    assert np.isclose(traced[1], 10000 * 2e-6 + 10000 * 4e-6)
    assert np.isclose(tree[2], 0.05 * q + 0.02 / fallback.SAMPLE_FRAMES + 6000 * 2e-6)
    assert np.isclose(traced[2], 10000 * 2e-6)
    assert tree_pays(c).tolist() == [True, True, False, True]


def _frames(costs_for, monkeypatch, n=2):
    """RI_TREE frames of the glass sphere scene, the measured costs replaced by
    ``costs_for(measured)``; returns the renderer, frames and the base frame."""
    orig = fallback.Ledger.costs

    def given(self):
        m = orig(self)
        return None if m is None else costs_for(m)

    monkeypatch.setattr(fallback.Ledger, "costs", given)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES", 8)  # a small frame's leaves evaluated
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES_MIXED", 32)
    sc = _scene(48, 36)
    accel = create_accelerator("BVH", sc.arrays())
    # coarse, the paper's tests alone: a 48x36 frame's tree interpolates some pixels
    st = RenderSettings(mode="RI_TREE", max_depth=4, ri_dist_thresh=0.25, ri_probe_angle=0.0)
    r = RITreeRenderer()
    frames = [r.render(sc, st, accel) for _ in range(n)]
    return r, sc, frames, render(sc, replace(st, mode="BASE"), accel=accel)


def test_a_tree_that_does_not_pay_falls_back_to_tracing(monkeypatch):
    def dear(m):  # lookups a second each: no tree pays
        return m._replace(lookup_s=float(m.queries.sum()), obj_ray_s=1e-6, ray_s=1e-6)

    r, sc, frames, base = _frames(dear, monkeypatch)
    obj = sc.instance_keys.slot["Obj"]
    f0, f1 = frames
    assert f0.stats["ri_objects"] == 1 and f0.stats["ri_traced_objects"] == 1
    assert any("'Obj' is traced" in note for note in f0.stats["ri_notes"])
    assert obj in r.fallback[False] and len(r.ri[False]) == 0
    assert r.caches[False].forest.live_nodes == 0  # its tree was freed
    # traced from then on: no interpolated pixel, and the base frame exactly
    assert f1.stats["ri_objects"] == 0 and not (f1.pixel_class == CLASS_INTERPOLATED).any()
    np.testing.assert_array_equal(f1.radiance, base.radiance)
    # an edit of the object gives it a tree again
    r.invalidate([obj])
    assert obj not in r.fallback[False]


def test_a_tree_that_pays_is_kept(monkeypatch):
    def cheap(m):  # free lookups and samples: every tree pays
        return m._replace(lookup_s=0.0, sample_s=0.0, obj_ray_s=1e-6, ray_s=1e-6)

    r, _, frames, _ = _frames(cheap, monkeypatch, n=3)
    assert all(f.stats["ri_traced_objects"] == 0 and not f.stats["ri_notes"] for f in frames)
    assert len(r.ri[False]) == 1
    assert (frames[-1].pixel_class == CLASS_INTERPOLATED).any()
