"""The edit model: stable slots and keys, Session.apply (all or nothing), update_scene diffs."""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import frame as frame_mod
from rstrace_engine.accel import accelerators, embree
from rstrace_engine.frame import RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.edits import (
    CameraChange,
    LightDelete,
    LightSet,
    MaterialSet,
    MeshSet,
    ObjectAdd,
    ObjectDelete,
    ObjectGeometry,
    ObjectMaterials,
    ObjectTransform,
    ObjectVisibility,
    WorldColor,
    apply_edits,
    diff_scenes,
)
from rstrace_engine.geometry.scene import Light, Material, Mesh, Scene, SceneError
from rstrace_engine.session import Session

ACCELS = ["BVH", "BRUTE_FORCE", "VISIBILITY_FIELD"] + (["EMBREE"] if embree.available() else [])


def row_scene(w: int = 24, h: int = 18, key_light: bool = True) -> Scene:
    """Three cubes in a row on a floor, two lights."""
    s = Scene()
    grey = s.add_material(Material("grey", diffuse=(0.6, 0.6, 0.6)), key="grey")
    s.add_material(Material("red", diffuse=(0.8, 0.1, 0.1)), key="red")
    cube = s.add_mesh(shapes.box((1.0, 1.0, 1.0), name="cube"), key="cube")
    floor = s.add_mesh(shapes.plane(10.0, name="floor"), key="floor")
    s.add_instance(floor, np.eye(4), [grey], name="Floor")
    for k, x in enumerate((-2.0, 0.0, 2.0)):
        s.add_instance(cube, shapes.transform((x, 0.0, 0.5)), [grey], name=f"Cube{k}")
    if key_light:
        s.add_light(Light("Key", "POINT", power=800.0, position=(-2.0, -3.0, 4.0)))
    s.add_light(Light("Sun", "SUN", power=1.0, direction=(0.3, 0.2, -1.0)))
    s.set_camera(shapes_camera(w, h))
    return s


def shapes_camera(w, h):
    from rstrace_engine.geometry.scene import Camera

    return Camera(matrix=shapes.look_at((0.0, -7.0, 3.0), (0.0, 0.0, 0.5)), width=w,
                  height=h)


# ----------------------------------------------------------------------------- lists


def test_one_list_of_modes_and_accelerators():
    from rstrace_engine import session

    assert accelerators.NAMES is frame_mod.ACCELERATORS
    assert session.AVAILABLE_MODES is frame_mod.AVAILABLE_MODES
    assert set(frame_mod.AVAILABLE_MODES) <= set(frame_mod.MODES)
    assert set(frame_mod.AVAILABLE_ACCELERATORS) <= set(frame_mod.ACCELERATORS)
    assert set(frame_mod.AVAILABLE_ACCELERATORS) == set(frame_mod.ACCELERATORS)
    with pytest.raises(SceneError, match="VOXELS"):
        accelerators.create_accelerator("VOXELS", row_scene().arrays())


# ----------------------------------------------------------------------------- slots


def test_slots_are_stable_and_tombstones_reused():
    s = row_scene()
    assert s.instance_slot("Cube1") == 2 and s.mesh_id("cube") == 0
    s.delete_instance(s.instance_slot("Cube1"))
    assert s.instances[2] is None and s.instance_slot("Cube2") == 3  # nobody renumbered
    with pytest.raises(SceneError, match="Cube1.*unknown"):
        s.instance_slot("Cube1")
    sa = s.arrays()
    assert list(sa.inst_alive) == [True, True, False, True]
    assert np.all(sa.inst_aabb[2, 0] > sa.inst_aabb[2, 1])  # an empty box
    slot = s.add_instance(0, shapes.transform((0.0, 2.0, 0.5)), [0], name="New", key=("x", 1))
    assert slot == 2 and s.instance_slot(("x", 1)) == 2
    with pytest.raises(SceneError, match="already in use"):
        s.add_instance(0, np.eye(4), [0], name="Dup", key=("x", 1))
    j = s.light_slot("Key")
    s.delete_light(j)
    assert s.arrays().light_kind[j] == -1 and np.all(s.arrays().light_intensity[j] == 0)
    assert s.add_light(Light("Again", "POINT"), key="again") == j


@pytest.mark.parametrize("accel", ACCELS)
def test_no_accelerator_hits_a_dead_or_hidden_slot(accel):
    s = row_scene()
    s.delete_instance(s.instance_slot("Cube1"))
    s.set_instance_visible(s.instance_slot("Cube2"), False)
    sa = s.arrays()
    acc = accelerators.create_accelerator(accel, sa)
    rng = np.random.default_rng(3)
    n = 4000
    o = np.column_stack([rng.uniform(-3, 3, n), np.full(n, -6.0), rng.uniform(0.05, 1.2, n)])
    d = np.column_stack([rng.normal(0, 0.05, n), np.ones(n), rng.normal(0, 0.05, n)])
    h = acc.closest_hit(o, d, np.zeros(n), np.full(n, np.inf))
    assert np.any(h.inst == 1) and not np.any(np.isin(h.inst, [2, 3]))
    ref = accelerators.create_accelerator("BRUTE_FORCE", sa).closest_hit(o, d, np.zeros(n),
                                                                          np.full(n, np.inf))
    np.testing.assert_array_equal(h.inst, ref.inst)
    assert not np.any(acc.any_hit(o, d, np.zeros(n), np.full(n, np.inf))
                      & (ref.inst < 0))
    only = acc.intersect_object(2, o, d, np.zeros(n), np.full(n, np.inf))
    assert np.all(only.inst == -1)


def test_deleted_light_renders_as_never_added():
    s = row_scene()
    s.delete_light(s.light_slot("Key"))
    a = Session(s).render().radiance
    b = Session(row_scene(key_light=False)).render().radiance
    np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------------- apply


def test_apply_every_kind_and_report():
    s = row_scene()
    sess = Session(s)
    sess.render()
    cube2 = shapes.box((0.6, 0.6, 1.4), name="tall")
    rep = sess.apply([
        ObjectTransform("Cube0", shapes.transform((-2.0, 0.5, 0.5))),
        MaterialSet("red", Material("red", diffuse=(0.9, 0.2, 0.1))),
        ObjectMaterials("Cube1", ("red",)),
        MeshSet("tall", cube2),
        ObjectGeometry("Cube2", "tall"),
        ObjectAdd("Extra", "cube", shapes.transform((0.0, 2.0, 0.5)), ("grey",)),
        ObjectVisibility("Floor", True),
        LightSet("Key", Light("Key", "POINT", power=400.0, position=(-2.0, -3.0, 4.0))),
        LightSet("Fill", Light("Fill", "POINT", power=100.0, position=(2.0, -3.0, 3.0))),
        LightDelete("Sun"),
        WorldColor((0.1, 0.1, 0.2)),
    ])
    assert rep.edits == 11 and rep.kinds["LightSet"] == 2
    assert rep.regions == 3 and rep.apply_ms > 0 and not rep.camera_changed
    sc = sess.scene
    assert sc.instance_slot("Extra") == 4 and sc.instances[3]["mesh"] == sc.mesh_id("tall")
    assert sc.lights[sc.light_slot("Key")].power == 400.0
    assert sc.light_slot("Fill") == 2 and sc.lights[1] is None
    assert s.n_lights == 2 and s.instances[1]["materials"] == [0]  # the host's scene untouched
    rep = sess.apply([ObjectDelete("Extra"), CameraChange(shapes_camera(24, 18))])
    assert rep.camera_changed and rep.full_frame and sess.scene.instances[4] is None


@pytest.mark.parametrize("bad, msg", [
    (ObjectTransform("Cube1", np.full((4, 4), np.nan)), "Cube1.*NaN"),
    (ObjectTransform("Cube1", np.diag([1.0, 0.0, 1.0, 1.0])), "Cube1.*singular"),
    (ObjectTransform("Nobody", np.eye(4)), "Nobody.*unknown"),
    (ObjectAdd("Blob", "no_mesh", np.eye(4)), "Blob.*unknown mesh"),
    (ObjectMaterials("Cube1", ("no_such",)), "Cube1.*unknown material"),
    (MeshSet("cube", Mesh("cube", np.zeros((0, 3)), np.zeros((0, 3), np.int32))),
     "cube.*no triangles"),
    (LightSet("Key", Light("Key", "POINT", power=-5.0)), "Key.*power"),
    (LightDelete("Ghost"), "Ghost.*unknown"),
    (MaterialSet("grey", Material("grey", diffuse=(2.0, 0.0, 0.0))), "grey"),
])
def test_bad_edit_changes_nothing(bad, msg):
    s = row_scene()
    sess = Session(s)
    before = sess.render()
    scene_before = sess.scene
    good = ObjectTransform("Cube0", shapes.transform((-2.0, 1.0, 0.5)))
    with pytest.raises(SceneError, match=msg):
        sess.apply([good, bad])
    assert sess.scene is scene_before
    np.testing.assert_array_equal(sess.scene.instances[1]["matrix"],
                                  shapes.transform((-2.0, 0.0, 0.5)))
    again = sess.render()  # nothing is dirty: the same frame
    np.testing.assert_array_equal(again.radiance, before.radiance)
    assert again.stats["incremental"] and again.stats["dirty_pixels"] == 0


def test_update_scene_diffs_into_the_same_edits():
    old = row_scene()
    new = row_scene()
    new.set_instance_matrix(new.instance_slot("Cube2"), shapes.transform((2.0, 1.0, 0.5)))
    new.set_material(new.material_id("red"), Material("red", diffuse=(0.1, 0.8, 0.1)))
    new.set_instance_materials(new.instance_slot("Cube0"), [new.material_id("red")])
    new.delete_instance(new.instance_slot("Cube1"))
    new.add_instance(new.mesh_id("cube"), shapes.transform((0.0, 2.0, 0.5)), [0], name="Add")
    new.set_light(new.light_slot("Key"), Light("Key", "POINT", power=100.0,
                                                 position=(-2.0, -3.0, 4.0)))
    new.set_world_color((0.2, 0.2, 0.2))
    kinds = sorted(type(e).__name__ for e in diff_scenes(old, new))
    assert kinds == sorted(["ObjectTransform", "MaterialSet", "ObjectMaterials", "ObjectDelete",
                            "ObjectAdd", "LightSet", "WorldColor"])
    assert diff_scenes(new, new) == []
    applied, _ = apply_edits(old, diff_scenes(old, new))
    assert diff_scenes(applied, new) == []
    sess = Session(old)
    sess.light_terms = False  # the light edit takes the per-pixel records: incremental
    sess.render()
    sess.update_scene(new)
    assert sess.render().stats["incremental"]
    np.testing.assert_array_equal(sess.render().radiance, Session(new).render().radiance)
    broken = row_scene()
    broken.instances[1]["matrix"] = np.full((4, 4), np.nan)  # bypasses the checks on purpose
    broken.instances[1]["aabb"] = np.full((2, 3), np.nan)
    scene_before = sess.scene
    with pytest.raises(SceneError, match="Cube0"):
        sess.update_scene(broken)
    assert sess.scene is scene_before


def test_update_settings_keeps_the_session():
    sess = Session(row_scene(), RenderSettings(max_depth=1))
    a = sess.render()
    sess.update_settings(RenderSettings(max_depth=1, seed=3, samples=2))
    b = sess.render()
    assert not b.stats["incremental"] and a.radiance.shape == b.radiance.shape


def test_the_callers_arrays_are_copied():
    """A host that reuses (mutates) its matrix array must not change the scene behind the
    session's back: the next edit with the same array object is still an edit."""
    sess = Session(row_scene())
    sess.render()
    m = shapes.transform((-2.0, 0.0, 0.5))
    for _ in range(2):
        m[1, 3] += 0.3
        rep = sess.apply([ObjectTransform("Cube0", m)])
        assert rep.regions == 1 and rep.dirty_pixels > 0
        frame = sess.render()
        np.testing.assert_array_equal(frame.radiance,
                                      Session(sess.scene.copy()).render().radiance)


def test_host_changing_its_scene_object_is_a_diff():
    """A host that edits the very Scene object it gave the session, then hands it back."""
    s = row_scene()
    sess = Session(s)
    sess.render()
    s.set_instance_matrix(s.instance_slot("Cube2"), shapes.transform((2.0, 1.5, 0.5)))
    rep = sess.update_scene(s)
    assert rep.kinds == {"ObjectTransform": 1}
    np.testing.assert_array_equal(sess.render().radiance, Session(s).render().radiance)
