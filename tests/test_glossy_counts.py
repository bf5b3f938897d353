"""Glossy samples by lobe (tracing/glossy_rays.glossy_counts, issue 24 session 43): a path's
first rough bounce on a lobe without transmission draws ``ceil(2 G sqrt(w))`` reflections
(a metal 2 G, a plastic by its layer's share of the albedo), a transmissive one G pairs;
unbiased, deterministic, and scenes without rough surfaces trace what they traced."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.tracing import glossy_rays, glossy_strata, whitted

# rough_materials' materials: 0 floor (matte), 1 metal, 2 glass, 3 plastic, 4 red (matte)
FLOOR, METAL, GLASS, PLASTIC, RED = range(5)


@pytest.mark.parametrize("lobes", [True, False])
def test_counts_by_lobe(lobes, monkeypatch):
    """Fresh points: the metal 2 G, the glass G pairs, the plastic ``ceil(2 G sqrt(w))``
    with ``w = E / (E + (1 - E) d)`` (its layer's albedo E toward the viewer, its diffuse
    albedo's largest channel d), a NaN albedo as w = 1; matte points and misses 1; a deeper
    bounce 1 whatever its lobe. Without the switch every fresh glossy point draws G."""
    monkeypatch.setattr(glossy_rays, "LOBE_COUNTS", lobes)
    sa = scenes.rough_materials(16, 12).arrays()
    mat = np.array([FLOOR, METAL, GLASS, PLASTIC, PLASTIC, PLASTIC, RED, -1, METAL, PLASTIC])
    fresh = np.array([True] * 8 + [False, False])
    ediel = np.array([0.0, 0.0, 0.0, 0.05, 0.5, np.nan, 0.0, 0.0, 0.0, 0.05])
    g = 4
    counts, glossy = glossy_rays.glossy_counts(sa, mat, fresh, g, ediel)
    assert list(glossy) == [False, True, True, True, True, True, False, False, True, True]
    d = 0.75  # the plastic's largest diffuse channel (0.15, 0.3, 0.75)

    def layer(e):
        return math.ceil(2 * g * math.sqrt(e / (e + (1 - e) * d)))

    if lobes:
        want = [1, 2 * g, g, layer(0.05), layer(0.5), 2 * g, 1, 1, 1, 1]
        assert want[3] < g < want[4] < 2 * g  # (the plastic: fewer head on, more at grazing)
    else:
        want = [1, g, g, g, g, g, 1, 1, 1, 1]
    assert counts.dtype == np.int64 and list(counts) == want


def test_lattices_of_per_point_counts():
    """A first bounce drawing n samples at pixel sample s of S takes the points s, s + S,
    ..., s + (n - 1) S of a lattice of S n (each count its own lattice size); one int for
    all is the count of every point; either way one kernel signature."""
    st = glossy_strata.pixel_strata(np.array([0, 64, 128, 192], np.int64) + 5, 64, 0, 4)
    src = np.arange(4)
    path = np.ones(4, np.int64)
    yes = np.ones(4, np.bool_)
    out = glossy_strata.lattices(st, src, path, yes, yes, np.array([1, 3, 8, 2]))
    assert list(out[:, 1]) == [0, 1, 2, 3] and (out[:, 2] == 4).all()
    assert list(out[:, 3]) == [4, 12, 32, 8]
    same = glossy_strata.lattices(st, src, path, yes, yes, 3)
    assert (same[:, 3] == 12).all() and np.array_equal(same[:, :3], out[:, :3])
    # one compiled signature whatever the counts came as (an array passed on as it is,
    # never a read-only view: a second signature, a compile the warm-up does not make)
    assert len(glossy_strata._lattices.signatures) == 1


def _frame(seed, lobes, monkeypatch, size=(40, 30), samples=2, glossy_samples=4):
    monkeypatch.setattr(glossy_rays, "LOBE_COUNTS", lobes)
    sc = scenes.rough_materials(*size)
    st = RenderSettings(mode="BASE", max_depth=5, samples=samples,
                        glossy_samples=glossy_samples, seed=seed)
    return whitted.render(sc, st, accel=create_accelerator("BVH", sc.arrays()))


def test_lobe_counts_are_unbiased_and_deterministic(monkeypatch):
    """rough_materials per seed with the switch on and off (the camera samples the same,
    the glossy samples other): the frames' mean differences over the seeds within three
    standard errors of 0 and the means within 0.5%; with the switch more secondary rays
    (the metal's doubled, more than the plastic's fewer); a seed's frame the same bit for
    bit when rendered again."""
    on, off, rays = [], [], []
    for seed in range(6):
        a = _frame(seed, True, monkeypatch)
        b = _frame(seed, False, monkeypatch)
        on.append(a.radiance.astype(np.float64))
        off.append(b.radiance.astype(np.float64))
        rays.append((a.stats["secondary_rays"], b.stats["secondary_rays"]))
    rays = np.array(rays)
    assert (rays[:, 0] > rays[:, 1]).all()
    on, off = np.stack(on), np.stack(off)
    assert not np.array_equal(on, off)
    assert abs(on.mean() / off.mean() - 1.0) < 0.005
    d = (on - off).mean(axis=(1, 2, 3))
    assert abs(d.mean()) <= 3.0 * d.std(ddof=1) / np.sqrt(len(d)) + 1e-12
    again = _frame(0, True, monkeypatch)
    assert np.array_equal(again.radiance, on[0].astype(again.radiance.dtype))


def test_lobe_counts_lower_the_metal_balls_noise(monkeypatch):
    """The metal ball's pixels (those wholly on it) vary less over seeds with the switch
    (twice its reflections: below 0.75 of the variance without), the glass ball's about as
    much (its count unchanged: above 0.7 of it, 8 seeds' noise)."""
    from rstrace_engine.bench.frame_rough import material_cover

    sc = scenes.rough_materials(40, 30)
    acc = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="BASE", max_depth=0)
    metal = material_cover(sc, "metal", st, acc) > 0.999
    glass = material_cover(sc, "glass", st, acc) > 0.999
    assert metal.sum() > 20 and glass.sum() > 20
    var = {}
    for lobes in (True, False):
        f = np.stack([_frame(s, lobes, monkeypatch, samples=1, glossy_samples=2)
                      .radiance.astype(np.float64).mean(axis=2) for s in range(8)])
        v = f.var(axis=0, ddof=1)
        var[lobes] = (v[metal].mean(), v[glass].mean())
    assert var[True][0] < 0.75 * var[False][0]
    assert var[True][1] > 0.7 * var[False][1]
