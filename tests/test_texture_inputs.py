"""Images into inputs other than the diffuse colour (issue 23): the texel at each hit
multiplies the metal colour (a metallic Principled's Base Color, a Glossy or Metallic BSDF's
Color), the Specular Tint, and the transmission tint per crossing (a Glass BSDF's Color; its
square root for a transmissive Principled's Base Color), as Cycles' closure weights take
the colour at the hit.

Each case renders a plane textured with a two-texel image (Closest: the left half of the
view one colour, the right half the other) and the same plane with the untextured material
of each colour: each half is that render's, bit for bit (BASE). The interpolants trace such
roots per pixel (the radiance is not affine in these texels); an edit that makes a textured
material metallic renders as a fresh session does.
"""

from __future__ import annotations

import numpy as np
import pytest
from bound_scenes import grid_texture, textured_floor
from tracer_scenes import ortho_down

from rstrace_engine import image
from rstrace_engine.accel.accelerators import create_accelerator
from rstrace_engine.frame import CLASS_INTERPOLATED, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.cameras import camera_rays
from rstrace_engine.geometry.edits import MaterialSet
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import (
    TEX_CLOSEST,
    TEX_METAL,
    TEX_NO_BASE,
    TEX_NONLINEAR,
    TEX_SPECULAR,
    TEX_TRANSMISSION,
    TEX_TRANSMISSION_SQRT,
    Light,
    Material,
    Scene,
)
from rstrace_engine.interpolants import interpolant_cache
from rstrace_engine.interpolants.render import InterpolantRenderer
from rstrace_engine.interpolants.samples import nonlinear_roots
from rstrace_engine.session import Session
from rstrace_engine.tracing import whitted
from rstrace_engine.tracing.shading import fresnel_dielectric

#: the two texels (float32, as textures are stored): left and right half of the view
C1 = np.array([0.9, 0.5, 0.2], np.float32)
C2 = np.array([0.1, 0.7, 0.4], np.float32)
TEXTURE = np.array([[C1, C2]], np.float32)  # (h 1, w 2): u < 0.5 the first

SUN = Light("Sun", "SUN", power=3.0, direction=(0.2, 0.1, -1.0))


def _glass_over_glow(material: Material) -> Scene:
    """A plane of ``material`` at z = 2 over an emissive floor (radiance (1, 2, 3))."""
    s = Scene()
    mid = s.add_material(material)
    glow = s.add_material(Material("glow", diffuse=(0.0,) * 3, emission=(1.0, 2.0, 3.0)))
    s.add_instance(s.add_mesh(shapes.plane(100.0, name="floor")), np.eye(4), [glow])
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="sheet")),
                   shapes.transform((0.0, 0.0, 2.0)), [mid], name="Sheet")
    s.set_world_color((0.0, 0.0, 0.0), lights=False)
    s.set_camera(ortho_down())
    return s


def _lit_plane(material: Material) -> Scene:
    """A plane of ``material`` under a sun, in a world that lights it and is reflected."""
    s = Scene()
    mid = s.add_material(material)
    s.add_instance(s.add_mesh(shapes.plane(20.0, name="sheet")), np.eye(4), [mid],
                   name="Sheet")
    s.add_light(SUN)
    s.set_world_color((0.3, 0.4, 0.5), lights=True)
    s.set_camera(ortho_down())
    return s


#: case -> (scene builder, Principled arguments, how the texture enters: Base Color, or
#: Specular Tint, the flags the material's texture must carry, ray depth)
CASES = {
    "mirror metal": (_lit_plane, dict(metallic=1.0, roughness=0.0), "base", TEX_METAL, 1),
    "rough metal": (_lit_plane, dict(metallic=1.0, roughness=0.5), "base", TEX_METAL, 1),
    "half metal": (_lit_plane, dict(metallic=0.5, roughness=0.3), "base", TEX_METAL, 1),
    # (a black base: the base under a tinted layer, test_tinted_layer_lets_the_base_through)
    "specular tint": (_lit_plane, dict(roughness=0.3, specular_level=1.0, base=(0, 0, 0)),
                      "tint", TEX_SPECULAR, 1),
    "Glass BSDF": (_glass_over_glow, dict(roughness=0.0, transmission=1.0,
                                          tint_per_crossing=True), "base", TEX_TRANSMISSION,
                   2),
    "Principled glass": (_glass_over_glow, dict(roughness=0.0, transmission=1.0), "base",
                         TEX_TRANSMISSION_SQRT, 2),
    "rough Principled glass": (_glass_over_glow, dict(roughness=0.4, transmission=0.8),
                               "base", TEX_TRANSMISSION_SQRT, 2),
}


def _material(args: dict, into: str, colour=None) -> Material:
    """The case's material: textured (``colour`` None) or of one ``colour``."""
    args = dict(args)
    base = np.array(args.pop("base", (0.2, 0.3, 0.25)), np.float64)
    if colour is None:
        if into == "base":
            base = np.ones(3)
            args.update(texture=TEXTURE, texture_flags=TEX_CLOSEST)
        else:
            args.update(texture=TEXTURE, texture_flags=TEX_CLOSEST | TEX_SPECULAR | TEX_NO_BASE)
    elif into == "base":
        base = np.asarray(colour, np.float64)
    else:
        args.update(specular_tint=np.asarray(colour, np.float64))
    mat, notes = principled_material("Sheet", base, **args)
    assert notes == [], notes
    return mat


def _render(scene: Scene, depth: int):
    return whitted.render(scene, RenderSettings(max_depth=depth, samples=2),
                          accel=create_accelerator("BVH", scene.arrays())).radiance


@pytest.mark.parametrize("case", sorted(CASES))
def test_texel_weights_what_its_input_weights(case):
    build, args, into, bits, depth = CASES[case]
    textured = _material(args, into)
    assert textured.texture_flags & TEX_NONLINEAR == bits
    got = _render(build(textured), depth)
    w = got.shape[1]
    left, right = slice(0, w // 2 - 1), slice(w // 2 + 1, w)  # (the seam's columns left out)
    for colour, cols in ((C1, left), (C2, right)):
        want = _render(build(_material(args, into, colour)), depth)
        np.testing.assert_array_equal(got[:, cols], want[:, cols], err_msg=case)
    # the two halves differ: the texel is the hit's own, not an average
    assert np.abs(got[:, left].mean(axis=(0, 1)) - got[:, right].mean(axis=(0, 1))).max() > 0.01


def test_tinted_layer_lets_the_base_through():
    """Cycles attenuates the base under the specular layer by that layer's albedo, tint
    included (its largest channel): where the Specular Tint's texel is black the base is
    lit as under no layer at all, where it is white as under the untinted layer."""
    black_white = np.array([[(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)]], np.float32)
    base = (0.5, 0.4, 0.3)
    args = dict(roughness=0.3, specular_level=1.0)
    mat, _ = principled_material("Sheet", base, texture=black_white,
                                 texture_flags=TEX_CLOSEST | TEX_SPECULAR | TEX_NO_BASE,
                                 **args)
    got = _render(_lit_plane(mat), 1)
    w = got.shape[1]
    for cols, level in ((slice(0, w // 2 - 1), 0.0), (slice(w // 2 + 1, w), 1.0)):
        plain, _ = principled_material("Sheet", base, roughness=0.3, specular_level=level)
        want = _render(_lit_plane(plain), 1)
        np.testing.assert_allclose(got[:, cols], want[:, cols], rtol=1e-12, atol=1e-15)


def test_principled_glass_reflects_untinted():
    """Cycles tints a Principled BSDF's refraction by the square root of its Base Color
    and its reflection by the Specular Tint alone: where the image is black the glass is
    still a (white) reflector, where it is white it is clear glass."""
    black_white = np.array([[(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)]], np.float32)
    world = np.array([0.5, 0.6, 0.7])
    mat, _ = principled_material("Sheet", np.ones(3), roughness=0.0, transmission=1.0,
                                 texture=black_white, texture_flags=TEX_CLOSEST)
    scene = _glass_over_glow(mat)
    scene.set_world_color(world, lights=False)
    got = _render(scene, 2)
    w = got.shape[1]
    f = fresnel_dielectric(1.0, 1.0 / 1.5)  # straight down onto the sheet
    np.testing.assert_allclose(got[:, :w // 2 - 1], np.broadcast_to(f * world, (got.shape[0],
                               w // 2 - 1, 3)), rtol=1e-6)  # (a float32 frame)
    clear, _ = principled_material("Sheet", np.ones(3), roughness=0.0, transmission=1.0)
    scene = _glass_over_glow(clear)
    scene.set_world_color(world, lights=False)
    np.testing.assert_array_equal(got[:, w // 2 + 1:], _render(scene, 2)[:, w // 2 + 1:])


def test_ward_model_keeps_the_average_and_says_so():
    """The WARD model has one mirror and lobe weight (the metal's among them): a textured
    metal colour, tint or transmission takes the texture's mean, with a message."""
    mat, notes = principled_material("Sheet", np.ones(3), metallic=1.0, roughness=0.0,
                                     texture=TEXTURE, texture_flags=TEX_CLOSEST, model="WARD")
    assert any("textured metallic colour" in n for n in notes)
    assert mat.texture_flags & TEX_NONLINEAR == 0
    np.testing.assert_allclose(mat.mirror, (C1 + C2) / 2, rtol=1e-6)
    mat, notes = principled_material("Sheet", (0.5, 0.5, 0.5), texture=TEXTURE,
                                     texture_flags=TEX_CLOSEST | TEX_SPECULAR | TEX_NO_BASE,
                                     model="WARD")
    assert any("textured Specular Tint" in n for n in notes)
    assert mat.texture is None  # it multiplied the tint alone: folded into it


def test_diffuse_and_emission_textures_are_unchanged():
    """A texture into the Base Color of a plain dielectric (and the emission) carries no
    new bits: the interpolants keep splitting it."""
    mat, notes = principled_material("Sheet", np.ones(3), roughness=0.5, texture=TEXTURE,
                                     texture_flags=TEX_CLOSEST)
    assert notes == [] and mat.texture_flags == TEX_CLOSEST


@pytest.fixture
def small_cells(monkeypatch):
    monkeypatch.setattr(interpolant_cache, "MIN_PIXELS", 6)
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)


def _tiles(metallic: float, roughness: float, **args) -> Scene:
    """bound_scenes.textured_floor (a fine grid image on the floor, a ball, a point light)
    with a Principled floor of that metallic and roughness."""
    scene = textured_floor("PERSP")
    mat, _ = principled_material("tiles", np.ones(3), metallic=metallic, roughness=roughness,
                                 texture=grid_texture(), **args)
    scene.materials[0] = mat.validated()
    return scene


@pytest.mark.parametrize("case, affine", [
    (dict(metallic=1.0, roughness=0.0), True),  # a mirror's Fresnel: affine in the texel
    (dict(metallic=0.0, roughness=0.0, transmission=1.0, tint_per_crossing=True), True),
    (dict(metallic=0.5, roughness=0.5), False),  # the lobe's multiple scattering: not
    (dict(metallic=0.0, roughness=0.0, transmission=1.0), False),  # sqrt(texel)
    (dict(metallic=0.0, roughness=0.0, texture_flags=TEX_SPECULAR), False),  # max(texel)
])
def test_nonlinear_roots(case, affine):
    scene = _tiles(**case)
    sa = scene.arrays()
    hits = create_accelerator("BVH", sa).closest_hit(*camera_rays(scene.camera))
    on_floor = hits.inst == 0
    assert on_floor.sum() > 100
    flagged = nonlinear_roots(sa, hits.inst, np.maximum(hits.prim, 0))
    assert not flagged[~on_floor].any()
    assert flagged[on_floor].all() != affine


@pytest.mark.parametrize("metallic, roughness", [(1.0, 0.0), (0.5, 0.0), (0.5, 0.5)])
def test_interpolants_keep_their_bound_on_textured_metal(small_cells, metallic, roughness):
    """INTERPOLANT within epsilon of BASE on a textured metal floor: a smooth one is
    interpolated (the texel applied per pixel, as the diffuse one), a rough one's roots
    fail their cells."""
    eps = 0.02
    scene = _tiles(metallic, roughness)
    accel = create_accelerator("BVH", scene.arrays())
    st = RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=2)
    frame = InterpolantRenderer().render(scene, st, accel)
    base = whitted.render(scene, st, accel=accel)
    err = np.abs(image.to_display(frame.radiance)
                 - image.to_display(base.radiance)).max(axis=-1)
    interp = frame.pixel_class == CLASS_INTERPOLATED
    print(f"metallic {metallic} roughness {roughness}: interpolated {interp.mean():.3f}, "
          f"max display error {err.max():.5f}")
    assert err.max() <= eps + 1e-6
    assert np.all(err[~interp] == 0.0)
    if roughness == 0.0:
        assert interp.mean() > 0.1


def test_edit_to_a_textured_metal_renders_as_fresh():
    """BASE: making the textured floor metallic (new texture bits) by an edit gives the
    fresh session's frame of the edited scene."""
    settings = RenderSettings(max_depth=2)
    sess = Session(_tiles(0.0, 0.3), settings)
    before = sess.render()
    sess.apply([MaterialSet("tiles", _tiles(0.7, 0.3).materials[0])])
    frame = sess.render()
    fresh = Session(sess.scene.copy(), settings).render()
    np.testing.assert_allclose(frame.radiance, fresh.radiance, rtol=0, atol=1e-6)
    assert frame.stats["incremental"]
    assert np.abs(frame.radiance - before.radiance).max() > 0.01
