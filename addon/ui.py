"""Panels: the RSTrace settings in Render Properties, the last render's statistics and
messages, and Blender's stock panels (camera, lights, materials, world, output, ...) enabled
for this engine through their ``COMPAT_ENGINES`` sets.

Layer: top (imports ``session`` for the statistics; nothing imports this).
"""

from __future__ import annotations

import bpy

from . import session

ENGINE = "RSTRACE"

#: Stock panels shown for BLENDER_RENDER that make no sense here.
_EXCLUDE = {
    "DATA_PT_camera_dof",  # no depth of field
    "DATA_PT_camera_dof_aperture",
    "DATA_PT_preview",  # previews are declined
    "MATERIAL_PT_preview",
    "RENDER_PT_simplify",
}

#: EEVEE's node-based material and world panels: the generic way to edit a Principled
#: material or a world Background without the Cycles add-on's panels.
_EXTRA = (
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "EEVEE_WORLD_PT_surface",
)


class RSTracePanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class RSTRACE_PT_render(RSTracePanel, bpy.types.Panel):
    bl_label = "RSTrace"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.rstrace
        col = layout.column()
        col.prop(props, "mode")
        col.prop(props, "accelerator")
        if props.accelerator == "VISIBILITY_FIELD":
            sub = col.column(align=True)
            sub.prop(props, "vf_directions")
            sub.prop(props, "vf_tiles")
        col = layout.column(align=True)
        col.prop(props, "samples")
        col.prop(props, "viewport_samples", text="Viewport")
        col.prop(props, "light_samples")
        col.prop(props, "glossy_samples")
        col.prop(props, "seed")
        layout.prop(props, "max_ray_depth")
        layout.prop(props, "shading_model")
        row = layout.row()
        row.active = props.mode in ("BASE", "INTERPOLANT")
        row.prop(props, "relight_memory", text="Relight Memory (MB)")


class RSTRACE_PT_interpolation(RSTracePanel, bpy.types.Panel):
    bl_label = "Interpolation"
    bl_parent_id = "RSTRACE_PT_render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.rstrace
        layout.active = props.mode != "BASE"
        layout.prop(props, "epsilon")
        layout.prop(props, "depth_cap")
        layout.prop(props, "memory_cap", text="Memory Cap (MB)")
        layout.prop(props, "interpolant_fallback")


class RSTRACE_PT_ri_tree(RSTracePanel, bpy.types.Panel):
    bl_label = "RI-Tree"
    bl_parent_id = "RSTRACE_PT_render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.rstrace
        col = layout.column()
        col.active = props.mode == "RI_TREE"
        col.prop(props, "ri_dist_thresh")
        col.prop(props, "ri_ang_thresh")
        col.prop(props, "ri_depth")
        col.prop(props, "ri_probe_angle")
        col.prop(props, "ri_cache_mb", text="Cache Size (MB)")
        col = layout.column()
        col.prop(props, "thickness_view")
        sub = col.column()
        sub.active = props.thickness_view
        sub.prop(props, "thickness_distance")


class RSTRACE_PT_statistics(RSTracePanel, bpy.types.Panel):
    bl_label = "Last Render"
    bl_parent_id = "RSTRACE_PT_render"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        state = session.peek_state(context.scene)
        if state is None or (not state.stats and not state.messages):
            layout.label(text="Not rendered yet")
            return
        stats = state.stats
        if stats:
            col = layout.column(align=True)
            col.label(text=f"{stats.get('width')} x {stats.get('height')} px, "
                           f"{stats.get('mode')}, {stats.get('accelerator')}")
            col.label(text=f"{stats.get('triangles', 0):,} triangles, "
                           f"{stats.get('objects', 0)} objects, {stats.get('lights', 0)} lights")
            col.label(text=f"Sync {stats.get('sync_seconds', 0.0):.3f} s, apply "
                           f"{stats.get('apply_seconds', 0.0):.3f} s, render "
                           f"{stats.get('render_seconds', 0.0):.3f} s")
            col.label(text=f"{stats.get('edits', 0)} edits since the last render, "
                           f"{stats.get('meshes_read', 0)} meshes read")
            if stats.get("incremental"):
                col.label(text=f"Incremental: {100.0 * stats.get('dirty_fraction', 0.0):.2f}% "
                               f"of the pixels re-rendered")
            else:
                col.label(text="Full frame")
            if stats.get("mode") == "INTERPOLANT":
                col.label(text=f"Interpolated {100.0 * stats.get('interpolated_fraction', 0):.1f}%"
                               f", {stats.get('invalidated_interpolants', 0):,} interpolants "
                               f"invalidated")
                fb = session.fallback_text(stats)
                if fb:
                    col.label(text=fb)
            if stats.get("mode") == "RI_TREE":
                col.label(text=f"Interpolated {100.0 * stats.get('interpolated_fraction', 0):.1f}%"
                               f", {stats.get('ri_objects', 0)} object(s) with an RI-tree, "
                               f"{stats.get('ri_traced_objects', 0)} traced (tree did not pay)")
            rays = session.shadow_rays_text(stats)
            if rays:
                col.label(text=rays)
            col.label(text=f"Memory {stats.get('memory_mb', 0.0):.1f} MB")
            if stats.get("accel_memory_mb") is not None:
                col.label(text=f"{stats.get('accelerator')} memory "
                               f"{stats['accel_memory_mb']:.1f} MB")
            for name, count in (stats.get("pixel_classes") or {}).items():
                col.label(text=f"{name.replace('_', ' ')}: {count:,} px")
        for level, text in state.messages:
            layout.label(text=text, icon="ERROR" if level == "ERROR" else "INFO")


classes = (RSTRACE_PT_render, RSTRACE_PT_interpolation, RSTRACE_PT_ri_tree,
           RSTRACE_PT_statistics)


def stock_panels() -> list:
    """Blender's panels this engine reuses (as Cycles does: every BLENDER_RENDER panel)."""
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if engines is None or panel.__name__ in _EXCLUDE:
            continue
        if "BLENDER_RENDER" in engines or panel.__name__ in _EXTRA:
            panels.append(panel)
    return panels


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in stock_panels():
        panel.COMPAT_ENGINES.add(ENGINE)


def unregister() -> None:
    for panel in stock_panels():
        panel.COMPAT_ENGINES.discard(ENGINE)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
