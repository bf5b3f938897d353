"""F12 and animation renders through the RSTrace engine, checked against Cycles."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from rstrace_engine.frame import CLASS_BACKGROUND, CLASS_COLORS, CLASS_TRACED

from . import builders as b
from .exr import read_exr, read_pass


def _state():
    import addon

    return addon.session.state_for(bpy.context.scene)


def _lum(a: np.ndarray) -> np.ndarray:
    return a[..., :3].mean(axis=-1)


def _cycles(samples: int = 128, max_bounces: int = 0, seeds=(1, 2),
            transmission_bounces: int = 0):
    """Render the current scene with Cycles (direct light plus ``max_bounces`` glossy and
    ``transmission_bounces`` transmission bounces, box filter of one pixel, no denoising)
    once per seed."""
    sc = bpy.context.scene
    engine = sc.render.engine
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = samples
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.max_bounces = max(max_bounces, transmission_bounces)
    cy.diffuse_bounces = 0
    cy.glossy_bounces = max_bounces
    cy.transmission_bounces = transmission_bounces
    cy.caustics_reflective = cy.caustics_refractive = False
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    out = []
    for seed in seeds:
        cy.seed = seed
        out.append(b.render_exr()["Combined"][..., :3])
    sc.render.engine = engine
    return out


def _ours(seeds=(0, 7)):
    sc = bpy.context.scene
    out = []
    for seed in seeds:
        sc.rstrace.seed = seed
        result = b.render_exr()
        assert result, f"no image written: {_state().messages}"
        out.append(result["Combined"][..., :3])
    return out


def _compare(ours: list, cycles: list) -> dict:
    """Noise-aware comparison: each renderer's noise is estimated from two seeds."""
    o, c = (ours[0] + ours[1]) / 2, (cycles[0] + cycles[1]) / 2
    sigma = np.hypot(_lum(np.abs(cycles[0] - cycles[1])) / 2,
                     _lum(np.abs(ours[0] - ours[1])) / 2)
    diff = np.abs(_lum(o) - _lum(c))
    over = diff > 0.02 * _lum(c) + 4.0 * sigma + 2e-3
    lit = _lum(c) > 0.05
    ratio = _lum(o)[lit] / _lum(c)[lit]
    stats = dict(rel_l1=float(np.abs(o - c).sum() / max(c.sum(), 1e-9)),
                 frac_over=float(over.mean()), median_ratio=float(np.median(ratio)),
                 mean_ours=float(o.mean()), mean_cycles=float(c.mean()))
    print("cycles agreement:", {k: round(v, 5) for k, v in stats.items()})
    return stats


needs_cycles = pytest.mark.skipif(not hasattr(bpy.types.Scene, "cycles"),
                                  reason="the Cycles add-on is not enabled in this bpy build")


# ----------------------------------------------------------------------------- F12


def test_f12_writes_combined_and_interpolation_passes(tmp_path):
    b.three_spheres_scene(48, 36)
    out = b.render_exr(tmp_path / "f12.exr")
    state = _state()
    assert state.error is None, state.messages
    combined, classes = out["Combined"], out["Interpolation"]
    assert combined.shape == (36, 48, 4) and classes.shape == (36, 48, 3)
    assert np.all(np.isfinite(combined)) and np.all(combined[..., 3] == 1.0)
    # BASE mode: every pixel is traced or background, shown in the class colours
    traced = np.all(np.isclose(classes, CLASS_COLORS[CLASS_TRACED]), axis=-1)
    background = np.all(np.isclose(classes, CLASS_COLORS[CLASS_BACKGROUND]), axis=-1)
    assert np.all(traced | background)
    assert 0.3 < traced.mean() < 0.9  # floor and spheres below, sky above
    assert background[-1].all() and traced[0].all()  # top row sky, bottom row floor
    # the sky is the world colour; the lit floor is brighter
    sky = combined[background][:, :3]
    np.testing.assert_allclose(sky, np.broadcast_to((0.02, 0.02, 0.03), sky.shape), atol=1e-5)
    assert _lum(combined[0]).mean() > 0.1
    assert state.stats["pixel_classes"]["traced"] == traced.sum()
    assert state.stats["triangles"] > 1000 and state.stats["render_seconds"] > 0


def test_film_transparent_gives_zero_alpha_background(tmp_path):
    b.three_spheres_scene(32, 24)
    bpy.context.scene.render.film_transparent = True
    combined = b.render_exr(tmp_path / "t.exr")["Combined"]
    assert combined[-1, :, 3].max() == 0.0 and combined[0, :, 3].min() == 1.0
    assert combined[-1, :, :3].max() == 0.0


def test_render_region_writes_only_the_border(tmp_path):
    sc = b.three_spheres_scene(40, 30)
    full = b.render_exr(tmp_path / "a.exr")["Combined"]
    sc.render.use_border = True
    sc.render.border_min_x, sc.render.border_max_x = 0.25, 0.75
    sc.render.border_min_y, sc.render.border_max_y = 0.0, 0.5
    for crop, shape in ((False, (30, 40, 4)), (True, (15, 20, 4))):
        sc.render.use_crop_to_border = crop
        part = b.render_exr(tmp_path / "b.exr")["Combined"]
        assert part.shape == shape
        if crop:
            np.testing.assert_allclose(part, full[0:15, 10:30], atol=1e-6)
        else:
            np.testing.assert_allclose(part[0:15, 10:30], full[0:15, 10:30], atol=1e-6)
            assert np.all(part[20:, :, :3] == 0.0)


def _core_modes():
    from rstrace_engine import session as core

    return getattr(core, "AVAILABLE_MODES", ("BASE",))


@pytest.mark.parametrize("mode", ["INTERPOLANT", "RI_TREE"])
def test_each_mode_renders_or_is_a_clean_error(mode, tmp_path):
    """A mode the core offers renders in that mode; one it does not is refused, clearly,
    rather than rendered in another mode."""
    sc = b.three_spheres_scene(24, 18)
    sc.rstrace.mode = mode
    if mode not in _core_modes():
        with pytest.raises(RuntimeError, match="RSTrace: mode .* is not available"):
            b.render_exr(tmp_path / "m.exr")  # operators raise on an engine's error
        state = _state()
        assert state.error is not None and "not available" in state.error, state.messages
        assert state.stats == {}  # nothing was rendered in another mode
        return
    out = b.render_exr(tmp_path / "m.exr")
    state = _state()
    assert state.error is None and state.stats["mode"] == mode, state.messages
    classes = out["Interpolation"].reshape(-1, 3)
    known = np.all(np.isclose(classes[:, None, :], CLASS_COLORS[None]), axis=-1).any(axis=1)
    assert known.all() and np.isfinite(out["Combined"]).all()


def test_unbuildable_accelerator_is_a_clean_error(tmp_path):
    """An accelerator that cannot be built (a visibility field past its memory cap) is
    refused with the reason; the scene renders again once the settings are sane."""
    sc = b.three_spheres_scene(16, 12)
    sc.rstrace.accelerator = "VISIBILITY_FIELD"
    sc.rstrace.vf_directions, sc.rstrace.vf_tiles = 2050, 1024
    with pytest.raises(RuntimeError, match="RSTrace: .*visibility field.*over the cap"):
        b.render_exr(tmp_path / "v.exr")
    assert _state().error is not None and _state().stats == {}
    sc.rstrace.accelerator = "BVH"  # and the scene renders again afterwards
    assert b.render_exr(tmp_path / "v2.exr")
    assert _state().error is None


# ----------------------------------------------------------------------------- Cycles


def _diffuse_scene():
    sc = b.setup_render(48, 36, samples=16, max_depth=0)
    b.set_world((0.0, 0.0, 0.0))
    b.add_object("Ground", b.grid("Ground", 12.0), material=b.diffuse("Floor", (0.6, 0.6, 0.55)))
    b.add_object("Red", b.uv_sphere("S1", 1.0, 32, 16), (-1.2, 0.3, 1.0),
                 b.diffuse("Red", (0.7, 0.15, 0.1)))
    # Principled with no dielectric specular is Lambertian too (exported as pure diffuse)
    b.add_object("Grey", b.uv_sphere("S2", 0.8, 32, 16), (1.3, -0.2, 0.8),
                 b.principled("Grey", (0.5, 0.6, 0.7), roughness=1.0, specular_level=0.0))
    b.point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    b.point_light("Fill", (4.0, -2.0, 3.5), 900.0, (0.9, 0.95, 1.0))
    b.camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    return sc


@needs_cycles
def test_diffuse_point_lights_agree_with_cycles_direct_lighting():
    _diffuse_scene()
    stats = _compare(_ours(), _cycles(max_bounces=0))
    assert stats["rel_l1"] < 0.01
    assert abs(stats["median_ratio"] - 1.0) < 0.005
    assert stats["frac_over"] < 0.03


@needs_cycles
@pytest.mark.parametrize("kind, fit, size, shift", [
    ("PERSP", "VERTICAL", (36, 48), (0.1, -0.05)),
    ("ORTHO", "AUTO", (48, 30), (-0.08, 0.12)),
])
def test_camera_models_agree_with_cycles(kind, fit, size, shift):
    sc = _diffuse_scene()
    sc.render.resolution_x, sc.render.resolution_y = size
    cam = sc.camera.data
    cam.type, cam.sensor_fit, cam.ortho_scale = kind, fit, 9.0
    cam.sensor_height = 20.0
    cam.shift_x, cam.shift_y = shift
    cam.clip_start = 2.0  # clips nothing visible, but is exported
    stats = _compare(_ours(), _cycles(max_bounces=0))
    assert stats["rel_l1"] < 0.01 and stats["frac_over"] < 0.03


@needs_cycles
def test_mirror_sphere_agrees_with_cycles_one_glossy_bounce():
    sc = b.setup_render(48, 36, samples=16, max_depth=1)
    b.set_world((0.0, 0.0, 0.0))
    b.add_object("Ground", b.grid("Ground", 12.0), material=b.diffuse("Floor", (0.6, 0.6, 0.55)))
    b.add_object("Red", b.uv_sphere("S1", 1.0, 32, 16), (-1.3, 0.8, 1.0),
                 b.diffuse("Red", (0.7, 0.15, 0.1)))
    b.add_object("Mirror", b.uv_sphere("S2", 1.0, 48, 24), (0.8, -0.3, 1.0),
                 b.principled("Mirror", (1.0, 1.0, 1.0), metallic=1.0, roughness=0.0))
    b.point_light("Key", (-3.0, -4.0, 6.0), 2500.0)
    b.point_light("Fill", (4.0, -2.0, 3.5), 900.0, (0.9, 0.95, 1.0))
    b.camera((0.0, -8.5, 3.6), (0.0, 0.3, 0.8))
    ours = _ours()
    stats = _compare(ours, _cycles(max_bounces=1))
    assert stats["rel_l1"] < 0.01 and stats["frac_over"] < 0.03
    # the reflection of the red sphere is really there: without reflections it is not
    sc.rstrace.max_ray_depth = 0
    flat = _ours()
    red = lambda a: a[..., 0] - a[..., 2]  # noqa: E731
    assert (red(ours[0]) - red(flat[0])).max() > 0.05


@needs_cycles
def test_image_texture_agrees_with_cycles():
    b.setup_render(40, 40, samples=16, max_depth=0)
    b.set_world((0.0, 0.0, 0.0))
    size = 64
    img = bpy.data.images.new("Quadrants", size, size)  # 8-bit sRGB, like a loaded PNG
    px = np.zeros((size, size, 4), np.float32)
    px[..., 3] = 1.0
    h = size // 2
    px[:h, :h, :3] = (0.9, 0.1, 0.1)  # bottom left: red
    px[:h, h:, :3] = (0.1, 0.9, 0.1)  # bottom right: green
    px[h:, :h, :3] = (0.1, 0.1, 0.9)  # top left: blue
    px[h:, h:, :3] = (0.9, 0.9, 0.9)  # top right: white
    img.pixels.foreach_set(px.ravel())
    mat = b.diffuse("Textured")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    bsdf = mat.node_tree.nodes["Diffuse BSDF"]
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Color"])
    b.add_object("Plane", b.grid("Plane", 4.0), material=mat)
    b.point_light("Lamp", (0.5, -0.5, 4.0), 1500.0)
    b.camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), lens=40.0)  # looking down, +Y up in the image
    ours = _ours()
    stats = _compare(ours, _cycles())
    assert stats["rel_l1"] < 0.02 and stats["frac_over"] < 0.05
    o = ours[0]
    assert o[10, 10, 0] > 3 * o[10, 10, 2]  # bottom-left red
    assert o[10, 30, 1] > 3 * o[10, 30, 0]  # bottom-right green
    assert o[30, 10, 2] > 3 * o[30, 10, 0]  # top-left blue


# ----------------------------------------------------------------------------- instancing


def _sphere_collection(name="Proto"):
    col = bpy.data.collections.new(name)
    proto = b.add_object("Ball", b.uv_sphere("Ball", 0.5, 16, 8), collection=col,
                         material=b.principled("Ball", (0.2, 0.5, 0.8)))
    return col, proto


def test_collection_instances_share_one_mesh(tmp_path):
    import addon

    b.setup_render(48, 36, samples=1)
    b.set_world((0.0, 0.0, 0.0))
    b.add_object("Ground", b.grid("Ground", 12.0))
    col, _ = _sphere_collection()
    for k in range(3):
        e = bpy.data.objects.new(f"Inst{k}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = col
        e.location = (-2.0 + 2.0 * k, 0.0, 0.5)
        bpy.context.scene.collection.objects.link(e)
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()
    dg = bpy.context.evaluated_depsgraph_get()
    ex = addon.export.export_scene(dg)
    assert len(ex.scene.instances) == 4 and len(ex.scene.meshes) == 2
    ball = [i for i in ex.scene.instances if i["name"].endswith("/Ball")]
    assert len(ball) == 3 and len({i["mesh"] for i in ball}) == 1
    xs = sorted(i["matrix"][0, 3] for i in ball)
    np.testing.assert_allclose(xs, [-2.0, 0.0, 2.0], atol=1e-6)
    combined = b.render_exr(tmp_path / "i.exr")["Combined"]
    assert _state().error is None
    # three blue balls: blue-dominant blobs left, centre and right
    blue = combined[..., 2] - combined[..., 0] > 0.05
    cols = np.nonzero(blue.any(axis=0))[0]
    assert cols.min() < 16 and cols.max() > 32 and blue[:, 20:28].any()


def test_geometry_node_instances_share_one_mesh():
    import addon

    b.setup_render(32, 24)
    _, proto = _sphere_collection()
    ng = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    out = ng.nodes.new("NodeGroupOutput")
    line = ng.nodes.new("GeometryNodeMeshLine")
    line.inputs["Count"].default_value = 5
    line.inputs["Offset"].default_value = (1.2, 0.0, 0.0)
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = proto
    iop = ng.nodes.new("GeometryNodeInstanceOnPoints")
    ng.links.new(line.outputs["Mesh"], iop.inputs["Points"])
    ng.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    ng.links.new(iop.outputs["Instances"], out.inputs["Geometry"])
    host = b.add_object("Scatter", bpy.data.meshes.new("Host"))
    host.modifiers.new("GN", "NODES").node_group = ng
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()
    ex = addon.export.export_scene(bpy.context.evaluated_depsgraph_get())
    scattered = [i for i in ex.scene.instances if i["name"].startswith("Scatter/")]
    assert len(scattered) == 5
    assert len({i["mesh"] for i in scattered}) == 1
    xs = sorted(i["matrix"][0, 3] for i in scattered)
    np.testing.assert_allclose(np.diff(xs), 1.2, atol=1e-5)


# ----------------------------------------------------------------------------- animation


def test_animation_of_three_frames_reuses_the_session(tmp_path, capfd):
    sc = b.three_spheres_scene(32, 24)
    bpy.data.lights["Fill"].use_shadow = False  # not modelled: must be reported once
    ob = bpy.data.objects["RedSphere"]
    sc.frame_start, sc.frame_end = 1, 3
    for frame, x in ((1, -2.2), (3, 0.2)):
        ob.location.x = x
        ob.keyframe_insert("location", frame=frame)
    sc.render.filepath = str(tmp_path / "frame_")
    capfd.readouterr()
    bpy.ops.render.render(animation=True)
    printed = capfd.readouterr()
    files = sorted(tmp_path.glob("frame_*.exr"))
    assert [f.name for f in files] == ["frame_0001.exr", "frame_0002.exr", "frame_0003.exr"]
    frames = [read_pass(read_exr(f), "Combined", components="RGB") for f in files]
    for a, c in ((frames[0], frames[1]), (frames[1], frames[2])):
        assert np.abs(a - c).max() > 0.05  # the red sphere moved
    state = _state()
    assert state.error is None and state.renders == 3
    assert "accel_update_s" in state.stats  # frames 2, 3 updated the persistent session
    reported = (printed.out + printed.err).count("shadows turned off")
    assert reported == 1
    # a moved object renders the same as a fresh session would
    import addon

    addon.session.forget_all()
    sc.frame_set(3)
    fresh = b.render_exr(tmp_path / "fresh.exr")["Combined"][..., :3]
    np.testing.assert_allclose(fresh, frames[2], atol=1e-5)


def test_orthographic_camera_and_shift(tmp_path):
    sc = b.three_spheres_scene(32, 24)
    cam = sc.camera.data
    cam.type = "ORTHO"
    cam.ortho_scale = 8.0
    sc.rstrace.samples = 1  # pixel centres: a shift by whole pixels moves the image exactly
    # up to the glossy rays' noise (their seeds are the pixel's; Principled's default
    # roughness 0.5: a plastic head on draws 7 of 16 since session 43's counts by lobe)
    sc.rstrace.glossy_samples = 64
    a = b.render_exr(tmp_path / "o.exr")["Combined"]
    assert _state().error is None and np.isfinite(a).all()
    cam.shift_x = 0.25  # a quarter of the larger dimension = 8 pixels
    shifted = b.render_exr(tmp_path / "s.exr")["Combined"]
    np.testing.assert_allclose(shifted[:, :-8], a[:, 8:], atol=0.02)
    assert math.isfinite(float(shifted.sum()))


@needs_cycles
def test_spot_light_cone_and_blend_agree_with_cycles():
    """A spot's cone and blend (smoothstep in cosine space) match Cycles on a floor."""
    sc = b.setup_render(48, 36, samples=16, max_depth=0)
    b.set_world((0.0, 0.0, 0.0))
    b.add_object("Ground", b.grid("Ground", 12.0), material=b.diffuse("Floor", (0.6, 0.6, 0.6)))
    spot = b.point_light("Spot", (0.0, 0.0, 4.0), 3000.0, kind="SPOT")
    spot.data.spot_size, spot.data.spot_blend = math.radians(70.0), 0.6
    spot.rotation_euler = (0.0, 0.0, 0.0)  # points down -Z
    b.camera((0.0, -7.0, 6.0), (0.0, 0.0, 0.0))
    stats = _compare(_ours(), _cycles(max_bounces=0))
    assert stats["rel_l1"] < 0.02
    assert abs(stats["median_ratio"] - 1.0) < 0.01
    assert stats["frac_over"] < 0.03
    assert sc.render.engine == "RSTRACE"
