"""Glossy rays (issue 24): GGX visible-normal sampling, the furnace test, determinism, the
mirror kept one ray, the depth budget, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from rstrace_engine import scenes
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Scene, SceneError
from rstrace_engine.scenes import _camera
from rstrace_engine.tracing import ggx_sampling as gs
from rstrace_engine.tracing import glossy_rays, whitted
from rstrace_engine.tracing import shading as sh


@njit(cache=True)
def _vndf_mean(co, alpha, n):
    """Mean of G2 / G1 over n x n stratified visible normals, and the least o . h."""
    so = math.sqrt(1.0 - co * co)
    acc = 0.0
    least = 1.0
    for a in range(n):
        for b in range(n):
            hx, hy, hz = gs.ggx_vndf(so, 0.0, co, alpha, (a + 0.5) / n, (b + 0.5) / n)
            c = so * hx + co * hz
            least = min(least, c)
            ci = 2.0 * c * hz - co  # the reflected direction's cosine
            if ci > 0.0:
                acc += gs.ggx_weight(co, ci, alpha)
    return acc / (n * n), least


@pytest.mark.parametrize("alpha", [0.04, 0.25, 0.5, 1.0])
@pytest.mark.parametrize("co", [0.2, 0.6, 0.95])
def test_vndf_weights_average_to_the_lobe_albedo(alpha, co):
    """Drawn from the visible normals, the weights G2 / G1 average to the lobe's
    single-scattering albedo, which ggx_albedo computes independently (microfacet normals
    drawn from D cos); every drawn normal faces the viewer."""
    mean, least = _vndf_mean(co, alpha, 200)
    e_white, _ = sh.ggx_albedo(co, alpha, 1.5)
    assert least > 0.0
    assert abs(mean - e_white) <= 0.05 * e_white, (mean, e_white)


def _ball(material, world=(1.0, 1.0, 1.0), size=48) -> Scene:
    s = Scene()
    s.add_instance(s.add_mesh(shapes.icosphere(4)), np.eye(4), [s.add_material(material)],
                   name="Ball")
    s.set_world_color(world, lights=False)
    s.set_camera(_camera((0.0, -4.0, 0.0), (0.0, 0.0, 0.0), size, size))
    return s


@pytest.mark.parametrize("roughness", [0.05, 0.2, 0.5, 1.0])
def test_white_furnace_rough_metal(roughness):
    """A white metal ball in a white world (background only, no lights): its glossy rays
    all escape and carry G2 / G1 times the multiple-scattering factor 1 / E, whose mean is
    1 -- the ball disappears (mean within 1.5%, every pixel within 16%: 16 samples)."""
    mat, _ = principled_material("white_metal", (1.0, 1.0, 1.0), metallic=1.0,
                                 roughness=roughness)
    f = whitted.render(_ball(mat), RenderSettings(max_depth=4, glossy_samples=16))
    ball = f.radiance[f.pixel_class > 0]
    assert ball.size and abs(ball.mean() - 1.0) <= 0.015, ball.mean()
    assert np.abs(ball - 1.0).max() <= 0.16


def _glass_albedo_dcos(co, alpha, eta, n=400):
    """Independent estimate of the rough dielectric's albedo: microfacet normals drawn from
    ``D cos_h`` (not the visible normals), weight ``|o.h| G2 / (cos_h cos_o)`` for the
    reflected and the refracted direction alike (Walter et al. 2007, eq. 41); a refracted
    direction on the viewer's side counts, as Cycles' tables count it."""
    u, p = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    a2 = alpha * alpha
    ct = np.sqrt((1.0 - u) / (1.0 + (a2 - 1.0) * u))
    st = np.sqrt(np.maximum(0.0, 1.0 - ct * ct))
    h = np.stack([st * np.cos(2 * np.pi * p), st * np.sin(2 * np.pi * p), ct], -1)
    o = np.array([math.sqrt(1.0 - co * co), 0.0, co])
    ch = h @ o
    keep = ch > 0.0
    sin2t = eta * eta * (1.0 - ch * ch)
    tir = sin2t >= 1.0
    cost = np.sqrt(np.maximum(0.0, 1.0 - sin2t))
    rs = (eta * ch - cost) / (eta * ch + cost)
    rp = (ch - eta * cost) / (ch + eta * cost)
    f = np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))
    lam = np.vectorize(lambda c: sh.ggx_lambda(abs(c), a2))
    lo = sh.ggx_lambda(co, a2)
    base = np.where(keep, ch / (ct * co), 0.0)
    rz = 2.0 * ch * ct - co  # reflected cosine
    t = -eta * o[None, None, :] + (eta * ch - cost)[..., None] * h  # refracted direction
    tz = t[..., 2]
    acc = np.where(keep & (rz > 0.0), f * base / (1.0 + lo + lam(rz)), 0.0)
    # a refraction counts wherever it goes, as in Cycles' tables (glass_albedo)
    acc += np.where(keep & ~tir, (1.0 - f) * base / (1.0 + lo + lam(tz)), 0.0)
    return acc.mean()


@pytest.mark.parametrize("alpha", [0.04, 0.25, 1.0])
@pytest.mark.parametrize("co", [0.95, 0.5, 0.2])
@pytest.mark.parametrize("eta", [1.0 / 1.5, 1.5])
def test_glass_albedo_quadrature(alpha, co, eta):
    """The rough dielectric's single-scattering albedo E (whose inverse scales the glass
    lobe, as Cycles' multiscatter GGX glass) agrees with an independent estimate (normals
    drawn from D cos_h) within 3%: from outside (eta 1/1.5) and inside (1.5)."""
    ref = _glass_albedo_dcos(co, alpha, eta)
    e = sh.ggx_glass_albedo(co, alpha, eta)
    assert 0.0 < e <= 1.0 + 1e-9
    assert abs(e - ref) <= 0.03 * ref, (e, ref)


#: Entries of Cycles' own tables (intern/cycles/scene/shader.tables, ``table_ggx_glass_E``
#: and ``table_ggx_glass_inv_E``, index ``z * 256 + cos * 16 + roughness``): roughness 1,
#: ``z = 7 / 15`` (IOR ``ior_from_F0(z^4)`` = 1.5575), cos ``1 / 15``, ``2 / 15``, ``3 / 15``,
#: ``10 / 15``; from outside (E) and from inside (inv_E).
CYCLES_GLASS_E = {(False, 1): 0.7788, (False, 2): 0.7258, (False, 3): 0.7067,
                  (False, 10): 0.7844, (True, 1): 0.7324, (True, 2): 0.6229,
                  (True, 3): 0.5649, (True, 10): 0.4878}


@pytest.mark.parametrize("inside, c", sorted(CYCLES_GLASS_E))
def test_glass_albedo_is_cycles_tables(inside, c):
    """The albedo whose inverse scales the rough glass lobe is the one Cycles tabulates
    (within 1.5%, its own Monte Carlo and our table's interpolation): from inside at grazing
    views Cycles' E counts refracted directions that leave on the viewer's side, so it is
    well above the single-scattering albedo (0.55 at cos 1/15; before, our table held that
    value and rough glass seen through itself was up to 14% brighter than Cycles)."""
    z = 7.0 / 15.0
    f0 = z ** 4
    ior = (1.0 + math.sqrt(f0)) / (1.0 - math.sqrt(f0))
    e = sh.ggx_glass_albedo(c / 15.0, 1.0, ior if inside else 1.0 / ior)
    ref = CYCLES_GLASS_E[(inside, c)]
    assert abs(e - ref) <= 0.015 * ref, (e, ref)


@pytest.mark.parametrize("roughness", [0.05, 0.2, 0.5, 1.0])
def test_white_furnace_rough_glass(roughness):
    """A clear rough glass ball (IOR 1.5) in a white world, no lights: with the glass lobe
    scaled by 1 / E (Cycles' multiscatter GGX glass) its rays carry back most of what they
    take, so the ball nearly disappears. Measured (16 glossy samples, depth 8) mean 0.997 /
    0.957 / 0.944 / 0.969 at roughness 0.05 / 0.2 / 0.5 / 1.0; single-scattering GGX
    gave 0.997 / 0.953 / 0.766 / 0.333 (docs/glossy.md). Asserted within 6%: Cycles' E
    (its tables, which ours are) counts the refracted directions that leave on the viewer's
    side, which the rays drop, so seen from inside at grazing views the lobe is given back
    less than it loses (with the single-scattering E: 0.963 / 0.992 at 0.5 / 1.0)."""
    mat, _ = principled_material("clear", (1.0, 1.0, 1.0), roughness=roughness, ior=1.5,
                                 transmission=1.0)
    f = whitted.render(_ball(mat), RenderSettings(max_depth=8, glossy_samples=16))
    ball = f.radiance[f.pixel_class > 0]
    assert ball.size and abs(ball.mean() - 1.0) <= 0.06, ball.mean()


def test_same_seed_same_image_other_seed_other_noise():
    sc = scenes.glossy(48, 36)
    a = whitted.render(sc, RenderSettings(glossy_samples=4, light_samples=2))
    b = whitted.render(sc, RenderSettings(glossy_samples=4, light_samples=2))
    c = whitted.render(sc, RenderSettings(glossy_samples=4, light_samples=2, seed=7))
    assert np.array_equal(a.radiance, b.radiance)
    assert not np.array_equal(a.radiance, c.radiance)


def test_glossy_image_converges_with_samples():
    """More glossy samples, less noise: the mean absolute error against 64 samples, over
    seeds 0-3, falls from 2 to 16 samples (deterministic: the same numbers every run;
    session 34: 0.0354 -> 0.0180, main's sampling 0.0367 -> 0.0179). Not one seed's RMS
    error: a highlight seen in a rough reflection makes a firefly in some seeds' frames
    (main's seed 1: 0.046 -> 0.041; seed 0 with the session-34 strata 0.050 -> 0.071)."""
    sc = scenes.glossy(48, 36, roughness=0.4)

    def frame(n, seed):
        st = RenderSettings(glossy_samples=n, light_samples=4, max_depth=3, seed=seed)
        return whitted.render(sc, st).radiance.astype(np.float64)

    e2 = e16 = 0.0
    for seed in range(4):
        ref = frame(64, seed)
        e2 += np.mean(np.abs(frame(2, seed) - ref))
        e16 += np.mean(np.abs(frame(16, seed) - ref))
    assert e16 < 0.6 * e2, (e2, e16)


def test_a_mirror_stays_one_ray():
    """Below roughness 0.05 a metal is a mirror: one ray, whatever the glossy samples."""
    mat, _ = principled_material("chrome", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.02)
    sc = _ball(mat, world=(0.3, 0.5, 0.7))
    a = whitted.render(sc, RenderSettings(glossy_samples=1))
    b = whitted.render(sc, RenderSettings(glossy_samples=64))
    assert np.array_equal(a.radiance, b.radiance)
    assert a.stats["secondary_rays"] == b.stats["secondary_rays"] == int(
        (a.pixel_class > 0).sum())


def _two_mirrors(roughness: float) -> Scene:
    """Two rough metal walls facing each other, the camera between them looking at one."""
    s = Scene()
    mat, _ = principled_material("metal", (0.9, 0.9, 0.9), metallic=1.0, roughness=roughness)
    m = s.add_material(mat)
    wall = s.add_mesh(shapes.plane(40.0, name="wall"))
    s.add_instance(wall, shapes.transform((0.0, 2.0, 0.0), 1.0, 0.0, 90.0), [m], name="A")
    s.add_instance(wall, shapes.transform((0.0, -2.0, 0.0), 1.0, 0.0, 90.0), [m], name="B")
    s.set_world_color((0.5, 0.5, 0.5), lights=False)
    s.set_camera(_camera((0.0, -1.0, 0.0), (0.0, 2.0, 0.0), 16, 12, lens=80.0))
    return s


@pytest.mark.parametrize("lobes", [True, False])
def test_depth_budget_splits_only_the_first_glossy_bounce(lobes, monkeypatch):
    """N glossy samples at a path's first rough bounce, one at every deeper one: level 1
    holds N rays per pixel (2 N on these rough metal walls with ``LOBE_COUNTS``: a lobe
    without transmission draws twice Glossy Samples), every deeper level at most as many
    as the one before."""
    monkeypatch.setattr(glossy_rays, "LOBE_COUNTS", lobes)
    sc = _two_mirrors(0.3)
    sa = sc.arrays()
    segs: list = []
    n = 16 * 12
    cam = sc.camera
    from rstrace_engine.geometry.cameras import camera_params
    cp = camera_params(cam)
    whitted.trace_pixels(sa, create_accelerator("BVH", sa), cp, np.arange(n),
                         np.full((n, 2), 0.5), 4, segments=segs, glossy_samples=8)
    sizes = [len(lv["ray"]) for lv in segs]
    assert sizes[0] == n
    k = 16 if lobes else 8
    assert n * k * 0.9 <= sizes[1] <= n * k
    for a, b in zip(sizes[1:], sizes[2:], strict=False):
        assert b <= a


def test_shade_without_seeds_refuses_rough_materials():
    sc = scenes.glossy(8, 6)
    sa = sc.arrays()
    o = np.array([[0.0, -6.5, 2.6]])
    d = np.array([[0.0, 1.0, -0.3]])
    hits = create_accelerator("BVH", sa).closest_hit(o, d, np.zeros(1), np.full(1, np.inf))
    surf = whitted.surfaces(sa, o, d, np.full(1, np.inf), hits)
    vis = np.zeros(len(surf.sh_state), np.bool_)
    with pytest.raises(ValueError, match="seeds"):
        whitted.shade(sa, hits, surf, vis, np.ones((1, 3)), True)


def test_glossy_samples_setting_is_checked():
    with pytest.raises(SceneError, match="glossy_samples"):
        RenderSettings(glossy_samples=0).validated()
    RenderSettings(glossy_samples=1).validated()


@pytest.mark.parametrize("roughness, clamped", [(-0.5, 0.0), (1.5, 1.0)])
def test_roughness_outside_range_is_clamped_with_a_message(roughness, clamped):
    mat, notes = principled_material("Odd", (0.5, 0.5, 0.5), metallic=1.0,
                                     roughness=roughness)
    ref, _ = principled_material("Odd", (0.5, 0.5, 0.5), metallic=1.0, roughness=clamped)
    assert mat.roughness == ref.roughness
    assert any("Roughness" in n and f"{roughness:g}" in n for n in notes), notes


def test_roughness_nan_names_the_material():
    with pytest.raises(SceneError, match="'Bad'.*Roughness"):
        principled_material("Bad", (0.5, 0.5, 0.5), roughness=float("nan"))


def test_anisotropy_is_reported():
    _, notes = principled_material("Brushed", (0.5, 0.5, 0.5), metallic=1.0, roughness=0.3,
                                   anisotropic=0.5)
    assert any("Anisotropic" in n for n in notes), notes
    _, notes = principled_material("Plain", (0.5, 0.5, 0.5), metallic=1.0, roughness=0.3)
    assert not any("Anisotropic" in n for n in notes)


def test_rough_glass_of_ior_1_is_invisible():
    """IOR 1 with any roughness: no interface, the rays pass straight on (as in Cycles):
    a white rough glass ball of IOR 1 in front of a coloured world shows the world."""
    mat, _ = principled_material("Air", (1.0, 1.0, 1.0), roughness=0.6, transmission=1.0,
                                 ior=1.0)
    f = whitted.render(_ball(mat, world=(0.2, 0.4, 0.6)), RenderSettings(max_depth=6))
    ball = f.radiance[f.pixel_class > 0]
    assert ball.size
    np.testing.assert_allclose(ball, np.broadcast_to([0.2, 0.4, 0.6], ball.shape), atol=1e-6)


def test_rough_glass_ball_from_inside_is_finite():
    """A camera inside a closed rough glass ball: glossy rays leave from inside, total
    internal reflection included; the image is finite and lit by the world."""
    mat, _ = principled_material("Frost", (1.0, 1.0, 1.0), roughness=0.4, transmission=1.0)
    s = Scene()
    s.add_instance(s.add_mesh(shapes.icosphere(3)), shapes.transform(scale=3.0),
                   [s.add_material(mat)], name="Ball")
    s.set_world_color((0.5, 0.5, 0.5), lights=False)
    s.set_camera(_camera((0.0, -1.0, 0.0), (0.0, 0.0, 0.0), 16, 12))
    f = whitted.render(s, RenderSettings(max_depth=6, glossy_samples=4))
    assert np.isfinite(f.radiance).all() and f.stats["nonfinite_samples"] == 0
    assert 0.05 < f.radiance.mean() <= 0.5 + 1e-6


def _rough_unlit_world(w=96, h=72):
    """A rough metal ball and a rough glass ball on one matte floor under a point light;
    the world a background only (its light would fail every cell)."""
    from rstrace_engine.geometry.scene import Light

    s = Scene()
    floor, _ = principled_material("floor", (0.6, 0.6, 0.55), specular_level=0.0)
    metal, _ = principled_material("metal", (0.9, 0.7, 0.4), metallic=1.0, roughness=0.3)
    glass, _ = principled_material("glass", (1.0, 1.0, 1.0), transmission=1.0,
                                   roughness=0.3)
    red, _ = principled_material("red", (0.8, 0.1, 0.1), specular_level=0.0)
    ball = s.add_mesh(shapes.icosphere(3))
    s.add_instance(s.add_mesh(shapes.plane(14.0)), np.eye(4), [s.add_material(floor)],
                   name="Floor")
    s.add_instance(ball, shapes.transform((-0.8, 0.5, 0.7), 0.7), [s.add_material(metal)],
                   name="Metal")
    s.add_instance(ball, shapes.transform((1.0, 0.0, 0.5), 0.5), [s.add_material(glass)],
                   name="Glass")
    s.add_instance(ball, shapes.transform((0.3, 2.0, 0.5), 0.5), [s.add_material(red)],
                   name="Red")
    s.add_light(Light("Key", "POINT", power=1200.0, position=(-3.0, -3.5, 5.0)))
    s.set_world_color((0.15, 0.16, 0.2), lights=False)
    s.set_camera(_camera((0.0, -6.0, 2.5), (0.0, 0.5, 0.5), w, h, lens=40.0))
    return s


def test_interpolant_mode_traces_rough_surfaces_within_epsilon(monkeypatch):
    """INTERPOLANT mode: cells whose samples' ray trees hold a rough surface fail
    ("glossy") and are traced per pixel as BASE traces them; the frame stays within
    epsilon of BASE's everywhere."""
    from rstrace_engine import image
    from rstrace_engine.interpolants.render import InterpolantRenderer

    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)  # cells always
    sc = _rough_unlit_world()
    accel = create_accelerator("BVH", sc.arrays())
    eps = 0.02
    st = RenderSettings(mode="INTERPOLANT", epsilon=eps, depth_cap=6, light_samples=4,
                        glossy_samples=4, max_depth=3)
    r = InterpolantRenderer()
    frame = r.render(sc, st, accel)
    base = whitted.render(sc, st, accel=accel)
    err = image.compare(frame.radiance, base.radiance, eps)
    assert err["max_error"] <= eps, err
    # (at this size the balls' cells fail before their samples are shaded -- box and
    # light tests -- so the "glossy" reason itself is checked on the samples below)


def test_samples_hitting_rough_surfaces_below_their_root_are_flagged_glossy():
    """The interpolants' samples: a line whose ray tree hits a rough surface below its root
    (the rough metal ball in a mirror) is flagged GLOSSY (its cells fail with the reason
    "glossy"); a line on the rough ball itself is not (its own light is the sample, its
    glossy rays are traced per pixel: ``roots="own"`` spawns none there); a line on the
    matte floor is not."""
    from rstrace_engine.interpolants.samples import GLOSSY, glossy_flags

    sc = _rough_unlit_world(16, 12)
    mirror, _ = principled_material("mirror", (0.95, 0.95, 0.95), metallic=1.0,
                                    roughness=0.0)
    sc.add_instance(sc.add_mesh(shapes.plane(3.0)),
                    shapes.transform((-0.8, 3.0, 1.0), 1.0, rotate_x_deg=90.0),
                    [sc.add_material(mirror)], name="Mirror")
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    # at the metal ball; at the floor; at the mirror, which shows the metal ball
    o = np.array([[-0.8, -3.0, 0.7], [4.0, -3.0, 3.0], [-0.8, 1.5, 0.7]])
    d = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    rad, tree = whitted.trace(sa, accel, o, d, 0.0, np.inf, 3, record=True, glossy_samples=1,
                              roots="own")
    assert np.count_nonzero(tree.node_ray == 0) == 1  # the rough root spawned nothing
    assert np.count_nonzero(tree.node_ray == 2) > 1
    assert list(glossy_flags(sa, tree, 3)) == [0, 0, GLOSSY]


def test_rough_roots_own_light_plus_below_is_the_whole_radiance():
    """``trace(roots="own")`` + ``trace(roots="below")`` is ``trace()``: the same rays,
    seeds and weights (to float rounding), with a world that lights (its glossy part
    carried by the glossy rays) and soft samples."""
    from rstrace_engine.tracing.soft_lights import sample_seeds

    sc = _rough_unlit_world(16, 12)
    sc.set_world_color((0.15, 0.16, 0.2), lights=True)
    sa = sc.arrays()
    accel = create_accelerator("BVH", sa)
    rng = np.random.default_rng(3)
    n = 400
    o = np.tile([0.0, -6.0, 2.5], (n, 1))
    d = np.column_stack([rng.uniform(-0.5, 0.5, n), np.ones(n), rng.uniform(-0.6, -0.1, n)])
    seeds = sample_seeds(np.arange(n), 7)
    kw = dict(seeds=seeds, light_samples=4, glossy_samples=4)
    whole, _ = whitted.trace(sa, accel, o, d, 0.0, np.inf, 3, **kw)
    own, _ = whitted.trace(sa, accel, o, d, 0.0, np.inf, 3, roots="own", **kw)
    below, _ = whitted.trace(sa, accel, o, d, 0.0, np.inf, 3, roots="below", **kw)
    np.testing.assert_allclose(own + below, whole, rtol=1e-12, atol=1e-12)
    assert (np.abs(below).sum(axis=1) > 0).mean() > 0.05  # the balls: a glossy part
    assert (np.abs(own - whole).sum(axis=1) > 0).any()


def test_interpolant_mode_interpolates_rough_surfaces_through_edits(monkeypatch):
    """INTERPOLANT with Blender's default plastic floor (Principled, roughness 0.5) under a
    rough metal ball and rough glass: the floor is interpolated (its own light from cells,
    its glossy rays per pixel), every frame -- the first and after moves of the balls into
    and out of the floor's reflection -- within epsilon of the BASE frame of the edited
    scene, every traced pixel BASE's; then the light's power, the light moved, the floor's
    roughness changed, and a camera step (reprojected pixels on the rough floor trace their
    visibility ray for their glossy rays)."""
    from dataclasses import replace

    from rstrace_engine import image
    from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT
    from rstrace_engine.geometry.edits import CameraChange, LightSet, MaterialSet, ObjectTransform
    from rstrace_engine.geometry.scene import Light
    from rstrace_engine.interpolants.render import InterpolantRenderer
    from rstrace_engine.session import Session

    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)  # cells always
    eps = 0.05
    kw = dict(max_depth=3, light_samples=4, glossy_samples=4)
    settings = RenderSettings(mode="INTERPOLANT", epsilon=eps, **kw)
    sc = _rough_unlit_world(160, 120)
    plastic, _ = principled_material("floor", (0.6, 0.6, 0.55))  # Blender's default lobe
    sc.set_material(sc.material_id("floor"), plastic)
    sess = Session(sc, settings)
    key = Light("Key", "POINT", power=1200.0, position=(-3.0, -3.5, 5.0))
    moves = [None, ("camera", 0.05), ("Metal", (-0.2, 0.9, 0.7), 0.7),
             ("Glass", (1.4, -0.6, 0.5), 0.5), ("Metal", (-1.2, 0.2, 0.7), 0.7), ("Key", 2.0),
             ("Key", (-2.0, -3.0, 4.0)), ("floor", 0.2)]
    for step, move in enumerate(moves):
        if move is None:
            pass
        elif move[0] == "camera":  # a step aside: reprojected pixels on the rough floor
            m = sess.scene.camera.matrix.copy()
            m[0, 3] += move[1]
            sess.apply([CameraChange(replace(sess.scene.camera, matrix=m))])
        elif move[0] == "Key" and isinstance(move[1], float):  # the light's power
            key = replace(key, power=key.power * move[1])
            sess.apply([LightSet("Key", key)])
        elif move[0] == "Key":  # moved
            key = replace(key, position=move[1])
            sess.apply([LightSet("Key", key)])
        elif move[0] == "floor":  # rougher or smoother
            mat, _ = principled_material("floor", (0.6, 0.6, 0.55), roughness=move[1])
            sess.apply([MaterialSet("floor", mat)])
        else:
            name, at, size = move
            sess.apply([ObjectTransform(name, shapes.transform(at, size))])
        frame = sess.render()
        rough = frame.stats["rough_interpolated"]
        interpolated = np.count_nonzero(frame.pixel_class == CLASS_INTERPOLATED)
        base = Session(sess.scene.copy(), RenderSettings(**kw)).render()
        m = image.compare(frame.radiance, base.radiance, eps)
        print(f"step {step}: {interpolated} interpolated, {rough} on rough surfaces, "
              f"max error {m['max_error']:.4f}")
        assert m["max_error"] <= eps + 1e-6, (step, m)
        traced = (frame.pixel_class != CLASS_INTERPOLATED) & (frame.pixel_class
                                                              != CLASS_REBUILT)
        np.testing.assert_allclose(frame.radiance[traced], base.radiance[traced], atol=1e-6)
        if step <= 1:
            assert rough > 0.1 * frame.radiance.shape[0] * frame.radiance.shape[1], rough
        if step == 1:
            assert frame.stats["reprojected_fraction"] > 0.02, frame.stats


def test_ri_tree_mode_samples_rough_surfaces():
    """RI_TREE mode shades rough surfaces with glossy rays (one per point: noisier than
    BASE, never a sharp mirror): close to BASE's frame in the mean."""
    from rstrace_engine.session import Session

    sc = _rough_unlit_world(64, 48)
    st = RenderSettings(mode="RI_TREE", light_samples=4, glossy_samples=4, max_depth=3,
                        samples=4)
    ri = Session(sc.copy(), st).render()
    base = whitted.render(sc, RenderSettings(light_samples=4, glossy_samples=4, max_depth=3,
                                             samples=4))
    assert np.isfinite(ri.radiance).all()
    rel = abs(float(ri.radiance.mean()) - float(base.radiance.mean())) / float(
        base.radiance.mean())
    assert rel < 0.05, rel


def _albedo_over_directions(co, alpha, n=1500, m=600):
    """Independent estimate of the GGX lobe's albedo (Fresnel 1): reflected directions over
    the hemisphere on a midpoint grid in (cos, azimuth), the BRDF ``D G2 / (4 cos_o cos_i)``
    times ``cos_i`` (not microfacet normals, as the table's own quadrature)."""
    a2 = alpha * alpha
    ci = ((np.arange(n) + 0.5) / n)[:, None]
    phi = ((np.arange(m) + 0.5) / m * np.pi)[None, :]
    si = np.sqrt(1.0 - ci * ci)
    so = math.sqrt(1.0 - co * co)
    hx, hy, hz = so + si * np.cos(phi), si * np.sin(phi), co + ci
    ch = hz / np.sqrt(hx * hx + hy * hy + hz * hz)
    d = a2 / (np.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)
    lam = np.vectorize(lambda c: sh.ggx_lambda(c, a2))
    g2 = 1.0 / (1.0 + lam(ci) + sh.ggx_lambda(co, a2))
    return float((d * g2 / (4.0 * co)).mean() * 2.0 * np.pi)


@pytest.mark.parametrize("roughness", [8 / 31, 12 / 31, 16 / 31, 24 / 31, 1.0])
@pytest.mark.parametrize("co", [3 / 31, 8 / 31, 16 / 31, 1.0])
def test_albedo_table_against_directions(roughness, co):
    """The tabulated albedo E (scripts/ggx_tables.py, read as Cycles reads its own) at grid
    points, against directions drawn over the hemisphere: within 0.2% (measured: 0.02% but
    at grazing views, 0.2%)."""
    alpha = roughness * roughness
    want = _albedo_over_directions(co, alpha)
    assert sh.ggx_e(co, alpha) == pytest.approx(want, rel=2e-3)


@pytest.mark.parametrize("roughness", [0.3, 0.6, 1.0])
def test_coloured_rough_metal_loses_what_cycles_loses(roughness):
    """A coloured metal's multiple-scattering factor is Cycles' ``1 + Fms (1 - E) / E``
    (Kulla-Conty's multiple-bounce Fresnel from the F82 average), less than a white metal's
    ``1 / E``; a white metal keeps all its energy (``E * factor == 1``)."""
    alpha = roughness * roughness
    for co in (0.2, 0.6, 1.0):
        e = sh.ggx_e(co, alpha)
        zd, zr, zg, zb = sh.multiscatter_factors(alpha, e, 1.5, 1.0, 0.6, 0.3, 1.0, 1.0, 1.0)
        assert zr * e == pytest.approx(1.0, rel=1e-12)
        ea = sh.ggx_e_avg(alpha)
        for f0, z in ((0.6, zg), (0.3, zb)):
            fss = f0 + (1.0 - f0) / 21.0
            assert z == pytest.approx(1.0 + fss * ea / (1.0 - fss * (1.0 - ea)) * (1 - e) / e)
            assert 1.0 <= z < 1.0 / e


def _sample_normal_per_sample(nx, ny, nz, ox, oy, oz, alpha, u1, u2):
    """``ggx_sample_normal`` as every sample computed it before its view frame was computed
    once per point (session 42), in Python floats (IEEE doubles, as numba's)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t1 = (1.0 + sign * nx * nx * a, sign * b, -sign * nx)
    t2 = (b, sign + ny * ny * a, -ny)
    lx = ox * t1[0] + oy * t1[1] + oz * t1[2]
    ly = ox * t2[0] + oy * t2[1] + oz * t2[2]
    lz = ox * nx + oy * ny + oz * nz
    vx, vy, vz = alpha * lx, alpha * ly, lz
    ln = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / ln, vy / ln, vz / ln
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        il = 1.0 / math.sqrt(lensq)
        s1 = (-vy * il, vx * il, 0.0)
    else:
        s1 = (1.0, 0.0, 0.0)
    s2 = (vy * s1[2] - vz * s1[1], vz * s1[0] - vx * s1[2], vx * s1[1] - vy * s1[0])
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    mx = p1 * s1[0] + p2 * s2[0] + p3 * vx
    my = p1 * s1[1] + p2 * s2[1] + p3 * vy
    mz = p1 * s1[2] + p2 * s2[2] + p3 * vz
    hx, hy, hz = alpha * mx, alpha * my, max(mz, 0.0)
    hl = math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / hl, hy / hl, hz / hl
    return (hx * t1[0] + hy * t2[0] + hz * nx, hx * t1[1] + hy * t2[1] + hz * ny,
            hx * t1[2] + hy * t2[2] + hz * nz)


def test_glossy_samples_share_their_view_frame_bit_for_bit():
    """A point's glossy samples compute the lobe's frame about the view and Smith's Lambda
    of the view once (``ggx_sample_frame``, ``ggx_weight_lo``): every normal and weight is
    the per-sample computation's, bit for bit."""
    rng = np.random.default_rng(42)
    for _ in range(300):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        o = rng.normal(size=3)
        o /= np.linalg.norm(o)
        if o @ n < 0.0:
            o = -o
        alpha = float(rng.choice([0.0025, 0.09, 0.25, 1.0]))
        frame = gs.ggx_sample_frame(*n, *o, alpha)
        for u1, u2 in rng.random((4, 2)):
            want = _sample_normal_per_sample(*n, *o, alpha, u1, u2)
            assert gs.ggx_sample_at(frame, *n, alpha, u1, u2) == want
            assert gs.ggx_sample_normal(*n, *o, alpha, u1, u2) == want
        co, ci, a2 = float(o @ n), float(rng.uniform(-1.0, 1.0)), alpha * alpha
        lo = 0.5 * (math.sqrt(1.0 + a2 * (max(1.0 - co * co, 0.0) / (co * co))) - 1.0)
        li = 0.5 * (math.sqrt(1.0 + a2 * (max(1.0 - ci * ci, 0.0) / (ci * ci))) - 1.0)
        assert gs.ggx_weight_lo(sh.ggx_lambda(co, a2), ci, a2) == (1.0 + lo) / (1.0 + lo + li)
        assert gs.ggx_weight(co, ci, alpha) == (1.0 + lo) / (1.0 + lo + li)


def test_glossy_rays_without_a_lobe_do_not_read_the_multiscatter_factors():
    """The shade kernel hands a glossy point's rays its multiscatter factors ``z`` where
    its layer has a lobe (specular or metallic) and ``(1, 1, 1, 1)`` where not; before
    session 42 the rays computed them again wherever the mirror share was not 0. Without
    a lobe the factors multiply a zero Fresnel: the rays are the same bits either way."""
    from rstrace_engine.tracing.glossy_rays import _glossy_rays
    from rstrace_engine.tracing.multiscatter import ggx_e, multiscatter_factors
    rng = np.random.default_rng(7)
    ns = 4
    for _ in range(40):
        g = rng.normal(size=3)
        g /= np.linalg.norm(g)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if d @ g > 0.0:
            d = -d
        alpha = float(rng.choice([0.09, 0.25, 0.5]))
        eta = float(rng.choice([1.0 / 1.5, 1.5, 1.0]))
        seeds = rng.integers(0, 2 ** 63, 1).astype(np.uint64)
        outs = []
        for real in (True, False):
            e = ggx_e(min(max(-float(d @ g), 0.0), 1.0), alpha)
            z = (multiscatter_factors(alpha, e, 1.5, 0.9, 0.8, 0.7, 1.0, 1.0, 1.0) if real
                 else (1.0, 1.0, 1.0, 1.0))
            out = (np.zeros((2 * ns, 3)), np.zeros((2 * ns, 3)), np.zeros((2 * ns, 3)),
                   np.zeros(2 * ns, np.bool_))
            # mirror share and transmission, specular 0 and metallic 0: no lobe
            _glossy_rays(np.int64(0), np.array([0, ns], np.int64), seeds,
                         np.zeros((0, 4), np.uint64), 0.1, 0.2, 0.3, *g, *g, *d, 1e-6,
                         1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.9, 0.9, 0.9, 0.4, 0.4, 0.4, 0.0, 0.0,
                         0.0, 1.5, 0.0, 0.9, 0.8, 0.7, 1.0, 1.0, 1.0, z, alpha, eta, 1.2,
                         *out)
            outs.append(out)
        for a, b in zip(*outs, strict=True):
            assert np.array_equal(a, b)
        assert outs[0][3].any()


def test_glossy_rays_of_a_negative_specular_texel_keep_the_layer_factor():
    """A specular texture (``TEX_SPECULAR``; the engine takes any finite texel, the add-on
    clips them to [0, 1]) may make a channel's specular weight negative where the others
    are 0: no lobe (the shade kernel's ``z`` stays 1) yet a non-zero Fresnel, which the
    glossy rays carry with the layer's multiple-scattering factor, as before session 42.
    The same ball with a subnormal green texel (a lobe: ``z`` computed; its green weight
    too small to change a bit) renders the same bits."""
    from rstrace_engine.geometry.elements import TEX_NO_BASE, TEX_SPECULAR
    from rstrace_engine.geometry.scene import Material

    frames = []
    for green in (0.0, 1e-44):
        tex = np.zeros((4, 4, 3), np.float32)
        tex[..., 0] = -0.5
        tex[..., 1] = green
        mat = Material("negative_specular", diffuse=(0.0, 0.0, 0.0), specular=(0.4, 0.4, 0.4),
                       roughness=0.2, mirror=(1.0, 1.0, 1.0), transmission=(0.4, 0.4, 0.4),
                       ior=1.5, model="PRINCIPLED", specular_ior=1.5, texture=tex,
                       texture_flags=TEX_SPECULAR | TEX_NO_BASE)
        assert (tex[..., 1] > 0).all() == (green > 0)
        f = whitted.render(_ball(mat, world=(0.6, 0.7, 0.9), size=16),
                           RenderSettings(max_depth=3, glossy_samples=4))
        frames.append(f.radiance)
    assert (frames[0][..., 1:] > 0).any()
    assert np.array_equal(frames[0], frames[1])
