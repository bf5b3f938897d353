"""Depsgraph updates -> edits, driven by real depsgraphs: each change is made with the data
API, ``depsgraph_update_post`` hands the updates to
:class:`addon.depsgraph_diff.SceneMirror`, and the edits it produces are checked; then the
F12 path applies them to the scene's persistent session and the frame must equal a fresh
render (BASE bit for bit, INTERPOLANT within epsilon)."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from . import builders as b
from .test_glue import FakeEngine


def _scene(width=32, height=24):
    sc = b.three_spheres_scene(width, height)
    sc.rstrace.samples = 1
    return sc


class Collector:
    """Turns every depsgraph update batch into edits (as view_update does)."""

    def __init__(self):
        import addon

        self.sync = addon.depsgraph_diff.SceneMirror()
        self.batches = []
        dg = bpy.context.evaluated_depsgraph_get()
        self._sync(dg, None)  # the first sync reads everything
        bpy.app.handlers.depsgraph_update_post.append(self.handler)

    def _sync(self, dg, dirty):
        import addon

        snap = self.sync.read(dg, dirty, "VIEWPORT", with_camera=False)
        result = self.sync.diff(snap, exists=addon.depsgraph_diff.existing_objects)
        self.sync.commit(result)
        return result.edits

    def handler(self, scene, dg):
        dirty = self.sync.dirty(dg)
        self.batches.append([] if dirty is None else self._sync(dg, dirty))

    def step(self, change):
        """Make a change, update the depsgraph; the kinds of the edits it produced."""
        n = len(self.batches)
        change()
        bpy.context.view_layer.update()
        out = [e for batch in self.batches[n:] for e in batch]
        return sorted(type(e).__name__ for e in out), out


def test_each_change_gives_its_edits():
    _scene()
    red = bpy.data.objects["RedSphere"]
    c = Collector()
    uid = red.session_uid
    kinds, out = c.step(lambda: setattr(red.location, "x", red.location.x + 0.3))
    assert kinds == ["ObjectTransform"] and out[0].key == uid
    assert np.allclose(out[0].matrix, np.array(red.matrix_world))
    assert c.step(lambda: setattr(red.rotation_euler, "z", 0.4))[0] == ["ObjectTransform"]
    assert c.step(lambda: setattr(red, "scale", (1.2, 1.2, 1.2)))[0] == ["ObjectTransform"]
    # not edits: selection, colour management, a viewport display setting
    assert c.step(lambda: red.select_set(True))[0] == []
    sc = bpy.context.scene
    assert c.step(lambda: setattr(sc.view_settings, "exposure", 1.0))[0] == []
    assert c.step(lambda: setattr(red, "display_type", "WIRE"))[0] == []
    # material colour: one MaterialSet, the mesh is not re-read
    mat = red.active_material
    kinds, out = c.step(lambda: setattr(mat.node_tree.nodes["Principled BSDF"].inputs[
        "Base Color"], "default_value", (0.1, 0.9, 0.1, 1.0)))
    assert kinds == ["MaterialSet"] and out[0].key == mat.session_uid
    assert abs(out[0].material.diffuse[1] - out[0].material.diffuse[0]) > 0.3
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
    kinds, out = c.step(lambda: setattr(lamp.data, "energy", lamp.data.energy * 2))
    assert kinds == ["LightSet"] and out[0].key == lamp.session_uid
    # vertices edited: that mesh only (shared by two spheres: one MeshSet)
    me = red.data
    users = [o for o in bpy.data.objects if o.data == me]
    kinds, out = c.step(lambda: me.vertices[0].co.__setitem__(2, me.vertices[0].co.z + 0.2))
    assert kinds == ["MeshSet"] and len(users) >= 1
    # duplicate linked: the mesh is shared, nothing re-read
    dup = red.copy()
    kinds, out = c.step(lambda: sc.collection.objects.link(dup))
    assert kinds == ["ObjectAdd"] and out[0].mesh_key == ("data", me.session_uid)
    # hide from renders, show again; hide in the viewport; delete
    assert c.step(lambda: setattr(dup, "hide_render", True))[0] == ["ObjectVisibility"]
    kinds, out = c.step(lambda: setattr(dup, "hide_render", False))
    assert kinds == ["ObjectVisibility"] and out[0].visible
    kinds, out = c.step(lambda: setattr(dup, "hide_viewport", True))
    assert kinds == ["ObjectVisibility"] and not out[0].visible
    dup_uid = dup.session_uid
    kinds, out = c.step(lambda: bpy.data.objects.remove(dup))
    assert kinds == ["ObjectDelete"] and out[0].key == dup_uid
    blue = bpy.data.objects["BlueSphere"]
    blue_mesh = ("data", blue.data.session_uid)  # its own mesh and material: freed with it
    blue_mat = blue.active_material.session_uid
    kinds, out = c.step(lambda: bpy.data.objects.remove(blue))
    assert kinds == ["MaterialDelete", "MeshDelete", "ObjectDelete"]
    assert {e.key for e in out[1:]} == {blue_mesh, blue_mat}
    assert blue_mesh not in c.sync.cache.meshes and blue_mesh not in c.sync.meshes
    assert blue_mat not in c.sync.cache.materials and blue_mat not in c.sync.materials
    # a new object with a new mesh; the world colour
    kinds, out = c.step(lambda: b.add_object("Box", b.grid("BoxMesh", 1.0), (0, 0, 2.0)))
    # (without a material it uses the default one, sent the first time it is needed)
    assert kinds == ["MaterialSet", "MeshSet", "ObjectAdd"]
    assert next(e for e in out if type(e).__name__ == "MaterialSet").key == "default"
    kinds, _ = c.step(lambda: b.set_world((0.2, 0.1, 0.05)))
    assert kinds == ["WorldColor"]


def test_world_ray_visibility_gives_a_world_edit():
    """The world's Diffuse and Glossy ray visibility both off: a background only (Cycles
    excludes it from both closures), sent as a WorldColor edit that says so."""
    _scene()
    world = b.set_world((0.2, 0.2, 0.2))
    c = Collector()
    kinds, _ = c.step(lambda: setattr(world.cycles_visibility, "diffuse", False))
    assert kinds == []  # Glossy still on: the world still lights (the mismatch is reported)

    kinds, out = c.step(lambda: setattr(world.cycles_visibility, "glossy", False))
    assert kinds == ["WorldColor"] and out[0].lights is False
    kinds, out = c.step(lambda: setattr(world.cycles_visibility, "glossy", True))
    assert kinds == ["WorldColor"] and out[0].lights is True


def test_deleting_a_textured_material_s_last_user_frees_its_pixels():
    _scene()
    img = bpy.data.images.new("Checker", 8, 8)
    img.pixels.foreach_set(np.tile([0.9, 0.1, 0.1, 1.0], 64).astype(np.float32))
    mat = b.principled("Textured")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes[
        "Principled BSDF"].inputs["Base Color"])
    ob = b.add_object("Board", b.grid("BoardMesh", 1.0), (0.0, 0.0, 0.3), mat)
    c = Collector()
    assert img.session_uid in c.sync.cache.textures and mat.session_uid in c.sync.materials
    mat_uid = mat.session_uid
    # another material freed: the pixels a live material holds stay cached
    kinds, _ = c.step(lambda: bpy.data.objects.remove(bpy.data.objects["BlueSphere"]))
    assert "MaterialDelete" in kinds and img.session_uid in c.sync.cache.textures
    kinds, _ = c.step(lambda: bpy.data.objects.remove(ob))
    assert kinds == ["MaterialDelete", "MeshDelete", "ObjectDelete"]
    assert mat_uid not in c.sync.cache.materials and img.session_uid not in c.sync.cache.textures
    assert "default" in c.sync.cache.materials  # (the default material is never dropped)


def test_collection_instances_and_unlink():
    _scene()
    red = bpy.data.objects["RedSphere"]
    coll = bpy.data.collections.new("Props")
    c = Collector()
    c.step(lambda: coll.objects.link(red))
    empty = bpy.data.objects.new("Inst", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = coll
    empty.location = (3.0, 0.0, 0.0)
    kinds, out = c.step(lambda: bpy.context.scene.collection.objects.link(empty))
    assert kinds == ["ObjectAdd"] and isinstance(out[0].key, tuple)
    assert out[0].key[0] == empty.session_uid
    kinds, out = c.step(lambda: setattr(empty.location, "y", 1.0))
    assert kinds == ["ObjectTransform"] and out[0].key[0] == empty.session_uid
    # moving the instanced object moves its instance too (it is read by a walk)
    kinds, out = c.step(lambda: setattr(red.location, "z", red.location.z + 0.2))
    assert kinds == ["ObjectTransform", "ObjectTransform"]
    assert {e.key if isinstance(e.key, int) else e.key[0] for e in out} == {
        red.session_uid, empty.session_uid}
    kinds, _ = c.step(lambda: bpy.context.scene.collection.objects.unlink(empty))
    assert kinds == ["ObjectDelete"]  # the instance vanished (its instancer still exists)


def test_undo_and_redo_keep_keys():
    _scene()
    red = bpy.data.objects["RedSphere"]
    uid = red.session_uid
    c = Collector()
    bpy.ops.ed.undo_push(message="before")
    c.step(lambda: setattr(red.location, "x", red.location.x + 1.0))
    bpy.ops.ed.undo_push(message="moved")
    kinds, out = c.step(lambda: bpy.ops.ed.undo())
    # undo re-evaluates everything; only what really differs comes out as edits
    assert "ObjectTransform" in kinds and all(k in ("ObjectTransform", "MeshSet")
                                              for k in kinds)
    assert {e.key for e in out if type(e).__name__ == "ObjectTransform"} == {uid}
    assert "MeshSet" not in kinds
    kinds, _ = c.step(lambda: bpy.ops.ed.redo())
    assert kinds == ["ObjectTransform"]
    assert bpy.data.objects["RedSphere"].session_uid == uid


def _f12(fresh=False):
    import addon

    sc = bpy.context.scene
    if fresh:
        addon.sync.drop_session(addon.session.state_for(sc))
    engine = FakeEngine()
    addon.session.FrameRenderer(engine).render(bpy.context.evaluated_depsgraph_get())
    state = addon.session.state_for(sc)
    assert not engine.errors, engine.errors
    return state.frame.radiance.copy(), dict(state.stats)


@pytest.mark.parametrize("mode", ["BASE", "INTERPOLANT"])
def test_f12_after_edits_equals_a_fresh_render(mode):
    """Each change of the issue's list through a real depsgraph, then F12 on the persistent
    session: equal to a fresh render (BASE bit for bit, INTERPOLANT within epsilon)."""
    sc = _scene(32, 24)
    sc.rstrace.mode = mode
    red = bpy.data.objects["RedSphere"]
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
    mat = red.active_material
    _f12()
    bpy.ops.ed.undo_push(message="start")

    def duplicate_linked():
        dup = red.copy()  # shares red's mesh
        dup.location = (0.4, 0.9, 1.0)
        sc.collection.objects.link(dup)

    changes = [  # (name, change, meshes it reads: 0 = nothing re-read but what changed)
        ("move", lambda: setattr(red.location, "x", red.location.x + 0.4), 0),
        ("rotate", lambda: setattr(red.rotation_euler, "z", 0.7), 0),
        # (in x and y only: the scene box, set by the spheres' tops, stays, so frames after
        # this stay incremental; a changed scene box renders a full frame)
        ("scale", lambda: setattr(red, "scale", (0.8, 0.8, 1.0)), 0),
        ("colour", lambda: setattr(mat.node_tree.nodes["Principled BSDF"].inputs[
            "Base Color"], "default_value", (0.2, 0.6, 0.9, 1.0)), 0),
        ("power", lambda: setattr(lamp.data, "energy", lamp.data.energy * 0.5), 0),
        ("hide", lambda: setattr(bpy.data.objects["BlueSphere"], "hide_render", True), 0),
        ("delete", lambda: bpy.data.objects.remove(bpy.data.objects["MirrorSphere"]), 0),
        ("add", lambda: b.add_object("Box", b.uv_sphere("Small", 0.3, 8, 4),
                                     (-0.5, -0.5, 0.6)), 1),
        ("duplicate-linked", duplicate_linked, 0),
        ("undo", lambda: bpy.ops.ed.undo(), None),  # back to "start": everything at once
    ]
    eps = sc.rstrace.epsilon
    for name, change, reads in changes:
        if name == "undo":
            bpy.ops.ed.undo_push(message="before undo")
        change()
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["edits"] >= 1 and not stats["new_session"], name
        if reads is not None:
            assert stats["meshes_read"] == reads, (name, stats["meshes_read"])
        if mode == "BASE" and "LightSet" in stats["edit_kinds"]:
            # each step's session is the previous step's fresh one: a light edit is its
            # first, a full frame that starts keeping the per-light terms
            # (Session.light_terms); test_f12_light_edits_relight... has the later ones
            assert not stats["incremental"] and stats["light_records_mb"] > 0.0, stats
        elif mode == "BASE":
            assert stats["incremental"] and stats["dirty_fraction"] < 1.0, (
                name, stats["edit_kinds"], stats["dirty_fraction"])
        ref, _ = _f12(fresh=True)
        if mode == "BASE":
            np.testing.assert_array_equal(inc, ref, err_msg=name)
        else:
            from rstrace_engine.image import to_display

            err = np.abs(to_display(inc) - to_display(ref)).max()
            assert err <= 2 * eps + 1e-6, (name, err)
    # the undo brought back the deleted sphere and dropped the added objects
    assert "MirrorSphere" in bpy.data.objects and "Box" not in bpy.data.objects


def test_shading_model_switch_rereads_the_cached_materials():
    """The per-datablock material cache is per shading model: switching it between two F12
    renders of one session converts every material again (MaterialSet edits), and the frame
    equals a fresh render of the new model."""
    sc = _scene(32, 24)
    principled, _ = _f12()
    sc.rstrace.shading_model = "WARD"
    bpy.context.view_layer.update()
    ward, stats = _f12()
    assert not stats["new_session"] and stats["edit_kinds"].get("MaterialSet", 0) >= 3
    ref, _ = _f12(fresh=True)
    np.testing.assert_array_equal(ward, ref)
    assert np.abs(ward - principled).max() > 1e-3  # the models shade differently


def test_last_render_stats_is_documented_and_filled():
    import addon

    _scene(16, 12)
    _f12()
    stats = addon.last_render_stats(bpy.context.scene)
    for key in ("sync_seconds", "apply_seconds", "render_seconds", "dirty_fraction",
                "interpolated_fraction", "invalidated_interpolants", "memory_mb", "edits"):
        assert key in stats and key in addon.last_render_stats.__doc__, key
    assert stats["memory_mb"] > 0.0


@pytest.mark.parametrize("mode", ["BASE", "INTERPOLANT", "RI_TREE"])
def test_memory_stat_counts_the_accelerator_and_the_mode_s_cache(mode):
    """Blender's memory figure is the session's whole: scene arrays, the accelerator (the
    BVH was left out in every mode) and the mode's own cache (RI_TREE's was left out)."""
    import addon

    sc = _scene(16, 12)
    sc.rstrace.mode = mode
    _, stats = _f12(fresh=True)
    state = addon.session.state_for(sc)
    arrays = sum(getattr(a, "nbytes", 0) for a in state.session.scene.arrays()) / 1e6
    accel = stats["accel_memory_mb"]
    assert accel > 0.0
    cache = stats["memory_mb"] - arrays - accel - (stats.get("records_mb") or 0.0)
    assert cache >= -1e-9
    if mode == "RI_TREE":
        assert cache > 0.0  # its trees


def test_f12_after_a_camera_edit_and_file_load():
    """The camera object moved or its lens changed: a CameraChange (a full frame, equal to
    a fresh render); loading a file drops every session (no stale ID or key survives)."""
    import addon

    sc = _scene(32, 24)
    _f12()
    cam = sc.camera
    for change in (lambda: setattr(cam.location, "x", cam.location.x + 0.3),
                   lambda: setattr(cam.data, "lens", cam.data.lens * 1.2)):
        change()
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["edit_kinds"] == {"CameraChange": 1} and not stats["incremental"]
        assert stats["meshes_read"] == 0 and not stats["new_session"]
        np.testing.assert_array_equal(inc, _f12(fresh=True)[0])
    assert addon.session.peek_state(sc) is not None
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert addon.session._STATES == {}


def test_selecting_the_engine_starts_the_kernel_warmup(monkeypatch):
    import addon

    started = []
    monkeypatch.setattr(addon.kernels, "start_warmup", started.append)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    bpy.context.view_layer.update()
    assert started == []
    sc.rstrace.mode = "INTERPOLANT"
    sc.render.engine = "RSTRACE"
    bpy.context.view_layer.update()
    assert started and started[-1] == "INTERPOLANT"


def test_last_render_panel_shows_the_stats():
    """Render Properties > RSTrace > Last Render draws the last F12's numbers."""
    from types import SimpleNamespace

    import addon

    class Layout:
        def __init__(self):
            self.lines = []

        def column(self, align=False):
            return self

        def label(self, text="", icon="NONE"):
            self.lines.append(text)

    sc = _scene(16, 12)
    panel = SimpleNamespace(layout=Layout())
    addon.ui.RSTRACE_PT_statistics.draw(panel, SimpleNamespace(scene=sc))
    assert panel.layout.lines == ["Not rendered yet"]
    _f12()
    bpy.data.objects["RedSphere"].location.x += 0.2
    bpy.context.view_layer.update()
    _f12()
    panel = SimpleNamespace(layout=Layout())
    addon.ui.RSTRACE_PT_statistics.draw(panel, SimpleNamespace(scene=sc))
    text = "\n".join(panel.layout.lines)
    stats = addon.last_render_stats(sc)
    assert "16 x 12 px, BASE" in text and "1 edits since the last render" in text
    assert f"{100.0 * stats['dirty_fraction']:.2f}% of the pixels re-rendered" in text
    assert f"Memory {stats['memory_mb']:.1f} MB" in text


def test_animation_frames_pass_what_moved_as_edits():
    sc = _scene(24, 18)
    red = bpy.data.objects["RedSphere"]
    red.keyframe_insert("location", frame=1)
    red.location.x += 0.5
    red.keyframe_insert("location", frame=2)
    sc.frame_set(1)
    _f12()
    sc.frame_set(2)
    inc, stats = _f12()
    assert stats["edit_kinds"] == {"ObjectTransform": 1} and stats["meshes_read"] == 0
    assert stats["incremental"] and stats["dirty_fraction"] < 1.0
    ref, _ = _f12(fresh=True)
    np.testing.assert_array_equal(inc, ref)


def _instancer(target, count: int):
    """An object whose geometry nodes put ``count`` instances of ``target`` on a line."""
    ng = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = ng.nodes, ng.links
    out = nodes.new("NodeGroupOutput")
    line = nodes.new("GeometryNodeMeshLine")
    line.inputs["Count"].default_value = count
    line.inputs["Offset"].default_value = (0.0, 1.5, 0.0)
    info = nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = target
    inst = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(line.outputs["Mesh"], inst.inputs["Points"])
    links.new(info.outputs["Geometry"], inst.inputs["Instance"])
    links.new(inst.outputs["Instances"], out.inputs["Geometry"])
    holder = bpy.data.objects.new("Scatter", bpy.data.meshes.new("ScatterMesh"))
    holder.modifiers.new("GN", "NODES").node_group = ng
    holder.location = (-3.0, -2.0, 0.5)
    return holder, line


def test_geometry_node_instances_appear_and_vanish():
    _scene()
    red = bpy.data.objects["RedSphere"]
    c = Collector()
    holder, line = _instancer(red, 3)
    kinds, out = c.step(lambda: bpy.context.scene.collection.objects.link(holder))
    adds = [e for e in out if type(e).__name__ == "ObjectAdd"]
    assert len(adds) == 3 and all(e.key[0] == holder.session_uid for e in adds)
    assert kinds.count("MeshSet") == 1  # the instanced geometry, read once, shared by all
    assert len({e.mesh_key for e in adds}) == 1
    kinds, out = c.step(lambda: setattr(line.inputs["Count"], "default_value", 5))
    assert kinds == ["ObjectAdd", "ObjectAdd"]  # same geometry: no MeshSet
    kinds, out = c.step(lambda: setattr(line.inputs["Count"], "default_value", 1))
    assert kinds.count("ObjectDelete") == 4 and "ObjectAdd" not in kinds
    kinds, out = c.step(lambda: setattr(holder.location, "x", -2.0))
    assert kinds == ["ObjectTransform"]


def test_deleting_the_last_user_frees_its_mesh_and_undo_brings_it_back():
    """Deleting the only user of a mesh frees the mesh in the session and the export cache;
    re-meshing an object frees its old mesh; undo of the delete re-exports the mesh. Every
    F12 frame equals a fresh render (BASE)."""
    import addon

    sc = _scene(32, 24)
    state = addon.session.state_for(sc)
    _f12()
    blue = bpy.data.objects["BlueSphere"]
    key = ("data", blue.data.session_uid)
    assert key in state.mirror.cache.meshes and key in state.session.scene.mesh_keys.slot
    n_meshes = sum(m is not None for m in state.session.scene.meshes)
    bpy.ops.ed.undo_push(message="before delete")
    bpy.data.objects.remove(blue)
    bpy.ops.ed.undo_push(message="deleted")
    bpy.context.view_layer.update()
    blue_mat = bpy.data.materials["Blue"].session_uid  # (the object is gone: by name)
    inc, stats = _f12()
    assert stats["edit_kinds"] == {"ObjectDelete": 1, "MeshDelete": 1, "MaterialDelete": 1}
    assert stats["incremental"]
    core = state.session.scene
    assert key not in core.mesh_keys.slot and key not in state.mirror.cache.meshes
    assert blue_mat not in core.material_keys.slot and blue_mat not in state.mirror.cache.materials
    assert sum(m is not None for m in core.meshes) == n_meshes - 1
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])
    # a geometry swap leaving the red sphere's own mesh unused
    red, mirror = bpy.data.objects["RedSphere"], bpy.data.objects["MirrorSphere"]
    red_key = ("data", red.data.session_uid)
    red.data = mirror.data
    bpy.context.view_layer.update()
    inc, stats = _f12()
    kinds = stats["edit_kinds"]  # (the red material was the old mesh's: slots change too,
    # and the red material, used by nothing else, is freed)
    assert kinds == {"ObjectGeometry": 1, "ObjectMaterials": 1, "MeshDelete": 1,
                     "MaterialDelete": 1}, kinds
    assert red_key not in state.session.scene.mesh_keys.slot
    assert red_key not in state.mirror.cache.meshes
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])
    # undo to before the delete (the swap was never pushed): the sphere and its mesh return
    bpy.ops.ed.undo()
    bpy.context.view_layer.update()
    assert "BlueSphere" in bpy.data.objects
    inc, stats = _f12()
    kinds = stats["edit_kinds"]
    assert kinds.get("ObjectAdd") == 1 and kinds.get("MeshSet", 0) >= 1, kinds
    assert kinds.get("MaterialSet", 0) >= 2, kinds  # the blue and red materials are back
    assert stats["meshes_read"] >= 1  # re-exported: the cache had dropped it
    assert key in state.mirror.cache.meshes and key in state.session.scene.mesh_keys.slot
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])


def test_f12_light_edits_relight_and_equal_a_fresh_render():
    """Issue 21: a light's power, colour and position changed through the depsgraph relight
    the kept frame from its per-light records -- no pixel re-traced -- and equal a fresh
    render bit for bit. The records start at the session's first light edit (that F12 is a
    full frame); the later ones relight."""
    sc = _scene(32, 24)
    sc.rstrace.mode = "BASE"
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
    _f12()
    lamp.data.energy *= 0.9
    bpy.context.view_layer.update()
    inc, stats = _f12()
    assert not stats.get("relit") and stats["light_records_mb"] > 0.0, stats
    changes = [
        ("power", lambda: setattr(lamp.data, "energy", lamp.data.energy * 0.4)),
        ("colour", lambda: setattr(lamp.data, "color", (1.0, 0.7, 0.4))),
        ("move", lambda: setattr(lamp.location, "x", lamp.location.x + 0.5)),
    ]
    inc = list(_relit_each(sc, changes))[-1][1]
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])  # and a fresh export


def _relit_each(sc, changes):
    """Each light edit ``(name, change)`` made through the depsgraph and F12'd: one
    LightSet, relit with no pixel traced, a fresh core session's frame of the synced scene
    bit for bit (a fresh F12 would drop this session). Yields ``(name, image)``."""
    import addon
    from rstrace_engine.session import Session

    for name, change in changes:
        change()
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["edit_kinds"] == {"LightSet": 1}, (name, stats["edit_kinds"])
        assert stats.get("relit") and stats["traced_pixels"] == 0, (name, stats)
        core = addon.session.state_for(sc).session
        ref = Session(core.scene.copy(), core.settings).render().radiance
        np.testing.assert_array_equal(inc, ref, err_msg=name)
        yield name, inc


def test_f12_world_edits_relight_in_interpolant_mode():
    """Issue 21: the world's Background colour and strength changed through the depsgraph in
    INTERPOLANT mode, the world lighting before and after, relight the kept frame (its
    traced pixels from their light records, its interpolated ones by their own world term
    rescaled; interpolants kept but where their trees show the world) and stay within
    epsilon of a fresh render; a NaN strength makes the world black (as Cycles, reported),
    a world that stops lighting: every interpolant rebuilt, not relit."""
    from rstrace_engine.image import to_display

    sc = _scene(48, 36)
    sc.rstrace.mode = "INTERPOLANT"
    sc.rstrace.interpolant_fallback = False  # cells, to test their relight (timed fallback off)
    world = b.set_world((0.2, 0.2, 0.24), lights=True)
    bg = world.node_tree.nodes["Background"]
    _f12()
    bg.inputs["Strength"].default_value = 1.2  # the first world edit starts the records
    bpy.context.view_layer.update()
    _f12()
    from dataclasses import replace

    import addon
    from rstrace_engine.session import Session

    eps = sc.rstrace.epsilon
    steps = [
        ("colour", lambda: setattr(bg.inputs["Color"], "default_value",
                                   (0.35, 0.25, 0.15, 1.0)), True),
        ("strength", lambda: setattr(bg.inputs["Strength"], "default_value", 2.5), True),
        ("nan", lambda: setattr(bg.inputs["Strength"], "default_value", float("nan")),
         False),
    ]
    for name, change, relit in steps:
        change()
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["edit_kinds"] == {"WorldColor": 1}, (name, stats["edit_kinds"])
        assert bool(stats.get("relit")) == relit, (name, stats)
        core = addon.session.state_for(sc).session
        if relit:
            assert stats["dirty_fraction"] < 0.5, (name, stats["dirty_fraction"])
        else:
            assert not core.scene.world_lights or not np.any(core.scene.world_color > 0)
        for st in (core.settings, replace(core.settings, mode="BASE")):
            ref = Session(core.scene.copy(), st).render().radiance
            err = np.abs(to_display(inc) - to_display(ref)).max()
            assert err <= eps + 1e-6, (name, st.mode, err)


def test_relight_memory_property_caps_the_records():
    """Relight Memory (the add-on's cap of the per-light records) reaches the core: at 0
    an F12 after a light edit keeps no records and says so (a message naming the setting),
    re-traces and equals a fresh render; a negative cap is refused by the property itself;
    raised again, the next light edit relights."""
    import addon
    from rstrace_engine.frame import RenderSettings
    from rstrace_engine.session import RELIGHT_OFF

    sc = _scene(32, 24)
    sc.rstrace.mode = "BASE"
    props = sc.rstrace
    assert props.relight_memory == RenderSettings().relight_memory_mb
    props.relight_memory = -5.0  # clamped by the property (min 0)
    assert props.relight_memory == 0.0
    assert addon.properties.render_settings(props).relight_memory_mb == 0.0
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
    _f12()
    for k in range(2):
        lamp.data.energy *= 0.8
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["light_records_mb"] == 0.0 and not stats.get("relit"), stats
        assert stats["relight_off"] == RELIGHT_OFF
        state = addon.session.state_for(sc)
        assert ("INFO", RELIGHT_OFF) in state.messages
        assert k == 0 or stats["incremental"]
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])
    props.relight_memory = 64.0
    for _ in range(2):  # a full frame that starts keeping them, then a relit one
        lamp.data.energy *= 0.8
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert "relight_off" not in stats
    assert stats.get("relit") and stats["light_records_mb"] > 0.0, stats


def test_f12_after_light_linking_edits_equals_a_fresh_render():
    """Light linking edited between F12s (a receiver collection set, an object added to it,
    the collection unset) and shadow linking (a blocker collection), on one persistent
    session: each F12 is incremental and equals a fresh render bit for bit (BASE); a power
    edit of the linked light and its receivers' changes relight (the light shaded again
    with its links), shadow linking turned on or off re-traces. (A link removed once left
    the pixels it should have lit as they were.)"""
    import addon
    from rstrace_engine.session import Session

    sc = _scene(32, 24)
    sc.rstrace.mode = "BASE"
    lamp = next(o for o in bpy.data.objects if o.type == "LIGHT")
    lit = bpy.data.collections.new("Lit")
    lit.objects.link(bpy.data.objects["RedSphere"])
    _f12()
    lamp.data.energy *= 0.9  # the session's first light edit: the records start
    bpy.context.view_layer.update()
    _f12()
    changes = [
        ("receivers set", lambda: setattr(lamp.light_linking, "receiver_collection", lit)),
        ("receiver added", lambda: lit.objects.link(bpy.data.objects["BlueSphere"])),
        ("power", lambda: setattr(lamp.data, "energy", lamp.data.energy * 0.5)),
        ("receivers unset", lambda: setattr(lamp.light_linking, "receiver_collection", None)),
        ("blockers set", lambda: setattr(lamp.light_linking, "blocker_collection", lit)),
        ("blockers unset", lambda: setattr(lamp.light_linking, "blocker_collection", None)),
    ]
    prev = None
    for name, change in changes:
        change()
        bpy.context.view_layer.update()
        inc, stats = _f12()
        assert stats["edit_kinds"] == {"LightSet": 1} and stats["incremental"], (name, stats)
        assert bool(stats.get("relit")) == (not name.startswith("blockers")), (name, stats)
        core = addon.session.state_for(sc).session
        ref = Session(core.scene.copy(), core.settings).render().radiance
        np.testing.assert_array_equal(inc, ref, err_msg=name)
        assert prev is None or not np.array_equal(inc, prev), name  # each change shows
        prev = inc
    np.testing.assert_array_equal(inc, _f12(fresh=True)[0])  # and a fresh export
