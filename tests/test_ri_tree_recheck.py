"""The RI_TREE continuation check (issue 22, :mod:`rstrace_engine.ri_tree.recheck`): pixels
whose interpolated samples meet different things across their neighbourhood are traced
again, exactly as the base frame traces them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.ri_tree import recheck
from rstrace_engine.ri_tree import tree_cache as ri_cache
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render


def test_flagged_pixels_are_the_tainted_ones_near_a_change_of_key():
    c = recheck.Continuations(6, 5, 2)
    key = np.zeros((2, 30), np.uint64)
    taint = np.ones((2, 30), np.bool_)
    taint[:, 0] = False  # pixel (0, 0): no interpolated sample
    taint[0, 5] = False  # pixel (0, 5): one of its two samples
    key[1, 3 * 6 + 4] = 7  # one sample of pixel (row 3, column 4) meets something else
    c.store(np.arange(30), key.ravel(), taint.ravel())
    got = set(c.flagged().tolist())
    want = {y * 6 + x for y in (2, 3, 4) for x in (3, 4, 5)}
    assert got == want
    key[0, 0] = 9  # a change next to an untainted pixel flags its tainted neighbours only
    c.store(np.arange(30), key.ravel(), taint.ravel())
    got = set(c.flagged().tolist())
    assert got == want | {1, 6, 7}
    # the tiles arrive one by one
    c2 = recheck.Continuations(6, 5, 2)
    for rows in (np.arange(12), np.arange(12, 30)):
        c2.store(rows, key[:, rows].ravel(), taint[:, rows].ravel())
    assert set(c2.flagged().tolist()) == got


def test_node_keys_tell_landing_objects_and_lights_apart():
    path = np.array([3, 3, 3, 3, 6])
    inst = np.array([2, 2, 4, -1, 2])
    vis = np.array([[True, False], [True, True], [True, False], [True, False], [True, False]])
    k = recheck.node_keys(path, inst, vis)
    assert len(set(k.tolist())) == 5
    assert recheck.node_keys(path[:1], inst[:1], vis[:1])[0] == k[0]


@pytest.fixture()
def _interpolate_all(monkeypatch):
    # the trees are measured, not the fallback's decision; the cost rule's counts lowered
    # for small frames (as tests/test_ri_tree_bounds.py)
    monkeypatch.setattr(RITreeRenderer, "auto_fallback", False)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES", 4)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES_MIXED", 16)


@pytest.fixture(scope="module")
def volumes():
    """Seed 004's random volumes at 100x100 with 4 samples a pixel, and the base frame."""
    sc = scenes.random_volumes(100, 100)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(max_depth=5, samples=4)
    return sc, accel, st, render(sc, st, accel=accel)


def _frames(sc, accel, st, base, check=True):
    r = RITreeRenderer()
    r.recheck = check
    out = []
    for _ in range(2):  # cold, and warm (the trees kept)
        f = r.render(sc, replace(st, mode="RI_TREE"), accel)
        px = np.abs(image.to_display(f.radiance)
                    - image.to_display(base.radiance)).max(axis=-1)
        out.append((px, f))
    return out


@pytest.mark.usefixtures("_interpolate_all")
def test_the_check_removes_flips_behind_glass_the_cell_test_admits(volumes):
    """At an exit-ray test of 0.1 degrees the interpolated exit rays through the blobs land
    across edges of what lies behind them (shadows on the floor, other blobs): measured
    0.395 with 6 pixels over 0.1 cold, 9 warm. The check re-traces the pixels whose
    neighbourhood disagrees (183 and 248 pixels, 2% of the frame) and leaves none over 0.1
    (measured 0.0028)."""
    sc, accel, st, base = volumes
    st = replace(st, ri_probe_angle=0.1)
    off = _frames(sc, accel, st, base, check=False)
    assert max(px.max() for px, _ in off) > 0.2
    assert max(np.count_nonzero(px > 0.1) for px, _ in off) >= 3
    for px, f in _frames(sc, accel, st, base):
        assert px.max() <= 0.1, f"max display error {px.max():.3f}"
        assert np.quantile(px, 0.999) <= 0.01
        assert 0 < f.stats["retraced_pixels"] < 0.1 * px.size


@pytest.mark.usefixtures("_interpolate_all")
def test_the_defaults_bound_the_random_volumes(volumes):
    sc, accel, st, base = volumes
    for px, f in _frames(sc, accel, st, base):
        assert px.max() <= 0.1, f"max display error {px.max():.3f}"
        assert f.stats["retraced_pixels"] > 0


@pytest.mark.usefixtures("_interpolate_all")
def test_retraced_pixels_are_the_base_frames(volumes, monkeypatch):
    """Every pixel re-traced: the frame is the base frame bit for bit (the same camera
    rays, jitter and seeds, four samples a pixel)."""
    sc, accel, st, base = volumes
    monkeypatch.setattr(recheck.Continuations, "flagged",
                        lambda self: np.arange(self.w * self.h, dtype=np.int64))
    for _, f in _frames(sc, accel, replace(st, ri_probe_angle=0.25), base):
        assert f.stats["retraced_pixels"] == f.radiance.shape[0] * f.radiance.shape[1]
        np.testing.assert_array_equal(f.radiance, base.radiance)


@pytest.mark.usefixtures("_interpolate_all")
def test_the_papers_settings_are_not_checked(volumes):
    """With the exit-ray test off (the paper's tests alone) the check is off too."""
    sc, accel, st, base = volumes
    (_, f), _ = _frames(sc, accel, replace(st, ri_probe_angle=0.0), base)
    assert f.stats["retraced_pixels"] == 0


@pytest.mark.usefixtures("_interpolate_all")
def test_a_cancel_during_the_check_keeps_the_frame_as_traced(volumes):
    """``cancel`` is polled between the check's batches too: cancelled there, the frame
    says so and keeps its pixels as the trees gave them."""
    from rstrace_engine.ri_tree.render import RI_TILE_RAYS

    sc, accel, st, _ = volumes
    st = replace(st, mode="RI_TREE", ri_probe_angle=0.1)
    tiles = -(-100 // max(1, RI_TILE_RAYS // (100 * 4)))
    polls = []

    def cancel():  # the tiles' polls pass, the check's first one stops it
        polls.append(1)
        return len(polls) > tiles

    r = RITreeRenderer()
    f = r.render(sc, st, accel, cancel=cancel)
    assert len(polls) == tiles + 1
    assert f.stats["cancelled"] and f.stats["retraced_pixels"] == 0
    r0 = RITreeRenderer()
    r0.recheck = False
    np.testing.assert_array_equal(f.radiance, r0.render(sc, st, accel).radiance)


@pytest.mark.usefixtures("_interpolate_all")
def test_retraced_pixels_on_rough_surfaces_are_the_base_frames(monkeypatch):
    """Rough surfaces at 4 pixel samples: a re-traced pixel takes the base frame's glossy
    rays (its Glossy Samples and the pixel's strata, tracing/glossy_strata.py), so with
    every pixel re-traced the frame is the base frame bit for bit."""
    sc = scenes.rough_materials(40, 30)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(max_depth=5, samples=4, glossy_samples=4, ri_probe_angle=0.25)
    base = render(sc, st, accel=accel)
    monkeypatch.setattr(recheck.Continuations, "flagged",
                        lambda self: np.arange(self.w * self.h, dtype=np.int64))
    for _, f in _frames(sc, accel, st, base):
        assert f.stats["retraced_pixels"] == 40 * 30
        np.testing.assert_array_equal(f.radiance, base.radiance)
