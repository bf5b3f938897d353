"""The feature corpus (issue 23): one small scene per Blender feature (96 x 72), each
asserted either *modelled* -- rendered by RSTrace as Cycles renders it, the largest relative
error of 8 x 8-block means within the feature's stated tolerance -- or *reported* -- the F12
render's messages name it. docs/compatibility.md lists the same features with the errors
measured here (:func:`test_compatibility_page_lists_the_corpus` keeps the two together).

Cycles renders as in the agreement tests (test_cycles_agreement): direct light, the glossy
and transmission bounces a scene needs, box filter of one pixel, no denoising, one seed.
Add a feature here whenever one is modelled or found.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
import pytest

from . import builders as b
from .test_render import _lum, _state, needs_cycles

W, H = 96, 72
PAGE = Path(__file__).resolve().parents[2] / "docs" / "compatibility.md"


@dataclass
class Feature:
    name: str
    build: object  # () -> None: the scene (on a fresh factory file)
    words: tuple = ()  # reported: every word is in one of the render's messages
    tol: float | None = None  # modelled: largest 8x8-block relative error vs Cycles
    compare: str = "combined"  # combined, holdout (colour and alpha), depth, normal
    glossy: int = 0  # Cycles' glossy / transmission bounces (ours: max ray depth)
    transmission: int = 0
    cycles_samples: int = 64
    samples: int = 16
    extra: dict = field(default_factory=dict)

    @property
    def modelled(self) -> bool:
        return self.tol is not None


# ----------------------------------------------------------------------------- scenes


def _stage(ball_material=None, world=(0.0, 0.0, 0.0), key: bool = True,
           chrome: bool = True):
    """Floor, a red ball, a mirror ball, a key light, the camera; returns the red ball.
    (The light scenes have no mirror ball: the lights seen in it are the seen-lights rows'.)
    The world is black: a coloured one that lights nothing (diffuse and glossy visibility
    off) is still seen in RSTrace's mirrors, not in Cycles' (reported in docs/compatibility.md)."""
    b.set_world(world, lights=False)
    b.add_object("Ground", b.grid("Ground", 12.0), material=b.diffuse("Floor", (0.6, 0.6, 0.55)))
    ball = b.add_object("Ball", b.uv_sphere("Ball", 1.0, 32, 16), (-0.9, 0.4, 1.0),
                        ball_material or b.diffuse("Red", (0.7, 0.15, 0.1)))
    if chrome:
        b.add_object("Chrome", b.uv_sphere("Chrome", 1.0, 32, 16), (1.2, -0.2, 1.0),
                     b.principled("Chrome", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0))
    if key:
        b.point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    b.camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    return ball


def _light(kind: str, **settings):
    def build():
        _stage(key=False, chrome=False)
        ob = b.point_light("Lamp", (-2.0, -3.0, 5.0), 1500.0, kind=kind)
        b.look_at(ob, (0.0, 0.0, 0.5))
        for attr, value in settings.items():
            setattr(ob.data, attr, value)
    return build


def _light_node_strength():
    _stage(key=False, chrome=False)
    ob = b.point_light("Lamp", (-2.0, -3.0, 5.0), 500.0)
    ob.data.use_nodes = True
    ob.data.node_tree.nodes["Emission"].inputs["Strength"].default_value = 3.0


def _light_unseen():
    _stage()
    fill = b.point_light("Fill", (3.0, -2.0, 4.0), 2000.0, (0.5, 0.7, 1.0))
    fill.visible_diffuse = fill.visible_glossy = False


def _glossy_stage():
    """The stage with a glossy red ball (roughness 0.3: a highlight lights draw) and a
    fill light; returns the fill."""
    _stage(b.principled("Glossy red", (0.7, 0.15, 0.1), roughness=0.3))
    return b.point_light("Fill", (3.0, -2.0, 4.0), 2000.0, (0.5, 0.7, 1.0))


def _fill_without(part: str):
    def build():
        setattr(_glossy_stage(), f"visible_{part}", False)
    return build


def _linking(which: str, state: str):
    """The Key's receiver or blocker collection holding the red ball, linked ``state``
    (INCLUDE: the Key lights only the ball / only the ball casts its shadows; EXCLUDE:
    every object but the ball)."""
    def build():
        _glossy_stage()
        ball = bpy.data.objects["Ball"]
        col = bpy.data.collections.new(f"Key {which}s")
        col.objects.link(ball)
        col.collection_objects[0].light_linking.link_state = state
        setattr(bpy.data.objects["Key"].light_linking, f"{which}_collection", col)
    return build


def _scaled_spot():
    _stage(key=False, chrome=False)
    ob = b.point_light("Spot", (-2.0, -3.0, 5.0), 1500.0, kind="SPOT")
    b.look_at(ob, (0.0, 0.0, 0.5))
    ob.data.spot_size = math.radians(40.0)
    ob.data.spot_blend = 0.2
    ob.scale = (1.0, 2.5, 1.0)


def _emission():
    mat = b.principled("Glow", (0.0, 0.0, 0.0), specular_level=0.0)
    node = mat.node_tree.nodes["Principled BSDF"]
    node.inputs["Emission Color"].default_value = (1.0, 0.6, 0.2, 1.0)
    node.inputs["Emission Strength"].default_value = 2.0
    mat.cycles.emission_sampling = "NONE"  # (RSTrace: emissive meshes light nothing)
    _stage(mat).visible_diffuse = False  # Cycles: the floor's BSDF rays would see it


def _tinted_glass():
    glass = b.principled("Green glass", (0.2, 0.9, 0.3), roughness=0.0,
                         **{"IOR": 1.5, "Transmission Weight": 1.0})
    _stage(glass)


def _holdout_object():
    _stage().is_holdout = True


def _holdout_collection():
    ball = _stage()
    col = bpy.data.collections.new("Cutout")
    bpy.context.scene.collection.children.link(col)
    for c in list(ball.users_collection):
        c.objects.unlink(ball)
    col.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Cutout"].holdout = True


def _holdout_shader():
    mat = bpy.data.materials.new("Hole")
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    hold = nodes.new("ShaderNodeHoldout")
    mat.node_tree.links.new(hold.outputs[0], nodes["Material Output"].inputs["Surface"])
    _stage(mat)


def _passes():
    _stage()
    layer = bpy.context.view_layer
    layer.use_pass_z = layer.use_pass_normal = True


def _with_material(setup):
    """A scene whose ball has a Principled material changed by ``setup(mat, nodes)``."""
    def build():
        mat = b.principled("Ball material", (0.7, 0.15, 0.1))
        setup(mat, mat.node_tree.nodes)
        _stage(mat)
    return build


def _link(mat, node, output, socket):
    mat.node_tree.links.new(node.outputs[output], socket)


def _bump(mat, nodes):
    noise, bump = nodes.new("ShaderNodeTexNoise"), nodes.new("ShaderNodeBump")
    _link(mat, noise, "Fac", bump.inputs["Height"])
    _link(mat, bump, "Normal", nodes["Principled BSDF"].inputs["Normal"])


def _procedural(mat, nodes):
    _link(mat, nodes.new("ShaderNodeTexNoise"), "Color",
          nodes["Principled BSDF"].inputs["Base Color"])


def _displacement(mat, nodes):
    _link(mat, nodes.new("ShaderNodeDisplacement"), "Displacement",
          nodes["Material Output"].inputs["Displacement"])


def _volume(mat, nodes):
    _link(mat, nodes.new("ShaderNodeVolumeAbsorption"), 0,
          nodes["Material Output"].inputs["Volume"])


def _set_input(label, value):
    def setup(mat, nodes):
        nodes["Principled BSDF"].inputs[label].default_value = value
    return setup


def _scene_change(change):
    def build():
        ball = _stage()
        change(ball, bpy.context.scene)
    return build


def _dof(ball, sc):
    sc.camera.data.dof.use_dof = True


def _motion_blur(ball, sc):
    sc.render.use_motion_blur = True


def _hair(ball, sc):
    bpy.context.view_layer.objects.active = ball
    ball.modifiers.new("Hair", "PARTICLE_SYSTEM")
    ball.particle_systems[0].settings.type = "HAIR"


def _world_volume(ball, sc):
    nodes = sc.world.node_tree.nodes
    vol = nodes.new("ShaderNodeVolumeScatter")
    sc.world.node_tree.links.new(vol.outputs[0], nodes["World Output"].inputs["Volume"])


def _shadow_catcher(ball, sc):
    ball.is_shadow_catcher = True


def _indirect_only(ball, sc):
    col = bpy.data.collections.new("Bounce")
    sc.collection.children.link(col)
    col.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Bounce"].indirect_only = True


def _mist_pass(ball, sc):
    bpy.context.view_layer.use_pass_mist = True
    bpy.context.view_layer.use_pass_diffuse_direct = True


def _textured_ball(**args):
    """The ball with an 8 x 8 checker image (test_material_features.textured) fed as
    ``args`` say."""
    from .test_material_features import checker, textured

    def build():
        mat = textured("Checker ball", checker(), **args)
        if args.get("into") == "Emission Color":
            mat.cycles.emission_sampling = "NONE"  # (RSTrace: emissive meshes light nothing)
        ball = _stage(mat)
        if args.get("into") == "Emission Color":
            ball.visible_diffuse = False  # Cycles: the floor's BSDF rays would see it
    return build


def _bsdf_image(shader: str, into: str, **inputs):
    """The ball of a ``shader`` BSDF node whose ``into`` is the 8 x 8 checker image."""
    from .test_material_features import checker

    def build():
        mat = bpy.data.materials.new("Checker ball")
        nodes = mat.node_tree.nodes
        nodes.remove(nodes["Principled BSDF"])
        bsdf, tex = nodes.new(shader), nodes.new("ShaderNodeTexImage")
        tex.image = checker()
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        _link(mat, tex, "Color", bsdf.inputs[into])
        _link(mat, bsdf, 0, nodes["Material Output"].inputs["Surface"])
        _stage(mat)
    return build


def _two_images():
    from .test_material_features import checker, textured

    mat = textured("Checker ball", checker(), into="Specular Tint")
    other = mat.node_tree.nodes.new("ShaderNodeTexImage")
    other.image = checker("Other", 4)
    _link(mat, other, "Color", mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    _stage(mat)


def _other_uv_map():
    from .test_material_features import checker, textured

    mat = textured("Checker ball", checker())
    uvmap = mat.node_tree.nodes.new("ShaderNodeUVMap")
    uvmap.uv_map = "Second"
    _link(mat, uvmap, "UV", mat.node_tree.nodes["Image"].inputs["Vector"])
    ball = _stage(mat)
    ball.data.uv_layers.new(name="Second")


def _bent_quads():
    from .test_material_features import _bent_quads as bent

    _stage(chrome=False)
    ob = b.add_object("Bent", bent(), (1.2, -0.5, 1.2), b.diffuse("Grey", (0.7, 0.7, 0.7)))
    ob.rotation_euler = (math.radians(60.0), 0.0, math.radians(20.0))


def _no_material():
    ball = _stage(chrome=False)
    ball.data.materials.clear()
    ball.data.materials.append(None)  # an empty slot
    b.add_object("Bare", b.uv_sphere("Bare", 0.8, 32, 16), (1.2, -0.2, 0.8))  # none at all


def _seen_lights(sun: bool = False):
    """The stage, lit by the Key, with lights Cycles shows: a panel (an area light facing
    the camera, camera visibility on), a sphere light (no soft falloff) and a spot with a
    radius, both seen by the camera and in the mirror ball; with ``sun`` a sun with a 40
    degree disc seen in the ball only (Cycles: a sun is not seen by the camera unless its
    camera visibility is on)."""
    def build():
        _stage()
        panel = b.point_light("Panel", (-2.6, -2.0, 2.2), 60.0, kind="AREA")
        panel.data.shape = "RECTANGLE"
        panel.data.size, panel.data.size_y = 0.8, 0.5
        b.look_at(panel, (0.0, -8.5, 3.6))
        bulb = b.point_light("Bulb", (2.6, -2.6, 2.6), 150.0, (1.0, 0.8, 0.6))
        bulb.data.shadow_soft_size = 0.3
        spot = b.point_light("Spot", (0.4, -3.0, 3.4), 150.0, (0.6, 0.8, 1.0), kind="SPOT")
        spot.data.shadow_soft_size = 0.25
        spot.data.spot_size = math.radians(90.0)
        b.look_at(spot, (0.0, -8.5, 3.6))
        for ob in (panel, bulb, spot):
            ob.visible_camera = True
        if sun:  # behind the camera: its disc in the middle of the ball
            ob = b.point_light("Sun", (0.0, -12.0, 5.0), 0.5, kind="SUN")
            ob.data.angle = math.radians(40.0)
            b.look_at(ob, (1.2, -0.2, 1.0))
    return build


def _metal_ball(kind: str, **inputs):
    """A mirror metal ball filling most of the frame inside a white emissive dome (radiance
    1, seen in the ball only: each pixel is the metal's Fresnel at its angle, the F82 dip
    in its outer ring): a Principled BSDF (metallic, Specular Tint the F82 tint) or a
    Metallic BSDF node (F82 Edge Tint, or Physical Conductor)."""
    def build():
        b.set_world((0.0, 0.0, 0.0), lights=False)
        mat = bpy.data.materials.new("Metal ball")
        nodes = mat.node_tree.nodes
        if kind == "principled":
            bsdf = nodes["Principled BSDF"]
            bsdf.inputs["Metallic"].default_value = 1.0
        else:
            nodes.remove(nodes["Principled BSDF"])
            bsdf = nodes.new("ShaderNodeBsdfMetallic")
            bsdf.fresnel_type = kind
            _link(mat, bsdf, 0, nodes["Material Output"].inputs["Surface"])
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        b.add_object("Ball", b.uv_sphere("Ball", 1.0, 64, 32), (0.0, 0.0, 0.0), mat)
        glow = b.principled("Dome", (0.0, 0.0, 0.0), specular_level=0.0)
        node = glow.node_tree.nodes["Principled BSDF"]
        node.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        node.inputs["Emission Strength"].default_value = 1.0
        glow.cycles.emission_sampling = "NONE"  # (RSTrace: emissive meshes light nothing)
        b.add_object("Dome", b.uv_sphere("Dome", 30.0, 32, 16), (0.0, 0.0, 0.0), glow)
        b.camera((0.0, -3.6, 0.0), (0.0, 0.0, 0.0), lens=50.0)
    return build


def _override():
    _stage(chrome=False)
    bpy.context.view_layer.material_override = b.principled("Clay", (0.3, 0.35, 0.7),
                                                            roughness=0.6)


FEATURES = [
    # modelled: against Cycles
    Feature("point light", _light("POINT"), tol=0.05),
    Feature("spot light (size, blend)", _light("SPOT", spot_size=math.radians(50.0),
                                                spot_blend=0.3), tol=0.05),
    Feature("sun light", _light("SUN", energy=3.0), tol=0.05),
    Feature("area light (soft shadows)", _light("AREA", energy=400.0, size=1.5), tol=0.08,
            cycles_samples=128, samples=8),
    Feature("light node Emission Strength", _light_node_strength, tol=0.05),
    Feature("light with Diffuse and Glossy visibility off", _light_unseen, tol=0.05,
            glossy=1),
    # (direct light only: rough reflections of the glossy ball are the glossy issue's)
    Feature("light with Diffuse visibility off", _fill_without("diffuse"), tol=0.05),
    Feature("light with Glossy visibility off", _fill_without("glossy"), tol=0.05),
    Feature("light linking (receivers)", _linking("receiver", "INCLUDE"), tol=0.05),
    Feature("shadow linking (blockers, one excluded)", _linking("blocker", "EXCLUDE"),
            tol=0.05),
    Feature("non-uniformly scaled spot", _scaled_spot, tol=0.05),
    Feature("emission (seen directly and in a mirror)", _emission, tol=0.05, glossy=1),
    Feature("mirror metal (one glossy bounce)", _stage, tol=0.05, glossy=1),
    Feature("tinted Principled glass", _tinted_glass, tol=0.1, glossy=8, transmission=8),
    Feature("holdout object", _holdout_object, tol=0.05, compare="holdout", glossy=1),
    Feature("holdout collection", _holdout_collection, tol=0.05, compare="holdout",
            glossy=1),
    Feature("Holdout shader", _holdout_shader, tol=0.05, compare="holdout", glossy=1),
    Feature("Depth pass", _passes, tol=0.03, compare="depth"),
    Feature("Normal pass", _passes, tol=0.02, compare="normal"),
    Feature("image texture, byte sRGB, Linear", _textured_ball(), tol=0.05),
    Feature("image texture, Closest", _textured_ball(interpolation="Closest"), tol=0.05),
    Feature("image texture, Generated coordinates", _textured_ball(coords="Generated"),
            tol=0.05),
    Feature("image texture, Object coordinates through Mapping",
            _textured_ball(coords="Object", mapping={"Scale": (2.0, 2.0, 2.0),
                                                     "Rotation": (0.0, 0.0, 0.5)}), tol=0.05),
    Feature("image texture, Clip extension",
            _textured_ball(coords="Generated", extension="CLIP",
                           mapping={"Scale": (1.5, 1.5, 1.0)}), tol=0.05),
    Feature("image into Emission Color", _textured_ball(into="Emission Color"), tol=0.05,
            glossy=1),
    Feature("image into Glossy BSDF colour",
            _bsdf_image("ShaderNodeBsdfGlossy", "Color", Roughness=0.3), tol=0.05),
    Feature("image into a metallic Base Color",
            _textured_ball(inputs={"Metallic": 1.0, "Roughness": 0.3}), tol=0.05),
    Feature("image into Specular Tint",
            _textured_ball(into="Specular Tint", inputs={
                "Base Color": (0.05, 0.05, 0.05, 1.0), "Roughness": 0.3,
                "Specular IOR Level": 1.0}), tol=0.05),
    Feature("image into Glass BSDF colour",
            _bsdf_image("ShaderNodeBsdfGlass", "Color", Roughness=0.0), tol=0.05,
            glossy=8, transmission=8),
    Feature("image into a transmissive Principled's Base Color",
            _textured_ball(inputs={"Roughness": 0.0, "Transmission Weight": 1.0,
                                   "Specular IOR Level": 0.5}), tol=0.05,
            glossy=8, transmission=8),
    Feature("flat-shaded non-planar quads", _bent_quads, tol=0.05),
    Feature("no material, empty slot (default surface)", _no_material, tol=0.05),
    Feature("view layer material override", _override, tol=0.05),
    Feature("lights seen by the camera and in a mirror (area, sphere, spot)",
            _seen_lights(), tol=0.08, glossy=1),
    Feature("sun disc seen in a mirror", _seen_lights(sun=True), tol=0.08, glossy=1),
    Feature("Principled metallic Specular Tint (F82)",
            _metal_ball("principled", **{"Base Color": (0.95, 0.64, 0.54, 1.0),
                                         "Specular Tint": (0.2, 0.5, 1.0, 1.0),
                                         "Roughness": 0.0}), tol=0.02, glossy=1),
    Feature("Metallic BSDF Edge Tint (F82)",
            _metal_ball("F82", **{"Base Color": (0.9, 0.85, 0.5, 1.0),
                                  "Edge Tint": (1.0, 0.3, 0.2, 1.0), "Roughness": 0.0}),
            tol=0.02, glossy=1),
    Feature("Metallic BSDF Physical Conductor",
            _metal_ball("PHYSICAL_CONDUCTOR", **{"IOR": (0.27, 0.68, 1.22),
                                                 "Extinction": (3.61, 2.62, 2.29),
                                                 "Roughness": 0.0}), tol=0.02, glossy=1),
    # reported: named in the render's messages
    Feature("depth of field", _scene_change(_dof), words=("depth of field",)),
    Feature("motion blur", _scene_change(_motion_blur), words=("motion blur",)),
    Feature("Principled alpha", _with_material(_set_input("Alpha", 0.5)),
            words=("transparency", "'Ball material'")),
    Feature("bump map", _with_material(_bump), words=("bump", "'Ball material'")),
    Feature("procedural texture", _with_material(_procedural),
            words=("Noise Texture", "'Ball material'")),
    Feature("displacement", _with_material(_displacement),
            words=("displacement", "'Ball material'")),
    Feature("diffuse roughness", _with_material(_set_input("Diffuse Roughness", 0.5)),
            words=("diffuse roughness", "'Ball material'")),
    Feature("volume under a surface", _with_material(_volume),
            words=("volume shaders", "'Ball material'")),
    Feature("world volume", _scene_change(_world_volume), words=("world volumes",)),
    Feature("particle hair", _scene_change(_hair), words=("particle hair", "'Ball'")),
    Feature("shadow catcher", _scene_change(_shadow_catcher),
            words=("shadow catcher", "'Ball'")),
    Feature("indirect only collection", _scene_change(_indirect_only),
            words=("indirect only", "'Bounce'")),
    Feature("passes not written (Mist, Diffuse Direct)", _scene_change(_mist_pass),
            words=("passes not written", "Mist", "Diffuse Direct")),
    Feature("two images into Base Color and Specular Tint", _two_images,
            words=("Specular Tint besides another into the Base Color", "'Checker ball'")),
    Feature("Texture Coordinate Normal output", _textured_ball(coords="Normal"),
            words=("'Normal' output", "'Image'", "'Checker ball'")),
    Feature("UV Map node naming another UV map", _other_uv_map,
            words=("UV Map nodes", "'Second'", "'Ball'")),
]


# ----------------------------------------------------------------------------- measures


def _blocks(a: np.ndarray, block: int = 8) -> np.ndarray:
    h, w = (a.shape[0] // block) * block, (a.shape[1] // block) * block
    return a[:h, :w].reshape(h // block, block, w // block, block, *a.shape[2:]).mean(
        axis=(1, 3))


def block_error(ours: np.ndarray, ref: np.ndarray, floor: float = 0.05) -> float:
    """Largest relative error of 8x8-block luminance means over the blocks of ``ref``
    holding at least ``floor`` of its brightest block's light."""
    o, c = _blocks(_lum(ours)), _blocks(_lum(ref))
    keep = c > floor * c.max()
    return float(np.max(np.abs(o[keep] - c[keep]) / c[keep]))


def depth_error(ours: np.ndarray, ref: np.ndarray) -> float:
    """Largest 8x8-block median of the per-pixel relative depth error, over the pixels both
    renderers hit (their sample 0 lies elsewhere in a pixel: at a silhouette one may hit
    the ball and the other the floor behind it), blocks with at least 16 such pixels."""
    both = (ours < 1e9) & (ref < 1e9)
    rel = np.where(both, np.abs(ours - ref) / np.where(both, ref, 1.0), np.nan)
    h, w = (rel.shape[0] // 8) * 8, (rel.shape[1] // 8) * 8
    cells = rel[:h, :w].reshape(h // 8, 8, w // 8, 8).swapaxes(1, 2).reshape(h // 8, w // 8, 64)
    counts = np.sum(~np.isnan(cells), axis=-1)
    return float(max(np.nanmedian(c) for c, n in zip(cells.reshape(-1, 64), counts.ravel(),
                                                     strict=True) if n >= 16))


def normal_error(ours: np.ndarray, ref: np.ndarray) -> float:
    """Largest length of the difference of 8x8-block mean normals (unit normals: relative)."""
    return float(np.max(np.linalg.norm(_blocks(ours) - _blocks(ref), axis=-1)))


def alpha_error(ours: np.ndarray, ref: np.ndarray) -> float:
    """Largest difference of 8x8-block mean alpha."""
    return float(np.max(np.abs(_blocks(ours) - _blocks(ref))))


# ----------------------------------------------------------------------------- renders


def _render(feature: Feature, engine: str) -> dict:
    sc = b.setup_render(W, H, samples=feature.samples,
                        max_depth=max(feature.glossy, feature.transmission))
    if engine == "CYCLES":
        sc.render.engine = "CYCLES"
        cy = sc.cycles
        cy.device = "CPU"
        cy.samples = feature.cycles_samples
        cy.use_adaptive_sampling = cy.use_denoising = False
        cy.max_bounces = max(feature.glossy, feature.transmission)
        cy.diffuse_bounces = 0
        cy.glossy_bounces = feature.glossy
        cy.transmission_bounces = feature.transmission
        cy.caustics_reflective = cy.caustics_refractive = False
        cy.pixel_filter_type = "BOX"
        cy.filter_width = 1.0
        cy.seed = 1
    out = b.render_exr()
    assert out, f"{engine}: no image written: {_state().messages}"
    return out


def measure(feature: Feature) -> dict:
    """RSTrace's and Cycles' renders of a modelled feature's scene, and the errors."""
    feature.build()
    ours = _render(feature, "RSTRACE")
    messages = list(_state().messages)
    ref = _render(feature, "CYCLES")
    if feature.compare == "depth":
        err = dict(error=depth_error(ours["Depth"][..., 0], ref["Depth"][..., 0]))
    elif feature.compare == "normal":
        err = dict(error=normal_error(ours["Normal"], ref["Normal"]))
    else:
        err = dict(error=block_error(ours["Combined"][..., :3], ref["Combined"][..., :3]))
        if feature.compare == "holdout":
            err["alpha"] = alpha_error(ours["Combined"][..., 3], ref["Combined"][..., 3])
            err["holes"] = int(np.sum(ours["Combined"][..., 3] == 0.0))
    print(f"{feature.name}: {err}")
    return dict(err, messages=messages)


MODELLED = [f for f in FEATURES if f.modelled]
REPORTED = [f for f in FEATURES if not f.modelled]


@needs_cycles
@pytest.mark.parametrize("feature", MODELLED, ids=[f.name for f in MODELLED])
def test_modelled_feature_agrees_with_cycles(feature):
    m = measure(feature)
    assert m["error"] <= feature.tol, (feature.name, m)
    if feature.compare == "holdout":
        assert m["holes"] > 100 and m["alpha"] <= 0.05, m
        assert not any("holdout" in text.lower() for _, text in m["messages"]), m


@pytest.mark.parametrize("feature", REPORTED, ids=[f.name for f in REPORTED])
def test_unmodelled_feature_is_reported(feature):
    feature.build()
    b.setup_render(W, H, samples=1, max_depth=1)
    assert b.render_exr(), _state().messages
    texts = [text for _, text in _state().messages]
    assert any(all(w in t for w in feature.words) for t in texts), (feature.name, texts)


def test_compatibility_page_lists_the_corpus():
    """Every corpus feature has its row in docs/compatibility.md, with its status."""
    rows = {}
    for line in PAGE.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) >= 2:
            rows[cells[0]] = cells[1]
    for f in FEATURES:
        assert f.name in rows, f"docs/compatibility.md has no row for {f.name!r}"
        want = "modelled" if f.modelled else "reported"
        assert re.match(want, rows[f.name]), (f.name, rows[f.name])


@pytest.mark.parametrize("mode", ["INTERPOLANT", "RI_TREE"])
def test_holdout_and_passes_in_every_mode(mode):
    """The holes, Depth and Normal do not depend on the mode that rendered the colours:
    each mode's alpha, Depth and Normal are BASE's, bit for bit."""
    _holdout_object()
    layer = bpy.context.view_layer
    layer.use_pass_z = layer.use_pass_normal = True
    sc = b.setup_render(W, H, samples=2, max_depth=1)
    base = b.render_exr()
    sc.rstrace.mode = mode
    other = b.render_exr()
    assert other, _state().messages
    assert np.array_equal(base["Combined"][..., 3], other["Combined"][..., 3])
    holes = base["Combined"][..., 3] == 0.0
    assert holes.sum() > 100 and np.all(other["Combined"][holes] == 0.0)
    for name in ("Depth", "Normal"):
        assert np.array_equal(base[name], other[name]), name


def test_holdout_with_a_render_region_and_transparent_film():
    _holdout_object()
    sc = b.setup_render(W, H, samples=2, max_depth=1)
    full = b.render_exr()["Combined"]
    sc.render.film_transparent = True
    sc.render.use_border = True
    sc.render.use_crop_to_border = False
    sc.render.border_min_x, sc.render.border_max_x = 0.0, 0.5
    sc.render.border_min_y, sc.render.border_max_y = 0.25, 1.0
    part = b.render_exr()["Combined"]
    y0, x1 = int(0.25 * H), int(0.5 * W)
    region = part[y0:, :x1]
    # the holes as in the full frame; the sky transparent too; colours premultiplied
    held = full[y0:, :x1, 3] == 0.0
    assert held.sum() > 50 and np.all(region[held] == 0.0)
    sky = region[..., 3] == 0.0
    assert sky.sum() > held.sum()
    np.testing.assert_array_equal(region[~sky], full[y0:, :x1][~sky])
