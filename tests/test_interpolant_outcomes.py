"""The per-cell outcome log and the per-pixel outcome diagnostics
(``scripts/interpolant_outcomes.py``)."""

from __future__ import annotations

import numpy as np
from repo_files import load_module

from rstrace_engine.interpolants.interpolant_cache import OUTCOMES


def _script():
    return load_module("scripts/interpolant_outcomes.py", "interpolant_outcomes")


def test_pixel_outcomes_agree_with_the_frame_and_its_cell_counts():
    mod = _script()
    # the measured fallback decides from timings (its ledger may trace a 96x72 frame whole,
    # building no cell: nothing to compare): off here
    grid, stats = mod.pixel_outcomes("museum_1999", 0.01, 6, 96, 72, fallback=False)
    names = (*OUTCOMES, *mod.EXTRA)
    assert grid.shape == (72, 96)
    assert grid.min() >= 0 and grid.max() < len(names)
    share = np.bincount(grid.reshape(-1), minlength=len(names)) / grid.size
    # interpolated pixels are exactly the frame's
    assert abs(share[names.index("interpolated")] - stats["interpolated_fraction"]) < 1e-12
    # every built cell got one outcome, the same the frame's stats count
    outcomes = stats["cell_outcomes"]
    assert sum(outcomes.values()) == stats["cells_built"]
    # a failed pixel names a failed cell (or a small one), never "valid" on this scene's
    # pixels unless its hit left the certified slab
    failed = [n for n in OUTCOMES if n != "valid" and share[names.index(n)] > 0]
    assert failed and all(outcomes.get(n, 0) > 0 for n in failed)


def test_corners_first_gives_the_same_frames_with_fewer_samples(monkeypatch):
    from rstrace_engine import scenes
    from rstrace_engine.accel.accelerators import create_accelerator
    from rstrace_engine.bench.trade import moved_cameras
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.interpolants import interpolant_cache as cache_mod
    from rstrace_engine.interpolants.render import InterpolantRenderer

    sc = scenes.build("museum_1999", 96, 72)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.01)
    cams = list(moved_cameras(sc).values())
    # the measured fallback decides from timings (it would make the two runs' frames differ
    # by what each machine moment measured): off here
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    runs = {}
    for on in (True, False):
        monkeypatch.setattr(cache_mod, "CORNERS_FIRST", on)
        r = InterpolantRenderer()
        frames = []
        for cam in cams:
            sc.set_camera(cam)
            frames.append(r.render(sc, st, accel))
        runs[on] = frames
    traced = {on: sum(f.stats["samples_traced"] for f in fr) for on, fr in runs.items()}
    assert traced[True] < traced[False]  # the path is taken: cells fail at their corners
    for a, b in zip(runs[True], runs[False], strict=True):
        assert np.array_equal(a.radiance, b.radiance)
        assert np.array_equal(a.pixel_class, b.pixel_class)
        assert a.stats["cell_outcomes"] == b.stats["cell_outcomes"]
        assert a.stats["cells_valid"] == b.stats["cells_valid"]
