"""The pure helpers of ``scripts/rough_equal_time.py --own-reference`` (issue 24, session 35):
Mitsuba's error read from a power-law fit, means and ratios with standard errors."""

from __future__ import annotations

import numpy as np
import pytest
from repo_files import load_module


def _script():
    return load_module("scripts/rough_equal_time.py", "rough_equal_time")


def test_power_fit_recovers_a_power_law_and_reads_it_between_and_beyond_the_points():
    mod = _script()
    spps = (12, 16, 24, 32, 48, 64, 96)
    errs = [0.2 * s ** -0.45 for s in spps]
    fit = mod.power_fit(spps, errs)
    assert fit[0] == pytest.approx(-0.45, abs=1e-12)
    assert fit[1] == pytest.approx(np.log(0.2), abs=1e-12)
    for spp in (20.5, 103.0, 200.0):
        assert mod.power_at(fit, spp) == pytest.approx(0.2 * spp ** -0.45, rel=1e-12)


def test_mean_se_and_ratio_se():
    mod = _script()
    m, se = mod.mean_se([1.0, 2.0, 3.0, 4.0])
    assert m == 2.5
    assert se == pytest.approx(np.std([1, 2, 3, 4], ddof=1) / 2.0)
    assert mod.mean_se([5.0]) == (5.0, 0.0)
    r, rse = mod.ratio_se((2.0, 0.2), (1.0, 0.05))
    assert r == 2.0
    assert rse == pytest.approx(2.0 * np.hypot(0.1, 0.05))
    assert mod.ratio_se((3.0, 0.0), (1.5, 0.0)) == (2.0, 0.0)
