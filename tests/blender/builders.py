"""Small scene builders for the bpy tests (``bpy.data`` and ``bmesh``, no operators)."""

from __future__ import annotations

import math
import os
import tempfile

import bmesh
import bpy
import numpy as np
from mathutils import Vector

from .exr import read_exr, read_pass


def _canonical_order(bm) -> None:
    """Put ``bm``'s edges and faces in an order set by their vertices alone (by index).

    ``bmesh.ops.create_uvsphere`` makes the same vertices (in the same order) and the same
    faces every time, but its edges and faces come in an order that changes from one
    process to the next (and for large spheres from one call to the next). Blender's
    vertex normals (summed in face order) then differ by an ulp, the triangles reach the
    engine in another order, and the same script renders images that differ in a few
    pixels by a float32 ulp: no two runs could be compared bit for bit.
    """
    bm.verts.index_update()
    for seq, key in ((bm.edges, lambda e: sorted(v.index for v in e.verts)),
                     (bm.faces, lambda f: [v.index for v in f.verts])):
        seq.index_update()
        keys = [key(x) for x in seq]
        rank = [0] * len(keys)
        for r, i in enumerate(sorted(range(len(keys)), key=keys.__getitem__)):
            rank[i] = r
        seq.sort(key=lambda x: rank[x.index])  # (bmesh sorts by a number only)


def uv_sphere(name: str, radius: float = 1.0, segments: int = 32, rings: int = 16,
              smooth: bool = True):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius,
                              calc_uvs=True)
    _canonical_order(bm)
    bm.to_mesh(me)
    bm.free()
    # (an edge's two vertices come either way round as well: stored lower first)
    ev = np.empty(2 * len(me.edges), np.int32)
    me.edges.foreach_get("vertices", ev)
    me.edges.foreach_set("vertices", np.sort(ev.reshape(-1, 2), axis=1).ravel())
    me.shade_smooth() if smooth else me.shade_flat()
    return me


def grid(name: str, size: float = 10.0, divisions: int = 1):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")
    bmesh.ops.create_grid(bm, x_segments=divisions, y_segments=divisions, size=size / 2,
                          calc_uvs=True)
    bm.to_mesh(me)
    bm.free()
    return me


def add_object(name: str, data, location=(0.0, 0.0, 0.0), material=None, scale=None,
               collection=None):
    ob = bpy.data.objects.new(name, data)
    ob.location = location
    if scale is not None:
        ob.scale = scale
    if material is not None:
        data.materials.append(material)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def principled(name: str, base=(0.8, 0.8, 0.8), metallic: float = 0.0,
               roughness: float = 0.5, specular_level: float = 0.5, **inputs):
    mat = bpy.data.materials.new(name)
    node = mat.node_tree.nodes["Principled BSDF"]
    node.inputs["Base Color"].default_value = (*base, 1.0)
    node.inputs["Metallic"].default_value = metallic
    node.inputs["Roughness"].default_value = roughness
    node.inputs["Specular IOR Level"].default_value = specular_level
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    mat.diffuse_color = (*base, 1.0)
    return mat


def diffuse(name: str, colour=(0.8, 0.8, 0.8)):
    """A material whose surface is a Diffuse BSDF (exactly Lambertian in Cycles too)."""
    mat = bpy.data.materials.new(name)
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    bsdf = nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0
    out = nodes["Material Output"]
    mat.node_tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def point_light(name: str, location, power: float, colour=(1.0, 1.0, 1.0), kind="POINT"):
    data = bpy.data.lights.new(name, kind)
    data.energy = power
    data.color = colour
    if kind in ("POINT", "SPOT"):
        data.shadow_soft_size = 0.0
        data.use_soft_falloff = False
    return add_object(name, data, location)


def look_at(ob, target) -> None:
    direction = Vector(target) - ob.location
    ob.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def camera(location=(0.0, -8.0, 3.0), target=(0.0, 0.0, 0.5), lens: float = 35.0):
    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    ob = add_object("Camera", data, location)
    look_at(ob, target)
    bpy.context.scene.camera = ob
    return ob


def set_world(colour=(0.0, 0.0, 0.0), lights: bool = True):
    """A world of a uniform colour; ``lights=False``: a background only (its Diffuse and
    Glossy ray visibility off, in Cycles as in RSTrace)."""
    world = bpy.data.worlds.new("World")
    bpy.context.scene.world = world
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Color"].default_value = (*colour, 1.0)
        bg.inputs["Strength"].default_value = 1.0
    world.color = colour
    world.cycles_visibility.diffuse = world.cycles_visibility.glossy = lights
    return world


def setup_render(width: int = 48, height: int = 36, engine: str = "RSTRACE", samples=4,
                 max_depth: int = 2):
    sc = bpy.context.scene
    r = sc.render
    r.engine = engine
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.film_transparent = False
    ims = r.image_settings
    ims.media_type = "MULTI_LAYER_IMAGE"
    ims.color_depth = "32"
    ims.exr_codec = "NONE"
    if engine == "RSTRACE":
        sc.rstrace.samples = samples
        sc.rstrace.max_ray_depth = max_depth
    return sc


def three_spheres_scene(width=48, height=36):
    """Diffuse floor, a red diffuse sphere, a mirror sphere, a blue sphere; two lamps; a
    dim background that lights nothing (the paper's Plate A is lit by its lamps only, and
    the interpolants' tests need a point-lit scene: a world's light fails every cell)."""
    setup_render(width, height)
    set_world((0.02, 0.02, 0.03), lights=False)
    floor = principled("Floor", (0.55, 0.55, 0.5), roughness=0.8)
    red = principled("Red", (0.7, 0.12, 0.1), roughness=0.4)
    blue = principled("Blue", (0.1, 0.2, 0.65), roughness=0.5)
    mirror = principled("Mirror", (0.95, 0.95, 0.95), metallic=1.0, roughness=0.0)
    add_object("Ground", grid("Ground", 12.0), material=floor)
    sphere = uv_sphere("Sphere", 1.0, 24, 12)
    add_object("RedSphere", sphere, (-1.6, 0.4, 1.0), red)
    mo = add_object("MirrorSphere", sphere.copy(), (0.6, -0.9, 1.0))
    mo.data.materials.clear()
    mo.data.materials.append(mirror)
    bo = add_object("BlueSphere", sphere.copy(), (1.5, 1.6, 0.8), scale=(0.8, 0.8, 0.8))
    bo.data.materials.clear()
    bo.data.materials.append(blue)
    point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    point_light("Fill", (4.0, -2.0, 3.5), 900.0, (0.9, 0.95, 1.0))
    camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    return bpy.context.scene


def animated_three_spheres(width=64, height=48, frame_end=4):
    """Plate A with the red sphere (location), the blue sphere (rotation, scale), the key
    light (location, power) and the camera (location) keyframed from frame 1 to
    ``frame_end``."""
    sc = three_spheres_scene(width, height)
    sc.frame_start, sc.frame_end = 1, frame_end
    red, blue = bpy.data.objects["RedSphere"], bpy.data.objects["BlueSphere"]
    key, cam = bpy.data.objects["Key"], bpy.data.objects["Camera"]
    for frame, t in ((1, 0.0), (frame_end, 1.0)):
        red.location.x = -2.2 + 2.0 * t
        red.keyframe_insert("location", frame=frame)
        blue.rotation_euler.z = 1.2 * t
        blue.scale = (0.8 + 0.3 * t,) * 3
        blue.keyframe_insert("rotation_euler", frame=frame)
        blue.keyframe_insert("scale", frame=frame)
        key.location.x = -3.0 + 2.5 * t
        key.keyframe_insert("location", frame=frame)
        key.data.energy = 2500.0 - 900.0 * t
        key.data.keyframe_insert("energy", frame=frame)
        cam.location = (0.8 * t, -8.5 + 0.6 * t, 3.6 + 0.3 * t)
        cam.keyframe_insert("location", frame=frame)
    return sc


def render_exr(path=None, layer: str = "ViewLayer") -> dict[str, np.ndarray]:
    """F12 (write_still) to a multilayer EXR and read its passes back.

    Returns {"Combined": (h, w, 4), "Interpolation": (h, w, 3), "Depth": (h, w, 1),
    "Normal": (h, w, 3)}, each but Combined where present.
    """
    sc = bpy.context.scene
    if path is None:
        fd, path = tempfile.mkstemp(suffix=".exr")
        os.close(fd)
    sc.render.filepath = str(path)
    if os.path.exists(path):
        os.remove(path)
    bpy.ops.render.render(write_still=True)
    if not os.path.exists(path):
        return {}
    channels = read_exr(path)
    os.remove(path)
    out = {"Combined": read_pass(channels, "Combined", layer, "RGBA")}
    for name, components in (("Interpolation", "RGB"), ("Depth", "Z"), ("Normal", "XYZ")):
        if f"{layer}.{name}.{components[0]}" in channels:
            out[name] = read_pass(channels, name, layer, components)
    return out


def deg(x: float) -> float:
    return math.radians(x)
