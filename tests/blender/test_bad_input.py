"""Bad input never crashes or hangs: a report naming the problem, and a frame without the
offending object or a clean error."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from . import builders as b


def _state():
    import addon

    return addon.session.state_for(bpy.context.scene)


def _scene(width=32, height=24):
    sc = b.setup_render(width, height, samples=1)
    b.set_world((0.05, 0.05, 0.05))
    b.add_object("Ground", b.grid("Ground", 10.0), material=b.principled("Floor"))
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 16, 8), (0.0, 0.0, 1.0),
                 b.principled("Ball", (0.8, 0.2, 0.2)))
    b.point_light("Lamp", (2.0, -3.0, 5.0), 1500.0)
    b.camera()
    return sc


def _render_and_messages(tmp_path, capfd):
    capfd.readouterr()
    out = b.render_exr(tmp_path / "bad.exr")
    printed = capfd.readouterr()
    state = _state()
    return out, state, printed.out + printed.err


def _warned(state, *words) -> bool:
    return any(all(w in text for w in words) for level, text in state.messages
               if level == "WARNING")


@pytest.mark.parametrize("case", ["zero_scale", "nan_location", "empty_mesh", "no_faces"])
def test_bad_object_is_skipped_reported_and_the_frame_rendered(case, tmp_path, capfd):
    _scene()
    good, _, _ = _render_and_messages(tmp_path, capfd)
    if case == "zero_scale":
        b.add_object("Flat", b.uv_sphere("Flat", 1.0, 8, 4), (2.0, 0.0, 1.0),
                     scale=(0.0, 1.0, 1.0))
    elif case == "nan_location":
        b.add_object("Lost", b.uv_sphere("Lost", 1.0, 8, 4), (float("nan"), 0.0, 1.0))
    elif case == "empty_mesh":
        b.add_object("Nothing", bpy.data.meshes.new("Nothing"))
    else:  # vertices and edges but no faces
        me = bpy.data.meshes.new("Wire")
        me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1), (1, 2)], [])
        b.add_object("Wire", me)
    name = {"zero_scale": "Flat", "nan_location": "Lost", "empty_mesh": "Nothing",
            "no_faces": "Wire"}[case]
    out, state, printed = _render_and_messages(tmp_path, capfd)
    assert state.error is None
    assert _warned(state, f"'{name}'", "skipped"), state.messages
    assert f"'{name}'" in printed  # reported through Blender's report
    assert state.stats["objects"] == 2
    np.testing.assert_allclose(out["Combined"], good["Combined"], atol=1e-6)


def test_nan_light_is_skipped(tmp_path, capfd):
    _scene()
    lamp = b.point_light("Broken", (0.0, 0.0, 0.0), 100.0)
    lamp.location.z = float("nan")
    out, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None and _warned(state, "'Broken'")
    assert state.stats["lights"] == 1 and np.isfinite(out["Combined"]).all()


def test_no_camera_is_a_clean_error(tmp_path):
    import addon
    from rstrace_engine.geometry.scene import SceneError

    _scene()
    bpy.context.scene.camera = None
    # Blender itself refuses before the engine is called ...
    with pytest.raises(RuntimeError, match="no camera"):
        b.render_exr(tmp_path / "nocam.exr")
    # ... and the exporter (used by scripts and the viewport) says so too
    with pytest.raises(SceneError, match="no active camera"):
        addon.export.export_scene(bpy.context.evaluated_depsgraph_get())
    lamp = bpy.data.objects["Lamp"]
    with pytest.raises(SceneError, match="'Lamp' is a light, not a camera"):
        addon.export.export_scene(bpy.context.evaluated_depsgraph_get(), camera_object=lamp)


def test_broken_camera_is_a_clean_error(tmp_path):
    sc = _scene()
    sc.camera.scale = (0.0, 0.0, 0.0)
    with pytest.raises(RuntimeError, match="RSTrace: camera .*singular"):
        b.render_exr(tmp_path / "flatcam.exr")
    sc.camera.scale = (1.0, 1.0, 1.0)
    sc.camera.location.x = float("nan")
    with pytest.raises(RuntimeError, match="RSTrace: camera .*NaN"):
        b.render_exr(tmp_path / "nancam.exr")


def test_nothing_visible_is_a_clean_error(tmp_path):
    sc = b.setup_render(16, 12)
    b.camera()
    with pytest.raises(RuntimeError, match="nothing to render"):
        b.render_exr(tmp_path / "empty.exr")
    assert sc.render.engine == "RSTRACE"


def test_no_lights_renders_with_a_warning(tmp_path, capfd):
    _scene()
    bpy.data.objects.remove(bpy.data.objects["Lamp"])
    mat = bpy.data.materials["Ball"]
    mat.node_tree.nodes["Principled BSDF"].inputs["Emission Strength"].default_value = 2.0
    out, state, printed = _render_and_messages(tmp_path, capfd)
    assert state.error is None and _warned(state, "no lights")
    assert "no lights" in printed
    c = out["Combined"]
    assert c[..., 0].max() > 1.0  # the emissive ball is visible


@pytest.mark.parametrize("scale", [1e4, 1e-4])
def test_huge_and_tiny_scenes_render_like_unit_scale(scale, tmp_path, capfd):
    """The same scene scaled by 1e4 or 1e-4 (lights scaled by scale^2, so irradiance is
    unchanged) renders the same image: offsets scale with the scene."""
    sc = _scene(32, 24)
    sc.rstrace.max_ray_depth = 1
    ref, _, _ = _render_and_messages(tmp_path, capfd)
    for ob in bpy.data.objects:
        ob.location = ob.location * scale
        if ob.type == "MESH":
            ob.scale = ob.scale * scale
        elif ob.type == "LIGHT":
            ob.data.energy *= scale * scale
    cam = sc.camera.data
    cam.clip_start, cam.clip_end = 0.1 * scale, 1000.0 * scale
    out, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None, state.messages
    a, r = out["Combined"][..., :3], ref["Combined"][..., :3]
    assert np.isfinite(a).all()
    np.testing.assert_allclose(a, r, rtol=1e-3, atol=1e-3)


def test_far_from_origin_scene(tmp_path, capfd):
    """Translated by 1e5 (float32 in Blender limits how far): same image within noise."""
    sc = _scene(32, 24)
    ref, _, _ = _render_and_messages(tmp_path, capfd)
    for ob in bpy.data.objects:
        ob.location.x += 1e5
    out, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None
    diff = np.abs(out["Combined"][..., :3] - ref["Combined"][..., :3])
    assert np.mean(diff) < 0.01 and sc.render.engine == "RSTRACE"
