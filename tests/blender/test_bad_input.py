"""Bad input never crashes or hangs: a report naming the problem, and a frame without the
offending object or a clean error."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from . import builders as b
from .test_render import _cycles, _ours, needs_cycles


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


@pytest.mark.parametrize("case", ["zero_scale", "nan_location", "empty_mesh", "no_faces",
                                  "degenerate_faces"])
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
    elif case == "no_faces":  # vertices and edges but no faces
        me = bpy.data.meshes.new("Wire")
        me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1), (1, 2)], [])
        b.add_object("Wire", me)
    else:  # faces of zero area only (collinear vertices): stopped the whole render before
        me = bpy.data.meshes.new("Degen")
        me.from_pydata([(0, 0, 1), (1, 0, 1), (2, 0, 1), (3, 0, 1)], [],
                       [(0, 1, 2), (1, 2, 3)])
        b.add_object("Degen", me)
    name = {"zero_scale": "Flat", "nan_location": "Lost", "empty_mesh": "Nothing",
            "no_faces": "Wire", "degenerate_faces": "Degen"}[case]
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


@pytest.mark.parametrize("case", ["negative", "nan", "huge", "nan_colour", "nan_spot"])
def test_light_with_unusable_values_is_skipped(case, tmp_path, capfd):
    """A light whose power, colour or spot shape cannot be rendered is skipped with a
    message naming it and the setting (a negative power is legal in Blender): it used to
    refuse the whole render."""
    _scene()
    good, _, _ = _render_and_messages(tmp_path, capfd)
    if case == "nan_spot":
        ob = b.point_light("Broken", (0.0, 0.0, 4.0), 100.0, kind="SPOT")
        ob.data.spot_blend = float("nan")
    else:
        ob = b.point_light("Broken", (0.0, 0.0, 4.0), 100.0)
    if case == "negative":
        ob.data.energy = -10.0
    elif case == "nan":
        ob.data.energy = float("nan")
    elif case == "huge":
        ob.data.energy = 1e6
        ob.data.exposure = 30.0
    elif case == "nan_colour":
        ob.data.color = (float("nan"), 1.0, 1.0)
    out, state, printed = _render_and_messages(tmp_path, capfd)
    word = {"negative": "negative", "nan": "NaN", "huge": "Exposure", "nan_colour": "Color",
            "nan_spot": "Blend"}[case]
    assert state.error is None
    assert _warned(state, "'Broken'", "skipped", word), state.messages
    assert "'Broken'" in printed
    assert state.stats["lights"] == 1
    np.testing.assert_allclose(out["Combined"], good["Combined"], atol=1e-6)


def test_base_colour_above_one_is_reported(tmp_path, capfd):
    _scene()
    bpy.data.materials["Ball"].node_tree.nodes["Principled BSDF"].inputs[
        "Base Color"].default_value = (2.0, 0.4, 0.4, 1.0)
    _, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None
    assert _warned(state, "'Ball'", "Base Color above 1"), state.messages


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


def test_a_mesh_past_the_triangle_limit_is_a_clean_error_before_any_build(tmp_path,
                                                                           monkeypatch):
    """A mesh past the scene's triangle limit (the BVH's 28-bit triangle ids: a small
    limit stands in) is refused by name through the render's report, before any BVH is
    built (main: no such check; ``concat_meshes`` raised an OverflowError after every
    mesh's build); with the limit back, the same scene renders."""
    from rstrace_engine.geometry import footprint

    _scene()
    real = footprint.MAX_TRIANGLES
    monkeypatch.setattr(footprint, "MAX_TRIANGLES", 100)  # the Ball has 224 triangles
    with pytest.raises(RuntimeError, match=r"RSTrace: mesh 'Ball': 224 triangles .*more "
                                           r"than the 100 a scene can hold"):
        b.render_exr(tmp_path / "big.exr")
    assert "a scene can hold" in (_state().error or "")
    monkeypatch.setattr(footprint, "MAX_TRIANGLES", real)
    out = b.render_exr(tmp_path / "fits.exr")
    assert _state().error is None and np.isfinite(out["Combined"]).all()


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


# ----------------------------------------------------------------------------- issue 11


@pytest.mark.parametrize("media", ["MULTI_LAYER_IMAGE", "IMAGE"])
def test_ctrl_c_during_a_render_is_a_cancel(media, tmp_path, monkeypatch):
    """SIGINT (Ctrl+C in a background render) while tracing: reported, nothing written, no
    crash, and the next render works. It used to escape as KeyboardInterrupt: Blender then
    wrote a result that was never started (EXR: segfault) or a blank PNG."""
    import signal

    import addon

    sc = _scene()
    ims = sc.render.image_settings
    ims.media_type = media
    if media == "IMAGE":
        ims.file_format = "PNG"
    path = tmp_path / ("c.exr" if media != "IMAGE" else "c.png")
    sc.render.filepath = str(path)
    real = addon.session.FrameRenderer._progress

    def interrupted(self, fraction, message=""):
        signal.raise_signal(signal.SIGINT)  # Python's handler: KeyboardInterrupt here
        return real(self, fraction, message)

    monkeypatch.setattr(addon.session.FrameRenderer, "_progress", interrupted)
    # Python's own SIGINT handler, as in a terminal (a shell starting the tests in the
    # background without job control ignores SIGINT: the signal would be lost)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(RuntimeError, match="interrupted"):
            bpy.ops.render.render(write_still=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert not path.exists()
    assert "interrupted" in (_state().error or "")
    monkeypatch.setattr(addon.session.FrameRenderer, "_progress", real)
    bpy.ops.render.render(write_still=True)
    assert path.exists() and _state().error is None


def _principled_input(material: str, name: str, value) -> None:
    node = bpy.data.materials[material].node_tree.nodes["Principled BSDF"]
    node.inputs[name].default_value = value


@pytest.mark.parametrize("name", ["Roughness", "Metallic"])
def test_nan_input_is_reported_under_its_name(name, tmp_path, capfd):
    _scene()
    _principled_input("Ball", name, float("nan"))
    out, state, printed = _render_and_messages(tmp_path, capfd)
    assert state.error is None and np.isfinite(out["Combined"]).all()
    assert _warned(state, "'Ball'", f"'{name}'"), state.messages
    assert f"'{name}'" in printed


def test_ior_outside_its_range_is_reported(tmp_path, capfd):
    _scene()
    _principled_input("Ball", "IOR", 0.5)
    _, state, printed = _render_and_messages(tmp_path, capfd)
    assert _warned(state, "IOR 0.5", "'Ball'"), state.messages
    assert "IOR 0.5" in printed


def test_emission_beyond_the_radiance_limit_reaches_the_report(tmp_path, capfd):
    """Emission >= 1e30 cannot be averaged: those samples are left out (black), and both
    the material and the dropped samples are said in Blender's report."""
    _scene()
    _principled_input("Ball", "Emission Color", (1.0, 1.0, 1.0, 1.0))
    _principled_input("Ball", "Emission Strength", 1e30)
    out, state, printed = _render_and_messages(tmp_path, capfd)
    assert state.error is None and np.isfinite(out["Combined"]).all()
    assert _warned(state, "'Ball'", "radiance limit"), state.messages
    assert _warned(state, "left out of the image"), state.messages
    assert "left out of the image" in printed


def test_tiny_ortho_scale_renders(tmp_path, capfd):
    """1e-9 typed in Blender arrives as 9.99999997e-10 (float32): it is the limit, and
    renders, instead of being refused with a message quoting the limit it meets."""
    sc = _scene()
    cam = sc.camera.data
    cam.type = "ORTHO"
    cam.ortho_scale = 1e-9
    out, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None, state.messages
    assert np.isfinite(out["Combined"]).all()


def test_emissive_meshes_are_said_once_and_the_world_light_not(tmp_path, capfd):
    """An emissive mesh lights no surface: the render's report and the Last Render messages
    say so, once. A uniform world lights surfaces (issue 20): nothing to say about it."""
    _scene()  # a grey world
    _principled_input("Ball", "Emission Color", (1.0, 0.5, 0.2, 1.0))
    _principled_input("Ball", "Emission Strength", 3.0)
    _, state, printed = _render_and_messages(tmp_path, capfd)
    assert not _warned(state, "world"), state.messages
    assert _warned(state, "emissive", "'Ball'"), state.messages
    assert printed.count("emissive meshes are not light sources") == 1
    b.set_world((0.0, 0.0, 0.0))  # a black world has nothing to say
    _principled_input("Ball", "Emission Strength", 0.0)
    import addon

    addon.session.forget_all()
    _, state, _ = _render_and_messages(tmp_path, capfd)
    assert not _warned(state, "not modelled") and not _warned(state, "emissive")


def test_embree_renders_the_bvh_image(tmp_path, capfd):
    """An accelerator must not change the image: Blender's default cube on a floor, lit by a
    point light and a sun (grazing shadows), rendered with both, compared pixel by pixel.
    Embree once gave 864 black pixels (of 3,072) here against the BVH's 0."""
    pytest.importorskip("embreex")
    sc = b.setup_render(64, 48, samples=1, max_depth=2)
    b.set_world((0.05, 0.05, 0.05))
    b.add_object("Ground", b.grid("Ground", 10.0), material=b.principled("Floor"))
    import bmesh

    me = bpy.data.meshes.new("Cube")
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bm.to_mesh(me)
    bm.free()
    b.add_object("Cube", me, (0.0, 0.0, 1.0), b.principled("Cube", (0.8, 0.8, 0.8)))
    b.point_light("Light", (4.07, 1.0, 5.9), 1000.0)
    sun = b.point_light("Sun", (0.0, 0.0, 5.0), 2.0, kind="SUN")
    sun.rotation_euler = (math.radians(80.0), 0.0, math.radians(30.0))
    b.camera((7.36, -6.93, 4.96), (0.0, 0.0, 0.5))
    images = {}
    for name in ("BVH", "EMBREE"):
        sc.rstrace.accelerator = name
        out, state, _ = _render_and_messages(tmp_path, capfd)
        assert state.error is None and state.stats["accelerator"] == name, state.messages
        images[name] = out["Combined"][..., :3]
    a, e = images["BVH"], images["EMBREE"]
    black = [int(np.count_nonzero(x.max(axis=-1) < 1e-3)) for x in (a, e)]
    assert abs(black[0] - black[1]) <= 1, black
    diff = np.abs(a - e).max(axis=-1)
    print(f"black pixels BVH/Embree {black}, pixels > 1e-3: {np.count_nonzero(diff > 1e-3)}, "
          f"max {diff.max():.2g}")
    assert np.count_nonzero(diff > 1e-3) <= 2 and diff.max() < 0.05, diff.max()


# ----------------------------------------------------------------------------- issue 20


def _area_light(name: str, location=(0.5, -0.5, 4.5), energy: float = 600.0, **settings):
    """An area light above the camera's frame (Cycles shows lights to camera rays)."""
    data = bpy.data.lights.new(name, "AREA")
    data.energy = energy
    for key, value in settings.items():
        setattr(data, key, value)
    return b.add_object(name, data, location)


@pytest.mark.parametrize("case, word", [
    ("zero_size", "Size is 0"), ("ellipse_zero_axis", "Size Y is 0"),
    ("rectangle_zero_axis", "Size Y is 0"), ("zero_scale", "scale is 0"),
    ("nan_size", "Size is NaN"), ("inf_size", "Size with the object's scale"),
    ("nan_radius", "Radius is NaN"), ("inf_radius", "Radius"), ("portal", "portal"),
    ("spread_zero", "Spread is 0"), ("spread_nan", "Spread is nan"),
])
def test_light_cycles_renders_dark_is_skipped(case, word, tmp_path, capfd):
    """Cycles renders no light from these (measured: a black frame where the light was
    the only one): an area light of zero size, an ellipse or rectangle with a zero axis, a
    zero X scale, a NaN or infinite (3.4e38 once typed) size, a NaN or infinite radius, a
    portal. Each is skipped with a message naming the light and the setting, and the frame
    is the one without it. So is Spread 0 (or NaN, which Cycles takes as 0): Cycles renders
    a collimated beam from it, which the tracer does not model."""
    _scene()
    good, _, _ = _render_and_messages(tmp_path, capfd)
    if case in ("nan_radius", "inf_radius"):
        ob = b.point_light("Broken", (0.5, -0.5, 3.0), 300.0)
        ob.data.shadow_soft_size = float("nan") if case == "nan_radius" else float("inf")
    elif case == "zero_size":
        ob = _area_light("Broken", size=0.0)
    elif case == "ellipse_zero_axis":
        ob = _area_light("Broken", shape="ELLIPSE", size=1.0, size_y=0.0)
    elif case == "rectangle_zero_axis":
        ob = _area_light("Broken", shape="RECTANGLE", size=1.0, size_y=0.0)
    elif case == "zero_scale":
        ob = _area_light("Broken", size=1.0)
        ob.scale = (0.0, 1.0, 1.0)
    elif case == "nan_size":
        ob = _area_light("Broken", size=float("nan"))
    elif case == "inf_size":
        ob = _area_light("Broken", size=float("inf"))
    elif case in ("spread_zero", "spread_nan"):
        ob = _area_light("Broken", size=1.0, spread=0.0 if case == "spread_zero" else math.nan)
    else:
        ob = _area_light("Broken", size=1.0)
        ob.data.cycles.is_portal = True
    out, state, printed = _render_and_messages(tmp_path, capfd)
    assert state.error is None
    assert _warned(state, "'Broken'", "skipped", word), state.messages
    assert "'Broken'" in printed
    assert state.stats["lights"] == 1 and np.isfinite(out["Combined"]).all()
    np.testing.assert_allclose(out["Combined"], good["Combined"], atol=1e-6)


def _block_error(a: np.ndarray, ref: np.ndarray) -> float:
    """Mean relative error of the 8x8-block means (luminance) of ``a`` against ``ref``,
    printed and returned: per-pixel differences would measure the sampling noise of soft
    lights (16 samples x 16 light samples: 4% per pixel between two seeds here)."""
    from .test_cycles_agreement import _block_errors

    err = float(_block_errors(a, ref).mean())
    print(f"mean 8x8-block error {err:.4f}")
    return err


def _close_to_cycles(ours: list, cycles: list) -> float:
    """:func:`_block_error` of the two-seed means."""
    return _block_error((ours[0] + ours[1]) / 2, (cycles[0] + cycles[1]) / 2)


@needs_cycles
@pytest.mark.parametrize("case", [
    "sun_angle_max", "sun_angle_nan", "sphere_cuts_geometry",
    "area_scaled_non_uniformly", "area_mirrored_x", "area_mirrored_z", "area_tiny",
    "world_strength_nan",
])
def test_odd_light_values_render_as_cycles_renders_them(case, tmp_path, capfd):
    """Values Cycles renders, rendered the same (measured with Cycles 5.0): a sun angle at
    its maximum (180 degrees: a hemisphere of directions); NaN sun angle (Cycles: a hard
    sun, said); a sphere light whose radius cuts through the floor
    and encloses the ball; an area light scaled 2 x 1 (as a 2 x 1 rectangle), mirrored in
    X (unchanged) or in Z (emits upwards: nothing lit here); an area light of 0.1 mm (a
    Lambertian point); a world strength of NaN (a black world, said)."""
    sc = _scene(48, 36)
    sc.rstrace.samples, sc.rstrace.light_samples, sc.rstrace.max_ray_depth = 16, 16, 0
    b.set_world((0.0, 0.0, 0.0))
    lamp = bpy.data.objects["Lamp"]
    words = None
    if case in ("sun_angle_max", "sun_angle_nan"):
        bpy.data.objects.remove(lamp)
        sun = b.point_light("Odd", (0.0, 0.0, 5.0), 3.0, kind="SUN")
        sun.rotation_euler = (math.radians(30.0), 0.0, math.radians(20.0))
        sun.data.angle = math.pi if case == "sun_angle_max" else float("nan")
        words = ("'Odd'", "Angle") if case == "sun_angle_nan" else None
    elif case == "sphere_cuts_geometry":  # through the floor, hidden by the ball
        lamp.location = (0.0, 2.0, 0.45)
        lamp.data.shadow_soft_size = 0.6
        lamp.data.energy = 200.0
    elif case == "area_scaled_non_uniformly":
        _area_light("Odd", size=1.0).scale = (2.0, 1.0, 1.0)
    elif case == "area_mirrored_x":
        _area_light("Odd", shape="RECTANGLE", size=2.0, size_y=1.0).scale = (-1.0, 1.0, 1.0)
    elif case == "area_mirrored_z":
        _area_light("Odd", size=1.0).scale = (1.0, 1.0, -1.0)
    elif case == "area_tiny":
        _area_light("Odd", size=1e-4)
    else:
        world = b.set_world((0.5, 0.5, 0.5))
        world.node_tree.nodes["Background"].inputs["Strength"].default_value = float("nan")
        words = (f"'{world.name}'", "Strength")
    cycles = _cycles(samples=256)
    capfd.readouterr()
    ours = _ours()
    state = _state()
    assert state.error is None, state.messages
    assert all(np.isfinite(x).all() for x in ours)
    if words is not None:
        assert _warned(state, *words), state.messages
    assert _close_to_cycles(ours, cycles) < 0.02


def test_area_light_scale_is_the_size_cycles_gives_it(tmp_path, capfd):
    """An area light of 1 x 1 scaled 2 x 1 renders as one of 2 x 1 (Cycles: the world
    matrix's X and Y columns times the sizes): the same light, so the same samples (up to
    float32 rounding of the matrix). Mirrored in X it is the same emitter, sampled from the
    other end: the same image up to sampling noise."""
    sc = _scene()
    sc.rstrace.samples = 16
    bpy.data.objects.remove(bpy.data.objects["Lamp"])
    panel = _area_light("Panel", shape="RECTANGLE", size=2.0, size_y=1.0)
    panel.rotation_euler = (math.radians(20.0), 0.0, math.radians(30.0))
    rect, _, _ = _render_and_messages(tmp_path, capfd)
    panel.data.size = 1.0
    panel.scale = (2.0, 1.0, 1.0)
    scaled, state, _ = _render_and_messages(tmp_path, capfd)
    assert not _warned(state, "'Panel'"), state.messages
    diff = np.abs(scaled["Combined"] - rect["Combined"]).max(axis=-1)
    assert np.count_nonzero(diff > 1e-4) <= 3, diff.max()
    panel.scale = (-2.0, 1.0, 1.0)
    mirrored, _, _ = _render_and_messages(tmp_path, capfd)
    assert _block_error(mirrored["Combined"], rect["Combined"]) < 0.02


def test_sheared_area_light_is_rendered_as_a_rectangle_and_said(tmp_path, capfd):
    """A rotated area light under a non-uniformly scaled parent: Cycles spans a
    parallelogram (non-orthogonal axes); it is rendered as a rectangle of the same side
    lengths, and said."""
    _scene()
    parent = b.add_object("Stretch", None, (0.0, 0.0, 0.0))
    parent.scale = (2.0, 1.0, 1.0)
    panel = _area_light("Panel", size=1.0)
    panel.rotation_euler = (0.0, 0.0, math.radians(45.0))
    panel.parent = parent
    out, state, _ = _render_and_messages(tmp_path, capfd)
    assert state.error is None and np.isfinite(out["Combined"]).all()
    assert _warned(state, "sheared", "'Panel'"), state.messages
    assert state.stats["lights"] == 2
