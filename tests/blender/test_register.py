"""Registration, settings and panels of the add-on."""

from __future__ import annotations

import bpy
import pytest

from rstrace_engine.frame import RenderSettings


def test_register_unregister_twice(rstrace_addon):
    for _ in range(2):
        rstrace_addon.unregister()
        assert not hasattr(bpy.types.Scene, "rstrace")
        assert "RSTRACE" not in bpy.types.DATA_PT_lens.COMPAT_ENGINES
        assert rstrace_addon.session._on_load_pre not in bpy.app.handlers.load_pre
        rstrace_addon.register()
        assert hasattr(bpy.types.Scene, "rstrace")
        assert "RSTRACE" in bpy.types.DATA_PT_lens.COMPAT_ENGINES
        assert rstrace_addon.session._on_load_pre in bpy.app.handlers.load_pre
    bpy.context.scene.render.engine = "RSTRACE"
    assert bpy.context.scene.render.engine == "RSTRACE"


def test_engine_class_flags():
    from addon.engine import RSTraceRenderEngine as E

    assert (E.bl_idname, E.bl_label) == ("RSTRACE", "RSTrace")
    assert E.bl_use_shading_nodes_custom is False
    assert E.bl_use_preview is False


def test_settings_map_to_render_settings():
    from addon import properties

    props = bpy.context.scene.rstrace
    assert props.mode == "BASE" and props.accelerator == "BVH"
    props.mode, props.epsilon, props.max_ray_depth = "INTERPOLANT", 0.05, 3
    props.samples, props.accelerator, props.depth_cap, props.memory_cap = 9, "EMBREE", 4, 64.0
    rs = properties.render_settings(props)
    assert rs == RenderSettings(mode="INTERPOLANT", epsilon=pytest.approx(0.05), max_depth=3,
                                samples=9, accelerator="EMBREE", depth_cap=4,
                                memory_cap_mb=64.0, seed=0,
                                ri_dist_thresh=pytest.approx(0.05))  # a float32 property
    mode_ids = {i.identifier for i in props.bl_rna.properties["mode"].enum_items}
    accel_ids = {i.identifier for i in props.bl_rna.properties["accelerator"].enum_items}
    assert mode_ids == {"BASE", "INTERPOLANT", "RI_TREE"}
    assert accel_ids == {"BVH", "EMBREE", "VISIBILITY_FIELD"}


def test_light_samples_map_to_render_settings():
    """Light Samples: the core's default, and the scene's value in the render settings and
    in the viewport's (every viewport pass takes them: refinement adds passes)."""
    from addon import properties, viewport

    props = bpy.context.scene.rstrace
    assert props.light_samples == RenderSettings().light_samples
    props.light_samples = 7
    assert properties.render_settings(props).light_samples == 7
    assert viewport.viewport_settings(bpy.context.scene).light_samples == 7


def test_glossy_samples_map_to_render_settings():
    from addon import properties, viewport

    props = bpy.context.scene.rstrace
    assert props.glossy_samples == RenderSettings().glossy_samples
    props.glossy_samples = 5
    assert properties.render_settings(props).glossy_samples == 5
    assert viewport.viewport_settings(bpy.context.scene).glossy_samples == 5


def test_stock_panels_enabled_and_settings_panel_polls():
    from addon import ui

    for name in ("DATA_PT_lens", "DATA_PT_light", "RENDER_PT_format",
                 "EEVEE_MATERIAL_PT_surface", "EEVEE_WORLD_PT_surface"):
        assert "RSTRACE" in getattr(bpy.types, name).COMPAT_ENGINES, name
    assert "RSTRACE" not in bpy.types.DATA_PT_camera_dof.COMPAT_ENGINES

    class Ctx:
        engine = "RSTRACE"

    assert ui.RSTRACE_PT_render.poll(Ctx)
    Ctx.engine = "CYCLES"
    assert not ui.RSTRACE_PT_render.poll(Ctx)


def test_kernel_status_reports_compiling_with_an_empty_cache(tmp_path, monkeypatch):
    from addon import runtime

    monkeypatch.setitem(runtime._state, "cache_dir", str(tmp_path))
    monkeypatch.setitem(runtime._state, "kernels_ready", False)
    assert "compiling kernels" in runtime.kernel_status()
    (tmp_path / "whitted.render-1.py311.nbi").write_bytes(b"")
    assert runtime.kernel_status() == "loading compiled kernels"
    monkeypatch.setitem(runtime._state, "kernels_ready", True)
    assert runtime.kernel_status() is None


def test_interpolation_pass_is_registered_for_the_compositor():
    sc = bpy.context.scene
    sc.render.engine = "RSTRACE"
    tree = bpy.data.node_groups.new("Compositing", "CompositorNodeTree")
    if hasattr(sc, "compositing_node_group"):  # Blender 5
        sc.compositing_node_group = tree
    node = tree.nodes.new("CompositorNodeRLayers")
    node.scene = sc
    enabled = {o.name for o in node.outputs if o.enabled}
    assert {"Image", "Alpha", "Interpolation"} <= enabled
