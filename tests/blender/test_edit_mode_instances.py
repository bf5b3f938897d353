"""A geometry-nodes instance of an Edit Mode object's geometry (Object
Info, As Instance off, then Geometry to Instance: the instance's geometry is made by the
instancer, key ``("inst", ...)``) renders with that geometry. Its evaluated mesh says
``is_editmode``; the export converts ``ob.original.evaluated_get(...)``, i.e. the
instancer, whose own mesh has no faces, and the instance is dropped with no note (the
instancer's "no faces" is suppressed for instancers): a silently missing object."""

from __future__ import annotations

import bmesh
import bpy

from . import builders as b
from .test_edit_mode import _edit_mode, _move


def _instancer(target):
    ng = bpy.data.node_groups.new("GN", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = target
    info.inputs["As Instance"].default_value = False
    to_instance = ng.nodes.new("GeometryNodeGeometryToInstance")
    ng.links.new(info.outputs["Geometry"], to_instance.inputs[0])
    ng.links.new(to_instance.outputs[0], ng.nodes.new("NodeGroupOutput").inputs[0])
    me = bpy.data.meshes.new("InstancerMesh")
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=3, y_segments=3, size=5.0)
    bm.to_mesh(me)
    ob = b.add_object("Instancer", me, location=(0.0, 0.0, -3.0))
    ob.modifiers.new("GN", "NODES").node_group = ng
    return ob


def _instance_top(cache=None):
    """The highest vertex (object space) of the instancer's instance, or None if the
    walk left it out; the walk's skip notes."""
    import addon

    cache = cache or addon.export.ExportCache()
    snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
    tops = [float(cache.mesh(r.mesh_key).vertices[:, 2].max())
            for r in snap.objects.values() if r.name.startswith("Instancer/")]
    return (tops[0] if tops else None), snap.notes.skipped


def test_geometry_nodes_instance_of_an_edit_mode_mesh_is_not_dropped():
    b.three_spheres_scene(48, 36)
    red = bpy.data.objects["RedSphere"]
    _instancer(red)
    bpy.context.view_layer.update()
    top, _ = _instance_top()
    assert abs(top - 1.0) < 1e-6  # Object Mode: the red sphere's shape
    _edit_mode(red)
    _move(red, 0.6)
    top, skipped = _instance_top()
    # (s33-int: None, no note)
    assert top is not None, f"instance dropped silently (notes: {skipped})"
    assert abs(top - 1.6) < 1e-6
