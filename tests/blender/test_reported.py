"""Features rstrace does not model are named in the render's messages, never rendered
silently wrong (issue 23); and objects that render through their instances are not reported
as faceless. One small scene per feature, checked on the export's warnings (what the render
reports)."""

from __future__ import annotations

import bpy
import pytest

from . import builders as b


def _warnings():
    import addon

    return addon.export.export_scene(bpy.context.evaluated_depsgraph_get()).warnings


def _scene(material=None):
    b.setup_render(32, 24)
    ball = b.add_object("Ball", b.uv_sphere("Ball", 1.0, 16, 8), (0.0, 0.0, 1.0), material)
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()
    return ball


def _reported(warnings, *words) -> bool:
    return any(all(w in text for w in words) for text in warnings)


# ----------------------------------------------------------------------------- materials


def test_displacement_is_reported():
    mat = b.principled("Bumpy")
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    disp = nodes.new("ShaderNodeDisplacement")
    links.new(disp.outputs["Displacement"], nodes["Material Output"].inputs["Displacement"])
    _scene(mat)
    w = _warnings()
    assert _reported(w, "displacement", "'Bumpy'"), w


@pytest.mark.parametrize("shader", ["principled", "diffuse"])
def test_diffuse_roughness_is_reported(shader):
    if shader == "principled":
        mat = b.principled("Rough", **{"Diffuse Roughness": 0.5})
    else:
        mat = b.diffuse("Rough")
        mat.node_tree.nodes["Diffuse BSDF"].inputs["Roughness"].default_value = 0.5
    _scene(mat)
    w = _warnings()
    assert _reported(w, "diffuse roughness", "'Rough'"), w


def test_lambertian_diffuse_is_not_reported():
    _scene(b.diffuse("Smooth"))
    assert not _reported(_warnings(), "diffuse roughness")


def _holdout_material(name: str):
    mat = bpy.data.materials.new(name)
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    hold = nodes.new("ShaderNodeHoldout")
    mat.node_tree.links.new(hold.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def _viewport_warnings():
    import addon

    cache = addon.export.ExportCache()
    snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(), cache,
                                   source="VIEWPORT")
    return snap.warnings


def test_holdout_shader_is_modelled_in_renders_and_reported_in_the_viewport():
    import addon

    _scene(_holdout_material("Hole"))
    cache = addon.export.ExportCache()
    snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
    (rec,) = snap.objects.values()
    entry = cache.materials[rec.material_keys[0]]
    # a hole for camera rays (the render cuts it out), black in reflections
    assert entry.holdout and max(entry.material.diffuse) == 0.0
    assert not _reported(snap.warnings, "Holdout"), snap.warnings
    assert _reported(_viewport_warnings(), "holdouts", "viewport", "'Ball'")


@pytest.mark.parametrize("where", ["object", "collection"])
def test_holdout_objects_are_flagged(where):
    import addon

    if where == "object":
        _scene().is_holdout = True
    else:
        _in_collection("Cutout").holdout = True
    snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(),
                                   addon.export.ExportCache())
    held = {rec.name for rec in snap.objects.values() if rec.holdout}
    assert held == ({"Ball"} if where == "object" else {"Box"})
    assert not _reported(snap.warnings, "holdout"), snap.warnings


def test_volume_under_a_surface_is_reported():
    mat = b.principled("Smoky")
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    vol = nodes.new("ShaderNodeVolumeAbsorption")
    links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    _scene(mat)
    w = _warnings()
    assert _reported(w, "volume shaders", "'Smoky'"), w


def test_world_volume_is_reported():
    _scene()
    world = bpy.data.worlds.new("Foggy")
    bpy.context.scene.world = world
    nodes = world.node_tree.nodes
    vol = nodes.new("ShaderNodeVolumeScatter")
    world.node_tree.links.new(vol.outputs[0], nodes["World Output"].inputs["Volume"])
    w = _warnings()
    assert _reported(w, "world volumes", "'Foggy'"), w


def test_particle_hair_is_reported():
    ball = _scene()
    bpy.context.view_layer.objects.active = ball
    ball.modifiers.new("Hair", "PARTICLE_SYSTEM")
    ball.particle_systems[0].settings.type = "HAIR"
    w = _warnings()
    assert _reported(w, "particle hair", "'Ball'"), w


def test_unwritten_passes_are_named():
    from addon.session import unwritten_passes

    _scene()
    layer = bpy.context.view_layer
    assert unwritten_passes(layer) == []
    layer.use_pass_z = layer.use_pass_normal = True  # written
    assert unwritten_passes(layer) == []
    layer.use_pass_mist = layer.use_pass_ambient_occlusion = True
    layer.use_pass_diffuse_direct = True
    (message,) = unwritten_passes(layer)
    for name in ("Mist", "Ambient Occlusion", "Diffuse Direct", f"'{layer.name}'"):
        assert name in message, message
    assert "Normal" not in message and " Z" not in message
    if hasattr(layer, "cycles"):  # Cycles' own passes, and AOVs
        layer.cycles.use_pass_shadow_catcher = layer.cycles.denoising_store_passes = True
        layer.aovs.add().name = "Dirt"
        (message,) = unwritten_passes(layer)
        for name in ("Shadow Catcher", "Denoising", "AOV 'Dirt'"):
            assert name in message, message


# ----------------------------------------------------------------------------- objects


def test_shadow_catcher_is_reported():
    _scene().is_shadow_catcher = True
    w = _warnings()
    assert _reported(w, "shadow catcher", "'Ball'"), w


def _in_collection(name: str):
    _scene()
    col = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(col)
    b.add_object("Box", b.grid("Box", 1.0), (2.0, 0.0, 0.5), collection=col)
    return bpy.context.view_layer.layer_collection.children[name]


def test_indirect_only_collection_is_reported():
    _in_collection("Bounce").indirect_only = True
    w = _warnings()
    assert _reported(w, "indirect only", "'Bounce'"), w


def test_plain_scene_reports_none_of_these():
    _in_collection("Plain")
    w = _warnings()
    for word in ("holdout", "shadow catcher", "indirect only", "override", "displacement"):
        assert not _reported(w, word), w


# ----------------------------------------------------------------------------- no faces


def _faceless(name: str, points: int = 2):
    me = bpy.data.meshes.new(name)
    me.from_pydata([(float(i) * 2.0, 0.0, 0.5) for i in range(points)], [], [])
    return me


def test_vertex_instancing_parent_is_not_faceless():
    b.setup_render(32, 24)
    parent = b.add_object("Dots", _faceless("Dots"))
    parent.instance_type = "VERTS"
    child = b.add_object("Pebble", b.uv_sphere("Pebble", 0.3, 8, 4))
    child.parent = parent
    b.add_object("Lonely", _faceless("Lonely"))  # a real faceless mesh: still reported
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()
    w = _warnings()
    assert not _reported(w, "'Dots'", "no faces"), w
    assert _reported(w, "'Lonely'", "no faces"), w


def test_geometry_nodes_instancer_is_not_faceless():
    b.setup_render(32, 24)
    ob = b.add_object("Scatter", _faceless("Scatter", 0))
    tree = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    out = nodes.new("NodeGroupOutput")
    line = nodes.new("GeometryNodeMeshLine")
    line.inputs["Count"].default_value = 3
    cube = nodes.new("GeometryNodeMeshCube")
    inst = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(line.outputs["Mesh"], inst.inputs["Points"])
    links.new(cube.outputs["Mesh"], inst.inputs["Instance"])
    links.new(inst.outputs["Instances"], out.inputs[0])
    ob.modifiers.new("GN", "NODES").node_group = tree
    b.add_object("Lonely", _faceless("Lonely"))
    b.point_light("Lamp", (0.0, -3.0, 5.0), 1000.0)
    b.camera()
    w = _warnings()
    assert not _reported(w, "'Scatter'", "no faces"), w
    assert _reported(w, "'Lonely'", "no faces"), w


@pytest.mark.parametrize("metallic, roughness, anisotropic", [
    (1.0, 0.0, 0.0), (1.0, 0.25, 0.0), (0.0, 0.5, 0.0), (1.0, 0.25, 0.5)])
def test_rough_reflection_is_rendered_anisotropy_reported(metallic, roughness, anisotropic):
    """Glossy rays model rough reflections (issue 24): no message for them; an anisotropic
    lobe, rendered isotropic, is named."""
    _scene(b.principled("Satin", metallic=metallic, roughness=roughness,
                        Anisotropic=anisotropic))
    w = _warnings()
    assert not _reported(w, "rough reflections", "'Satin'"), w
    assert _reported(w, "anisotropy", "'Satin'") == (anisotropic > 0.0), w
