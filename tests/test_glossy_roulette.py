"""Russian roulette of the deeper rough bounces' weak rays (tracing/glossy_rays.roulette,
issue 24 session 33): unbiased, deterministic, cheaper, and nothing else changes."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine import tolerances as tol
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import glossy_rays, whitted
from rstrace_engine.tracing.shader import Spawned


def _kids(w):
    w = np.asarray(w, np.float64)
    m = len(w)
    return Spawned(np.zeros((m, 3)), np.zeros((m, 3)), w.copy(), np.ones(m, np.bool_))


def test_weak_rays_go_on_with_their_probability_and_carry_its_inverse():
    """Over many points (deterministic seeds) a ray carrying ``r`` of its point's weight
    goes on in a fraction ``r / GLOSSY_ROULETTE_REL`` of them with weight divided by that
    (the expected weight unchanged); a ray at or above the fraction, a first rough bounce
    (``fresh``) and a point that is not rough are untouched."""
    n = 4000
    rel = tol.GLOSSY_ROULETTE_REL
    r = 0.2 * rel  # the weak ray: goes on 20% of the time
    w = np.tile([[r, 0.5 * r, 0.1 * r], [1.5 * rel, rel, 0.0]], (n, 1))
    weight = np.ones((n, 3))
    gstart = np.arange(n + 1, dtype=np.int64)
    seeds = np.arange(n, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    glossy = np.ones(n, np.bool_)
    fresh = np.zeros(n, np.bool_)
    fresh[:10] = True
    glossy[10:20] = False
    kids = _kids(w)
    glossy_rays.roulette(gstart, glossy, fresh, seeds, weight, kids)
    weak, strong = np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)
    assert kids.ok[strong].all() and np.array_equal(kids.w[strong], w[strong])
    assert kids.ok[weak[:20]].all() and np.array_equal(kids.w[weak[:20]], w[weak[:20]])
    live = kids.ok[weak[20:]]
    assert abs(live.mean() - 0.2) < 4.0 * np.sqrt(0.2 * 0.8 / (n - 20))
    assert np.allclose(kids.w[weak[20:]][live], w[weak[20:]][live] / 0.2)
    # the expected weight: the survivors' sum over the points, as the weights' sum
    total = kids.w[weak[20:]][live].sum(axis=0)
    assert np.allclose(total, w[weak[20:]].sum(axis=0), rtol=0.1)
    # deterministic: the same draws again
    again = _kids(w)
    glossy_rays.roulette(gstart, glossy, fresh, seeds, weight, again)
    assert np.array_equal(again.ok, kids.ok) and np.array_equal(again.w, kids.w)


def _glass_balls(seed, roulette, monkeypatch, glossy_samples=8):
    monkeypatch.setattr(glossy_rays, "ROULETTE", roulette)
    sc = scenes.rough_materials(40, 30)
    st = RenderSettings(mode="BASE", max_depth=5, glossy_samples=glossy_samples, seed=seed)
    return whitted.render(sc, st, accel=create_accelerator("BVH", sc.arrays()))


def test_roulette_is_unbiased_and_cheaper(monkeypatch):
    """rough_materials (a rough glass ball, its internal reflections the weak rays): per
    seed the frame with the roulette against the one without it (the same first-bounce
    samples), their mean differences over the seeds within three standard errors of 0 and
    the means within 0.5%; fewer secondary and shadow rays with it; a seed's frame is the
    same bit for bit when rendered again."""
    on, off, rays = [], [], []
    for seed in range(6):
        a = _glass_balls(seed, True, monkeypatch)
        b = _glass_balls(seed, False, monkeypatch)
        on.append(a.radiance.astype(np.float64))
        off.append(b.radiance.astype(np.float64))
        rays.append((a.stats["secondary_rays"], b.stats["secondary_rays"],
                     a.stats["shadow_rays"], b.stats["shadow_rays"]))
    rays = np.array(rays)
    assert (rays[:, 0] < 0.8 * rays[:, 1]).all() and (rays[:, 2] < rays[:, 3]).all()
    on, off = np.stack(on), np.stack(off)
    assert abs(on.mean() / off.mean() - 1.0) < 0.005
    d = (on - off).mean(axis=(1, 2, 3))  # per seed: the frames' difference in mean
    assert abs(d.mean()) <= 3.0 * d.std(ddof=1) / np.sqrt(len(d)) + 1e-12
    again = _glass_balls(0, True, monkeypatch)
    assert np.array_equal(again.radiance, on[0].astype(again.radiance.dtype))


@pytest.mark.parametrize("switch", ["ROULETTE", "LOBE_COUNTS"])
@pytest.mark.parametrize("name", ["three_spheres", "glass_horizon", "studio"])
def test_scenes_without_rough_surfaces_trace_what_they_traced(name, switch, monkeypatch):
    """Mirrors, sharp glass and soft light only: neither the roulette (it takes a deeper
    rough bounce's rays) nor the counts by lobe (a first rough bounce's) touch their rays."""
    sc = scenes.build(name, 40, 30)
    st = RenderSettings(mode="BASE", max_depth=5, samples=2, light_samples=4)
    frames = []
    for on in (True, False):
        monkeypatch.setattr(glossy_rays, switch, on)
        frames.append(whitted.render(sc, st))
    assert np.array_equal(frames[0].radiance, frames[1].radiance)
    for k in ("secondary_rays", "shadow_rays"):
        assert frames[0].stats[k] == frames[1].stats[k]
