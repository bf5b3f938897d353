"""A first rough bounce's glossy samples at an interface follow one of their reflected and
refracted rays, chosen by their weights (tracing/glossy_rays.first_choice, issue 24
session 35): one ray per sample, unbiased, stratified, deterministic; nothing else changes."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import glossy_rays, whitted
from rstrace_engine.tracing.glossy_strata import no_strata
from rstrace_engine.tracing.shader import Spawned


def _kids(w, ok=None):
    w = np.asarray(w, np.float64)
    m = len(w)
    ok = np.ones(m, np.bool_) if ok is None else np.asarray(ok, np.bool_)
    return Spawned(np.zeros((m, 3)), np.zeros((m, 3)), w.copy(), ok.copy())


def test_each_sample_follows_one_ray_in_proportion_to_its_weight():
    """Points of 16 samples, each a reflection carrying 0.05 and a refraction 0.95: every
    pair keeps exactly one ray, its weight the pair's divided by its probability; the
    reflections' share over a point's 16 samples is stratified (0 or 1 of them, never
    more), 5% over all points; a deeper bounce (not ``fresh``), a point that is not rough
    and a pair with one ray are untouched; the same draws again."""
    n, g = 400, 16
    pair = [[0.05, 0.04, 0.03], [0.95, 0.9, 0.8]]
    w = np.tile(pair, (n * g, 1))
    ok = np.ones(2 * n * g, np.bool_)
    ok[2 * g * 5 + 1] = False  # point 5, sample 0: a total internal reflection, no refraction
    gstart = np.arange(0, n * g + 1, g, dtype=np.int64)
    seeds = np.arange(n, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    glossy = np.ones(n, np.bool_)
    fresh = np.ones(n, np.bool_)
    fresh[:3] = False
    glossy[3:5] = False
    kids = _kids(w, ok)
    glossy_rays.first_choice(gstart, glossy, fresh, seeds, no_strata(n), kids)
    rows = np.arange(5 * 2 * g)  # points 0-4: untouched
    assert np.array_equal(kids.ok[rows], ok[rows]) and np.array_equal(kids.w[rows], w[rows])
    assert kids.ok[2 * g * 5] and np.array_equal(kids.w[2 * g * 5], w[2 * g * 5])
    refl = kids.ok[0::2].reshape(n, g)[6:]
    refr = kids.ok[1::2].reshape(n, g)[6:]
    assert (refl ^ refr).all()  # one ray per sample
    per_point = refl.sum(axis=1)
    assert per_point.max() <= 1  # 16 x 0.05 = 0.8: stratified, never two
    assert abs(refl.mean() - 0.05) < 0.01
    wr = kids.w[0::2].reshape(n, g, 3)[6:][refl]
    wt = kids.w[1::2].reshape(n, g, 3)[6:][refr]
    assert np.allclose(wr, np.array(pair[0]) / 0.05) and np.allclose(wt, np.array(pair[1]) / 0.95)
    again = _kids(w, ok)
    glossy_rays.first_choice(gstart, glossy, fresh, seeds, no_strata(n), again)
    assert np.array_equal(again.ok, kids.ok) and np.array_equal(again.w, kids.w)


def _balls(seed, on, monkeypatch, samples=1):
    monkeypatch.setattr(glossy_rays, "FIRST_CHOICE", on)
    sc = scenes.rough_materials(40, 30)
    st = RenderSettings(mode="BASE", max_depth=5, samples=samples, glossy_samples=8, seed=seed)
    return whitted.render(sc, st, accel=create_accelerator("BVH", sc.arrays()))


@pytest.mark.parametrize("samples", [1, 2])
def test_choice_is_unbiased_and_cheaper(samples, monkeypatch):
    """rough_materials (a rough glass ball: its first interface reflects a few percent):
    per seed the frame with the choice against the one without (at 2 pixel samples the
    choice reads the pixel's lattice), their mean differences over 12 seeds within three
    standard errors of 0 and the means within 0.5%; fewer secondary and shadow rays with
    it; a seed's frame is the same bit for bit when rendered again. (Seeds 0-5 alone put
    the mean difference, 0.02% of the frame's, at 2.8 standard errors: over 24 seeds it
    is 0.015%, 1.0 standard error.)"""
    on, off, rays = [], [], []
    for seed in range(12):
        a = _balls(seed, True, monkeypatch, samples)
        b = _balls(seed, False, monkeypatch, samples)
        on.append(a.radiance.astype(np.float64))
        off.append(b.radiance.astype(np.float64))
        rays.append((a.stats["secondary_rays"], b.stats["secondary_rays"],
                     a.stats["shadow_rays"], b.stats["shadow_rays"]))
    rays = np.array(rays)
    assert (rays[:, 0] < 0.95 * rays[:, 1]).all() and (rays[:, 2] < rays[:, 3]).all()
    on, off = np.stack(on), np.stack(off)
    assert abs(on.mean() / off.mean() - 1.0) < 0.005
    d = (on - off).mean(axis=(1, 2, 3))
    assert abs(d.mean()) <= 3.0 * d.std(ddof=1) / np.sqrt(len(d)) + 1e-12
    again = _balls(0, True, monkeypatch, samples)
    assert np.array_equal(again.radiance, on[0].astype(again.radiance.dtype))


@pytest.mark.parametrize("name", ["studio", "three_spheres", "glass_horizon"])
def test_scenes_without_rough_glass_trace_what_they_traced(name, monkeypatch):
    """Soft light, mirrors and sharp glass (no glossy samples), as the roulette's test: the
    choice touches none of their rays."""
    sc = scenes.build(name, 40, 30)
    st = RenderSettings(mode="BASE", max_depth=5, samples=2, light_samples=4)
    frames = []
    for on in (True, False):
        monkeypatch.setattr(glossy_rays, "FIRST_CHOICE", on)
        frames.append(whitted.render(sc, st))
    assert np.array_equal(frames[0].radiance, frames[1].radiance)
    for k in ("secondary_rays", "shadow_rays"):
        assert frames[0].stats[k] == frames[1].stats[k]
