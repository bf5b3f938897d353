"""A geometry-nodes instance of an Edit Mode object's geometry (Object
Info, As Instance off, then Geometry to Instance: the instance's geometry is made by the
instancer, key ``("inst", ...)``) renders with that geometry. Its evaluated mesh says
``is_editmode``; the export converts ``ob.original.evaluated_get(...)``, i.e. the
instancer, whose own mesh has no faces, and the instance is dropped with no note (the
instancer's "no faces" is suppressed for instancers): a silently missing object.

An Edit Mode object instanced many times (collection instances) is converted once per
walk, not once per instance (900 instances of a 40k-vertex mesh: 1.5 s a walk)."""

from __future__ import annotations

from contextlib import contextmanager

import bmesh
import bpy
import numpy as np

from . import builders as b
from .test_edit_mode import _edit_mode, _f12, _fresh, _move


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


def test_an_edit_mode_object_instanced_many_times_is_converted_once_a_walk(monkeypatch):
    """Every instance of the object renders its edit mesh (the one conversion's key and
    shape), each walk converts it once and frees it right after the read (conversions
    entered and left, per walk: per reader), and an edit that sends no update (a
    script's bmesh edit) is still seen by F12 (a fresh render depsgraph)."""
    import addon

    b.three_spheres_scene(48, 36)
    red = bpy.data.objects["RedSphere"]
    source = bpy.data.collections.new("Source")
    source.objects.link(red)
    n = 12
    for i in range(n):
        copy = bpy.data.objects.new(f"Copy{i}", None)
        copy.instance_type = "COLLECTION"
        copy.instance_collection = source
        copy.location = (2.5 * (i % 4) - 3.75, 2.5 + 2.5 * (i // 4), 0.0)
        bpy.context.scene.collection.objects.link(copy)
    _edit_mode(red)
    _move(red, 0.6)
    real = addon.export._edit_mode_mesh
    calls = []  # [reader, left]

    @contextmanager
    def counted(r, inst, ob):
        calls.append([r, False])
        with real(r, inst, ob) as me:
            yield me
        calls[-1][1] = True

    def per_walk() -> list[int]:
        assert all(left for _, left in calls)
        readers = []
        for r, _ in calls:
            if all(r is not s for s in readers):
                readers.append(r)
        return [sum(r is c for c, _ in calls) for r in readers]

    monkeypatch.setattr(addon.export, "_edit_mode_mesh", counted)
    cache = addon.export.ExportCache()
    for top in (1.6, 1.6, 1.9):
        if top == 1.9:
            _move(red, 0.3)
        calls.clear()
        snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
        recs = [rec for rec in snap.objects.values() if rec.name == "RedSphere"
                or rec.name.startswith("Copy")]
        assert sorted(rec.name for rec in recs) == sorted(
            ["RedSphere"] + [f"Copy{i}/RedSphere" for i in range(n)])
        assert {rec.mesh_key for rec in recs} == {("data", red.data.session_uid)}
        assert abs(float(cache.mesh(recs[0].mesh_key).vertices[:, 2].max()) - top) < 1e-6
        assert per_walk() == [1]  # (main: [n + 1])
    before = _f12()
    bm = bmesh.from_edit_mesh(red.data)  # no update sent
    for v in bm.verts:
        v.co.z -= 0.5
    calls.clear()
    unsent = _f12()
    assert calls and set(per_walk()) == {1}
    assert np.abs(unsent - before).max() > 0.1
    np.testing.assert_array_equal(unsent, _fresh())
