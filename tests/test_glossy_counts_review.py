"""Review of session 43's glossy counts by lobe (issue 24): where a pixel's samples reach
points with different counts, the frames stay deterministic and mode-consistent (an
incremental frame after random edits, several pixel samples and Glossy Samples, equals a
fresh session's bit for bit), and each sample's points stay stratified and uniform."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.session import Session
from rstrace_engine.tracing import glossy_rays, glossy_strata


@pytest.mark.parametrize("scene_name", ["rough_room", "rough_soft_room"])
def test_random_edits_at_several_samples_stay_exact(scene_name):
    """Rough materials at 3 pixel samples and 3 glossy samples (a metal 6, the plastic
    1-6 by its view: a pixel's samples reach different counts): every incremental frame
    of a seeded edit sequence is a fresh session's bit for bit."""
    assert glossy_rays.LOBE_COUNTS
    settings = RenderSettings(mode="BASE", max_depth=3, samples=3, glossy_samples=3)
    gen = EditGenerator(SOAK_SCENES[scene_name](24, 18), seed=5)
    sess = Session(gen.scene.copy(), settings)
    sess.render()
    for _ in range(10):
        sess.apply(gen.step())
        frame = sess.render()
        fresh = Session(sess.scene.copy(), settings).render()
        assert np.array_equal(frame.radiance, fresh.radiance)


def test_a_pixels_samples_with_different_counts_stay_stratified_under_one_rotation():
    """Four samples of a pixel at one path with counts 1, 3, 2, 5 share one rotation, and
    each sample's lattice points (``(j + 0.5) / size``, j = s, s + S, ..., before the
    rotation) lie 1 / n apart, the first within ``(0, 1 / n]``: stratified within the
    sample. (That each point is uniform follows from the rotation being uniform; not
    checked here.)"""
    S = 4
    st = glossy_strata.pixel_strata(np.arange(S, dtype=np.int64) * 16 + 3, 16, 7, S)
    counts = np.array([1, 3, 2, 5])
    yes = np.ones(S, np.bool_)
    rows = glossy_strata.lattices(st, np.arange(S), np.ones(S, np.int64), yes, yes, counts)
    assert len(set(rows[:, 0].tolist())) == 1  # one rotation: the pixel's, at this path
    for s in range(S):
        j = rows[s, 1] + np.arange(counts[s]) * rows[s, 2]
        u = (j + 0.5) / float(rows[s, 3])
        assert np.allclose(np.diff(u), 1.0 / counts[s])
        assert 0.0 < u[0] <= 1.0 / counts[s]


@pytest.mark.parametrize("g", [1, 1024])
def test_counts_at_the_ends_of_glossy_samples_and_a_black_tint(g):
    """G = 1: a metal 2, a plastic 1 or 2; G = 1024 (the most): a metal 2048, a plastic at
    most 2048, their lattices ``S n`` without overflow; a plastic point whose layer's
    albedo is 0 (w = 0) draws one reflection; a black Specular Tint is no lobe (one pair,
    not glossy); a black base (d = 0, the layer all of the albedo) is no layer: 2 G."""
    from rstrace_engine import scenes
    from rstrace_engine.geometry.principled import principled_material

    sc = scenes.rough_materials(16, 12)
    black_tint, _ = principled_material("plastic_black_tint", (0.15, 0.3, 0.75),
                                        specular_tint=(0.0, 0.0, 0.0))
    black_base, _ = principled_material("plastic_black_base", (0.0, 0.0, 0.0))
    t = sc.add_material(black_tint)
    b = sc.add_material(black_base)
    sa = sc.arrays()
    # metal, plastic head on and grazing, glass, black tint, black base, plastic at E = 0
    mat = np.array([1, 3, 3, 2, t, b, 3])
    fresh = np.ones(len(mat), np.bool_)
    ediel = np.array([0.0, 0.04, 0.9, 0.0, 0.5, 0.0, 0.0])
    counts, glossy = glossy_rays.glossy_counts(sa, mat, fresh, g, ediel)
    assert list(glossy) == [True, True, True, True, False, True, True]
    assert counts.dtype == np.int64
    assert list(counts[[0, 3, 4, 5, 6]]) == [2 * g, g, 1, 2 * g, 1]
    assert 1 <= counts[1] <= counts[2] <= 2 * g and counts[2] > 1
    spp = 4096
    st = glossy_strata.pixel_strata(np.arange(len(mat), dtype=np.int64), 1, 0, spp)
    rows = glossy_strata.lattices(st, np.arange(len(mat)), np.ones(len(mat), np.int64),
                                  fresh, glossy, counts)
    assert list(rows[:, 3]) == list(np.where(glossy, spp * counts, 0))


def test_the_plastics_mixed_counts_are_unbiased(monkeypatch):
    """rough_materials at 4 pixel samples and 2 glossy samples: the plastic ball's points
    draw 1-4 reflections by their view, so a pixel's samples there meet different counts
    in one lattice rotation. Over seeds, the plastic's pixels' mean with the switch on
    minus off (the same camera samples) is within three standard errors of 0."""
    from rstrace_engine import scenes
    from rstrace_engine.accel.accelerators import create_accelerator
    from rstrace_engine.bench.frame_rough import material_cover
    from rstrace_engine.tracing import whitted

    sc = scenes.rough_materials(32, 24)
    acc = create_accelerator("BVH", sc.arrays())
    plastic = material_cover(sc, "plastic", RenderSettings(mode="BASE", max_depth=0), acc)
    plastic = plastic > 0.5
    assert plastic.sum() > 10
    d = []
    for seed in range(8):
        m = []
        for on in (True, False):
            monkeypatch.setattr(glossy_rays, "LOBE_COUNTS", on)
            st = RenderSettings(mode="BASE", max_depth=4, samples=4, glossy_samples=2,
                                seed=seed)
            m.append(whitted.render(sc, st, accel=acc).radiance[plastic].mean())
        d.append(m[0] - m[1])
    d = np.array(d)
    assert abs(d.mean()) <= 3.0 * d.std(ddof=1) / np.sqrt(len(d)) + 1e-12
    assert abs(d.mean()) < 0.01 * m[1]
