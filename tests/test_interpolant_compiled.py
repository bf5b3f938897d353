"""A frame during which numba compiled or loaded a kernel is not judged (issue 20:
:data:`~rstrace_engine.interpolants.fallback.SKIP_COMPILED`): its costs timed the compiler
(``make demo`` from an empty kernel cache judged its INTERPOLANT frame on 7.9 s of compiling
"with cells" against 0.016 s traced, and traced the next 8 frames). Decided by given costs
and a real compile, not timings (the core tests judge such frames, ``conftest.py``: these
turn it on)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants import fallback, interpolant_cache
from rstrace_engine.interpolants.fallback import (
    COMPILED_FRAMES,
    REPROBE_FRAMES,
    Budget,
    Fallback,
    FrameCosts,
)
from rstrace_engine.interpolants.render import InterpolantRenderer

EPS = 0.05


@pytest.fixture(autouse=True)
def _skip_compiled(monkeypatch):
    monkeypatch.setattr(fallback, "SKIP_COMPILED", True)
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)


def _dear(n: int = 2) -> FrameCosts:  # cells that cost a second: they do not pay
    rays = np.full(n, fallback.MIN_RAYS, np.int64)
    return FrameCosts(rays, rays, rays // 10, np.zeros(n, np.int64), 1.0, 0.0, 1e-6)


def test_a_frame_that_compiled_judges_and_learns_nothing():
    fb = Fallback(2)
    fb.learn(_dear(), fb.frame_traced(), compiled=True)
    assert not fb.all_traced and not fb.traced.any() and fb.ray_s is None and fb.last is None
    fb.learn(_dear(), fb.frame_traced())  # the next frame, no kernel loaded: judged
    assert fb.all_traced and fb.ray_s == 1e-6
    fb.frames_all = REPROBE_FRAMES  # the whole frame's re-probe is due ...
    assert not fb.whole_frame_traced()
    fb.learn(_dear()._replace(walk_s=0.0, ray_s=2e-6), fb.frame_traced(), compiled=True)
    assert fb.all_traced and not fb.whole_frame_traced()  # ... and stays due: not judged
    assert fb.ray_s == 1e-6


def test_the_ledger_sees_the_compiler_lock(monkeypatch):
    b = Budget(1000, ray_s=1e-6)
    assert not b.seal()
    numba.njit(lambda x: x + 1)(1)  # a new function: compiled (the compiler lock taken)
    assert b.seal() and b.compiled
    assert not Budget(1000, ray_s=1e-6).seal()  # (a ledger begun after it)
    c = Budget(1000, ray_s=1e-6)
    fallback.NUMBA_LOCKS[0] += 1  # a kernel loaded by another thread (the add-on's warm-up)
    assert c.seal()
    monkeypatch.setattr(fallback, "SKIP_COMPILED", False)
    assert not c.seal()


def _dear_frames(monkeypatch, compiles: list):
    """A renderer of ``three_spheres`` frames whose costs say their cells do not pay (a
    walk of a second, no wall-clock cut), the first ``compiles[0]`` of them compiling a new
    function inside their cells' timed work (as a cold cache's first INTERPOLANT frame)."""
    measured = fallback.FrameLedger.costs
    monkeypatch.setattr(fallback.FrameLedger, "costs",
                        lambda self, fb: measured(self, fb)._replace(walk_s=1.0, ray_s=1e-9))
    monkeypatch.setattr(fallback, "MIN_RAYS", 1)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)
    resolve = interpolant_cache.InterpolantCache.resolve

    def compiling(self, *a, **kw):
        if compiles[0]:
            compiles[0] -= 1
            numba.njit(lambda x: x + 1)(1)  # (a new function: compiled now)
        return resolve(self, *a, **kw)

    monkeypatch.setattr(interpolant_cache.InterpolantCache, "resolve", compiling)
    sc = scenes.three_spheres(96, 72, subdivisions=3)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    return lambda: r.render(sc, st, accel)


def test_a_frame_that_compiled_in_its_walk_is_not_judged_and_says_so(monkeypatch):
    compiles = [1]
    render = _dear_frames(monkeypatch, compiles)
    first = render()
    assert compiles == [0] and first.stats["fallback"]["walked_rays"] > 0
    s = first.stats["fallback"]
    assert s["compiled"] and not s["all_traced"] and s["traced_objects"] == 0
    notes = first.stats["fallback_notes"]
    assert len(notes) == 1 and "not judged" in notes[0] and "measured" not in notes[0]
    second = render()  # no kernel loaded: judged on its costs
    s = second.stats["fallback"]
    assert not s["compiled"] and s["all_traced"]
    assert not any("not judged" in n for n in second.stats["fallback_notes"])
    assert "cost more than they save" in second.stats["fallback_notes"][0]


def test_a_kernel_loaded_every_frame_does_not_keep_cells_that_do_not_pay():
    # (review: a warm-up loading beside every frame, or a signature new every frame, would
    # leave every frame unjudged: after COMPILED_FRAMES such frames in a row one is judged)
    fb = Fallback(2)
    for i in range(COMPILED_FRAMES + 1):
        b = Budget(1000, ray_s=1e-6)
        fallback.NUMBA_LOCKS[0] += 1  # (a kernel loaded during every frame)
        compiled = b.seal(fb.compiled)
        assert compiled == (i < COMPILED_FRAMES) and not fb.all_traced
        fb.learn(_dear(), fb.frame_traced(), compiled=compiled)
    assert fb.all_traced and fb.compiled == 0 and fb.ray_s == 1e-6
    fb.frames_all = REPROBE_FRAMES  # a re-probe that compiles is not judged (the count anew)
    b = Budget(1000, ray_s=1e-6)
    fallback.NUMBA_LOCKS[0] += 1
    assert b.seal(fb.compiled)


def test_rendered_frames_that_all_compile_are_judged_in_the_end(monkeypatch):
    monkeypatch.setattr(fallback, "COMPILED_FRAMES", 2)
    render = _dear_frames(monkeypatch, [3])  # every frame compiles a new function in its walk
    seen = [render().stats["fallback"] for _ in range(3)]
    assert [s["compiled"] for s in seen] == [True, True, False]
    assert [s["all_traced"] for s in seen] == [False, False, True]
