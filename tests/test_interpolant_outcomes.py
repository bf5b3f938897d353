"""The per-cell outcome log and the per-pixel outcome diagnostics
(``scripts/interpolant_outcomes.py``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from rstrace_engine.interpolants.cache import OUTCOMES

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location(
        "interpolant_outcomes", ROOT / "scripts" / "interpolant_outcomes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pixel_outcomes_agree_with_the_frame_and_its_cell_counts():
    mod = _script()
    grid, stats = mod.pixel_outcomes("museum_1999", 0.01, 6, 96, 72)
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
