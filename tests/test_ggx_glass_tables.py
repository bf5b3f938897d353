"""The rough dielectric's albedo tables (``tracing/ggx_glass_tables.py``, written by
``scripts/ggx_glass_tables.py``): on the grid they are the 128 x 128 quadrature; between
grid points, at the indices and angles scenes use, the trilinear read stays within 1%."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import tolerances as tol
from rstrace_engine.tracing import glass_albedo as ga
from rstrace_engine.tracing import shading as sh
from rstrace_engine.tracing.ggx_glass_tables import GLASS_E, Z_MAX

NZ, NR, NC = GLASS_E.shape[1:]


@pytest.mark.parametrize("side", [0, 1])
@pytest.mark.parametrize("i, j, c", [(0, 0, 0), (3, 5, 17), (15, 15, 31), (6, 9, 1)])
def test_grid_points_are_the_quadrature(side, i, j, c):
    z = Z_MAX * i / (NZ - 1)
    k = (1.0 + z) / (1.0 - z)
    eta = 1.0 / k if side == 0 else k
    alpha = max((j / (NR - 1)) ** 2, tol.GLOSSY_ALPHA_MIN)
    co = max(c / (NC - 1), tol.GGX_COS_MIN)
    q = ga.ggx_glass_albedo_quadrature(co, alpha, eta, 128)
    assert GLASS_E[side, i, j, c] == pytest.approx(q, abs=1.0 / 65535.0)
    if 0 < c and 0 < j and i < NZ - 1:  # the read at a grid point is the entry
        assert sh.ggx_glass_albedo(co, alpha, eta) == pytest.approx(q, abs=2.0 / 65535.0)


@pytest.mark.parametrize("ior", [1.33, 1.45, 1.5, 2.42])
def test_between_grid_points_within_a_percent(ior):
    """Measured (3,000 random points, IOR 1.02-3, roughness 0.05-1, cos 0.02-1): largest
    relative error 3.1% (grazing cos < 0.03, or an index ratio under 1.1 near its critical
    angle), 99th percentile 0.84%, mean 0.12%; the 12 x 12 lattice the shader used before
    was off by up to 5.2%. Here: common indices, cos >= 0.05."""
    rng = np.random.default_rng(int(ior * 100))
    worst = 0.0
    for _ in range(60):
        co, r = rng.uniform(0.05, 1.0), rng.uniform(0.1, 1.0)
        for eta in (1.0 / ior, ior):
            q = ga.ggx_glass_albedo_quadrature(co, r * r, eta, 128)
            worst = max(worst, abs(sh.ggx_glass_albedo(co, r * r, eta) / q - 1.0))
    assert worst < 0.01, worst
