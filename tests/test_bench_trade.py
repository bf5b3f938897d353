"""``python -m rstrace_engine.bench trade``'s measurement (a smoke test on a small view: the
rows, their keys and the bound; no times are asserted)."""

from __future__ import annotations

import math

from rstrace_engine.bench import trade
from rstrace_engine.frame import RenderSettings
from rstrace_engine.interpolants.render import InterpolantRenderer


def test_rows_carry_speedups_ceilings_and_the_bound(monkeypatch):
    # a 64 x 48 first frame is all the first chunk the fallback traces to price a ray: the
    # rows without it (cells wherever they may be) say what the columns are
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    d = RenderSettings()
    grid = trade.settings_grid(quick=True, spps=(1,), caps=(d.depth_cap, 5))
    # the quick sweep, and the cap rows other than the default's (which it already has)
    assert grid == [(0.0, d.depth_cap, d.memory_cap_mb, 1), (0.01, d.depth_cap,
                    d.memory_cap_mb, 1), (0.1, d.depth_cap, d.memory_cap_mb, 1),
                    (0.01, 5, d.memory_cap_mb, 1)]
    rows = trade.run_scene("museum_1999", 64, 48, 5, grid[:2], repeat=1)
    assert len(rows) == 2
    for r in rows:
        assert set(trade.JSON_KEYS) <= set(r)
        for key in ("first_frame_speedup", "camera_step_speedup", "pan_speedup",
                    "first_ceiling", "step_ceiling", "pan_ceiling"):
            assert math.isfinite(r[key]) and r[key] > 0, key
        assert r["n_over_epsilon"] == 0
    # epsilon 0 interpolates nothing: its frames are base frames
    assert rows[0]["interpolated_fraction"] == 0.0 and rows[0]["max_error"] == 0.0
    assert rows[1]["interpolated_fraction"] > 0.0
    assert "ceiling (first / step / pan)" in trade.markdown(rows, 64, 48)


def test_a_sequence_that_loads_a_kernel_is_timed_again(monkeypatch):
    # numba loading a kernel inside a timed frame is not the mode's cost (the bench warms
    # every kernel first): the sequence is run again, once, and the row says so
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    calls = {"counts": 0, "frames": 0}
    real_render = InterpolantRenderer.render

    def render(self, *a, **k):
        calls["frames"] += 1
        return real_render(self, *a, **k)

    def counts(since=None):
        calls["counts"] += 1
        return {"loaded": 3 if calls["counts"] == 1 else 0, "compiled": 0}

    monkeypatch.setattr(InterpolantRenderer, "render", render)
    monkeypatch.setattr(trade.kernel_cache, "counts", counts)
    d = RenderSettings()
    rows = trade.run_scene("museum_1999", 48, 36, 5, [(0.01, d.depth_cap, d.memory_cap_mb, 1)],
                           repeat=1)
    assert rows[0]["kernel_loads"] == 3
    assert calls["counts"] == 2  # the first sequence loaded: one more, and no more
    warm_frames = 3  # the small warm-up scene's three cameras
    assert calls["frames"] == warm_frames + 2 * 3


def test_a_kernel_that_loads_in_every_sequence_is_timed_after_one_rerun(monkeypatch):
    # a kernel that loads in every sequence is the mode's cost, not a warm-up left over: the
    # first sequence is run again, once, then the sequences are timed as they are (the
    # loop ends), and ``kernel_loads`` counts the loads and the compiles
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    calls = {"counts": 0}

    def counts(since=None):
        calls["counts"] += 1
        assert calls["counts"] <= 4, "the timed sequence is run again and again"
        return {"loaded": 2, "compiled": 1}

    monkeypatch.setattr(trade.kernel_cache, "counts", counts)
    d = RenderSettings()
    rows = trade.run_scene("museum_1999", 48, 36, 5, [(0.01, d.depth_cap, d.memory_cap_mb, 1)],
                           repeat=2)
    assert rows[0]["kernel_loads"] == 3
    assert calls["counts"] == 3  # one sequence run again, then the two timed
    assert math.isfinite(rows[0]["worst_speedup"])
