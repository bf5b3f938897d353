"""Blender lights and the world -> :class:`~rstrace_engine.geometry.scene.Light` and a world
colour, one datablock at a time.

Point, sun and spot lights map directly; area lights and light radii are approximated (and
noted).

Layer: imported by ``export`` only.
"""

from __future__ import annotations

import math

import numpy as np

from rstrace_engine.geometry.scene import MAX_LIGHT_POWER, Light

from .materials import Notes, follow_link, rgb, uses_nodes


def read_light(ob, name: str, m: np.ndarray, notes: Notes) -> Light | None:
    """A :class:`Light` from an evaluated light object with world matrix ``m`` (4, 4), or
    None (with a note) when it cannot be rendered."""
    data = ob.data
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
    exposure = float(getattr(data, "exposure", 0.0))
    try:
        power = float(data.energy) * 2.0 ** exposure if math.isfinite(exposure) else math.nan
    except OverflowError:  # an exposure above ~1024
        power = math.inf
    why = _unusable(data, colour, power, exposure)
    if why:
        notes.skip(f"light '{name}' skipped: {why}")
        return None
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


def _unusable(data, colour, power: float, exposure: float) -> str | None:
    """Why a light's values cannot be rendered (naming the setting), or None. A light with
    a NaN or negative power, colour or spot shape is skipped, like one with a NaN
    transform, instead of refusing the whole render."""
    name, unit = ("Strength", "W/m2") if data.type == "SUN" else ("Power", "W")
    what = name if exposure == 0.0 else f"{name} x 2^Exposure ({exposure:g})"
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


# ----------------------------------------------------------------------------- camera, world


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
