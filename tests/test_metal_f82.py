"""Cycles' F82-tint conductor Fresnel (issue 23): the Principled BSDF's metallic part with its
Specular Tint, a Metallic BSDF's Edge Tint, and its Physical Conductor as the F82 fit
(geometry/principled.py, tracing/shading.py). Against Cycles: tests/blender (the feature
corpus's metal rows)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tracer_scenes import plane_scene

from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.geometry.principled import (
    conductor_f82,
    conductor_fresnel,
    principled_material,
)
from rstrace_engine.tracing import whitted
from rstrace_engine.tracing.shading import f82_metal

S5 = (6.0 / 7.0) ** 5


def _schlick(c, f0):
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def _f82_reference(c, f0, tint):
    """Cycles' fresnel_f82tint_B and fresnel_f82, written out."""
    f = 6.0 / 7.0
    b = (f0 + (1.0 - f0) * f ** 5) * (7.0 / f ** 6) * (1.0 - tint)
    s = 1.0 - c
    return min(max(f0 + (1.0 - f0) * s ** 5 - b * c * s ** 6, 0.0), 1.0)


@pytest.mark.parametrize("f0", [0.0, 0.3, 0.9, 1.0])
@pytest.mark.parametrize("tint", [0.0, 0.4, 1.0])
def test_f82_curve_is_cycles(f0, tint):
    cs = np.linspace(0.0, 1.0, 57)
    got = np.array([f82_metal(c, f0, tint) for c in cs])
    want = np.array([_f82_reference(c, f0, tint) for c in cs])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # the tint is the ratio to Schlick's value at cos = 1/7; white tint is Schlick exactly
    if tint > 0.0 or f0 < 1.0:
        assert f82_metal(1.0 / 7.0, f0, tint) == pytest.approx(tint * _schlick(1 / 7, f0),
                                                               abs=1e-12)
    if tint == 1.0:  # (the operations of the old Schlick expression: bit for bit)
        x = 1.0 - cs
        np.testing.assert_array_equal(got, f0 + (1.0 - f0) * (x * x * x * x * x))


def test_conductor_fit_is_close_to_the_exact_fresnel():
    metals = {"gold": ((0.18, 0.42, 1.37), (3.42, 2.35, 1.77)),
              "copper": ((0.27, 0.68, 1.22), (3.61, 2.62, 2.29)),
              "aluminium": ((1.35, 0.96, 0.62), (7.47, 6.40, 5.30)),
              "iron": ((2.91, 2.95, 2.59), (3.08, 2.93, 2.77))}
    cs = np.linspace(0.0, 1.0, 201)
    for name, (n, k) in metals.items():
        f0, tint = conductor_f82(n, k)
        np.testing.assert_allclose(f0, conductor_fresnel(1.0, n, k), rtol=1e-12)
        for i in range(3):
            exact = conductor_fresnel(cs, n[i], k[i])
            fit = np.array([f82_metal(c, f0[i], tint[i]) for c in cs])
            assert f82_metal(1 / 7, f0[i], tint[i]) == pytest.approx(
                conductor_fresnel(1 / 7, n[i], k[i]), abs=1e-12)
            assert np.abs(fit - exact).max() < 0.025, name
    # a dielectric-like conductor (k = 0): the normal-incidence Fresnel of n
    f0, _ = conductor_f82((1.5, 1.5, 1.5), (0.0, 0.0, 0.0))
    np.testing.assert_allclose(f0, 0.04, rtol=1e-12)


def test_tinted_mirror_metal_reflects_the_f82_curve():
    """A mirror metal floor under a white world seen at cos = 1/7 and at 0.5: the reflected
    world times the F82 curve of its colour and Specular Tint."""
    base, tint = (0.9, 0.6, 0.3), (0.2, 0.5, 1.0)
    mat, _ = principled_material("metal", base, metallic=1.0, roughness=0.0,
                                 specular_tint=tint)
    assert mat.metal_tint == tint
    s = plane_scene(mat, [], world=(1.0, 1.0, 1.0))
    sa = s.arrays()
    acc = create_accelerator("BRUTE_FORCE", sa)
    for c in (1.0 / 7.0, 0.5):
        d = np.array([math.sqrt(1.0 - c * c), 0.0, -c])
        o = -3.0 * d
        rad, _ = whitted.trace(sa, acc, o[None], d[None], 0.0, np.inf, 1)
        want = [_f82_reference(c, f, t) for f, t in zip(base, tint, strict=True)]
        np.testing.assert_allclose(rad[0], want, rtol=1e-9)
    white, _ = principled_material("metal", base, metallic=1.0, roughness=0.0)
    assert white.metal_tint == (1.0, 1.0, 1.0)
