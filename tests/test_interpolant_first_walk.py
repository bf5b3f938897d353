"""A cache's first walk is priced before it is walked (issue 20: a user who picks
interpolants never loses; :data:`~rstrace_engine.interpolants.fallback.PRICE_FIRST_WALK`): a
frame on a cache with no cell whose allowance cannot pay a first chunk at the price its scene
learned walks nothing and is the base frame bit for bit; the price is the scene's cache's
(:attr:`~rstrace_engine.interpolants.fallback.Fallback.first_walk`), learned from a first
chunk that built no structure and loaded no kernel; after ``REPROBE_FRAMES`` declined frames
in a row one walks and prices it again. Decided by given prices, not timings (the core tests
run unpriced, ``conftest.py``: these turn it on)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import fallback, interpolant_cache
from rstrace_engine.interpolants.fallback import CHUNK_MIN, REPROBE_FRAMES, Budget, Fallback
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render

EPS = 0.05
DEAR = 1000.0  # a first walk's price (traced rays a ray walked) that no allowance pays


@pytest.fixture(autouse=True)
def _priced(monkeypatch):
    monkeypatch.setattr(fallback, "PRICE_FIRST_WALK", True)
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)


def _scene(sub: int = 3):
    sc = scenes.three_spheres(96, 72, subdivisions=sub)
    return sc, create_accelerator("BVH", sc.arrays())


ST = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)


def _frame(r, sc, accel, **kw):
    r.prepare(sc.arrays(), ST, accel)
    r.cache.fallback.ray_s = 1.0  # a dear ray: a large allowance (whatever the load)
    return r.render(sc, ST, accel, **kw)


def test_a_first_walk_the_allowance_cannot_pay_is_declined_once_priced():
    b = Budget(100_000, ray_s=1e-5)  # an allowance of ALLOWANCE * 100,000 traced rays
    b.empty = True
    b.first_walk = 2.0 * fallback.ALLOWANCE * 100_000 / CHUNK_MIN  # twice the allowance
    assert b.first_cost() == pytest.approx(2.0 * b.limit)
    assert b.chunk(50_000) == 0 and b.cut and b.declined
    assert b.spent_for_good(0)  # (the rest of the frame: the base tracer's tiles)
    b = Budget(100_000, ray_s=1e-5)
    b.empty = True
    b.first_walk = 0.5 * fallback.ALLOWANCE * 100_000 / CHUNK_MIN  # affordable: it walks
    assert b.chunk(50_000) == CHUNK_MIN and not b.cut and not b.declined
    assert not b.spent_for_good(0)
    b.walked_chunk(CHUNK_MIN, 1e-4)
    assert b.first_cost() == 0.0  # priced after a walk by what it measured, as before
    # a scene not priced yet walks (its first frame: cells that pay are never declined)
    fb = Fallback(4)
    fb.ray_s = 1e-5
    b = fb.budget(100_000, 4, 1, empty=True)
    assert b.first_walk is None and b.chunk(50_000) == CHUNK_MIN and not b.declined


def test_the_price_applies_to_empty_caches_and_not_after_reprobe_frames_declined():
    fb = Fallback(4)
    fb.ray_s = 1e-6
    fb.first_walk = 3.0
    assert fb.budget(10_000, 4, 1, empty=True).first_walk == 3.0
    assert fb.budget(10_000, 4, 1, empty=False).first_walk is None  # cells kept
    for i in range(REPROBE_FRAMES):
        b = fb.budget(10_000, 4, 1, empty=True)
        assert b.first_walk == 3.0, i
        b.declined = True
        fb.walked_or_declined(b)
    assert fb.declined == REPROBE_FRAMES
    b = fb.budget(10_000, 4, 1, empty=True)  # declined that many in a row: this one walks
    assert b.first_walk is None
    b.walked = CHUNK_MIN
    fb.walked_or_declined(b)
    assert fb.declined == 0


def test_the_price_is_learned_from_a_first_chunk_without_structures_or_kernels():
    loaded = [False]

    def first_chunk(added, build=False, empty=True):
        b = Budget(1_000_000, ray_s=1e-6)
        b.empty = empty
        b.open()
        if build:
            fallback.timed_structure("topo", 10, lambda: None)
        if loaded[0]:  # a kernel compiled or loaded: numba takes its compiler lock
            from numba.core.compiler_lock import global_compiler_lock
            with global_compiler_lock:
                pass
        b.close()
        b.walked_chunk(CHUNK_MIN, added)
        return b

    assert first_chunk(CHUNK_MIN * 2e-6).learned == pytest.approx(2.0)  # 2 rays' prices
    assert first_chunk(CHUNK_MIN * 4e-6, build=True).learned is None  # built a structure
    assert first_chunk(CHUNK_MIN * 4e-6, empty=False).learned is None  # cells kept
    loaded[0] = True
    assert first_chunk(CHUNK_MIN * 4e-6).learned is None  # a kernel loaded
    loaded[0] = False
    b = first_chunk(CHUNK_MIN * 1e-6)
    b.open()  # a frame's second walked chunk: not learned
    b.walked_chunk(CHUNK_MIN, CHUNK_MIN * 9e-6)
    assert b.learned == pytest.approx(1.0)
    fb = Fallback(1)
    fb.walked_or_declined(b)
    assert fb.first_walk == pytest.approx(1.0)  # the cache's price from then on


def test_a_frame_learns_the_price_only_where_the_structures_were_built():
    sc, accel = _scene()
    warm = InterpolantRenderer()
    _frame(warm, sc, accel)  # (kernels loaded, the scene's structures built)
    r = InterpolantRenderer()
    f = _frame(r, sc, accel)
    assert f.stats["fallback"]["walked_rays"] >= CHUNK_MIN
    assert r.cache.fallback.first_walk is not None  # learned: its structures were kept
    sc2, accel2 = _scene(2)  # a new scene: its first walk builds its structures
    r2 = InterpolantRenderer()
    f = _frame(r2, sc2, accel2)
    assert f.stats["fallback"]["walked_rays"] >= CHUNK_MIN
    assert r2.cache.fallback.first_walk is None


def test_a_price_learned_on_one_scene_does_not_decline_another():
    sc, accel = _scene()
    sc2, accel2 = _scene(2)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), ST, accel)
    r.cache.fallback.first_walk = DEAR  # as learned on a dear scene
    assert _frame(r, sc, accel).stats["fallback"]["walked_rays"] == 0  # declined there
    f = _frame(r, sc2, accel2)  # the same renderer on another scene: its first frame walks
    assert f.stats["fallback"]["walked_rays"] > 0
    assert _frame(InterpolantRenderer(), sc2, accel2).stats["fallback"]["walked_rays"] > 0


def test_declined_frames_are_the_base_frame_and_then_one_walks():
    """On main the same frames walk a first chunk of CHUNK_MIN rays (no first-walk price)."""
    sc, accel = _scene()
    base = render(sc, replace(ST, mode="BASE"), accel=accel)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), ST, accel)
    fb = r.cache.fallback
    fb.first_walk = DEAR
    for i in range(REPROBE_FRAMES):
        f = _frame(r, sc, accel)
        s = f.stats["fallback"]
        assert s["walked_rays"] == 0 and f.stats["cells_built"] == 0, i
        assert s["declined"] and fb.declined == i + 1
        assert "walked no cell" in f.stats["fallback_notes"][0]  # said why (in Blender)
        np.testing.assert_array_equal(f.radiance, base.radiance)
        np.testing.assert_array_equal(f.pixel_class, base.pixel_class)
    f = _frame(r, sc, accel, cancel=lambda: True)  # cancelled: neither walked nor declined
    assert f.stats["cancelled"] and fb.declined == REPROBE_FRAMES  # the count kept
    f = _frame(r, sc, accel)  # after REPROBE_FRAMES declined in a row: this one walks
    assert f.stats["fallback"]["walked_rays"] > 0 and not f.stats["fallback"]["declined"]
    assert fb.declined == 0
    assert not any("walked no cell" in n for n in f.stats["fallback_notes"])


def test_a_declined_reprobe_keeps_the_whole_frame_traced():
    sc, accel = _scene()
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), ST, accel)
    fb = r.cache.fallback
    fb.first_walk = DEAR
    fb.all_traced, fb.frames_all = True, REPROBE_FRAMES  # the whole frame's re-probe is due
    f = _frame(r, sc, accel)
    assert f.stats["fallback"]["declined"]
    assert fb.all_traced and fb.frames_all == 0  # judged nothing: traced frames again
    assert fb.whole_frame_traced()


def test_an_incremental_frame_does_not_teach_the_price():
    """An edit's dirty pixels (``pixels``) are not a frame's first walk: clustered rays, and
    under ``SERIAL_BELOW`` rays on one thread (``threads_for``) against the ray price of
    full frames (a price learned there, inflated by the threads, declined full frames whose
    cells pay); like the fallback's judgements (``costs``), only full frames teach it."""
    sc, accel = _scene()
    full = _frame(InterpolantRenderer(), sc, accel)  # (kernels loaded, structures built)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), ST, accel)
    assert r.cache.pool.n_live == 0
    f = _frame(r, sc, accel, pixels=np.ones(96 * 72, np.bool_), base=full)
    assert f.stats["fallback"]["walked_rays"] >= CHUNK_MIN  # it walked a first chunk
    assert r.cache.fallback.first_walk is None  # and taught nothing
