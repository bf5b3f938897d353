"""Export: depsgraph -> rstrace_engine Scene (materials, lights, camera, world, visibility,
reports) and its speed on a 1M-triangle mesh."""

from __future__ import annotations

import math
import time

import bpy
import numpy as np
import pytest

from rstrace_engine.geometry.attributes import ATTR_NONE, ATTR_VERTEX, mesh_corners
from rstrace_engine.geometry.packing import mesh_slots, mesh_triangles

from . import builders as b


def _export(**kwargs):
    import addon

    return addon.export.export_scene(bpy.context.evaluated_depsgraph_get(), **kwargs)


def _basic_scene(material=None):
    b.setup_render(32, 24)
    b.add_object("Ball", b.uv_sphere("Ball", 1.0, 16, 8), (0.0, 0.0, 1.0), material)
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()


def _material(ex, name):
    return next(m for m in ex.scene.materials if m.name == name)


def test_mesh_arrays_match_blender_geometry():
    _basic_scene()
    ob = bpy.data.objects["Ball"]
    ob.rotation_euler = (0.3, 0.2, 0.1)
    ob.scale = (1.0, 2.0, 0.5)
    ex = _export()
    me = ob.data
    me.calc_loop_triangles()
    mesh = ex.scene.meshes[0]
    assert len(mesh["tris"]) == len(me.loop_triangles) == 16 * 8 * 2 - 2 * 16
    assert mesh["nmode"] == ATTR_VERTEX  # smooth: one normal row per vertex
    v = np.array([tuple(x.co) for x in me.vertices])
    np.testing.assert_allclose(mesh["verts"], v, atol=1e-6)
    t = np.array([tuple(x.vertices) for x in me.loop_triangles])
    np.testing.assert_array_equal(mesh_triangles(mesh), t)
    # smooth shading: corner normals are the vertex normals
    vn = np.array([tuple(x.vector) for x in me.vertex_normals])
    np.testing.assert_allclose(mesh_corners(mesh, "normals"), vn[t], atol=1e-6)
    uv = np.array([tuple(x.uv) for x in me.uv_layers.active.data])
    loops = np.array([tuple(x.loops) for x in me.loop_triangles])
    np.testing.assert_allclose(mesh_corners(mesh, "uvs"), uv[loops], atol=1e-6)
    np.testing.assert_allclose(ex.scene.instances[0]["matrix"], np.array(ob.matrix_world),
                               atol=1e-6)


def test_flat_and_custom_normals_domains():
    _basic_scene()
    me = bpy.data.objects["Ball"].data
    me.shade_flat()
    ex = _export()
    mesh = ex.scene.meshes[0]
    assert mesh["nmode"] == ATTR_NONE  # flat: every corner its triangle's own normal
    n = mesh_corners(mesh, "normals")
    np.testing.assert_allclose(n[:, 0], n[:, 1], atol=1e-6)  # one normal per face
    v = mesh["verts"][mesh_triangles(mesh)]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.min(np.einsum("ij,ij->i", fn, n[:, 0])) > 0.99
    me.normals_split_custom_set_from_vertices([(0.0, 0.0, 1.0)] * len(me.vertices))
    assert me.normals_domain == "CORNER"
    n = mesh_corners(_export().scene.meshes[0], "normals")
    np.testing.assert_allclose(n.reshape(-1, 3), np.tile((0, 0, 1), (n.size // 3, 1)), atol=1e-4)


def test_normals_are_handed_over_per_vertex_or_not_at_all():
    """The export hands a smooth mesh's normals over per vertex (Blender's POINT domain)
    and a flat one's not at all (the engine computes each triangle's own), with no (m, 3,
    3) corner array, its arrays ``owned``; the scene model then holds the same mode and
    every corner's bits that the per-corner arrays the export gathered before gave."""
    import dataclasses

    from addon.meshes import mesh_arrays
    from rstrace_engine.geometry.mesh_math import flat_triangle_normals
    from rstrace_engine.geometry.scene import Scene

    _basic_scene()
    ob = bpy.data.objects["Ball"]
    for flat in (False, True):
        if flat:
            ob.data.shade_flat()
        me = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        mesh = mesh_arrays(me, "Ball")
        assert mesh.owned and mesh.corner_normals is None
        assert mesh.smooth is not flat and (mesh.vertex_normals is None) is flat
        t = mesh.triangles
        if flat:  # (what the export gave before: each triangle's own, at its corners)
            corners = np.zeros((len(t), 3, 3), np.float32)
            flat_triangle_normals(mesh.vertices, t, corners)
        else:
            corners = mesh.vertex_normals[t]
        before = dataclasses.replace(mesh, vertex_normals=None, corner_normals=corners,
                                     smooth=True, owned=False)
        got = [Scene(), Scene()]
        got = [s.meshes[s.add_mesh(m)] for s, m in zip(got, (mesh, before), strict=True)]
        assert got[0]["nmode"] == got[1]["nmode"] == (ATTR_NONE if flat else ATTR_VERTEX)
        n0, n1 = (mesh_corners(d, "normals") for d in got)
        assert np.array_equal(n0.view(np.uint32), n1.view(np.uint32))


def test_material_slots_and_indices():
    b.setup_render(32, 24)
    me = b.uv_sphere("Two", 1.0, 8, 4)
    red, blue = b.principled("Red", (1, 0, 0)), b.principled("Blue", (0, 0, 1))
    me.materials.append(red)
    me.materials.append(blue)
    me.polygons.foreach_set("material_index", [k % 2 for k in range(len(me.polygons))])
    b.add_object("Two", me)
    b.camera()
    ex = _export()
    inst = ex.scene.instances[0]
    names = [ex.scene.materials[k].name for k in inst["materials"]]
    assert names == ["Red", "Blue"]
    me.calc_loop_triangles()
    poly = np.array([t.polygon_index for t in me.loop_triangles])
    np.testing.assert_array_equal(mesh_slots(ex.scene.meshes[0]), poly % 2)


_GLASS = dict(base=(1.0, 1.0, 1.0), roughness=0.0, **{"Transmission Weight": 1.0, "IOR": 1.5})
_EMISSIVE = dict(base=(0.5, 0.5, 0.5), specular_level=0.0,
                 **{"Emission Color": (1.0, 0.5, 0.25, 1.0), "Emission Strength": 4.0})


@pytest.mark.parametrize("model, inputs, expect", [
    ("WARD", dict(base=(0.8, 0.2, 0.1), roughness=0.5),
     dict(diffuse=(0.8 * 0.96, 0.2 * 0.96, 0.1 * 0.96), specular=(0.04,) * 3, mirror=(0,) * 3,
          roughness=0.25)),
    ("WARD", dict(base=(0.9, 0.6, 0.2), metallic=1.0, roughness=0.0),
     dict(diffuse=(0,) * 3, mirror=(0.9, 0.6, 0.2), specular=(0,) * 3)),
    # the tracer's Fresnel alone splits glass into reflection and refraction (issue 11)
    ("WARD", _GLASS, dict(diffuse=(0,) * 3, transmission=(1.0,) * 3, mirror=(0,) * 3,
                          ior=1.5)),
    ("WARD", _EMISSIVE, dict(diffuse=(0.5,) * 3, specular=(0,) * 3, emission=(4.0, 2.0, 1.0))),
    ("PRINCIPLED", dict(base=(0.8, 0.2, 0.1), roughness=0.5),
     dict(diffuse=(0.8, 0.2, 0.1), specular=(1.0,) * 3, specular_ior=1.5, mirror=(1.0,) * 3,
          roughness=0.25, metallic=0.0)),  # its reflection layer: glossy rays (issue 24)
    ("PRINCIPLED", dict(base=(0.9, 0.6, 0.2), metallic=1.0, roughness=0.0),
     dict(diffuse=(0,) * 3, metallic=1.0, metal=(0.9, 0.6, 0.2), mirror=(1.0,) * 3,
          specular=(0,) * 3)),
    ("PRINCIPLED", _GLASS, dict(diffuse=(0,) * 3, transmission=(1.0,) * 3, specular=(0,) * 3,
                                ior=1.5)),
    ("PRINCIPLED", _EMISSIVE, dict(diffuse=(0.5,) * 3, specular=(0,) * 3, specular_ior=1.0,
                                   emission=(4.0, 2.0, 1.0))),
])
def test_principled_mapping(model, inputs, expect):
    _basic_scene(b.principled("P", **inputs))
    bpy.context.scene.rstrace.shading_model = model
    mat = _material(_export(), "P")
    assert mat.model == model
    for key, value in expect.items():
        np.testing.assert_allclose(getattr(mat, key), value, atol=1e-3, err_msg=key)


def test_viewport_colour_fallback_and_unsupported_shader_reported():
    mat = bpy.data.materials.new("Toon")
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    toon = nodes.new("ShaderNodeBsdfToon")
    mat.node_tree.links.new(toon.outputs[0], nodes["Material Output"].inputs["Surface"])
    mat.diffuse_color = (0.1, 0.6, 0.3, 1.0)
    _basic_scene(mat)
    ex = _export()
    # the default (Principled-like) model: the base is the diffuse albedo (the GGX layer's
    # share is taken per view angle in the tracer)
    np.testing.assert_allclose(_material(ex, "Toon").diffuse, (0.1, 0.6, 0.3), atol=1e-3)
    assert any("Toon" in w and "not supported" in w for w in ex.warnings)


def test_lights_are_exported_in_blender_units():
    _basic_scene()
    spot = bpy.data.lights.new("Spot", "SPOT")
    spot.energy, spot.spot_size, spot.spot_blend = 500.0, math.radians(40.0), 0.3
    spot.shadow_soft_size = 0.0
    so = b.add_object("Spot", spot, (1.0, 2.0, 3.0))
    so.rotation_euler = (math.radians(90.0), 0.0, 0.0)  # points along +Y
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy, sun.color = 3.0, (1.0, 0.9, 0.8)
    b.add_object("Sun", sun)
    ex = _export()
    lights = {li.name: li for li in ex.scene.lights}
    assert set(lights) == {"Lamp", "Spot", "Sun"}
    assert lights["Lamp"].power == pytest.approx(1000.0)
    np.testing.assert_allclose(lights["Lamp"].position, (0.0, -3.0, 5.0), atol=1e-6)
    s = lights["Spot"]
    assert s.kind == "SPOT" and s.power == pytest.approx(500.0)
    assert s.spot_size == pytest.approx(math.radians(40.0))
    assert s.spot_blend == pytest.approx(0.3)
    np.testing.assert_allclose(s.direction, (0.0, 1.0, 0.0), atol=1e-6)
    assert lights["Sun"].kind == "SUN" and lights["Sun"].power == pytest.approx(3.0)
    np.testing.assert_allclose(lights["Sun"].direction, (0.0, 0.0, -1.0), atol=1e-6)
    np.testing.assert_allclose(lights["Sun"].color, (1.0, 0.9, 0.8), atol=1e-6)
    assert not ex.warnings


def test_soft_lights_are_read_as_cycles_reads_them():
    """Radius and soft falloff, sun angle, area shape and size with the object's scale
    (Cycles: the world matrix's X and Y columns times Size and Size Y; the object's scale
    does not change a radius), spread; nothing approximated, nothing to report."""
    _basic_scene()
    lamp = bpy.data.lights["Lamp"]
    lamp.shadow_soft_size, lamp.use_soft_falloff = 0.25, True
    b.add_object("Lamp2", lamp.copy(), (1.0, 0.0, 5.0)).scale = (3.0, 3.0, 3.0)
    bpy.data.objects["Lamp2"].data.use_soft_falloff = False
    spot = bpy.data.lights.new("Spot", "SPOT")
    spot.energy, spot.shadow_soft_size, spot.use_soft_falloff = 300.0, 0.4, False
    b.add_object("Spot", spot, (0.0, 0.0, 4.0))
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy, sun.angle = 2.0, math.radians(12.0)
    b.add_object("Sun", sun)
    panel = bpy.data.lights.new("Panel", "AREA")
    panel.energy, panel.shape, panel.size, panel.size_y = 100.0, "RECTANGLE", 2.0, 0.5
    panel.spread = math.radians(60.0)
    po = b.add_object("Panel", panel, (0.0, 1.0, 4.0))
    po.rotation_euler = (0.0, 0.0, math.radians(90.0))  # local X along world +Y
    po.scale = (1.5, -2.0, 1.0)  # mirrored in Y: the same rectangle, emitting down
    disk = bpy.data.lights.new("Disk", "AREA")
    disk.shape, disk.size, disk.size_y = "DISK", 0.8, 5.0  # a disk ignores Size Y
    b.add_object("Disk", disk, (2.0, 0.0, 3.0))
    ex = _export()
    lights = {li.name: li for li in ex.scene.lights}
    assert (lights["Lamp"].radius, lights["Lamp"].soft_falloff) == (pytest.approx(0.25), True)
    assert (lights["Lamp2"].radius, lights["Lamp2"].soft_falloff) == (pytest.approx(0.25),
                                                                      False)
    s = lights["Spot"]
    assert (s.kind, s.radius, s.soft_falloff) == ("SPOT", pytest.approx(0.4), False)
    assert lights["Sun"].angle == pytest.approx(math.radians(12.0))
    p = lights["Panel"]
    assert (p.kind, p.shape, p.power) == ("AREA", "RECTANGLE", pytest.approx(100.0))
    assert p.size == pytest.approx((3.0, 1.0))
    assert p.spread == pytest.approx(math.radians(60.0))
    np.testing.assert_allclose(p.axis, (0.0, 1.0, 0.0), atol=1e-6)
    np.testing.assert_allclose(p.direction, (0.0, 0.0, -1.0), atol=1e-6)
    np.testing.assert_allclose(p.position, (0.0, 1.0, 4.0), atol=1e-6)
    d = lights["Disk"]
    assert (d.shape, d.size) == ("DISK", pytest.approx((0.8, 0.8)))
    assert not ex.warnings


def test_normalize_off_multiplies_the_power_by_cycles_area():
    """Normalize off: Cycles does not divide the power by the emitter's area (measured:
    an area light of 2 x 2 m renders 4x brighter, a point light of radius 0 4x, radius 0.5
    pi x, a sun of angle 10 degrees pi sin^2(5 degrees) x)."""
    _basic_scene()
    bpy.data.lights["Lamp"].normalize = False
    panel = bpy.data.lights.new("Panel", "AREA")
    panel.energy, panel.size, panel.normalize = 100.0, 2.0, False
    b.add_object("Panel", panel, (0.0, 1.0, 4.0)).scale = (1.0, 1.5, 1.0)
    bulb = bpy.data.lights.new("Bulb", "POINT")
    bulb.energy, bulb.shadow_soft_size, bulb.normalize = 10.0, 0.5, False
    b.add_object("Bulb", bulb, (1.0, 1.0, 4.0))
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy, sun.angle, sun.normalize = 2.0, math.radians(10.0), False
    b.add_object("Sun", sun)
    lights = {li.name: li for li in _export().scene.lights}
    assert lights["Lamp"].power == pytest.approx(4000.0)
    assert lights["Panel"].power == pytest.approx(100.0 * 2.0 * 3.0)
    assert lights["Bulb"].power == pytest.approx(10.0 * math.pi)
    assert lights["Sun"].power == pytest.approx(2.0 * math.pi * math.sin(math.radians(5.0)) ** 2)


def test_light_settings_not_modelled_are_reported_by_name():
    _basic_scene()
    lamp = bpy.data.lights["Lamp"]
    lamp.use_shadow = False
    lamp.diffuse_factor = 0.5
    spot = bpy.data.lights.new("Spot", "SPOT")
    b.add_object("Spot", spot, (0.0, 0.0, 4.0)).scale = (1.0, 2.0, 1.0)
    b.add_object("Spot2", spot, (1.0, 0.0, 4.0)).scale = (1.0, 1.0, 3.0)  # a narrower cone
    b.add_object("Spot3", spot, (2.0, 0.0, 4.0)).scale = (2.0, 2.0, 2.0)  # unchanged
    warnings = _export().warnings
    assert any("shadows turned off" in w and "'Lamp'" in w for w in warnings), warnings
    # EEVEE's light factors: Cycles ignores them too, so nothing to report
    assert not any("factors" in w for w in warnings), warnings
    # non-uniformly scaled spots are modelled (an elliptical cone): their frame is kept
    assert not any("spot" in w for w in warnings), warnings
    frames = {li.name: li.spot_frame for li in _export().scene.lights}
    assert len(frames["Spot"]) == 9 and len(frames["Spot2"]) == 9
    assert frames["Spot3"] == ()  # a uniform scale: the round cone


def test_light_emission_node_multiplies_colour_and_power():
    """Cycles multiplies a light's Emission node colour x strength into its own; any other
    node tree is reported."""
    _basic_scene()
    lamp = bpy.data.lights["Lamp"]
    lamp.use_nodes = True
    emission = lamp.node_tree.nodes["Emission"]
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    emission.inputs["Strength"].default_value = 2.0
    ex = _export()
    light = ex.scene.lights[0]
    assert light.power == pytest.approx(2000.0)
    np.testing.assert_allclose(light.color, (1.0, 0.5, 0.25), atol=1e-6)
    assert not ex.warnings
    noise = lamp.node_tree.nodes.new("ShaderNodeTexNoise")
    lamp.node_tree.links.new(noise.outputs["Color"], emission.inputs["Color"])
    ex = _export()
    assert ex.scene.lights[0].power == pytest.approx(1000.0)
    assert any("node trees" in w and "'Lamp'" in w for w in ex.warnings), ex.warnings


def test_light_with_diffuse_and_glossy_visibility_off_lights_nothing():
    """Cycles leaves it out of both closures: RSTrace leaves it out, and says so."""
    _basic_scene()
    lamp = bpy.data.objects["Lamp"]
    lamp.visible_diffuse = lamp.visible_glossy = False
    ex = _export()
    assert "Lamp" not in {li.name for li in ex.scene.lights}
    assert any("Diffuse and Glossy ray visibility off" in w and "'Lamp'" in w
               for w in ex.warnings), ex.warnings
    assert not any("is not modelled" in w and "'Lamp'" in w for w in ex.warnings)


def test_light_ray_visibility_and_linking_are_read_and_world_visibility_reported():
    _basic_scene()
    lamp = bpy.data.objects["Lamp"]
    lamp.visible_glossy = False
    lit = bpy.data.collections.new("Lit")
    sub = bpy.data.collections.new("Sub")
    lit.children.link(sub)
    for name, col in (("A", lit), ("B", sub)):
        col.objects.link(bpy.data.objects.new(name, None))
    lit.collection_objects[0].light_linking.link_state = "EXCLUDE"
    lamp.light_linking.receiver_collection = lit
    lamp.light_linking.blocker_collection = sub
    world = b.set_world((0.1, 0.1, 0.1))
    world.cycles_visibility.diffuse = False
    ex = _export()
    warnings = ex.warnings
    light = next(li for li in ex.scene.lights if li.name == "Lamp")
    assert (light.diffuse, light.glossy) == (True, False)
    assert light.receivers == (("A", False), ("B", True))
    assert light.blockers == (("B", True),)
    assert not any("'Lamp'" in w for w in warnings), warnings
    assert any("world ray visibility (Diffuse off)" in w and "'World'" in w
               for w in warnings), warnings
    assert ex.scene.world_lights
    # Diffuse and Glossy both off: a background only (Cycles excludes it from both)
    world.cycles_visibility.glossy = False
    ex = _export()
    assert not ex.scene.world_lights
    np.testing.assert_allclose(ex.scene.world_color, (0.1, 0.1, 0.1), atol=1e-6)
    assert not any("world ray visibility" in w for w in ex.warnings), ex.warnings


def test_camera_and_resolution():
    _basic_scene()
    sc = bpy.context.scene
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 200, 100, 50
    cam = sc.camera.data
    cam.lens, cam.sensor_width, cam.sensor_fit = 70.0, 30.0, "HORIZONTAL"
    cam.shift_x, cam.shift_y, cam.clip_start, cam.clip_end = 0.1, -0.2, 0.5, 300.0
    c = _export().scene.camera
    assert (c.width, c.height, c.kind, c.sensor_fit) == (100, 50, "PERSP", "HORIZONTAL")
    assert (c.lens, c.sensor_width, c.clip_start, c.clip_end) == pytest.approx(
        (70.0, 30.0, 0.5, 300.0))
    assert (c.shift_x, c.shift_y) == pytest.approx((0.1, -0.2))
    np.testing.assert_allclose(c.matrix, np.array(sc.camera.matrix_world), atol=1e-6)
    cam.type, cam.ortho_scale = "ORTHO", 12.0
    c = _export().scene.camera
    assert c.kind == "ORTHO" and c.ortho_scale == pytest.approx(12.0)


def test_world_colour_from_background_node_and_sky_reported():
    _basic_scene()
    world = b.set_world((0.2, 0.3, 0.4))
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 2.0
    ex = _export()
    np.testing.assert_allclose(ex.scene.world_color, (0.4, 0.6, 0.8), atol=1e-6)
    sky = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    world.node_tree.links.new(sky.outputs["Color"],
                              world.node_tree.nodes["Background"].inputs["Color"])
    ex = _export()
    np.testing.assert_allclose(ex.scene.world_color, (0.4, 0.6, 0.8), atol=1e-6)
    assert any("Environment" in w for w in ex.warnings)


def test_objects_hidden_from_render_are_skipped(tmp_path):
    _basic_scene()
    hidden = b.add_object("Hidden", b.uv_sphere("H", 0.5, 8, 4), (2.0, 0.0, 1.0))
    hidden.hide_render = True
    lamp2 = b.point_light("HiddenLamp", (0.0, 0.0, 9.0), 100.0)
    lamp2.hide_render = True
    ex = _export()
    assert [i["name"] for i in ex.scene.instances] == ["Ball"]
    assert [li.name for li in ex.scene.lights] == ["Lamp"]
    # and in a real render (a render depsgraph), too
    import addon

    b.render_exr(tmp_path / "h.exr")
    stats = addon.session.state_for(bpy.context.scene).stats
    assert stats["objects"] == 1 and stats["lights"] == 1


def _big_grid(n: int):
    """An n x n quad grid (2 n^2 triangles) built with foreach_set."""
    ys, xs = np.mgrid[0:n + 1, 0:n + 1]
    co = np.stack([xs.ravel() / n, ys.ravel() / n, np.zeros(xs.size)], 1).astype(np.float32)
    q = (ys[:-1, :-1] * (n + 1) + xs[:-1, :-1]).ravel()
    corners = np.stack([q, q + 1, q + n + 2, q + n + 1], 1).astype(np.int32)
    me = bpy.data.meshes.new("Big")
    me.vertices.add(len(co))
    me.vertices.foreach_set("co", co.ravel())
    me.loops.add(corners.size)
    me.loops.foreach_set("vertex_index", corners.ravel())
    me.polygons.add(len(corners))
    me.polygons.foreach_set("loop_start", np.arange(0, corners.size, 4, dtype=np.int32))
    me.update()
    uv = me.uv_layers.new(name="UVMap")
    uv.uv.foreach_set("vector", co[corners.ravel(), :2].ravel())
    return me


def test_export_of_a_million_triangles():
    b.setup_render(32, 24)
    me = _big_grid(708)  # 1,002,528 triangles
    b.add_object("Big", me)
    b.point_light("Lamp", (0.5, 0.5, 3.0), 100.0)
    b.camera((0.5, -1.0, 2.0), (0.5, 0.5, 0.0))
    dg = bpy.context.evaluated_depsgraph_get()
    me_eval = bpy.data.objects["Big"].evaluated_get(dg).data
    _ = len(me_eval.loop_triangles)  # Blender's own triangulation is not ours to time
    import addon

    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        ex = addon.export.export_scene(dg)
        runs.append((time.perf_counter() - t0, ex.stats))
    best, stats = min(runs, key=lambda r: r[0])
    tris = ex.scene.triangle_count
    print(f"export of {tris:,} triangles: {best:.3f} s (add-on mesh read "
          f"{stats['mesh_read_seconds']:.3f} s, core Scene.add_mesh "
          f"{stats['mesh_add_seconds']:.3f} s)")
    assert tris == 2 * 708 * 708
    assert ex.scene.arrays().tris.shape == (tris, 3)
    # Speed is measured and printed here, not asserted (the machine is shared and noisy):
    # about 0.1 s add-on read + 0.25 s core on an idle machine.


class _Items:
    """``me.loop_triangles`` seen through a test: items' addresses shifted from ``shift_at``
    on (a layout that is not one array), the item ``wrong_at`` answering other corners
    than the array holds, ``foreach_get`` counted."""

    def __init__(self, tris, shift_at=None, wrong_at=None):
        self.tris, self.shift_at, self.reads = tris, shift_at, 0
        self.wrong_at = wrong_at  # an item whose loops differ from the array's

    def __getitem__(self, i):
        item = self.tris[i]
        shift = 4 if self.shift_at is not None and i >= self.shift_at else 0
        wrong = i == self.wrong_at

        class _Item:
            loops = tuple(c + 1 for c in item.loops) if wrong else item.loops

            def as_pointer(self):
                return item.as_pointer() + shift

        return _Item()

    def foreach_get(self, prop, out):
        self.reads += 1
        self.tris.foreach_get(prop, out)


def test_corner_triangles_are_blenders_own_read_in_place():
    """``meshes.corner_triangles`` reads Blender's array of triangle corners in place (a
    view, not the ~100 ms per million triangles of ``foreach_get``'s per-item read) and
    gives exactly what ``foreach_get`` gives, on tris, quads (a concave one, which Blender
    splits on its other diagonal) and n-gons; where the items are not one array it reads
    them with ``foreach_get``."""
    from addon.meshes import corner_triangles

    b.setup_render(32, 24)
    ball = b.uv_sphere("Ball", 1.0, 16, 8)  # quads and triangle fans
    bpy.ops.mesh.primitive_circle_add(vertices=11, fill_type="NGON")  # an 11-gon
    ngon = bpy.context.object.data
    dart = bpy.data.meshes.new("Dart")  # a concave quad
    dart.from_pydata([(2, 1, 0), (0, 0.2, 0), (-2, 1, 0), (0, 0, 0)], [], [(0, 1, 2, 3)])
    for me in (ball, ngon, dart, _big_grid(64)):
        me.calc_loop_triangles()
        tris = me.loop_triangles
        nt = len(tris)
        want = np.empty((nt, 3), np.int32)
        tris.foreach_get("loops", want.reshape(-1))
        items = _Items(tris)
        got = corner_triangles(items, nt, len(me.loops))
        np.testing.assert_array_equal(got, want, err_msg=me.name)
        assert items.reads == 0, me.name  # read in place, not item by item
        items = _Items(tris, shift_at=nt // 2)  # two arrays: read with foreach_get
        np.testing.assert_array_equal(corner_triangles(items, nt, len(me.loops)), want)
        assert items.reads == 1
        if me is dart:
            assert want.tolist() == [[0, 1, 3], [1, 2, 3]]  # the flipped diagonal


def test_corner_gathers_after_a_range_check():
    """``meshes._gather`` gives ``values[index]`` (rows) as a fresh array, on indices
    ``meshes._in_range`` checked first: an index out of range is refused with a message
    naming the mesh, before anything is gathered."""
    from addon.meshes import _gather, _in_range
    from rstrace_engine.geometry.scene import SceneError

    values = np.arange(20, dtype=np.float32).reshape(10, 2)
    index = np.array([[0, 9, 3], [4, 4, 1]], np.int32)
    _in_range(index, 10, "Ball", "triangle corner")
    out = _gather(values, index)
    np.testing.assert_array_equal(out, values[index.astype(np.int64)])
    assert out.shape == (2, 3, 2) and out.dtype == np.float32 and out.flags.c_contiguous
    np.testing.assert_array_equal(_gather(np.arange(10, 20, dtype=np.int32), index),
                                  index + 10)
    for bad in ([0, 10], [-1, 3]):
        with pytest.raises(SceneError, match=r"mesh 'Ball': a triangle corner index out of "
                                             r"range 0\.\.9"):
            _in_range(np.array(bad, np.int32), 10, "Ball", "triangle corner")


def test_row_gathers_move_each_row_as_one_item_bit_for_bit():
    """``meshes._gather`` moves a row of several values (a uv: 8 bytes, a normal: 12) as
    one item of its bytes: the result is ``values[index]`` bit for bit (signed zeros, NaN
    payloads, subnormals, infinities), for rows of 2 and 3 float32, for a source that is
    not aligned to its row size (Blender's arrays are read in place) and for none at all.
    (A guard of the rewritten gather: main's plain indexing passes it too.)"""
    from addon.meshes import _gather

    rng = np.random.default_rng(7)
    index = rng.integers(0, 500, (300, 3)).astype(np.int32)
    special = np.array([0x7FC12345, 0x80000000, 0, 0x7F800000, 0xFF800000, 1, 0x80000001],
                       np.uint32).view(np.float32)  # (a NaN payload, +-0, +-inf, subnormals)
    for width in (2, 3):
        values = rng.standard_normal((500, width)).astype(np.float32)
        values.reshape(-1)[:len(special)] = special
        buf = np.zeros(values.nbytes + 4, np.uint8)  # (4 bytes in: not 8-aligned)
        odd = np.frombuffer(buf[4:], np.float32).reshape(500, width)
        odd[...] = values
        want = values[index.astype(np.int64)]
        for src in (values, odd):
            got = _gather(src, index)
            assert got.shape == (300, 3, width) and got.dtype == np.float32
            assert got.flags.c_contiguous and not np.shares_memory(got, src)
            assert got.tobytes() == want.tobytes()
        assert _gather(values[:0], np.zeros((0, 3), np.int32)).shape == (0, 3, width)


def _read_scene_meshes():
    """Meshes of every kind the read handles, evaluated: quads and fans with uvs (POINT
    normals), a flat one (FACE), one with a sharp face (CORNER), one with material
    indices, a big grid (131k triangles)."""
    b.setup_render(32, 24)
    smooth = b.uv_sphere("Smooth", 1.0, 16, 8)
    smooth.shade_smooth()
    flat = b.uv_sphere("Flat", 1.0, 12, 6)
    flat.shade_flat()
    split = b.uv_sphere("Split", 1.0, 16, 8)
    split.shade_smooth()
    split.polygons[0].use_smooth = False
    slots = b.uv_sphere("Slots", 1.0, 16, 8)
    for name in ("A", "B"):
        slots.materials.append(bpy.data.materials.new(name))
    slots.polygons.foreach_set("material_index",
                               np.arange(len(slots.polygons), dtype=np.int32) % 3)
    big = _big_grid(256)
    for k, me in enumerate((smooth, flat, split, slots, big)):
        b.add_object(me.name, me, (3.0 * k, 0.0, 0.0))
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    return [bpy.data.objects[me.name].evaluated_get(dg).data
            for me in (smooth, flat, split, slots, big)]


def test_blender_arrays_are_read_in_place_and_equal_foreach_get():
    """``meshes.blender_array`` views Blender's own attribute arrays (no copy): equal to
    ``foreach_get``'s copies, read-only; a layout that is not one array, or items whose
    values differ from the view's, give None (the caller copies with ``foreach_get``)."""
    from addon.meshes import blender_array

    meshes = _read_scene_meshes()
    assert [me.normals_domain for me in meshes[:3]] == ["POINT", "FACE", "CORNER"]
    for me in meshes:
        for name, prop, width, dtype in (("position", "vector", 3, np.float32),
                                         (".corner_vert", "value", 1, np.int32),
                                         (".edge_verts", "value", 2, np.int32)):
            data = next(a for a in me.attributes if a.name == name).data
            view = blender_array(data, len(data), width, dtype, prop)
            want = np.empty(len(data) * width, dtype)
            data.foreach_get(prop, want)
            np.testing.assert_array_equal(view, want, err_msg=f"{me.name} {name}")
            assert not view.flags.writeable and not view.flags.owndata
        uv = me.uv_layers.active.uv
        want = np.empty(len(uv) * 2, np.float32)
        uv.foreach_get("vector", want)
        np.testing.assert_array_equal(blender_array(uv, len(uv), 2, np.float32, "vector"),
                                      want)
        if me.normals_domain == "CORNER":
            cn = me.corner_normals
            want = np.empty(len(cn) * 3, np.float32)
            cn.foreach_get("vector", want)
            np.testing.assert_array_equal(
                blender_array(cn, len(cn), 3, np.float32, "vector"), want)
    tris = meshes[0].loop_triangles
    nt = len(tris)
    assert blender_array(_Items(tris), nt, 3, np.int32, "loops") is not None
    assert blender_array(_Items(tris, shift_at=nt // 2), nt, 3, np.int32, "loops") is None
    assert blender_array(_Items(tris, wrong_at=nt - 1), nt, 3, np.int32, "loops") is None
    assert blender_array(tris, nt, 3, np.int32, "loops") is not None
    assert blender_array(tris, nt, 3, np.int64, "loops") is None  # (another item size)


def test_mesh_read_allocates_only_what_the_mesh_keeps():
    """``meshes.mesh_arrays`` reads Blender's arrays in place and gathers straight into the
    Mesh's own arrays: numpy allocates no more than the Mesh keeps (no copies of the raw
    attributes or of the triangles' corners, no int64 index temporaries; fresh memory is
    most of a large first read's cost), and gives exactly what ``foreach_get``'s copies
    give. A mesh without material indices keeps no slots (every triangle slot 0)."""
    import tracemalloc

    import addon
    from addon.meshes import mesh_arrays

    meshes = _read_scene_meshes()
    addon.kernels.wait(600)  # (the background kernel load allocates too: traced alike)
    for me in meshes:
        nl, nt = len(me.loops), len(me.loop_triangles)
        mesh_arrays(me, me.name, {})  # (Blender's lazy data and Python's imports, first)
        tracemalloc.start()
        try:
            mesh = mesh_arrays(me, me.name, {})
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        kept = sum(getattr(a.base, "nbytes", a.nbytes) for a in (  # (with any room)
            mesh.vertices, mesh.triangles, mesh.corner_normals, mesh.corner_uvs, mesh.slots,
            mesh.vertex_normals) if a is not None)
        # (what numpy's buffered index casts and the probes take: a few buffers of 64 KB)
        assert peak <= kept + 256 * 1024, (me.name, peak, kept)
        # what foreach_get's copies give
        corner_vert = np.empty(nl, np.int32)
        me.attributes[".corner_vert"].data.foreach_get("value", corner_vert)
        loops = np.empty(nt * 3, np.int32)
        me.loop_triangles.foreach_get("loops", loops)
        loops = loops.reshape(nt, 3).astype(np.int64)
        np.testing.assert_array_equal(mesh.triangles, corner_vert[loops])
        uv = np.empty(nl * 2, np.float32)
        me.uv_layers.active.uv.foreach_get("vector", uv)
        np.testing.assert_array_equal(mesh.corner_uvs, uv.reshape(nl, 2)[loops])
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        np.testing.assert_array_equal(mesh.vertices, co.reshape(-1, 3))
        assert mesh.vertices.flags.writeable  # (a copy: the views of Blender are read-only)
        if me.name == "Slots":
            poly = np.empty(nt, np.int32)
            me.loop_triangle_polygons.foreach_get("value", poly)
            np.testing.assert_array_equal(mesh.slots, np.minimum(poly % 3, 1))
        else:
            assert mesh.slots is None, me.name


def test_export_checks_refuse_bad_vertices_and_all_degenerate_meshes():
    """``export._checked`` (the read's own checks, without temporaries of the mesh's size):
    NaN or infinite coordinates, coordinates past ``COORD_MAX`` and meshes whose every
    triangle is degenerate are refused with a message naming the mesh; a mesh whose first
    4,096 triangles are degenerate but one later is not is kept (the probe's vertices are
    its own triangles', the same float64 values)."""
    from addon.export import _AREA_PROBE, _checked
    from rstrace_engine import tolerances as tol
    from rstrace_engine.geometry.scene import Mesh

    n = _AREA_PROBE + 10
    v = np.zeros((3 * n, 3), np.float32)  # every triangle a point at the origin...
    v[-3:] = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]  # ...but the last
    tris = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    tris[: _AREA_PROBE] = tris[-1]  # (the probe's triangles name the proper one's vertices
    tris[: _AREA_PROBE, 1] = tris[-1, 0]  # twice: degenerate)
    assert _checked(Mesh("Late", v, tris, owned=True), "Late", b"", "RENDER").mesh is not None
    flat = Mesh("Flat", v, tris[: _AREA_PROBE], owned=True)
    assert "all 4096 triangles are degenerate" in _checked(flat, "Flat", b"", "RENDER").reason
    for bad, message in ((np.nan, "NaN or infinite"), (np.inf, "NaN or infinite"),
                         (-np.inf, "NaN or infinite"), (2.0 * tol.COORD_MAX, "exceed"),
                         (-2.0 * tol.COORD_MAX, "exceed")):
        w = v.copy()
        w[5, 1] = bad
        entry = _checked(Mesh("Bad", w, tris, owned=True), "Bad", b"", "RENDER")
        assert entry.mesh is None and entry.reason.startswith("mesh 'Bad': ")
        assert message in entry.reason, (bad, entry.reason)
