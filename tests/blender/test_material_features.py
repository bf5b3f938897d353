"""Material and mesh features of issue 23 against Cycles: image texture coordinates
(Generated, Object, Mapping), Closest interpolation, byte sRGB images interpolated before
decoding, Extend/Clip, flat-shaded non-planar quads, Cycles' default surface, the view
layer's material override; and the texture set-ups not modelled, reported naming the
material and the node.

Scenes are 96 x 72 px, lit by a sun without angle, Cycles rendering direct light only
(``test_render._cycles``). Each modelled case asserts the largest 8 x 8-block relative
error (:func:`test_cycles_agreement._block_error`) within a tolerance stated beside the
value measured when it was written.
"""

from __future__ import annotations

import math

import bmesh
import bpy
import numpy as np
import pytest

from . import builders as b
from .test_cycles_agreement import _block_error
from .test_render import _cycles, _ours, _state, needs_cycles

W, H = 96, 72


def _setup():
    sc = b.setup_render(W, H, samples=16, max_depth=0)
    b.set_world((0.0, 0.0, 0.0))
    sun = b.point_light("Sun", (0.0, 0.0, 5.0), 3.0, kind="SUN")
    sun.data.angle = 0.0
    sun.rotation_euler = (math.radians(20.0), math.radians(10.0), 0.0)
    return sc


def _top_camera(scale: float = 2.2):
    cam = b.camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = scale
    return cam


def checker(name: str = "Checker", n: int = 8, byte: bool = True):
    """An n x n black-and-white checker image (byte sRGB, or float linear)."""
    img = bpy.data.images.new(name, n, n, alpha=False, float_buffer=not byte)
    cells = (np.add.outer(np.arange(n), np.arange(n)) % 2).astype(np.float32)
    rgba = np.ones((n, n, 4), np.float32)
    rgba[..., :3] = cells[..., None] * np.array([0.9, 0.8, 0.7], np.float32)
    img.pixels.foreach_set(rgba.reshape(-1))
    img.pack()
    return img


def textured(name: str, img, interpolation: str = "Linear", extension: str = "REPEAT",
             coords: str | None = None, mapping: dict | None = None, into: str = "Base Color",
             shader: str | None = None, inputs: dict | None = None):
    """A Principled material (roughness 1, no specular: a plain diffuse in both renderers)
    with ``img`` into ``into``; ``coords``: a Texture Coordinate output feeding the image,
    through a Mapping node of ``mapping`` (vector_type and inputs) when given. ``shader``: a
    BSDF node type in the Principled's place; ``inputs``: its inputs' values."""
    mat = b.principled(name, (0.8, 0.8, 0.8), roughness=1.0, specular_level=0.0)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    if shader is not None:
        nodes.remove(bsdf)
        bsdf = nodes.new(shader)
        links.new(bsdf.outputs[0], nodes["Material Output"].inputs["Surface"])
    for key, value in (inputs or {}).items():
        bsdf.inputs[key].default_value = value
    tex = nodes.new("ShaderNodeTexImage")
    tex.name = "Image"
    tex.image = img
    tex.interpolation = interpolation
    tex.extension = extension
    links.new(tex.outputs["Color"], bsdf.inputs[into])
    if into == "Emission Color":
        bsdf.inputs["Emission Strength"].default_value = 1.0
    vec = tex.inputs["Vector"]
    if mapping is not None:
        mp = nodes.new("ShaderNodeMapping")
        mp.name = "Map"
        mp.vector_type = mapping.get("type", "POINT")
        for key in ("Location", "Rotation", "Scale"):
            if key in mapping:
                mp.inputs[key].default_value = mapping[key]
        links.new(mp.outputs["Vector"], vec)
        vec = mp.inputs["Vector"]
    if coords is not None:
        tc = nodes.new("ShaderNodeTexCoord")
        tc.name = "Coords"
        links.new(tc.outputs[coords], vec)
    return mat


def _plane(name: str = "Plane", uv_scale: float = 3.0, size: float = 2.0):
    """A 2 x 2 plane (4 x 4 quads) whose UVs run over [0, uv_scale]: UV sampling and the
    Generated / Object coordinates give different pictures."""
    me = b.grid(name, size, 4)
    uv = np.empty(len(me.loops) * 2, np.float32)
    me.uv_layers[0].uv.foreach_get("vector", uv)
    me.uv_layers[0].uv.foreach_set("vector", uv * uv_scale)
    return me


def _warnings() -> list[str]:
    import addon

    return addon.export.export_scene(bpy.context.evaluated_depsgraph_get()).warnings


def _reported(messages, *parts) -> bool:
    """Whether one message (a text, or a render's ``(level, text)``) holds every part."""
    texts = [m[1] if isinstance(m, tuple) else m for m in messages]
    return any(all(p in t for p in parts) for t in texts)


def _agreement(cycles_samples: int = 64) -> float:
    return _block_error(_ours(), _cycles(samples=cycles_samples))


# ----------------------------------------------------------------------------- textures

#: case -> (material arguments, tolerance on the largest 8x8-block relative error; measured
#: 16 samples x 2 seeds; "grid": the value under the jittered pixel grid before the Sobol
#: sampler, docs/accuracy.md; values without it were measured under that grid)
TEXTURE_CASES = {
    # a magnified 8x8 byte checker, bilinear: Cycles interpolates the sRGB bytes
    "byte_srgb_linear": (dict(), 0.02),  # measured 0.0048 (grid 0.0114)
    "closest": (dict(interpolation="Closest"), 0.04),  # 0.0112 (grid 0.0197)
    "float_linear": (dict(byte=False), 0.02),  # 0.0044 (grid 0.0094)
    "generated": (dict(coords="Generated"), 0.02),  # 0.0054 (grid 0.0107)
    "object_mapping": (dict(coords="Object", mapping={
        "type": "POINT", "Location": (0.5, 0.5, 0.0), "Rotation": (0.0, 0.0, 0.4),
        "Scale": (0.5, 0.5, 1.0)}), 0.02),  # 0.0052 (grid 0.0126)
    "uv_mapping_texture": (dict(coords="UV", mapping={
        "type": "TEXTURE", "Location": (0.2, 0.1, 0.0), "Rotation": (0.0, 0.0, -0.3),
        "Scale": (2.0, 1.5, 1.0)}), 0.03),  # 0.0070 (grid 0.0222: 16 samples of a fine checker)
    "extend": (dict(extension="EXTEND", coords="Generated", mapping={
        "Scale": (1.6, 1.6, 1.0), "Location": (-0.3, -0.3, 0.0)}), 0.03),  # 0.0069 (grid 0.0107)
    "clip": (dict(extension="CLIP", coords="Generated", mapping={
        "Scale": (1.6, 1.6, 1.0), "Location": (-0.3, -0.3, 0.0)}), 0.02),  # 0.0038
    # an image into the Emission Color (the base colour a constant grey)
    "emission": (dict(into="Emission Color"), 0.02),  # 0.0100
    # images into the weights of the glossy lobe (roughness 0.4: the sun's highlight spread
    # over the plane): the metal colour of a Glossy BSDF, a Metallic BSDF and a metallic
    # Principled's Base Color; a dark dielectric's Specular Tint (and the base under it)
    "glossy_colour": (dict(shader="ShaderNodeBsdfGlossy", into="Color",
                           inputs={"Roughness": 0.4}), 0.03),  # 0.0179
    "metallic_bsdf": (dict(shader="ShaderNodeBsdfMetallic", into="Base Color",
                           inputs={"Roughness": 0.4}), 0.03),  # 0.0183
    "metal_base_colour": (dict(inputs={"Metallic": 1.0, "Roughness": 0.4}), 0.03),  # 0.0190
    "specular_tint": (dict(into="Specular Tint", inputs={
        "Base Color": (0.05, 0.05, 0.05, 1.0), "Roughness": 0.4,
        "Specular IOR Level": 1.0}), 0.02),  # 0.0110
}


@needs_cycles
@pytest.mark.parametrize("case", sorted(TEXTURE_CASES))
def test_image_texture_agrees_with_cycles(case):
    args, tolerance = TEXTURE_CASES[case]
    args = dict(args)
    _setup()
    img = checker(byte=args.pop("byte", True))
    b.add_object("Plane", _plane(), material=textured("Tex", img, **args))
    _top_camera()
    err = _agreement()
    print(f"{case}: largest 8x8-block error vs Cycles {err:.4f}")
    assert err < tolerance
    assert not _reported(_state().messages, "'Tex'"), _state().messages


@needs_cycles
@pytest.mark.parametrize("tint, tolerance", [((0.0, 0.0, 0.0), 0.02),  # 0.0108 (was 0.090)
                                             ((0.2, 0.5, 1.0), 0.02)])  # 0.0131
def test_plain_specular_tint_agrees_with_cycles(tint, tolerance):
    """A dielectric's Specular Tint without an image: the layer's reflection is tinted and
    the base under it loses the layer's albedo times the tint's largest channel (Cycles'
    layering; black: all of the base shows)."""
    _setup()
    mat = b.principled("Tint", (0.5, 0.5, 0.5), roughness=0.4, specular_level=1.0)
    mat.node_tree.nodes["Principled BSDF"].inputs["Specular Tint"].default_value = (*tint, 1)
    b.add_object("Plane", _plane(), material=mat)
    _top_camera()
    err = _agreement()
    print(f"Specular Tint {tint}: largest 8x8-block error vs Cycles {err:.4f}")
    assert err < tolerance


@needs_cycles
def test_byte_checker_mean_matches_cycles():
    """The issue's numbers: a magnified 8x8 checker's mean was 0.426 against Cycles' 0.229
    (decoded before interpolating); bilinear interpolation of the encoded bytes matches."""
    _setup()
    img = checker()
    b.add_object("Plane", _plane(uv_scale=1.0), material=textured("Tex", img))
    _top_camera(1.6)
    ours, cycles = _ours(), _cycles(samples=64)
    m_ours = float(np.mean((ours[0] + ours[1]) / 2))
    m_cycles = float(np.mean((cycles[0] + cycles[1]) / 2))
    print(f"checker mean ours {m_ours:.4f} cycles {m_cycles:.4f}")
    assert abs(m_ours / m_cycles - 1.0) < 0.02


# ----------------------------------------------------------------------------- mesh, defaults


def _bent_quads():
    """A 2 x 2 grid of quads, each with one corner lifted (non-planar), shaded flat."""
    me = bpy.data.meshes.new("Bent")
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=2, y_segments=2, size=1.0)
    for v in bm.verts:
        if abs(v.co.x) < 1e-6 and abs(v.co.y) < 1e-6:
            v.co.z = 0.6
        elif abs(v.co.x - 1.0) < 1e-6 and abs(v.co.y + 1.0) < 1e-6:
            v.co.z = -0.5
    bm.to_mesh(me)
    bm.free()
    me.shade_flat()
    return me


@needs_cycles
def test_flat_non_planar_quads_agree_with_cycles():
    _setup()
    b.add_object("Bent", _bent_quads(), material=b.diffuse("Grey", (0.7, 0.7, 0.7)))
    _top_camera()
    assert _agreement() < 0.02  # measured 0.0067 (one normal per quad: see docs/accuracy.md)


@needs_cycles
def test_default_surface_agrees_with_cycles():
    """No material and an empty slot: Cycles' default surface, a Principled BSDF at its
    defaults (its highlight included)."""
    _setup()
    b.add_object("Ground", b.grid("Ground", 8.0))  # no material
    ball = b.add_object("Ball", b.uv_sphere("Ball", 1.0, 48, 24), (0.0, 0.0, 1.0))
    ball.data.materials.append(None)  # an empty slot
    cam = b.camera((0.0, -6.0, 2.5), (0.0, 0.0, 0.9))
    sun = bpy.data.objects["Sun"]
    sun.rotation_euler = (math.radians(-50.0), 0.0, 0.0)  # toward the camera: a highlight
    del cam
    assert _agreement() < 0.04  # measured 0.0195


@needs_cycles
def test_material_override_agrees_with_cycles():
    _setup()
    b.add_object("Ground", b.grid("Ground", 8.0), material=b.diffuse("Floor", (0.1, 0.6, 0.1)))
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 48, 24), (0.0, 0.0, 1.0),
                 b.principled("Red", (0.8, 0.05, 0.05)))
    b.camera((0.0, -6.0, 2.5), (0.0, 0.0, 0.9))
    bpy.context.view_layer.material_override = b.principled("Clay", (0.3, 0.35, 0.7),
                                                            roughness=0.6)
    assert _agreement() < 0.04  # measured 0.0195
    assert not _reported(_state().messages, "override"), _state().messages


# ----------------------------------------------------------------------------- reported


@pytest.mark.parametrize("into, first", [("Emission Color", "Base Color"),
                                         ("Specular Tint", "Base Color")])
def test_two_images_into_one_material_are_reported(into, first):
    """A material has one image (its texel may multiply several inputs): a second, other
    image is reported naming both inputs, and the second input's own value used."""
    _setup()
    mat = textured("Glow", checker(), into=into)
    nodes = mat.node_tree.nodes
    other = nodes.new("ShaderNodeTexImage")
    other.image = checker("Other", 4)
    mat.node_tree.links.new(other.outputs["Color"], nodes["Principled BSDF"].inputs[first])
    b.add_object("Plane", _plane(), material=mat)
    _top_camera()
    w = _warnings()
    assert _reported(w, f"{into} besides another into the {first}", "'Glow'"), w


def test_one_image_into_several_inputs_is_one_texture():
    """The same image node into the Base Color, the Emission Color and the Specular Tint:
    one texture whose texel multiplies all three, nothing reported."""
    import addon
    from rstrace_engine.geometry.scene import TEX_EMISSION, TEX_NO_BASE, TEX_SPECULAR

    _setup()
    mat = textured("Tex", checker(), into="Base Color")
    nodes = mat.node_tree.nodes
    for into in ("Emission Color", "Specular Tint"):
        mat.node_tree.links.new(nodes["Image"].outputs["Color"],
                                nodes["Principled BSDF"].inputs[into])
    b.add_object("Plane", _plane(), material=mat)
    _top_camera()
    out = addon.export.export_scene(bpy.context.evaluated_depsgraph_get())
    assert not _reported(out.warnings, "'Tex'"), out.warnings
    (m,) = [m for m in out.scene.materials if m is not None and m.name == "Tex"]
    assert m.texture is not None
    assert m.texture_flags & (TEX_EMISSION | TEX_SPECULAR) == TEX_EMISSION | TEX_SPECULAR
    assert not m.texture_flags & TEX_NO_BASE


@pytest.mark.parametrize("output", ["Normal", "Camera", "Reflection"])
def test_unmodelled_texture_coordinates_are_reported(output):
    _setup()
    b.add_object("Plane", _plane(), material=textured("Tex", checker(), coords=output))
    _top_camera()
    w = _warnings()
    assert _reported(w, f"'{output}' output", "'Image'", "'Tex'"), w


def test_normal_mapping_and_other_uv_map_are_reported():
    _setup()
    mat = textured("Tex", checker(), coords="UV", mapping={"type": "NORMAL"})
    b.add_object("Plane", _plane(), material=mat)
    mat2 = textured("Other", checker())
    nodes = mat2.node_tree.nodes
    uvmap = nodes.new("ShaderNodeUVMap")
    uvmap.uv_map = "Second"
    mat2.node_tree.links.new(uvmap.outputs["UV"], nodes["Image"].inputs["Vector"])
    me = _plane("Plane2")
    me.uv_layers.new(name="Second")
    b.add_object("Plane2", me, (0.5, 0.0, 0.01), material=mat2)
    _top_camera()
    w = _warnings()
    assert _reported(w, "Mapping nodes of type 'Normal'", "'Map'", "'Tex'"), w
    assert _reported(w, "UV Map nodes", "'Other'", "'Second'", "'Plane2'"), w


def test_other_objects_space_is_reported():
    _setup()
    mat = textured("Tex", checker(), coords="Object")
    mat.node_tree.nodes["Coords"].object = bpy.data.objects["Sun"]
    b.add_object("Plane", _plane(), material=mat)
    _top_camera()
    w = _warnings()
    assert _reported(w, "another object's space", "'Coords'", "'Sun'", "'Tex'"), w


# ----------------------------------------------------------------------------- other modes


@pytest.mark.parametrize("case", ["emission", "object_mapping", "byte_srgb_linear",
                                  "metal_base_colour"])
def test_interpolant_mode_keeps_its_bound_on_new_textures(case):
    """The interpolants apply a texture per pixel as ``R + texel * D`` (the texel at the
    pixel's own hit): with a texture into the emission, Object coordinates through a Mapping
    node, or sRGB bytes decoded after interpolation, INTERPOLANT mode stays within epsilon
    of BASE (display space). A texel that also weights a rough metal colour is not affine:
    those cells fail (traced per pixel), within epsilon too."""
    from rstrace_engine.image import to_display

    args = dict(TEXTURE_CASES[case][0])
    _setup()
    b.add_object("Plane", _plane(), material=textured("Tex", checker(), **args))
    b.add_object("Ball", b.uv_sphere("Ball", 0.4, 24, 12), (0.3, 0.2, 0.4),
                 b.diffuse("Red", (0.7, 0.15, 0.1)))
    b.point_light("Lamp", (-1.0, -1.5, 2.0), 300.0)
    b.camera((0.0, -3.0, 2.5), (0.0, 0.0, 0.0))
    sc = b.setup_render(W, H, samples=1, max_depth=1)
    base = b.render_exr()["Combined"][..., :3]
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.epsilon = eps = 0.02
    # cells, to test them: where they do not pay (timed, so under load too) the fallback
    # would trace the frame (test_interpolant_mode)
    sc.rstrace.interpolant_fallback = False
    out = b.render_exr()["Combined"][..., :3]
    stats = _state().stats
    assert stats["mode"] == "INTERPOLANT" and stats["cells_built"] > 0, stats
    err = np.abs(to_display(out) - to_display(base)).max(axis=-1)
    print(f"{case}: max display error {err.max():.5f}, cells {stats['cells_built']}")
    assert err.max() <= eps + 1e-6
