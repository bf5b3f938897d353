"""Small scenes and helpers for the tracer tests (test_whitted, test_numerics, test_shading)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.attributes import mesh_corners
from rstrace_engine.geometry.packing import mesh_slots, mesh_triangles
from rstrace_engine.geometry.scene import Camera, Light, Material, Mesh, Scene


def ortho_down(height: float = 10.0, scale: float = 4.0, width: int = 32, rows: int = 24,
               centre=(0.0, 0.0)) -> Camera:
    """Orthographic camera above the XY plane looking straight down (-Z), +Y up."""
    m = np.eye(4)
    m[:3, 3] = (centre[0], centre[1], height)
    return Camera(matrix=m, kind="ORTHO", ortho_scale=scale, width=width, height=rows,
                  clip_start=1e-3, clip_end=1e3)


def plane_scene(material: Material, lights=(), camera: Camera | None = None,
                size: float = 20.0, world=(0.0, 0.0, 0.0),
                world_lights: bool = False) -> Scene:
    """A single plane (z = 0, normal +Z) under the given lights."""
    s = Scene()
    mid = s.add_material(material)
    pm = s.add_mesh(shapes.plane(size, name="floor"))
    s.add_instance(pm, np.eye(4), [mid], name="Floor")
    for li in lights:
        s.add_light(li)
    s.set_world_color(world, lights=world_lights)
    s.set_camera(camera or ortho_down())
    return s


def point_intensity(light: Light) -> np.ndarray:
    """Radiant intensity (W/sr) of a point or spot light, Blender's convention."""
    return np.asarray(light.color, np.float64) * light.power / (4.0 * math.pi)


def transformed(scene: Scene, scale: float = 1.0, offset=(0.0, 0.0, 0.0),
                gain: float = 1.0) -> Scene:
    """A copy of ``scene`` scaled by ``scale`` about the origin, then translated.

    Point/spot powers scale with ``scale**2`` so irradiance (and the image) stays the same;
    camera clipping and ortho scale follow the geometry. ``gain`` multiplies every light,
    the emission and the world colour, so the image is ``gain`` times the original (this
    keeps light powers within the scene's limit at large scales).
    """
    g = np.eye(4)
    g[:3, :3] *= scale
    g[:3, 3] = offset
    out = Scene()
    for m in scene.materials:
        out.add_material(replace(m, emission=tuple(np.asarray(m.emission) * gain)))
    for m in scene.meshes:
        out.add_mesh(Mesh(m["name"], m["verts"], mesh_triangles(m),
                          corner_normals=mesh_corners(m, "normals"),
                          corner_uvs=mesh_corners(m, "uvs"), slots=mesh_slots(m)))
    for inst in scene.instances:
        out.add_instance(inst["mesh"], g @ inst["matrix"], inst["materials"], inst["name"])
    for li in scene.lights:
        pos = g[:3, :3] @ np.asarray(li.position) + g[:3, 3]
        power = gain * (li.power if li.kind == "SUN" else li.power * scale * scale)
        out.add_light(Light(li.name, li.kind, li.color, power, tuple(pos), li.direction,
                            li.spot_size, li.spot_blend))
    c = scene.camera
    out.set_camera(Camera(g @ c.matrix, c.kind, c.lens, c.sensor_width, c.sensor_height,
                          c.sensor_fit, c.shift_x, c.shift_y, c.clip_start * scale,
                          c.clip_end * scale, c.ortho_scale * scale, c.width, c.height))
    out.set_world_color(np.asarray(scene.world_color) * gain, scene.world_lights)
    return out
