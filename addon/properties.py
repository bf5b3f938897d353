"""Render settings: one ``PointerProperty`` namespace on the scene, ``scene.rstrace``.

Lowest layer of the add-on: imports nothing from the rest of it. The values map one to one
onto :class:`rstrace_engine.frame.RenderSettings` through :func:`render_settings`.
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from rstrace_engine.frame import ACCELERATORS, INTERNAL_ACCELERATORS, MODES, RenderSettings

_MODE_UI = {
    "BASE": ("Base Tracer", "Classical Whitted ray tracing of every pixel"),
    "INTERPOLANT": ("Radiance Interpolants",
                    "Interpolate radiance from per-object 4D linetrees within the error bound "
                    "epsilon; edits invalidate only what they affect (ray segment trees). Not "
                    "faster than the Base Tracer in this version (README, Measured)"),
    "RI_TREE": ("RI-Tree",
                "Interpolate ray-surface intersections (hit point, normal, exit ray, "
                "thickness) from per-object 4D kd-trees. Not faster than the Base Tracer in "
                "this version: objects whose tree does not pay are traced"),
}
_ACCELERATOR_UI = {
    "BVH": ("BVH", "Two-level bounding volume hierarchy (numba); moving an object rebuilds "
            "only the top level"),
    "EMBREE": ("Embree", "Intel Embree through the embreex package, where it is installed"),
    "VISIBILITY_FIELD": ("Visibility Field",
                         "Parallel beam tilings in many directions, cheap to update for "
                         "moving objects"),
}
# the names come from the core's single lists (rstrace_engine.frame); only labels live here
MODE_ITEMS = tuple((k, *_MODE_UI.get(k, (k.title(), k))) for k in MODES)
ACCELERATOR_ITEMS = tuple((k, *_ACCELERATOR_UI.get(k, (k.title(), k))) for k in ACCELERATORS
                          if k not in INTERNAL_ACCELERATORS)

SHADING_MODEL_ITEMS = (
    ("PRINCIPLED", "Principled", "Materials follow Blender's Principled BSDF: a Fresnel-"
     "weighted GGX highlight over a diffuse base that loses what the highlight reflects "
     "(agrees with Cycles' direct lighting)"),
    ("WARD", "Ward", "Ward's isotropic highlight with a constant reflectance and a Whitted "
     "mirror for smooth surfaces (the model of the radiance-interpolant paper)"),
)


class RSTraceSettings(bpy.types.PropertyGroup):
    """Settings of the RSTrace render engine (``scene.rstrace``)."""

    mode: EnumProperty(name="Mode", items=MODE_ITEMS, default="BASE",
                       description="How pixels are computed")
    epsilon: FloatProperty(
        name="Epsilon", default=0.01, min=0.0, max=1.0, soft_max=0.2, precision=3,
        description="Error bound for interpolated radiance, in display space (0..1 of the "
                    "displayed value); smaller is more accurate and slower")
    max_ray_depth: IntProperty(
        name="Max Ray Depth", default=5, min=0, max=32, soft_max=12,
        description="Reflection and refraction depth of the Whitted tracer (0: direct light "
                    "only)")
    samples: IntProperty(
        name="Samples", default=1, min=1, max=4096, soft_max=64,
        description="Jittered (stratified) samples per pixel, averaged with a box filter")
    light_samples: IntProperty(
        name="Light Samples", default=RenderSettings.light_samples, min=1, max=4096,
        soft_max=64,
        description="Shadow rays per soft light (area lights, lights with a radius, a sun "
                    "with an angle, the world's light) at each shading point and pixel "
                    "sample, stratified; a light without extent takes one")
    glossy_samples: IntProperty(
        name="Glossy Samples", default=RenderSettings.glossy_samples, min=1, max=1024,
        soft_max=64,
        description="Reflected and refracted rays a rough surface (Principled above "
                    "roughness 0.05, Glossy and Glass nodes) spreads over its lobe at a "
                    "path's first rough bounce (an opaque lobe up to twice as many "
                    "reflections); deeper rough bounces take one, a mirror one")
    viewport_samples: IntProperty(
        name="Viewport Samples", default=4, min=1, max=1024, soft_max=64,
        description="Samples per pixel the rendered viewport refines to while idle (a coarse "
                    "preview first, then one sample, then more)")
    accelerator: EnumProperty(name="Accelerator", items=ACCELERATOR_ITEMS, default="BVH",
                              description="Ray intersection structure")
    depth_cap: IntProperty(
        name="Depth Cap", default=6, min=0, max=12,  # linetree.MAX_DEPTH
        description="Deepest subdivision of a linetree or RI-tree; cells that still fail "
                    "there are traced")
    interpolant_fallback: BoolProperty(
        name="Trace Where Cells Don't Pay", default=True,
        description="Interpolant mode: trace the rays whose cells cost more than they save, "
                    "learned from each frame's measured costs, so that the mode is never "
                    "much slower than Base (a small or cheaply lit scene may then interpolate "
                    "nothing: RSTrace > Last Render says so). Off: cells wherever the rays "
                    "need them, to see them in the Interpolation pass")
    memory_cap: FloatProperty(
        name="Memory Cap", default=256.0, min=0.0, soft_max=8192.0, precision=0,
        description="Memory for interpolants and RI-tree samples, in MB; the least "
                    "recently used are evicted beyond it")
    relight_memory: FloatProperty(
        name="Relight Memory", default=RenderSettings.relight_memory_mb, min=0.0, max=1e6,
        soft_max=8192.0, precision=0,
        description="Base mode: memory for the per-light records that let light edits "
                    "(power, colour, moving a light) relight the last frame instead of "
                    "re-tracing it, in MB. Over it, moved lights re-trace, then every light "
                    "edit does; 0: no records. Interpolant mode: the cap on the "
                    "interpolants' per-light shares, which let a light's power or colour "
                    "rescale them instead of rebuilding them")
    seed: IntProperty(name="Seed", default=0, min=0,
                      description="Seed of the pixel jitter pattern")
    shading_model: EnumProperty(name="Shading Model", items=SHADING_MODEL_ITEMS,
                                default="PRINCIPLED",
                                description="How Blender materials are shaded")
    vf_directions: IntProperty(
        name="Directions", default=34, min=1, max=2050,
        description="Visibility field: number of beam directions l (rounded up to 4, 10, 34, "
                    "130, 514 or 2050); more directions, fewer candidates per ray, more "
                    "memory")
    vf_tiles: IntProperty(
        name="Tiles", default=64, min=1, max=1024, soft_max=256,
        description="Visibility field: n, the n x n tiles of each direction's beam grid; "
                    "memory grows with l x n^2")
    # RI-tree: the paper's ranges (seed 004, Table 2) are the soft limits
    ri_dist_thresh: FloatProperty(
        name="Distance Threshold", default=0.05, min=1e-6, max=10.0, soft_min=0.01,
        soft_max=0.25, precision=3,
        description="RI-tree cells split while the traced and the interpolated output ray "
                    "at their midpoint differ by more than this (4D line space)")
    ri_ang_thresh: FloatProperty(
        name="Angular Threshold", default=30.0, min=0.01, max=180.0, soft_min=5.0,
        soft_max=30.0, precision=1,
        description="Rays are traced where the output directions of a cell's corners differ "
                    "by more than this many degrees (high curvature)")
    ri_depth: IntProperty(
        name="Depth Constraint", default=28, min=1, max=64, soft_min=22, soft_max=30,
        description="Deepest level of the RI-tree's binary 4D kd-trees")
    ri_probe_angle: FloatProperty(
        name="Exit-Ray Test", default=0.025, min=0.0, max=180.0, soft_min=0.0, soft_max=5.0,
        precision=3,
        description="RI-tree cells also split while the traced and the interpolated output "
                    "ray (the exit ray through glass, the reflection off a mirror) at their "
                    "midpoint differ by more than this many degrees; cells still over it at "
                    "the depth constraint are traced; pixels whose interpolated rays meet "
                    "different things behind the glass or in the mirror are traced again. "
                    "0: both off (the paper's tests alone)")
    ri_cache_mb: FloatProperty(
        name="Cache Size", default=100.0, min=0.001, max=1e6, soft_min=0.128,
        soft_max=4096.0, precision=3,
        description="Memory for RI-tree nodes and samples, in MB; the least recently used "
                    "are pruned beyond it")
    thickness_view: BoolProperty(
        name="Thickness View", default=False,
        description="Render objects as semi-transparent volumes by the distance a ray "
                    "travels inside them (exact in Base mode, interpolated in RI-Tree mode)")
    thickness_distance: FloatProperty(
        name="Thickness Distance", default=0.0, min=0.0, soft_max=100.0, unit="LENGTH",
        description="Distance inside objects that darkens a pixel to 1/e (0: a tenth of the "
                    "scene size)")


def _typed(value: float) -> float:
    """A float property's value as the decimal the user typed: Blender stores it in float32,
    so 0.1 reads back as 0.10000000149; the shortest decimal that float32 rounds to the same
    value is what was meant (and equals the engine's own default of 0.1)."""
    return float(str(np.float32(value)))


def render_settings(props: RSTraceSettings):
    """The scene's settings as a (validated) :class:`rstrace_engine.frame.RenderSettings`."""
    return RenderSettings(
        mode=props.mode, epsilon=_typed(props.epsilon), max_depth=int(props.max_ray_depth),
        samples=int(props.samples), light_samples=int(props.light_samples),
        glossy_samples=int(props.glossy_samples),
        accelerator=props.accelerator,
        depth_cap=int(props.depth_cap), memory_cap_mb=_typed(props.memory_cap),
        seed=int(props.seed), vf_directions=int(props.vf_directions),
        vf_tiles=int(props.vf_tiles), ri_dist_thresh=_typed(props.ri_dist_thresh),
        ri_ang_thresh=_typed(props.ri_ang_thresh), ri_depth=int(props.ri_depth),
        ri_cache_mb=_typed(props.ri_cache_mb), ri_probe_angle=_typed(props.ri_probe_angle),
        thickness_view=bool(props.thickness_view),
        thickness_distance=_typed(props.thickness_distance),
        relight_memory_mb=_typed(props.relight_memory),
        interpolant_fallback=bool(props.interpolant_fallback),
    ).validated()


classes = (RSTraceSettings,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.rstrace = PointerProperty(type=RSTraceSettings, name="RSTrace",
                                              description="RSTrace render settings")


def unregister() -> None:
    del bpy.types.Scene.rstrace
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
