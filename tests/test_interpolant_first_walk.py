"""A cache's first walk is priced before it is walked (issue 20: a user who picks
interpolants never loses; :data:`~rstrace_engine.interpolants.fallback.FIRST_WALK`): a frame
on a cache with no cell whose allowance cannot pay a first chunk at the learned price walks
nothing and is the base frame bit for bit; the price is learned from a first chunk; every
``REPROBE_FRAMES``-th declined frame in a row walks and prices it again. Decided by given
prices, not timings."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import fallback, interpolant_cache
from rstrace_engine.interpolants.fallback import CHUNK_MIN, Budget, Fallback
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render

EPS = 0.05


def test_a_first_walk_the_allowance_cannot_pay_is_declined():
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
    b.walked_chunk(CHUNK_MIN, 1e-4)  # (learning off: conftest)
    assert b.first_cost() == 0.0  # priced after a walk by what it measured, as before
    b = Budget(100_000, ray_s=1e-5)  # no price: walks as before
    assert b.first_cost() == 0.0 and b.chunk(50_000) == CHUNK_MIN


def test_the_price_applies_to_empty_caches_and_is_retried(monkeypatch):
    monkeypatch.setattr(fallback, "FIRST_WALK", [3.0])
    fb = Fallback(4)
    fb.ray_s = 1e-6
    assert fb.budget(10_000, 4, 1, empty=True).first_walk == 3.0
    assert fb.budget(10_000, 4, 1, empty=False).first_walk is None  # cells kept
    fb.declined = fallback.REPROBE_FRAMES  # declined that many frames in a row: walks
    assert fb.budget(10_000, 4, 1, empty=True).first_walk is None


def test_the_price_is_learned_from_a_first_chunk_without_structures_or_kernels(monkeypatch):
    monkeypatch.setattr(fallback, "LEARN_STRUCTURES", True)
    monkeypatch.setattr(fallback, "FIRST_WALK", [0.5])
    seen = {"loaded": 0}

    def first_chunk(added, build=False, empty=True):
        b = Budget(1_000_000, ray_s=1e-6)
        b.empty = empty
        b.open()
        if build:
            fallback.timed_structure("topo", 10, lambda: None)
        if seen["loaded"]:  # a kernel compiled or loaded: numba takes its compiler lock
            from numba.core.compiler_lock import global_compiler_lock
            with global_compiler_lock:
                pass
        b.close()
        b.walked_chunk(CHUNK_MIN, added)
        return b

    first_chunk(CHUNK_MIN * 2e-6)  # two traced rays' prices a ray walked
    assert fallback.FIRST_WALK[0] == pytest.approx(2.0)
    b = first_chunk(CHUNK_MIN * 4e-6, build=True)  # built a structure: not learned
    assert fallback.FIRST_WALK[0] == pytest.approx(2.0)
    first_chunk(CHUNK_MIN * 4e-6, empty=False)  # cells kept: not learned
    assert fallback.FIRST_WALK[0] == pytest.approx(2.0)
    seen.update(loaded=1)  # a kernel loaded: not learned
    first_chunk(CHUNK_MIN * 4e-6)
    assert fallback.FIRST_WALK[0] == pytest.approx(2.0)
    seen.update(loaded=0)
    b.open()  # a frame's second walked chunk: not learned
    b.walked_chunk(CHUNK_MIN, CHUNK_MIN * 9e-6)
    assert fallback.FIRST_WALK[0] == pytest.approx(2.0)
    first_chunk(CHUNK_MIN * 1e-6)
    assert fallback.FIRST_WALK[0] == pytest.approx(1.0)


def test_a_declined_frame_is_the_base_frame_and_a_reprobe_walks(monkeypatch):
    """On main the same frames walk a first chunk of CHUNK_MIN rays (no FIRST_WALK)."""
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    sc = scenes.three_spheres(96, 72, subdivisions=3)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    base = render(sc, replace(st, mode="BASE"), accel=accel)
    # a first chunk that costs 1,000 traced rays a ray walked: no allowance pays it
    monkeypatch.setattr(fallback, "FIRST_WALK", [1000.0])
    r = InterpolantRenderer()
    r.prepare(sa, st, accel)

    def frame(r):
        r.cache.fallback.ray_s = 1.0  # a dear ray: a large allowance (whatever the load)
        return r.render(sc, st, accel)

    for i in range(fallback.REPROBE_FRAMES):
        f = frame(r)
        s = f.stats["fallback"]
        assert s["walked_rays"] == 0 and f.stats["cells_built"] == 0, i
        assert r.cache.fallback.declined == i + 1
        np.testing.assert_array_equal(f.radiance, base.radiance)
        np.testing.assert_array_equal(f.pixel_class, base.pixel_class)
    # the REPROBE_FRAMES-th declined frame in a row: this one walks (and prices it again)
    f = frame(r)
    assert f.stats["fallback"]["walked_rays"] > 0
    assert r.cache.fallback.declined == 0
    # unpriced (conftest: None), a fresh renderer's first frame walks a first chunk
    monkeypatch.setattr(fallback, "FIRST_WALK", [None])
    fresh = InterpolantRenderer()
    fresh.prepare(sa, st, accel)
    f = frame(fresh)
    assert f.stats["fallback"]["walked_rays"] > 0
