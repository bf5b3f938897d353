"""Blender lights and the world -> :class:`~rstrace_engine.geometry.scene.Light` and a world
colour, one datablock at a time.

Every light setting Cycles renders is read as Cycles reads it (its ``blender/light.cpp`` and
``scene/light.cpp``): point and spot lights are spheres of radius ``shadow_soft_size`` (the
object's scale does not change it), a sun is a cone of directions ``angle`` wide, an area
light spans ``size`` x ``size_y`` along the object's local X and Y axes *with* their scale
and emits along its local -Z. Bad values are rendered as Cycles renders them or the light is
skipped with a message naming the light and the setting (tests/blender/test_bad_input.py).

Layer: imported by ``export`` only.
"""

from __future__ import annotations

import math

import numpy as np

from rstrace_engine import tolerances as tol
from rstrace_engine.geometry.scene import MAX_LIGHT_POWER, Light

from .materials import Notes, follow_link, rgb, uses_nodes


def read_light(ob, name: str, m: np.ndarray, notes: Notes) -> Light | None:
    """A :class:`Light` from an evaluated light object with world matrix ``m`` (4, 4), or
    None (with a note) when it cannot be rendered."""
    data = ob.data
    kind = data.type
    if kind not in ("POINT", "SUN", "SPOT", "AREA"):
        notes.warn(f"{kind.lower()} lights are not supported (skipped)", name)
        return None
    if not np.all(np.isfinite(m)):
        notes.skip(f"light '{name}' skipped: its transform has NaN or infinite values")
        return None
    z = m[:3, 2]
    zn = float(np.linalg.norm(z))
    if zn == 0.0:
        notes.skip(f"light '{name}' skipped: zero scale leaves it without a direction")
        return None
    # Cycles: the light points (and an area light emits) along the world matrix's -Z
    # column, mirrored or not
    direction = -z / zn
    if kind == "AREA" and getattr(getattr(data, "cycles", None), "is_portal", False):
        notes.skip(f"light '{name}' skipped: it is a portal (Cycles: it guides world "
                   f"sampling and emits no light)")
        return None
    if not (getattr(ob, "visible_diffuse", True) or getattr(ob, "visible_glossy", True)
             or _seen_by_rays(ob)):
        # Cycles leaves such a light out of both closures: it lights no surface (RSTrace
        # shades surfaces with those two only); kept where camera or refraction rays see
        # its own surface (tracing/seen_lights)
        notes.warn("lights with Diffuse and Glossy ray visibility off light no surface, as "
                   "in Cycles (left out)", name)
        return None
    colour = rgb(data.color)
    if getattr(data, "use_temperature", False):
        colour = colour * rgb(data.temperature_color)
    exposure = float(getattr(data, "exposure", 0.0))
    try:
        power = float(data.energy) * 2.0 ** exposure if math.isfinite(exposure) else math.nan
    except OverflowError:  # an exposure above ~1024
        power = math.inf
    node_colour, node_strength = _emission_node(data, name, notes)
    colour = colour * node_colour
    power *= node_strength
    shape = _shape(data, name, m, direction, notes)
    if isinstance(shape, str):
        notes.skip(f"light '{name}' skipped: {shape}")
        return None
    if not getattr(data, "normalize", True):
        # Cycles divides the power by the emitter's area only where Normalize is on: off,
        # the same power over its area is that area times brighter
        power *= _cycles_area(kind, shape)
    why = _unusable(data, colour, power, exposure)
    if why:
        notes.skip(f"light '{name}' skipped: {why}")
        return None
    _warn_unmodelled(ob, name, notes)
    common = (name, kind, tuple(colour), power, tuple(m[:3, 3]), tuple(direction))
    linking = getattr(ob, "light_linking", None)
    reach = dict(diffuse=bool(getattr(ob, "visible_diffuse", True)),
                 glossy=bool(getattr(ob, "visible_glossy", True)),
                 camera=bool(getattr(ob, "visible_camera", False)),
                 transmission=bool(getattr(ob, "visible_transmission", True)),
                 receivers=_linked(getattr(linking, "receiver_collection", None)),
                 blockers=_linked(getattr(linking, "blocker_collection", None)))
    if kind == "SPOT":
        # Cycles takes the cone in the light's scaled frame: a scale that differs between
        # axes (Z included) or a shear makes it elliptical (the frame is kept where so)
        return Light(*common, spot_size=float(np.clip(data.spot_size, 1e-4, math.pi)),
                     spot_blend=float(np.clip(data.spot_blend, 0.0, 1.0)),
                     spot_frame=tuple(float(x) for x in m[:3, :3].reshape(-1)), **reach,
                     **shape)
    return Light(*common, **reach, **shape)


def _linked(collection) -> tuple:
    """A light-linking collection as ``((object name, include), ...)``: its objects and
    those of its child collections (Blender's link state of the object, or of the child
    collection that holds it); ``()`` without a collection (every object)."""
    out: list = []

    def walk(col, state):
        for ob, co in zip(col.objects, col.collection_objects, strict=True):
            out.append((ob.name, (state or co.light_linking.link_state) == "INCLUDE"))
        for child, cc in zip(col.children, col.collection_children, strict=True):
            walk(child, state or cc.light_linking.link_state)

    if collection is not None:
        walk(collection, None)
    return tuple(out)


def _shape(data, name: str, m: np.ndarray, direction: np.ndarray, notes: Notes) -> dict | str:
    """The light's extent as :class:`Light` fields, or why it cannot be rendered."""
    kind = data.type
    if kind in ("POINT", "SPOT"):
        radius = float(data.shadow_soft_size)
        if math.isnan(radius):
            return "its Radius is NaN (Cycles renders no light from it)"
        if radius > tol.COORD_MAX:  # typing inf gives 3.4e38; Cycles renders no light
            return f"its Radius ({radius:g} m) is above {tol.COORD_MAX:g} m"
        return dict(radius=radius, soft_falloff=bool(data.use_soft_falloff))
    if kind == "SUN":
        # Blender keeps it in [0, pi] in float32, whose pi is 9e-8 above float64's
        angle = min(float(data.angle), math.pi)
        if math.isnan(angle):
            notes.warn("a NaN sun Angle is rendered as 0 (a hard sun), as Cycles does",
                       name)
            angle = 0.0
        return dict(angle=angle)
    # AREA: Cycles spans the emitter by the world matrix's X and Y columns times Size (X)
    # and Size Y (Y, for rectangles and ellipses; Size again for squares and disks)
    shape = data.shape
    size_u = float(data.size)
    size_v = float(data.size_y) if shape in ("RECTANGLE", "ELLIPSE") else size_u
    label_v = "Size Y" if shape in ("RECTANGLE", "ELLIPSE") else "Size"
    for label, value in (("Size", size_u), (label_v, size_v)):
        if math.isnan(value):
            return f"its {label} is NaN (Cycles renders no light from it)"
    x, y = m[:3, 0], m[:3, 1]
    ext_u = float(np.linalg.norm(x)) * size_u
    ext_v = float(np.linalg.norm(y)) * size_v
    if ext_u == 0.0 or ext_v == 0.0:
        what = ("its Size is 0" if size_u == 0.0 else f"its {label_v} is 0" if size_v == 0.0
                else "its object's scale is 0 along X or Y")
        return f"{what} (Cycles renders no light from a zero-size area light)"
    if max(ext_u, ext_v) > tol.COORD_MAX:  # typing inf gives 3.4e38; Cycles: no light
        return (f"its Size with the object's scale ({ext_u:g} x {ext_v:g} m) is above "
                f"{tol.COORD_MAX:g} m")
    z = -direction
    if _skewed(x, y, z):
        # Cycles spans a parallelogram (its sampling assumes a rectangle): a rectangle of
        # the same side lengths, along X made orthogonal to the direction, stands for it
        notes.warn("sheared area lights (a non-uniformly scaled parent and a rotated child) "
                   "are rendered as rectangles", name)
    xu = x - float(np.dot(x, z)) * z
    xn = float(np.linalg.norm(xu))
    if xn <= 1e-9 * float(np.linalg.norm(x)):
        return "its transform is singular (its X axis along its Z axis)"
    spread = min(float(data.spread), math.pi)  # as the sun's angle
    if not spread > 0.0:  # Cycles: 0 (and NaN, taken as 0) is a collimated beam
        return (f"its Spread is {spread:g} (Cycles renders a collimated beam, which is not "
                f"modelled)")
    return dict(shape=shape, axis=tuple(xu / xn), size=(ext_u, ext_v), spread=spread)


def _emission_node(data, name: str, notes: Notes) -> tuple[np.ndarray, float]:
    """The colour and strength of the light's Emission node, which Cycles multiplies into
    its colour and power ((1, 1, 1), 1 without a node tree); any other tree is reported and
    ignored."""
    tree = data.node_tree if uses_nodes(data) else None
    if tree is None:
        return np.ones(3), 1.0
    out = tree.get_output_node("CYCLES")
    node, _ = follow_link(out.inputs["Surface"]) if out is not None else (None, None)
    if node is None or node.bl_idname != "ShaderNodeEmission" or \
            node.inputs["Color"].is_linked or node.inputs["Strength"].is_linked:
        notes.warn("light node trees other than an Emission node's colour and strength are "
                   "ignored", name)
        return np.ones(3), 1.0
    return rgb(node.inputs["Color"].default_value), float(node.inputs["Strength"].default_value)


def _skewed(*axes) -> bool:
    """Whether some two of the matrix columns ``axes`` are not orthogonal."""
    for i, a in enumerate(axes):
        for b in axes[i + 1:]:
            if abs(float(np.dot(a, b))) > 1e-6 * float(np.linalg.norm(a) * np.linalg.norm(b)):
                return True
    return False


def _cycles_area(kind: str, shape: dict) -> float:
    """The area Cycles divides a light's power by (``Light::area``): a sphere's surface (4
    for radius 0), the sun's disc of directions (1 for angle 0), an area light's extent."""
    if kind in ("POINT", "SPOT"):
        r = shape["radius"]
        return 4.0 * math.pi * r * r if r > 0.0 else 4.0
    if kind == "SUN":
        a = shape["angle"]
        return math.pi * math.sin(0.5 * a) ** 2 if a > 0.0 else 1.0
    u, v = shape["size"]
    return u * v * (math.pi / 4.0 if shape["shape"] in ("DISK", "ELLIPSE") else 1.0)


def _seen_by_rays(ob) -> bool:
    """Whether camera or refraction rays see the light's own surface (it has an extent
    and that visibility on, as Cycles shows it)."""
    data = ob.data
    extent = (data.type == "AREA" or (data.type == "SUN" and data.angle > 0.0)
              or (data.type in ("POINT", "SPOT") and data.shadow_soft_size > 0.0))
    return extent and bool(getattr(ob, "visible_camera", False)
                           or getattr(ob, "visible_transmission", True))


def _warn_unmodelled(ob, name: str, notes: Notes) -> None:
    """Light settings Cycles renders and RSTrace does not, named."""
    data = ob.data
    if not data.use_shadow:
        notes.warn("lights with shadows turned off still cast shadows", name)
    # (the Diffuse/Specular/Transmission/Volume Scatter factors are EEVEE's: Cycles ignores
    # them, as RSTrace does, so they are not reported. Camera, Diffuse, Glossy and
    # Transmission visibility and light and shadow linking are modelled: the last two
    # visibilities also say whether mirror and smooth refraction rays see the light)


def _off(holder, flags) -> str:
    """The labels of the ray-visibility ``flags`` (label, attribute) turned off."""
    return "/".join(label for label, attr in flags if not getattr(holder, attr, True))


def _unusable(data, colour, power: float, exposure: float) -> str | None:
    """Why a light's values cannot be rendered (naming the setting), or None. A light with
    a NaN or negative power, colour or spot shape is skipped, like one with a NaN
    transform, instead of refusing the whole render."""
    name, unit = ("Strength", "W/m2") if data.type == "SUN" else ("Power", "W")
    what = name if exposure == 0.0 else f"{name} x 2^Exposure ({exposure:g})"
    if not getattr(data, "normalize", True):
        what += " x its area (Normalize off)"
    if not math.isfinite(power):
        return f"its {what} is NaN or infinite"
    if power < 0.0:
        return (f"its {what} is negative ({power:g} {unit}): negative lights are not "
                f"supported (Cycles subtracts their light)")
    if power > MAX_LIGHT_POWER:
        return f"its {what} ({power:g} {unit}) is above {MAX_LIGHT_POWER:g} {unit}"
    if not np.all(np.isfinite(colour)):
        return ("its Color or Temperature gives NaN or infinite values"
                if getattr(data, "use_temperature", False) else "its Color is NaN or infinite")
    if data.type == "SPOT" and not (math.isfinite(data.spot_size)
                                    and math.isfinite(data.spot_blend)):
        return "its spot Size or Blend is NaN"
    return None


# ----------------------------------------------------------------------------- world


def world_colour(world, notes: Notes) -> np.ndarray:
    """The world's constant colour: a Background node's Color x Strength, or world.color.
    It is the background and, uniform, lights surfaces (with occlusion) as Cycles' world
    does."""
    if world is None:
        return np.zeros(3)
    tree = world.node_tree if uses_nodes(world) else None
    if tree is None:
        return _finite_world(rgb(world.color), world.name, "Color", notes)
    out = tree.get_output_node("CYCLES")
    volume = out.inputs.get("Volume") if out is not None else None
    if volume is not None and volume.is_linked:
        notes.warn("world volumes (fog, Volume Scatter/Absorption on the World Output) are "
                   "not supported (ignored)", world.name)
    node, _ = follow_link(out.inputs["Surface"]) if out is not None else (None, None)
    if node is None:
        return np.zeros(3)
    if node.bl_idname != "ShaderNodeBackground":
        notes.warn(f"world shader '{node.bl_label}' is not supported: world.color is used",
                   world.name)
        return _finite_world(rgb(world.color), world.name, "Color", notes)
    colour_in = node.inputs["Color"]
    src, out_sock = follow_link(colour_in)
    if src is None:
        colour = rgb(colour_in.default_value)
    elif src.bl_idname == "ShaderNodeRGB":
        colour = rgb(out_sock.default_value)
    else:
        notes.warn(f"world colours from '{src.bl_label}' nodes (environment textures, "
                   f"skies) are not supported: the Background colour value is used, as "
                   f"background and as a uniform light", world.name)
        colour = rgb(colour_in.default_value)
    colour = _finite_world(colour, world.name, "Background Color", notes)
    strength_in = node.inputs["Strength"]
    strength = float(strength_in.default_value)
    if strength_in.is_linked:
        notes.warn("a linked world strength is not supported: its own value is used",
                   world.name)
    if not math.isfinite(strength):  # Cycles: a NaN strength gives a black world
        notes.skip(f"world '{world.name}': its Background Strength is NaN or infinite: the "
                   f"world is black (no background, no world light)")
        return np.zeros(3)
    return colour * max(strength, 0.0)


def world_lights(world, notes: Notes, colour=None) -> bool:
    """Whether the world lights surfaces: not where its Diffuse and Glossy ray visibility
    are both off (Cycles then excludes it from both closures: a background only). One of
    the two off, or Camera off, is reported (the world is then seen, or lights, anyway);
    both off, that mirrors still show it (``colour``: the world's, when not black)."""
    vis = getattr(world, "cycles_visibility", None)
    if vis is None:
        return True
    lights = vis.diffuse or vis.glossy
    off = _off(vis, (("Camera", "camera"),) + ((("Diffuse", "diffuse"), ("Glossy", "glossy"))
                                               if lights else ()))
    if off:
        notes.warn(f"world ray visibility ({off} off) is not modelled: the world is seen "
                   f"and lights surfaces", world.name)
    return bool(lights)


def _finite_world(colour: np.ndarray, name: str, setting: str, notes: Notes) -> np.ndarray:
    if np.all(np.isfinite(colour)):
        return colour
    notes.skip(f"world '{name}': its {setting} is NaN or infinite: the world is black (no "
               f"background, no world light)")
    return np.zeros(3)
