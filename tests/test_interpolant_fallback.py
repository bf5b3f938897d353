"""INTERPOLANT mode's fallback (issue 20): where cells do not pay, it learns it from measured
costs and traces. The decisions are tested with given costs, not with timings; wherever it
traces, the frame is the base tracer's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_TRACED, RenderSettings
from rstrace_engine.interpolants import fallback, frame_parts, interpolant_cache
from rstrace_engine.interpolants.fallback import (
    Budget,
    Fallback,
    FrameCosts,
    FrameLedger,
    cells_pay,
    object_costs,
)
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.tracing.whitted import render

EPS = 0.05
FLOAT_TOL = 1e-6


@pytest.fixture(autouse=True)
def small_cells(monkeypatch):
    """A small frame's cells are built from 6 rays on (default 48)."""
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)


def _costs(rays, walked, interpolated, cells, walk_s, build_s, ray_s) -> FrameCosts:
    a = lambda x: np.asarray(x, np.int64)  # noqa: E731
    return FrameCosts(a(rays), a(walked), a(interpolated), a(cells), walk_s, build_s, ray_s)


def test_decision_from_given_costs():
    # object 0: cheap walk, most rays interpolated (pays); object 1: builds dear, few rays
    # interpolated (does not pay); object 2: too few rays to judge; object 3: traced, no rays
    c = _costs(rays=[10000, 10000, 100, 0], walked=[8000, 10000, 100, 0],
               interpolated=[9000, 500, 0, 0], cells=[100, 300, 10, 0], walk_s=0.02,
               build_s=0.041, ray_s=5e-6)
    with_cells, traced = object_costs(c)
    share = 0.02 / 18100
    saved = fallback.SAVE_SHARE  # an interpolated ray saves this share of a traced one
    assert np.isclose(with_cells[0], 8000 * share + 0.041 * 100 / 410 / fallback.BUILD_FRAMES
                      + (10000 - saved * 9000) * 5e-6)
    assert np.isclose(traced[0], 10000 * 5e-6)
    assert np.isclose(with_cells[1], 10000 * share + 0.041 * 300 / 410 / fallback.BUILD_FRAMES
                      + (10000 - saved * 500) * 5e-6)
    assert cells_pay(c).tolist() == [True, False, True, True]


def test_learning_is_deterministic_reprobes_and_wins_back():
    # object 0: 200 cells, nothing interpolated; object 1: 49000 of 50000 rays interpolated
    # (the frame as a whole pays)
    dear = _costs([5000, 50000], [5000, 50000], [0, 49000], [200, 0], 0.001, 0.1, 1e-5)
    assert fallback.frame_pays(dear)
    fb = Fallback(2)
    fb.learn(dear, fb.frame_traced())
    assert fb.traced.tolist() == [True, False] and fb.ray_s == 1e-5 and not fb.all_traced
    again = Fallback(2)
    again.learn(dear, again.frame_traced())
    assert again.traced.tolist() == fb.traced.tolist()  # the same costs, the same decision
    # traced for REPROBE_FRAMES frames, then tried with cells again
    for _ in range(fallback.REPROBE_FRAMES):
        now = fb.frame_traced()
        assert now.tolist() == [True, False]
        fb.learn(dear, now)
    now = fb.frame_traced()
    assert now.tolist() == [False, False]  # the re-probe
    cheap = _costs([5000, 50000], [5000, 50000], [4900, 49000], [10, 10], 0.0, 0.0, 1e-5)
    fb.learn(cheap, now)  # its cells pay now: back to cells
    assert fb.traced.tolist() == [False, False]
    # an object whose cells the budget deferred is not judged (it had no chance yet)
    fb.learn(dear, fb.frame_traced(), deferred=np.array([3, 0]))
    assert fb.traced.tolist() == [False, False]
    # an edit gives a traced object a new chance; new slots start with cells
    fb.learn(dear, fb.frame_traced())
    fb.forget([0])
    fb.resize(3)
    assert fb.traced.tolist() == [False, False, False]


def test_budget():
    b = Budget(rays=1000, ray_s=None)
    assert b.may_build(0) and b.chunk(5000) == 0  # not priced: no limit, no walk (priced first)
    b.price(1e-3)  # limit: ALLOWANCE of tracing 1000 rays
    assert np.isclose(b.limit, fallback.ALLOWANCE * 1.0)
    b.price(1e-3, vis_s=1e-3, hit_share=0.5)  # closest-hit rays for all, half of them traced
    assert np.isclose(b.limit, fallback.ALLOWANCE * 1000 * (0.5e-3 + 1e-3))
    b.price(1e-3)
    b.spent = b.limit + 0.01
    assert not b.may_build(0) and b.chunk(5000) == 0
    assert b.may_build(30)  # 30 interpolated rays saved 15 ms (half a traced ray each)
    b.saved = 30
    assert b.may_build(0)
    # batches: the first at CELL_RAYS rays a cell (at most BUDGET_STEP), then what is left at
    # the measured cost per cell (at least BUDGET_MIN)
    c = Budget(rays=100000, ray_s=1e-3)  # a limit of ALLOWANCE * 100 s
    first = min(fallback.BUDGET_STEP, int(c.limit / (fallback.CELL_RAYS * 1e-3)))
    assert c.batch(10000, 0) == first and c.batch(5, 0) == min(5, first)
    c.charge(0.01, 100)  # 0.1 ms a cell
    left = c.limit - 0.01
    assert abs(c.batch(10 ** 6, 0) - left / 1e-4) <= 1
    assert abs(c.batch(10 ** 6, 1000) - (left + fallback.SAVE_SHARE) / 1e-4) <= 1
    c.charge(left - 1e-4, 1)  # a tenth of a millisecond left: one cell's worth
    assert c.batch(10 ** 6, 0) == fallback.BUDGET_MIN  # (at least, while it may build)
    c.charge(0.001, 1)
    assert c.batch(10000, 0) == 0
    assert Budget(rays=1000).batch(777, 0) == 777  # not priced: the whole step
    # chunks of a pass: CHUNK_MIN rays first, then as many as the rest affords at what the
    # mode added per ray walked so far (none under CHUNK_MIN), at most CHUNK_MAX
    d = Budget(rays=10 ** 6, ray_s=1e-6)  # a limit of ALLOWANCE seconds
    assert d.chunk(10 ** 6) == fallback.CHUNK_MIN and d.chunk(100) == 100
    d.walked, d.spent = 1000, 1e-3 * fallback.ALLOWANCE  # 1e-6 ALLOWANCE s a ray walked
    assert d.chunk(10 ** 6) == min(fallback.CHUNK_MAX, int(0.999 / 1e-6))
    d.spent = fallback.ALLOWANCE * (1 - fallback.CHUNK_MIN / 2e6)
    assert d.chunk(10 ** 6) == 0  # affords fewer than CHUNK_MIN rays: the rest is traced


def _scene(w=96, h=72):
    return scenes.three_spheres(w, h, subdivisions=3)


def _base(sc, accel, st):
    return render(sc, replace(st, mode="BASE"), accel=accel)


def test_objects_whose_cells_do_not_pay_are_traced_exactly(monkeypatch):
    monkeypatch.setattr(fallback, "MIN_RAYS", 1)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)  # (no wall-clock cut: judged on these costs)

    measured = FrameLedger.costs

    def dear(self, fb):  # walking costs a second: no object's cells pay
        m = measured(self, fb)
        return None if m is None else m._replace(walk_s=1.0, ray_s=1e-6)

    monkeypatch.setattr(FrameLedger, "costs", dear)
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    r.cache.fallback.ray_s = 1.0  # a dear ray: the first frame's budget builds every cell
    f0 = r.render(sc, st, accel)
    assert (f0.pixel_class == CLASS_INTERPOLATED).any()
    fb0 = f0.stats["fallback"]
    assert fb0["traced_objects"] >= 1
    # a frame that reprojects nothing (reprojection is free and proven: it stays on)
    r.cache.view = None
    f1 = r.render(sc, st, accel)
    base = _base(sc, accel, st)
    # every visible object traced: no cell walked or built, and the base frame exactly
    assert f1.stats["fallback"]["traced_objects"] == fb0["traced_objects"]
    assert not (f1.pixel_class == CLASS_INTERPOLATED).any()
    assert f1.stats["cells_built"] == 0
    np.testing.assert_array_equal(f1.radiance, base.radiance)
    # traced pixels are classed as traced
    assert (f1.pixel_class == CLASS_TRACED).sum() == (base.pixel_class == CLASS_TRACED).sum()


def test_objects_whose_cells_pay_keep_them(monkeypatch):
    monkeypatch.setattr(fallback, "MIN_RAYS", 1)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)  # (no wall-clock cut: judged on these costs)
    orig = FrameLedger.costs
    monkeypatch.setattr(FrameLedger, "costs",
                        lambda self, fb: orig(self, fb)._replace(walk_s=0.0, build_s=0.0,
                                                                 ray_s=1.0))
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    frames = [r.render(sc, st, accel) for _ in range(3)]
    assert all(f.stats["fallback"]["traced_objects"] == 0 for f in frames)
    assert (frames[-1].pixel_class == CLASS_INTERPOLATED).any()


def test_the_build_budget_defers_cells_and_traces_them(monkeypatch):
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    free = InterpolantRenderer()
    free.auto_fallback = False
    f_free = free.render(sc, st, accel)
    # a budget that lets every ray walk and builds one cell per frame (decided by counts,
    # not timings)
    monkeypatch.setattr(Budget, "chunk", lambda self, rest: rest)
    monkeypatch.setattr(Budget, "batch",
                        lambda self, step, now: min(step, 1) if self.built == 0 else 0)
    monkeypatch.setattr(Budget, "may_build", lambda self, now: self.built == 0)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    r.cache.fallback.ray_s = 1e-6  # priced: no ray traced to price one
    f = r.render(sc, st, accel)
    s = f.stats["fallback"]
    assert f.stats["cells_built"] == 1 < f_free.stats["cells_built"]
    assert s["deferred_cells"] > 0 and s["probe_rays"] == 0
    assert s["walked_rays"] == sc.camera.width * sc.camera.height
    base = _base(sc, accel, st)
    traced = f.pixel_class != CLASS_INTERPOLATED
    np.testing.assert_array_equal(f.radiance[traced], base.radiance[traced])
    err = np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max()
    assert err <= EPS + FLOAT_TOL


def test_a_frame_whose_allowance_is_spent_traces_the_rest_exactly(monkeypatch):
    # the allowance spent after the first chunk with cells: the rest of the frame is the
    # base tracer's (every pass: the ledger is the frame's)
    calls = []

    def once(self, rest):
        calls.append(rest)
        return min(rest, 1000) if len(calls) == 1 else 0

    monkeypatch.setattr(Budget, "chunk", once)
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3, samples=2)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    r.cache.fallback.ray_s = 1.0  # a dear ray: the chunk builds what it needs
    f = r.render(sc, st, accel)
    s = f.stats["fallback"]
    assert s["walked_rays"] == 1000 and s["probe_rays"] == 0
    assert f.stats["cells_built"] > 0
    base = _base(sc, accel, st)
    # pixels past the first 1000 of the first pass: traced in both samples, the base frame's
    rest = np.ones(sc.camera.width * sc.camera.height, bool)
    rest[:1000] = False
    rest = rest.reshape(f.pixel_class.shape)
    assert not (f.pixel_class[rest] == CLASS_INTERPOLATED).any()
    np.testing.assert_array_equal(f.radiance[rest], base.radiance[rest])
    err = np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max()
    assert err <= EPS + FLOAT_TOL


def test_a_pass_is_cut_for_good_only_when_no_saving_to_come_can_pay_a_walk():
    b = Budget(100_000, ray_s=1e-5)  # an allowance of ALLOWANCE * 1 s
    assert not b.spent_for_good(0)  # nothing spent yet
    b.spent = 2.0 * b.limit  # spent over it, nothing walked: no chunk walks again ...
    assert b.spent_for_good(0)
    # ... unless the later passes' reprojected samples may save it back
    back = int(2.0 * b.limit / (fallback.SAVE_SHARE * b.ray_s)) + 1
    assert not b.spent_for_good(back) and b.spent_for_good(back // 4)
    # after a walk: a chunk of CHUNK_MIN rays at the walk's cost per ray must be affordable
    b = Budget(100_000, ray_s=1e-5)
    b.walked, b.spent = 4096, 0.6 * b.limit  # 60% of the allowance for 4096 rays walked
    assert b.spent_for_good(0)  # 40% is left: 4096 more rays cost 60%
    b.spent = 0.25 * b.limit
    assert not b.spent_for_good(0)
    b.owed = 0.6 * b.limit  # the structures still owed count against it
    assert b.spent_for_good(0)
    assert not Budget(100_000).spent_for_good(0)  # not priced: never


def test_a_cut_first_pass_traces_the_rest_as_the_base_tracer(monkeypatch):
    # the ledger cuts the first pass (nothing reprojects: the first frame, the world
    # lights): the rest of the frame is traced in the base tracer's tiles, all samples of a
    # pixel together -- so its shadow-ray skips are proven over the same groups as the base
    # frame's, and it traces exactly the base frame's shadow rays (per pass, each pass's
    # groups held one sample of their pixels: other proofs, other rays, the same image)
    monkeypatch.setattr(Budget, "chunk", lambda self, rest: 0)
    monkeypatch.setattr(fallback, "ALLOWANCE", 0.0)  # nothing to spend: cut for good
    sc = scenes.build("studio", 64, 48)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3, samples=4,
                        light_samples=4)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    r.cache.fallback.ray_s = 1e-6  # priced: no first chunk traced to price a ray
    calls: list = []
    f = r.render(sc, st, accel, progress=lambda q, what: calls.append((q, what)))
    base = _base(sc, accel, st)
    # the progress follows the pixels: the passes (none of them here) to 0.05, the tail's
    # tiles on to 0.95 (not 95% for the passes, then the tail unreported)
    traced = [q for q, what in calls if what == "traced"]
    assert traced and traced == sorted(traced) and traced[-1] == pytest.approx(0.95)
    assert max(q for q, what in calls[:calls.index((traced[0], "traced"))]) <= 0.05
    assert f.stats["fallback"]["walked_rays"] == 0 and f.stats["cells_built"] == 0
    assert f.stats["fallback"]["tail_pixels"] == 64 * 48
    np.testing.assert_array_equal(f.radiance, base.radiance)
    np.testing.assert_array_equal(f.pixel_class, base.pixel_class)
    assert base.stats["shadow_rays_skipped"] > 0
    for key in ("shadow_rays", "shadow_rays_skipped", "secondary_rays"):
        assert f.stats[key] == base.stats[key], key
    assert f.stats["class_counts"]["traced"] + f.stats["class_counts"]["background"] == (
        4 * 64 * 48)


@pytest.mark.parametrize("tile_rays", [None, 1024])
@pytest.mark.parametrize("priced", [True, False])
def test_the_cut_tiles_closest_hits_are_not_traced_again(monkeypatch, priced, tile_rays):
    # the tile where the ledger cuts the first pass for good found the closest hits of all
    # its rays (one sample of its pixels); the tail traces every sample of the pixels from
    # the cut on, and takes those hits instead of tracing them again: the frame traces
    # exactly the base frame's closest-hit rays, and its image is the base frame's bit for
    # bit. Priced: cut at the tile's first ray (all of it found twice before); not priced:
    # cut after the first chunk (traced to price a ray), in the middle of the tile.
    monkeypatch.setattr(Budget, "chunk", lambda self, rest: 0)
    monkeypatch.setattr(fallback, "ALLOWANCE", 0.0)  # nothing to spend: cut for good
    monkeypatch.setattr(fallback, "CHUNK_MIN", 1000)
    if tile_rays is not None:  # tail tiles of 256 pixels: the handed hits span several
        monkeypatch.setattr(frame_parts, "TILE_RAYS", tile_rays)
    sc = scenes.build("studio", 64, 48)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3, samples=4,
                        light_samples=4)
    rays = [0]
    closest = accel.closest_hit

    def counted(o, *rest):
        rays[0] += len(o)
        return closest(o, *rest)

    monkeypatch.setattr(accel, "closest_hit", counted)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, accel)
    if priced:
        r.cache.fallback.ray_s = 1e-6  # priced: no first chunk traced to price a ray
    f = r.render(sc, st, accel)
    n_interp = rays[0]
    rays[0] = 0
    base = _base(sc, accel, st)
    tail = f.stats["fallback"]["tail_pixels"]
    assert tail == (64 * 48 if priced else 64 * 48 - 1000)
    np.testing.assert_array_equal(f.radiance, base.radiance)
    np.testing.assert_array_equal(f.pixel_class, base.pixel_class)
    # (before: the cut tile's rays after the cut, 3,072 or 2,072, traced twice)
    assert n_interp == rays[0]


def test_a_first_frame_prices_a_ray_with_its_first_chunk():
    sc = _scene(128, 96)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    f0 = r.render(sc, st, accel)
    k = 128 * 96
    s = f0.stats["fallback"]
    first = min(k, max(fallback.CHUNK_MIN, int(k * fallback.PRICE_SHARE)))
    assert s["probe_rays"] == first and s["ray_us"] > 0
    assert r.render(sc, st, accel).stats["fallback"]["probe_rays"] == 0  # priced: no probe
    base = _base(sc, accel, st)
    # the first chunk is the base tracer's: its pixels (the frame's first rows) traced
    rows = first // 128
    assert not (f0.pixel_class[:rows] == CLASS_INTERPOLATED).any()
    np.testing.assert_array_equal(f0.radiance[:rows], base.radiance[:rows])
    err = np.abs(image.to_display(f0.radiance) - image.to_display(base.radiance)).max()
    assert err <= EPS + FLOAT_TOL


def test_a_frame_whose_cells_do_not_pay_traces_every_object():
    # no object judged alone (too few rays each), but together their walk costs more than
    # the rays they interpolated saved
    n = fallback.MIN_RAYS // 4
    small = _costs([n] * 5, [n] * 5, [n // 10] * 5, [0] * 5, 1.0, 0.0, 1e-6)
    assert cells_pay(small).all() and not fallback.frame_pays(small)
    fb = Fallback(5)
    fb.learn(small, fb.frame_traced())
    assert fb.all_traced and not fb.traced.any()
    for _ in range(fallback.REPROBE_FRAMES):  # (the renderer counts its base frames)
        assert fb.whole_frame_traced()
        fb.frames_all += 1
    assert not fb.whole_frame_traced()  # the re-probe: every object with cells again
    cheap = small._replace(walk_s=0.0)
    fb.learn(cheap, fb.frame_traced())
    assert not fb.all_traced and not fb.whole_frame_traced()


def test_a_frame_that_did_not_pay_is_the_base_frame(monkeypatch):
    measured = FrameLedger.costs
    monkeypatch.setattr(FrameLedger, "costs",
                        lambda self, fb: measured(self, fb)._replace(walk_s=1.0, ray_s=1e-9))
    monkeypatch.setattr(fallback, "REPROBE_FRAMES", 2)
    monkeypatch.setattr(fallback, "MIN_RAYS", 1)
    # the first frame must walk its cells to be judged: a ledger that cut it short on a
    # loaded machine (its time allowance spent before a chunk walked) judged nothing (CI)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    r = InterpolantRenderer()
    frames = [r.render(sc, st, accel) for _ in range(4)]
    base = _base(sc, accel, st)
    assert [f.stats["fallback"]["all_traced"] for f in frames] == [True] * 4, \
        [f.stats["fallback"] for f in frames]
    for f in frames[1:3]:  # base frames, then the re-probe (with cells)
        np.testing.assert_array_equal(f.radiance, base.radiance)
        assert f.stats["cells_built"] == 0 and f.stats["epsilon"] == EPS
    assert "deferred_cells" in frames[3].stats["fallback"]
    assert frames[3].stats["fallback"]["build_budget_s"] is not None


def test_the_decision_is_reported_and_the_setting_turns_the_fallback_off(monkeypatch):
    measured = FrameLedger.costs
    monkeypatch.setattr(FrameLedger, "costs",
                        lambda self, fb: measured(self, fb)._replace(walk_s=1.0, ray_s=1e-9))
    monkeypatch.setattr(fallback, "MIN_RAYS", 1)
    # (the ledger never cuts the frame: its cut depends on the wall clock, under load too)
    monkeypatch.setattr(fallback, "ALLOWANCE", 1e9)
    sc = _scene()
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=EPS, max_depth=3)
    assert st.interpolant_fallback  # (the default)
    r = InterpolantRenderer()
    first = r.render(sc, st, accel)
    notes = first.stats["fallback_notes"]
    assert first.stats["fallback"]["all_traced"] and len(notes) == 1
    assert "cost more than they save" in notes[0] and "interpolant_fallback" in notes[0]
    assert r.render(sc, st, accel).stats["fallback_notes"] == notes  # (a base frame)
    off = r.render(sc, replace(st, interpolant_fallback=False), accel)
    assert "fallback" not in off.stats and "fallback_notes" not in off.stats
    assert off.stats["interpolated_fraction"] > 0.05
    fb = Fallback(3)
    assert fb.notes() == []  # cells everywhere: nothing to say
    fb.traced[1] = True
    assert fb.notes() and "1 object(s) traced" in fb.notes()[0]


def test_a_frame_the_ledger_cut_short_is_not_judged():
    # the whole frame's cells did not pay over the one chunk the ledger let them walk
    small = _costs([5000], [5000], [4000], [300], 0.001, 0.5, 1e-6)
    assert not fallback.frame_pays(small)
    fb = Fallback(1)
    fb.learn(small, fb.frame_traced(), cut=True)  # cut short: not judged, cells go on
    assert not fb.all_traced and not fb.traced.any() and fb.ray_s == 1e-6
    for _ in range(fallback.CUT_FRAMES - 2):
        fb.learn(small, fb.frame_traced(), cut=True)
        assert not fb.all_traced
    fb.learn(small, fb.frame_traced(), cut=True)  # CUT_FRAMES in a row: judged
    assert fb.all_traced and fb.whole_frame_traced()
    ok = Fallback(1)
    ok.learn(small, ok.frame_traced(), cut=True)
    ok.learn(small, ok.frame_traced())  # a frame not cut is judged at once
    assert ok.all_traced
    # a cut frame whose walk alone (builds left out) did not pay is judged at once
    walk = small._replace(walk_s=0.01, build_s=0.0)
    assert not fallback.frame_pays(walk)
    dear = Fallback(1)
    dear.learn(walk, dear.frame_traced(), cut=True)
    assert dear.all_traced


def test_a_build_is_paid_over_the_passes_it_serves():
    b = Budget(rays=4000, ray_s=1e-3, passes=4)  # a limit of ALLOWANCE * 4 s
    b.start_pass(0)
    assert b.charge(0.4, 10) == pytest.approx(0.3)  # pass 0 pays a quarter
    assert b.spent == pytest.approx(0.1) and b.build_s == pytest.approx(0.4)
    b.start_pass(1)
    assert b.spent == pytest.approx(0.2) and b.later == pytest.approx(0.2)
    assert b.charge(0.3, 5) == pytest.approx(0.2)  # pass 1 pays a third
    b.start_pass(2)
    b.start_pass(3)  # the last pass pays what is left: the frame has paid all its builds
    assert b.later == pytest.approx(0.0) and b.spent == pytest.approx(0.7)
    assert b.charge(0.1, 1) == 0.0 and b.spent == pytest.approx(0.8)
    one = Budget(rays=4000, ray_s=1e-3)  # one pass: a build is paid at once
    one.start_pass(0)
    assert one.charge(0.4, 10) == 0.0 and one.spent == pytest.approx(0.4)
    # but the frame owes a build whole at once, whichever pass pays it: what is left, and a
    # batch's size (cells at what they cost: CELL_RAYS rays, then measured), are the same
    # in a 4-pass frame's first pass as in a 1-pass frame (the shares put off counted)
    four, whole = Budget(10 ** 6, 1e-6, passes=4), Budget(10 ** 6, 1e-6)  # limits of 0.02 s
    four.start_pass(0)
    whole.start_pass(0)
    assert whole.batch(1000, 0) == 33 == four.batch(1000, 0)
    four.charge(0.004, 64)
    whole.charge(0.004, 64)
    assert four.spent == pytest.approx(0.001) and four.left() == pytest.approx(whole.left())
    assert abs(four.batch(10 ** 4, 0) - 256) <= 1 and abs(whole.batch(10 ** 4, 0) - 256) <= 1
    four.charge(0.0161, 1)  # the allowance owed: no more cells, no more walk in any pass
    assert four.spent < four.limit and not four.may_build(0) and four.chunk(10 ** 6) == 0


def test_a_chunk_is_sized_by_the_walk_not_the_builds():
    b = Budget(rays=10 ** 6, ray_s=1e-6)  # a limit of ALLOWANCE seconds
    b.start_pass(0)
    b.charge(0.015, 64)  # the first chunk's builds (they serve the chunks after it)
    b.spent += 0.001  # its walk
    b.walked = 4096
    # the allowance left (0.004 s) at the walk's 0.001 s per 4096 rays: 16384 rays
    assert abs(b.chunk(10 ** 6) - 16384) <= 1 and not b.cut
    b.spent += 0.004  # spent: the rest of the pass is traced
    assert b.chunk(10 ** 6) == 0 and b.cut


def test_builds_within_a_chunk_see_its_walk_so_far(monkeypatch):
    """A chunk's line coordinates and walk count against the budget while it builds (a
    first frame's first chunk built 20-33 cells on a walk that had spent its allowance)."""
    now = [0.0]
    monkeypatch.setattr(fallback, "CLOCK", lambda: now[0])
    b = Budget(rays=10 ** 6, ray_s=1e-6)  # a limit of ALLOWANCE seconds
    b.open()
    now[0] = 0.5 * fallback.ALLOWANCE  # half of it walked: half left, cells may be built
    assert b.left() == pytest.approx(0.5 * fallback.ALLOWANCE) and b.may_build(0)
    now[0] = 0.75 * fallback.ALLOWANCE  # a build took a quarter (charged: not counted twice)
    b.charge(0.25 * fallback.ALLOWANCE, 4)
    assert b.left() == pytest.approx(0.25 * fallback.ALLOWANCE)
    now[0] = 1.5 * fallback.ALLOWANCE  # the walk went on past the allowance: no more cells
    assert not b.may_build(0) and b.batch(64, 0) == 0
    b.close()  # (the chunk then books its time itself)
    assert b.left() == pytest.approx(0.75 * fallback.ALLOWANCE)
