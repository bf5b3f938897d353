"""What a user sees in RI_TREE mode at the default settings (issue 22): glass and a mirror
before a horizon, the largest display error against the base frame and the pixels over 0.1
bounded (not only the mean), and seed 004's tests alone shown to miss what the exit-ray test
sees."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import image, scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.ri_tree import tree_cache as ri_cache
from rstrace_engine.ri_tree.render import RITreeRenderer
from rstrace_engine.tracing.whitted import render

W, H = 160, 120


@pytest.fixture(autouse=True)
def _interpolate_all(monkeypatch):
    # the trees are measured, not the fallback's decision; and the cost rule's counts for a
    # frame this small (the defaults would leave most leaves unevaluated and their rays
    # traced: exact, and no test of the interpolation)
    monkeypatch.setattr(RITreeRenderer, "auto_fallback", False)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES", 4)
    monkeypatch.setattr(ri_cache, "SPLIT_QUERIES_MIXED", 16)


@pytest.fixture(scope="module")
def horizon():
    """The glass sphere, glass torus and chrome ball before a horizon, and its base frame."""
    sc = scenes.glass_horizon(W, H)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(max_depth=5)
    return sc, accel, st, render(sc, st, accel=accel)


def _errors(sc, accel, st, base, frames=2):
    r = RITreeRenderer()
    for _ in range(frames):  # the second frame: the trees kept (as a session)
        f = r.render(sc, replace(st, mode="RI_TREE"), accel)
    px = np.abs(image.to_display(f.radiance) - image.to_display(base.radiance)).max(axis=-1)
    return px, f


def test_defaults_show_no_artifact_on_glass_and_a_mirror_before_a_horizon(horizon):
    sc, accel, st, base = horizon
    px, f = _errors(sc, accel, st, base)
    interp = f.pixel_class == CLASS_INTERPOLATED
    # much of the glass and the mirror is interpolated: the bound is about interpolation
    # (0.7% of the frame, 134 pixels, at the 0.025 degree default: the cells still off at
    # the depth constraint and those where the torus's exit rays meet it again on one side
    # are traced; 2.2% at 0.05 degrees, over 5% at 0.1 degrees before they were); the
    # continuation check (ri_tree.recheck) then traces again the 48 pixels whose
    # neighbourhood meets different things behind the glass, 0.45% stay interpolated
    assert interp.mean() + f.stats["retraced_pixels"] / interp.size > 0.005, interp.mean()
    assert interp.mean() > 0.001, interp.mean()
    assert px.max() <= 0.1, f"max display error {px.max():.3f}"
    assert np.count_nonzero(px > 0.1) == 0
    assert np.count_nonzero(px > 0.05) <= 5, np.count_nonzero(px > 0.05)
    assert np.quantile(px, 0.999) <= 0.03


def test_the_papers_tests_alone_miss_the_exit_rays_error(horizon):
    """The paper's settings stay reachable (the exit-ray test off), and on this scene they
    show the error the exit-ray test bounds: the bound above is not a property of the scene."""
    sc, accel, st, base = horizon
    px, _ = _errors(sc, accel, replace(st, ri_probe_angle=0.0), base)
    assert px.max() > 0.2 and np.count_nonzero(px > 0.1) >= 5, (
        px.max(), np.count_nonzero(px > 0.1))


def test_defaults_bound_the_tomatoes():
    """Seed 004's tomatoes at 200x150 (a mirror bowl, seen through a wrap that does not
    refract, reflecting the tomatoes in it and its own rim), two frames with the trees kept:
    at the defaults no pixel over 0.1 (measured 0.015); the paper's tests alone leave
    hundreds (measured 0.78, 269 pixels)."""
    sc = scenes.tomatoes(200, 150)
    accel = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(max_depth=5)
    base = render(sc, st, accel=accel)
    px, f = _errors(sc, accel, st, base)
    assert px.max() <= 0.1, f"max display error {px.max():.3f}"
    assert np.quantile(px, 0.999) <= 0.01
    assert f.stats["interpolated_fraction"] > 0.0
    px, _ = _errors(sc, accel, replace(st, ri_probe_angle=0.0), base)
    assert px.max() > 0.3 and np.count_nonzero(px > 0.1) >= 50
