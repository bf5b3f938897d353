"""F12, animation frames and the viewport while objects are in Edit Mode: each renders
with its mesh as of the last edit-mode update, as Cycles and EEVEE render it (Blender's
evaluated edit-mode mesh is a wrapper of the edit mesh with no vertices or faces of its own:
read as it is, the object was skipped as faceless, a silently wrong image). The user's
scene is left as it was: still in Edit Mode, no mesh datablock added.

The reference is the same shape rendered in Object Mode (leaving Edit Mode writes the edit
mesh into the object's mesh): equal bit for bit, as is a render from nothing (BASE)."""

from __future__ import annotations

import bmesh
import bpy
import numpy as np

from . import builders as b
from .exr import read_exr, read_pass
from .test_viewport import _camera, _settled, _start, _view


def _edit_mode(*obs) -> None:
    """Edit Mode on ``obs`` together (multi-object editing), the first one active."""
    layer = bpy.context.view_layer
    layer.update()  # (its list of objects is brought up to date lazily)
    for ob in layer.objects:
        ob.select_set(ob in obs)
    layer.objects.active = obs[0]
    bpy.ops.object.mode_set(mode="EDIT")
    assert all(ob.mode == "EDIT" for ob in obs)


def _move(ob, dz: float, scale: float = 1.0) -> None:
    """Edit ``ob``'s edit mesh (its vertices scaled about the origin, then raised by
    ``dz``) and send the edit to the depsgraph, as an edit-mode operator does."""
    bm = bmesh.from_edit_mesh(ob.data)
    for v in bm.verts:
        v.co = v.co * scale
        v.co.z += dz
    bmesh.update_edit_mesh(ob.data)
    bpy.context.view_layer.update()


def _f12() -> np.ndarray:
    return b.render_exr()["Combined"][..., :3]


def _fresh() -> np.ndarray:
    """F12 from nothing: no session, no cached mesh."""
    import addon

    addon.session.forget_all()
    return _f12()


def test_f12_renders_objects_in_edit_mode_with_their_edits():
    b.three_spheres_scene(48, 36)
    red, blue = bpy.data.objects["RedSphere"], bpy.data.objects["BlueSphere"]
    meshes = len(bpy.data.meshes)
    object_mode = _f12()
    _edit_mode(red, blue)
    unedited = _f12()
    # (before: both spheres left out, "its mesh 'Mesh' has no faces")
    np.testing.assert_array_equal(unedited, object_mode)
    _move(red, 0.6)
    _move(blue, -0.2, 0.7)
    edited = _f12()  # (the session's cached meshes: checked by fingerprint, re-read)
    assert np.abs(edited - object_mode).max() > 0.1
    np.testing.assert_array_equal(edited, _fresh())
    _move(red, 0.5)  # an edit after an F12 in Edit Mode
    again = _f12()
    assert np.abs(again - edited).max() > 0.1
    np.testing.assert_array_equal(again, _fresh())
    # an edit that sends no update (a script's bmesh edit without update_edit_mesh):
    # a fresh render depsgraph (Cycles' F12 too) shows it, so does the cached read
    bm = bmesh.from_edit_mesh(red.data)
    for v in bm.verts:
        v.co.z -= 0.5
    unsent = _f12()
    assert np.abs(unsent - again).max() > 0.1
    np.testing.assert_array_equal(unsent, _fresh())
    _move(red, 0.5)  # (sent)
    last = _f12()
    np.testing.assert_array_equal(last, _fresh())
    # the scene as it was: still in Edit Mode, no datablock added, the object's own mesh
    # not written (leaving Edit Mode writes it)
    assert red.mode == blue.mode == "EDIT" and len(bpy.data.meshes) == meshes
    assert abs(max(v.co.z for v in red.data.vertices) - 1.0) < 1e-6
    bpy.ops.object.mode_set(mode="OBJECT")
    assert abs(max(v.co.z for v in red.data.vertices) - 2.1) < 1e-5
    np.testing.assert_array_equal(_f12(), last)  # the same shapes in Object Mode
    np.testing.assert_array_equal(_fresh(), last)


def test_each_edit_mode_mesh_keeps_its_own_key():
    """Walks with nothing changed take both meshes from the cache: the conversion of one
    may get the address of the other's, freed just before (checked: it does in the
    viewport's depsgraph), which must not make it the other's mesh."""
    import addon

    b.three_spheres_scene(48, 36)
    red, blue = bpy.data.objects["RedSphere"], bpy.data.objects["BlueSphere"]
    _edit_mode(red, blue)
    _move(red, 0.6)
    _move(blue, -0.2, 0.7)
    cache = addon.export.ExportCache()
    for _ in range(3):
        snap = addon.export.read_scene(bpy.context.evaluated_depsgraph_get(), cache)
        keys = {rec.name: rec.mesh_key for rec in snap.objects.values()}
        for ob in (red, blue):
            assert keys[ob.name] == ("data", ob.data.session_uid)
            z = cache.mesh(keys[ob.name]).vertices[:, 2]
            assert abs(float(z.max()) - (1.6 if ob is red else 0.5)) < 1e-6


def test_animation_frames_render_the_edit_mode_object(tmp_path):
    sc = b.three_spheres_scene(40, 30)
    sc.frame_start, sc.frame_end = 1, 2
    red, blue = bpy.data.objects["RedSphere"], bpy.data.objects["BlueSphere"]
    for frame, x in ((1, 1.5), (2, 0.9)):
        blue.location.x = x
        blue.keyframe_insert("location", frame=frame)
    _edit_mode(red)
    _move(red, 0.4, 1.2)

    def frames(prefix: str) -> list[np.ndarray]:
        sc.render.filepath = str(tmp_path / prefix)
        bpy.ops.render.render(animation=True)
        files = sorted(tmp_path.glob(f"{prefix}*.exr"))
        assert len(files) == 2
        return [read_pass(read_exr(f), "Combined", components="RGB") for f in files]

    edit_mode = frames("edit_")
    assert red.mode == "EDIT"
    import addon

    addon.session.forget_all()
    bpy.ops.object.mode_set(mode="OBJECT")
    for got, want in zip(edit_mode, frames("object_"), strict=True):
        np.testing.assert_array_equal(got, want)


def test_viewport_renders_the_edit_mode_object_and_follows_its_edits():
    sc, vr = _start()
    try:
        camera = _camera(_view())

        def frame() -> np.ndarray:
            vr.draw_view(camera, None)
            _settled(vr)
            return vr.worker.last_frame.radiance.copy()

        object_mode = frame()
        red = bpy.data.objects["RedSphere"]
        _edit_mode(red)
        np.testing.assert_array_equal(frame(), object_mode)
        _move(red, 0.5, 0.8)  # -> depsgraph_update_post -> view_update: an incremental edit
        edited = frame()
        assert np.abs(edited - object_mode).max() > 0.1
        bpy.ops.object.mode_set(mode="OBJECT")
        bpy.context.view_layer.update()
        np.testing.assert_array_equal(frame(), edited)  # the same shape in Object Mode
    finally:
        vr.free()
