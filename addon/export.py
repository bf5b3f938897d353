"""Evaluated depsgraph -> :class:`rstrace_engine.geometry.scene.Scene`.

One pass over ``depsgraph.object_instances``: meshes are read once per evaluated mesh
datablock with ``foreach_get`` into numpy (no per-vertex Python), and every instance of that
mesh (collection instances, geometry-node instances, curves and text evaluated to meshes)
shares it. Materials are read from the Principled BSDF (or a Diffuse, Emission, Glossy or
Glass BSDF) feeding the material output, falling back to the viewport colour. Point, sun and
spot lights map directly; area lights and light radii are approximated. Anything the
renderer cannot represent is collected in :class:`Notes` and reported once per render, never
silently dropped; an object that cannot be rendered at all (zero scale, NaN transform, no
faces) is skipped with a message naming it.

Layer: imports ``properties``-level modules only (no session, engine or ui).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from rstrace_engine.geometry.scene import (
    MAX_LIGHTS,
    Camera,
    Light,
    Mesh,
    Scene,
    SceneError,
    check_matrix,
)

from .materials import MaterialReader, Notes, follow_link, rgb, uses_nodes

log = logging.getLogger(__name__)


#: Object types whose evaluated geometry arrives as MESH instances in ``object_instances``
#: (so the object itself is skipped), and types with nothing to render.
_MESH_VIA_INSTANCES = {"CURVE", "SURFACE", "FONT", "META"}
_NOTHING_TO_RENDER = {"EMPTY", "CAMERA", "ARMATURE", "LATTICE", "SPEAKER", "LIGHT_PROBE"}

#: What a Whitted tracer does not model, said once per render where the scene has it. Neither
#: is modelled on purpose: an emissive mesh as an area light needs sampled (noisy) soft
#: shadows, and occluded world light needs sampled ambient occlusion; the radiance
#: interpolants, their error predicate (point-light shadows only) and the RI-tree assume a
#: deterministic, point-lit shading, and an unoccluded ambient term would be a silently wrong
#: image against Cycles instead of a reported gap.
NOT_MODELLED_WORLD = ("the world colour is seen as background and in mirrors but lights no "
                      "surface (world lighting is not modelled by the Whitted tracer)")
NOT_MODELLED_EMISSION = ("emissive objects are seen directly and in mirrors but light no "
                         "other surface (emissive meshes are not light sources)")


@dataclass
class Exported:
    """The result of :func:`export_scene`."""

    scene: Scene
    notes: Notes
    width: int
    height: int
    stats: dict = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        return self.notes.warnings + self.scene.warnings


# ----------------------------------------------------------------------------- helpers


def render_size(render) -> tuple[int, int]:
    """Blender's output size: resolution x percentage (at least one pixel)."""
    pct = render.resolution_percentage
    return (max(1, render.resolution_x * pct // 100), max(1, render.resolution_y * pct // 100))


def _matrix(m) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 array (a copy: instance matrices are transient)."""
    return np.array(m, dtype=np.float64)


def _instance_name(inst) -> str:
    ob = inst.object
    if inst.is_instance and inst.parent is not None:
        return f"{inst.parent.name}/{ob.name}"
    return ob.name



# ----------------------------------------------------------------------------- meshes


def _attribute(me, name: str, prop: str, size: int, dtype) -> np.ndarray | None:
    """A generic attribute's values (``size`` numbers), or None if the mesh lacks it.

    Attribute arrays are read as raw memory (about 1 ms per million values), unlike the
    per-item RNA path of e.g. ``me.loops.foreach_get("vertex_index")`` (about 100 ms).
    """
    attr = me.attributes.get(name)
    if attr is None:
        return None
    out = np.empty(size, dtype)
    attr.data.foreach_get(prop, out)
    return out


def mesh_arrays(me, name: str) -> Mesh | None:
    """Triangles of an evaluated mesh datablock as a :class:`Mesh`, or None if it has none.

    Everything is read with ``foreach_get`` into numpy, from raw attribute arrays where
    Blender has them; the one per-item read is ``loop_triangles.loops`` (the corners of
    Blender's own triangulation). Normals come from the mesh's normals domain (vertex, face
    or corner), uvs from the active render UV map.
    """
    tris_rna = me.loop_triangles
    nt = len(tris_rna)
    if nt == 0:
        return None
    nv, nl = len(me.vertices), len(me.loops)
    verts = _attribute(me, "position", "vector", nv * 3, np.float32)
    if verts is None:
        verts = np.empty(nv * 3, np.float32)
        me.vertices.foreach_get("co", verts)
    corner_vert = _attribute(me, ".corner_vert", "value", nl, np.int32)
    if corner_vert is None:
        corner_vert = np.empty(nl, np.int32)
        me.loops.foreach_get("vertex_index", corner_vert)
    loops = np.empty(nt * 3, np.int32)
    tris_rna.foreach_get("loops", loops)
    tris = np.take(corner_vert, loops)
    poly = np.empty(nt, np.int32)
    me.loop_triangle_polygons.foreach_get("value", poly)
    face_mat = _attribute(me, "material_index", "value", len(me.polygons), np.int32)
    slots = np.zeros(nt, np.int32) if face_mat is None else np.take(face_mat, poly)

    domain = me.normals_domain
    if domain == "POINT":
        vn = np.empty(nv * 3, np.float32)
        me.vertex_normals.foreach_get("vector", vn)
        normals = np.take(vn.reshape(-1, 3), tris, axis=0)
    elif domain == "FACE":
        pn = np.empty(len(me.polygons) * 3, np.float32)
        me.polygon_normals.foreach_get("vector", pn)
        normals = np.repeat(np.take(pn.reshape(-1, 3), poly, axis=0), 3, axis=0)
    else:  # CORNER: custom or split normals
        cn = np.empty(nl * 3, np.float32)
        me.corner_normals.foreach_get("vector", cn)
        normals = np.take(cn.reshape(-1, 3), loops, axis=0)

    uvs = None
    layer = next((u for u in me.uv_layers if u.active_render), None)
    if layer is not None:
        uv = np.empty(nl * 2, np.float32)
        layer.uv.foreach_get("vector", uv)
        uvs = np.take(uv.reshape(-1, 2), loops, axis=0).reshape(nt, 3, 2)
    nslots = max(len(me.materials), 1)
    np.clip(slots, 0, nslots - 1, out=slots)  # Blender clamps out-of-range indices
    return Mesh(name, verts.reshape(nv, 3), tris.reshape(nt, 3),
                corner_normals=normals.reshape(nt, 3, 3), corner_uvs=uvs, slots=slots)


# ----------------------------------------------------------------------------- lights


def _light(inst, notes: Notes) -> Light | None:
    ob = inst.object
    data = ob.data
    name = _instance_name(inst)
    m = _matrix(inst.matrix_world)
    if not np.all(np.isfinite(m)):
        notes.skip(f"light '{name}' skipped: its transform has NaN or infinite values")
        return None
    z = m[:3, 2]
    zn = float(np.linalg.norm(z))
    if zn == 0.0:
        notes.skip(f"light '{name}' skipped: zero scale leaves it without a direction")
        return None
    direction = tuple(-z / zn)
    colour = rgb(data.color)
    if getattr(data, "use_temperature", False):
        colour = colour * rgb(data.temperature_color)
    power = float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0))
    if not data.use_shadow:
        notes.warn("lights with shadows turned off still cast shadows", name)
    if uses_nodes(data) and data.node_tree is not None and len(data.node_tree.nodes) > 2:
        notes.warn("light node trees are ignored", name)
    if data.diffuse_factor != 1.0 or data.specular_factor != 1.0:
        notes.warn("light diffuse/specular factors are ignored", name)
    kind = data.type
    if kind in ("POINT", "SPOT") and data.shadow_soft_size > 0.0:
        notes.warn("lights with a radius are rendered as points (hard shadows)", name)
    if kind == "POINT":
        return Light(name, "POINT", tuple(colour), power, tuple(m[:3, 3]), direction)
    if kind == "SUN":
        if data.angle > math.radians(1.0):
            notes.warn("sun angles are ignored (hard shadows)", name)
        return Light(name, "SUN", tuple(colour), power, tuple(m[:3, 3]), direction)
    if kind == "SPOT":
        size = float(np.clip(data.spot_size, 1e-4, math.pi))
        return Light(name, "SPOT", tuple(colour), power, tuple(m[:3, 3]), direction,
                     spot_size=size, spot_blend=float(np.clip(data.spot_blend, 0.0, 1.0)))
    if kind == "AREA":
        # A Lambertian emitter of power P has on-axis intensity P/pi and falls off as cos;
        # a 180-degree spot with blend 1 falls off as smoothstep(cos), which integrates to
        # the same power when its nominal power is 4P (a point light's intensity is P/4pi).
        notes.warn("area lights are approximated by a point at their centre with a "
                   "cosine-like falloff (hard shadows)", name)
        return Light(name, "SPOT", tuple(colour), 4.0 * power, tuple(m[:3, 3]), direction,
                     spot_size=math.pi, spot_blend=1.0)
    notes.warn(f"{kind.lower()} lights are not supported (skipped)", name)
    return None


# ----------------------------------------------------------------------------- camera, world


def camera_from_object(cam_ob, width: int, height: int, render, notes: Notes) -> Camera:
    """A :class:`Camera` from an evaluated camera object. Raises :class:`SceneError`."""
    if cam_ob is None:
        raise SceneError("the scene has no active camera: add a camera and make it active "
                         "(Scene properties > Camera)")
    if cam_ob.type != "CAMERA":
        raise SceneError(f"the active camera '{cam_ob.name}' is a {cam_ob.type.lower()}, "
                         f"not a camera")
    cd = cam_ob.data
    if cd.type not in ("PERSP", "ORTHO"):
        raise SceneError(f"camera '{cam_ob.name}': {cd.type.lower()} cameras are not "
                         f"supported (use perspective or orthographic)")
    if cd.dof.use_dof:
        notes.warn("depth of field is not supported (everything is in focus)", cam_ob.name)
    if render.pixel_aspect_x != render.pixel_aspect_y:
        notes.warn("non-square pixel aspect is not supported (square pixels rendered)")
    if render.use_motion_blur:
        notes.warn("motion blur is not supported")
    if render.use_multiview:
        notes.warn("stereo and multi-view rendering are not supported: one centre view is "
                   "rendered")
    m = _matrix(cam_ob.matrix_world)
    try:
        check_matrix(cam_ob.name, m)
    except SceneError as exc:
        raise SceneError(f"camera {exc}") from None
    return Camera(matrix=m, kind=cd.type, lens=cd.lens, sensor_width=cd.sensor_width,
                  sensor_height=cd.sensor_height, sensor_fit=cd.sensor_fit,
                  shift_x=cd.shift_x, shift_y=cd.shift_y, clip_start=cd.clip_start,
                  clip_end=cd.clip_end, ortho_scale=cd.ortho_scale, width=width, height=height)


def world_colour(world, notes: Notes) -> np.ndarray:
    """The world's constant colour: a Background node's Color x Strength, or world.color."""
    if world is None:
        return np.zeros(3)
    tree = world.node_tree if uses_nodes(world) else None
    if tree is None:
        return rgb(world.color)
    out = tree.get_output_node("CYCLES")
    node, _ = follow_link(out.inputs["Surface"]) if out is not None else (None, None)
    if node is None:
        return np.zeros(3)
    if node.bl_idname != "ShaderNodeBackground":
        notes.warn(f"world shader '{node.bl_label}' is not supported: world.color is used",
                   world.name)
        return rgb(world.color)
    colour_in = node.inputs["Color"]
    src, out_sock = follow_link(colour_in)
    if src is None:
        colour = rgb(colour_in.default_value)
    elif src.bl_idname == "ShaderNodeRGB":
        colour = rgb(out_sock.default_value)
    else:
        notes.warn(f"world colours from '{src.bl_label}' nodes (environment textures, "
                   f"skies) are not supported: the Background colour value is used",
                   world.name)
        colour = rgb(colour_in.default_value)
    strength_in = node.inputs["Strength"]
    strength = float(strength_in.default_value)
    if strength_in.is_linked:
        notes.warn("a linked world strength is not supported: its own value is used",
                   world.name)
    return colour * max(strength, 0.0)


# ----------------------------------------------------------------------------- scene


def export_scene(depsgraph, camera_object=None, width: int | None = None,
                 height: int | None = None) -> Exported:
    """Export the evaluated ``depsgraph`` (a render or viewport depsgraph).

    camera_object : the camera to render through (default: the scene's active camera)
    width, height : output size in pixels (default: resolution x percentage)

    Raises :class:`SceneError` for problems that leave nothing sensible to render (no
    camera, a broken camera); everything else is skipped or approximated and noted.
    """
    t0 = time.perf_counter()
    bscene = depsgraph.scene_eval
    render = bscene.render
    if width is None or height is None:
        width, height = render_size(render)
    notes = Notes()
    scene = Scene()

    cam = camera_object if camera_object is not None else bscene.camera
    cam_eval = cam.evaluated_get(depsgraph) if cam is not None else None
    scene.set_camera(camera_from_object(cam_eval, width, height, render, notes))
    world = world_colour(bscene.world, notes)
    scene.set_world_color(world)
    if float(np.max(world)) > 0.0:
        notes.warn(NOT_MODELLED_WORLD)

    props = getattr(bscene, "rstrace", None)
    materials = MaterialReader(scene, notes, getattr(props, "shading_model", "PRINCIPLED"))
    meshes: dict[int, int | str] = {}  # evaluated mesh datablock -> mesh id or why not
    n_instances = n_lights = 0
    t_read = t_add = 0.0
    for inst in depsgraph.object_instances:
        ob = inst.object
        kind = ob.type
        if kind == "MESH":
            if not inst.show_self or (not inst.is_instance and ob.original.hide_render):
                continue
            name = _instance_name(inst)
            matrix = _matrix(inst.matrix_world)
            try:
                check_matrix(name, matrix)
            except SceneError as exc:
                notes.skip(f"skipped {exc}")
                continue
            me = ob.data
            key = me.as_pointer()
            if key not in meshes:
                t1 = time.perf_counter()
                mesh = mesh_arrays(me, me.name)
                t2 = time.perf_counter()
                meshes[key] = _add_mesh(scene, mesh, me.name)
                t_read += t2 - t1
                t_add += time.perf_counter() - t2
            mesh_id = meshes[key]
            if isinstance(mesh_id, str):
                notes.skip(f"skipped object '{name}': {mesh_id}")
                continue
            slots = ob.material_slots
            mats = [materials.material_id(s.material) for s in slots] if len(slots) else \
                [materials.material_id(m) for m in me.materials]
            nslots = max(len(me.materials), 1)
            if len(mats) < nslots:
                mats += [materials.default_id()] * (nslots - len(mats))
            if not mats:
                mats = [materials.default_id()]
            _check_visibility(ob, name, notes)
            if any(max(scene.materials[k].emission) > 0.0 for k in mats):
                notes.warn(NOT_MODELLED_EMISSION, name)
            if len(me.uv_layers) == 0 and any(
                    scene.materials[k].texture is not None for k in mats):
                notes.warn("textured objects without a UV map sample their texture at (0, 0)",
                           name)
            scene.add_instance(mesh_id, matrix, mats, name=name)
            n_instances += 1
        elif kind == "LIGHT":
            if not inst.is_instance and ob.original.hide_render:
                continue
            light = _light(inst, notes)
            if light is None:
                continue
            if len(scene.lights) >= MAX_LIGHTS:
                notes.skip(f"light '{light.name}' skipped: at most {MAX_LIGHTS} lights are "
                           f"supported")
                continue
            try:
                scene.add_light(light)
                n_lights += 1
            except SceneError as exc:
                notes.skip(f"skipped {exc}")
        elif kind in _MESH_VIA_INSTANCES or kind in _NOTHING_TO_RENDER:
            continue
        else:
            notes.warn(f"{kind.lower().replace('_', ' ')} objects are not supported (skipped)",
                       _instance_name(inst))
    if n_lights == 0:
        notes.warn("the scene has no lights: only emission and the world colour are visible")
    if n_instances == 0:
        raise SceneError("nothing to render: the scene has no visible mesh objects"
                         + (f" ({'; '.join(notes.skipped)})" if notes.skipped else ""))
    elapsed = time.perf_counter() - t0
    stats = dict(objects=n_instances, meshes=len(scene.meshes), lights=n_lights,
                 materials=len(scene.materials), triangles=scene.triangle_count,
                 export_seconds=elapsed, mesh_read_seconds=t_read, mesh_add_seconds=t_add)
    return Exported(scene, notes, width, height, stats)


def _add_mesh(scene: Scene, mesh: Mesh | None, name: str) -> int | str:
    """The new mesh's id, or the reason it cannot be rendered."""
    if mesh is None:
        return f"its mesh '{name}' has no faces"
    try:
        return scene.add_mesh(mesh)
    except SceneError as exc:
        return str(exc)


def _check_visibility(ob, name: str, notes: Notes) -> None:
    if not (ob.visible_camera and ob.visible_shadow and ob.visible_glossy
            and ob.visible_transmission):
        notes.warn("per-object ray visibility is not supported (objects are visible to all "
                   "rays)", name)
