"""Glossy samples stratified across a pixel's samples and a first rough bounce's siblings
(issue 24, session 34; tracing/glossy_strata.py, docs/glossy.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Scene
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.scenes import _camera
from rstrace_engine.tracing import glossy_rays, whitted
from rstrace_engine.tracing import glossy_strata as gs
from rstrace_engine.tracing.soft_lights import sample_seeds

ROUGHNESS = 0.2  # alpha 0.04: a head-on view's reflections all leave above the plane


def _plane() -> Scene:
    s = Scene()
    mat, _ = principled_material("metal", (0.9, 0.9, 0.9), metallic=1.0, roughness=ROUGHNESS)
    s.add_instance(s.add_mesh(shapes.plane(40.0)), np.eye(4), [s.add_material(mat)],
                   name="Plane")
    s.set_world_color((0.5, 0.5, 0.5), lights=False)
    s.set_camera(_camera((0.0, -4.0, 3.0), (0.0, 0.0, 0.0), 8, 8))
    return s


def _first_bounce_u(spp: int, glossy: int, strata: bool, pixel: int = 7):
    """The lattice coordinate ``u1`` (``ggx_sampling.ggx_vndf``'s radius squared) of every
    first-bounce ray of one pixel's ``spp`` samples, each looking straight down at a rough
    metal plane (the local view is the normal: the microfacet normal ``h`` of a reflection
    gives ``u1 = sin^2 / (alpha^2 cos^2 + sin^2)`` exactly)."""
    sc = _plane()
    sa = sc.arrays()
    acc = create_accelerator("BVH", sa)
    o = np.tile([[0.0, 0.0, 2.0]], (spp, 1)) + np.arange(spp)[:, None] * [1e-3, 0.0, 0.0]
    d = np.tile([[0.0, 0.0, -1.0]], (spp, 1))
    gids = np.arange(spp, dtype=np.int64) * 64 + pixel
    st = gs.pixel_strata(gids, 64, 5, spp) if strata else None
    segs: list = []
    whitted.trace(sa, acc, o, d, 0.0, np.inf, 1, segments=segs, seeds=sample_seeds(gids, 5),
                  glossy_samples=glossy, strata=st)
    wi = segs[1]["dir"]
    h = wi + np.array([0.0, 0.0, 1.0])
    h /= np.linalg.norm(h, axis=1)[:, None]
    c2 = h[:, 2] ** 2
    alpha = ROUGHNESS ** 2
    return (1.0 - c2) / (alpha * alpha * c2 + 1.0 - c2), segs[1]["ray"]


def _spread(x: np.ndarray) -> float:
    """Circular spread of values in [0, 1): 1 minus the largest gap between neighbours."""
    x = np.sort(np.mod(x, 1.0))
    gaps = np.diff(np.concatenate([x, x[:1] + 1.0]))
    return float(1.0 - gaps.max())


@pytest.mark.parametrize("lobes", [True, False])
@pytest.mark.parametrize("spp,glossy", [(4, 4), (8, 1), (2, 8)])
def test_a_pixels_samples_draw_one_lattice_jointly(spp, glossy, lobes, monkeypatch):
    """A pixel's S samples' G glossy rays each at its first rough bounce are the N = S G
    points of one rotated lattice: ``u1 N`` has the same fraction for every ray (the u1 lie
    1 / N apart), and each sample holds G of them (2 G on this rough metal plane with
    ``LOBE_COUNTS``, N = 2 S G). Without strata (main: each sample's own lattice of G,
    rotated by its own seed) they do not. Fails on main (no strata)."""
    monkeypatch.setattr(glossy_rays, "LOBE_COUNTS", lobes)
    k = 2 * glossy if lobes else glossy  # each sample's reflections
    n = spp * k
    u, ray = _first_bounce_u(spp, glossy, True)
    assert len(u) == n and np.array_equal(np.bincount(ray, minlength=spp), [k] * spp)
    assert _spread(u * n) < 1e-6
    u0, _ = _first_bounce_u(spp, glossy, False)
    assert len(u0) == n and _spread(u0 * n) > 0.05


def test_lattice_rows_of_first_bounces_only():
    """A path's first rough bounce at pixel sample s takes G points of the pixel's lattice
    of S G, one every S from s, rotated by a hash of the pixel and the path (the pixel's
    samples share it, another path or pixel has another); a deeper rough bounce and a point
    that draws no glossy rays get a zero row (their own draw), and no strata no rows."""
    spp, g = 4, 3
    st = gs.pixel_strata(np.array([0, 64, 128, 192, 1], np.int64) + 5, 64, 0, spp)
    assert list(st.index) == [0, 1, 2, 3, 0] and len(set(st.seed[:4])) == 1
    assert st.seed[4] != st.seed[0]
    src = np.array([0, 1, 2, 3, 4, 0, 1, 2])
    path = np.array([1, 1, 1, 1, 1, 3, 2, 1])
    fresh = np.array([True] * 6 + [False, True])
    glossy = np.array([True] * 7 + [False])
    out = gs.lattices(st, src, path, fresh, glossy, g)
    assert list(out[:6, 1]) == [0, 1, 2, 3, 0, 0] and (out[:6, 2] == spp).all()
    assert (out[:6, 3] == spp * g).all()
    assert len(set(out[:4, 0])) == 1 and out[4, 0] != out[0, 0] and out[5, 0] != out[0, 0]
    assert not out[6:].any()
    assert gs.lattices(None, src, path, fresh, glossy, g).shape == (0, 4)


def _rough(seed, strata, monkeypatch, spp=4, glossy=4, w=40, h=30):
    if not strata:
        monkeypatch.setattr(gs, "pixel_strata", lambda *a: None)
    sc = scenes.rough_materials(w, h)
    st = RenderSettings(mode="BASE", max_depth=5, samples=spp, glossy_samples=glossy,
                        seed=seed)
    f = whitted.render(sc, st, accel=create_accelerator("BVH", sc.arrays()))
    monkeypatch.undo()
    return f


def test_strata_are_unbiased_deterministic_and_incremental_equals_fresh(monkeypatch):
    """rough_materials at 4 x 4: per seed the frame with strata against the one without
    (each sample its own lattice), the mean difference over 6 seeds within three standard
    errors of 0 and the means within 1%; the same frame bit for bit again; an incremental
    frame's traced pixels bit for bit the full frame's (the strata depend on the pixel, the
    sample and the path, not on the batch)."""
    on, off = [], []
    for seed in range(6):
        on.append(_rough(seed, True, monkeypatch).radiance.astype(np.float64))
        off.append(_rough(seed, False, monkeypatch).radiance.astype(np.float64))
    on, off = np.stack(on), np.stack(off)
    assert abs(on.mean() / off.mean() - 1.0) < 0.01
    d = (on - off).mean(axis=(1, 2, 3))
    assert abs(d.mean()) <= 3.0 * d.std(ddof=1) / np.sqrt(len(d)) + 1e-12
    full = _rough(0, True, monkeypatch)
    assert np.array_equal(full.radiance, on[0].astype(full.radiance.dtype))
    sc = scenes.rough_materials(40, 30)
    st = RenderSettings(mode="BASE", max_depth=5, samples=4, glossy_samples=4, seed=0)
    acc = create_accelerator("BVH", sc.arrays())
    dirty = np.zeros(40 * 30, np.bool_)
    dirty[np.random.default_rng(3).choice(40 * 30, 150, replace=False)] = True
    base = _rough(1, True, monkeypatch)  # another frame of the camera: its pixels replaced
    inc = whitted.render(sc, st, accel=acc, pixels=dirty, base=base)
    got = inc.radiance.reshape(-1, 3)
    assert np.array_equal(got[dirty], full.radiance.reshape(-1, 3)[dirty])


@pytest.mark.parametrize("name,depth", [("three_spheres", 5), ("glass_horizon", 5),
                                        ("studio", 5), ("rough_materials", 0)])
def test_frames_that_draw_no_glossy_rays_compute_no_strata(name, depth, monkeypatch):
    """Mirrors, sharp glass and soft light, and rough surfaces at ray depth 0: no lattice
    is computed where the frame draws no glossy rays (its cost is the rough scenes' only;
    before 7db3404 every frame built it), in BASE frames, the interpolants' passes and tail
    and the RI-tree's tiles: all ask :func:`~.glossy_strata.frame_strata`."""
    from rstrace_engine.ri_tree.render import RITreeRenderer

    def refused(*a, **k):
        raise AssertionError("strata computed for a frame that draws no glossy rays")

    monkeypatch.setattr(gs, "pixel_strata", refused)
    sc = scenes.build(name, 40, 30)
    st = RenderSettings(mode="BASE", max_depth=depth, samples=2, light_samples=4)
    acc = create_accelerator("BVH", sc.arrays())
    whitted.render(sc, st, accel=acc)
    InterpolantRenderer().render(sc, replace(st, mode="INTERPOLANT", epsilon=0.05), acc)
    RITreeRenderer().render(sc, replace(st, mode="RI_TREE"), acc)


def test_a_rough_frame_asks_for_strata_in_every_mode(monkeypatch):
    """The other side of the test above: a rough scene at ray depth 5 computes its pixels'
    strata in each mode (a guard that skipped them would render each sample with its own
    lattice: another image)."""
    from rstrace_engine.ri_tree.render import RITreeRenderer

    asked = []
    real = gs.pixel_strata

    def counted(*a, **k):
        asked.append(1)
        return real(*a, **k)

    monkeypatch.setattr(gs, "pixel_strata", counted)
    sc = scenes.build("rough_materials", 24, 18)
    st = RenderSettings(mode="BASE", max_depth=5, samples=2, glossy_samples=2)
    acc = create_accelerator("BVH", sc.arrays())
    for render in (lambda: whitted.render(sc, st, accel=acc),
                   lambda: InterpolantRenderer().render(
                       sc, replace(st, mode="INTERPOLANT", epsilon=0.05), acc),
                   lambda: RITreeRenderer().render(sc, replace(st, mode="RI_TREE"), acc)):
        asked.clear()
        render()
        assert asked, "a rough frame computed no strata"


def test_a_cut_interpolant_frames_tail_is_the_base_frame_on_rough_surfaces(monkeypatch):
    """An INTERPOLANT frame whose ledger cuts the first pass for good traces the rest in the
    base tracer's tiles (interpolants/frame_parts.trace_tail): on rough surfaces at 4 pixel
    samples those pixels take the base frame's strata, so the frame is the base frame bit
    for bit (the tail without them: each sample its own lattice, another image)."""
    from rstrace_engine.interpolants import fallback
    from rstrace_engine.interpolants.fallback import Budget

    monkeypatch.setattr(Budget, "chunk", lambda self, rest: 0)
    monkeypatch.setattr(fallback, "ALLOWANCE", 0.0)  # nothing to spend: cut for good
    sc = scenes.rough_materials(40, 30)
    acc = create_accelerator("BVH", sc.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=0.05, max_depth=5, samples=4,
                        glossy_samples=4)
    r = InterpolantRenderer()
    r.prepare(sc.arrays(), st, acc)
    r.cache.fallback.ray_s = 1e-6  # priced: cut at the first ray
    f = r.render(sc, st, acc)
    assert f.stats["fallback"]["tail_pixels"] == 40 * 30
    base = whitted.render(sc, replace(st, mode="BASE"), accel=acc)
    assert np.array_equal(f.radiance, base.radiance)


def test_next_paths_is_the_old_compaction_bit_for_bit():
    """``next_paths`` (one numba pass) gives what ``_next_front`` built before with
    ``flatnonzero``, ``child_paths``, ``np.where`` and fancy-index gathers: the same values,
    dtypes and C-contiguous arrays, for empty levels, levels where every ray dies or none
    does, points with no pairs (repeated ``gstart`` entries), one pair a point (no
    ``gstart``) and paths near int64's limit (both wrap)."""
    from rstrace_engine.tracing.seen_lights import SEEN_GLOSSY, SEEN_NONE, SEEN_TRANSMISSION

    rng = np.random.default_rng(41)
    for it in range(600):
        n = int(rng.integers(0, 7))
        if it % 3 == 0 or n == 0:
            gstart = glossy = None
            pairs = n
        else:
            counts = rng.integers(0, 4, n) * (it % 7 != 1)
            glossy = rng.random(n) < 0.5
            gstart = np.zeros(n + 1, np.int64)
            np.cumsum(counts, out=gstart[1:])
            pairs = int(gstart[-1])
        ok = rng.random(2 * pairs) < (0.0, 0.5, 1.0)[it % 3 if it % 5 else 1]
        src = rng.integers(0, 100, n).astype(np.int32)
        path = rng.integers(1, 2**62 if it % 4 == 0 else 50, n).astype(np.int64)
        fresh = rng.random(n) < 0.5
        tag, nseeds = (rng.integers(0, 2**63, n).astype(np.uint64) for _ in range(2))
        ko, kd, kw = (rng.normal(size=(2 * pairs, 3)) for _ in range(3))
        k = np.flatnonzero(ok)
        which, f, t = gs.child_paths(k, gstart, glossy, fresh, tag, nseeds)
        sees = np.where(k & 1, SEEN_TRANSMISSION, SEEN_GLOSSY).astype(np.int8)
        if gstart is not None:
            sees[glossy[which]] = SEEN_NONE
        old = (k, which, src[which], path[which] * 2 + (k & 1), f, t, sees, ko[k], kd[k],
               kw[k])
        new = gs.next_paths(ok, gstart, glossy, src, path, fresh, tag, nseeds, ko, kd, kw,
                            SEEN_NONE, SEEN_GLOSSY, SEEN_TRANSMISSION)
        for a, b in zip(old, new, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and b.flags.c_contiguous
            assert a.tobytes() == b.tobytes()
