"""MeshDelete / MaterialDelete: a mesh or material no object uses any more leaves the session
(slot, packing, accelerator).

The incremental frame after the delete equals a fresh session's (BASE exactly, INTERPOLANT
within epsilon of the BASE frame); the slot is a tombstone reused by the next mesh; a delete
/ add loop keeps the scene, the packing and the BVH's per-mesh cache the same size. The
random edit sequences of ``test_incremental`` include ``mesh_delete`` too (every accelerator
and mode).
"""

from __future__ import annotations

import numpy as np
import pytest

from rstrace_engine import image
from rstrace_engine.bench.soak import SOAK_SCENES, EditGenerator
from rstrace_engine.frame import CLASS_INTERPOLATED, CLASS_REBUILT, RenderSettings
from rstrace_engine.geometry import shapes
from rstrace_engine.geometry.edits import (
    MaterialDelete,
    MaterialSet,
    MeshDelete,
    MeshSet,
    ObjectAdd,
    ObjectDelete,
    ObjectGeometry,
    ObjectMaterials,
    ObjectVisibility,
    diff_scenes,
)
from rstrace_engine.geometry.scene import Material, SceneError
from rstrace_engine.session import Session
from tests.test_edits import row_scene
from tests.test_incremental import check_base_step


def _with_ball(w=24, h=18):
    """row_scene plus a sphere mesh used by one object ("Ball"), mesh key "ball"."""
    s = row_scene(w, h)
    ball = s.add_mesh(shapes.icosphere(1, 0.5, name="ball"), key="ball")
    s.add_instance(ball, shapes.transform((0.0, -1.5, 0.5)), [0], name="Ball")
    return s


def test_mesh_delete_tombstones_and_reuses_the_slot():
    s = _with_ball()
    mid = s.mesh_id("ball")
    with pytest.raises(SceneError, match="ball.*still used by object 'Ball'"):
        s.delete_mesh(mid)
    s.set_instance_visible(s.instance_slot("Ball"), False)  # hidden still uses it
    with pytest.raises(SceneError, match="ball.*still used"):
        s.delete_mesh(mid)
    n_tris = len(s.arrays().tris)
    s.delete_instance(s.instance_slot("Ball"))
    s.delete_mesh(mid)
    assert s.meshes[mid] is None and "ball" not in s.mesh_keys.slot
    sa = s.arrays()
    assert sa.mesh_tri_start[mid] == sa.mesh_tri_start[mid + 1]  # no triangles left
    assert len(sa.tris) == n_tris - 80 and len(sa.verts) == sum(
        len(m["verts"]) for m in s.meshes if m is not None)
    with pytest.raises(SceneError, match="unknown key"):
        s.mesh_id("ball")
    with pytest.raises(SceneError, match="unknown mesh id"):
        s.add_instance(mid, np.eye(4), [0], name="Orphan")
    assert s.add_mesh(shapes.box((0.3, 0.3, 0.3), name="small"), key="small") == mid


@pytest.mark.parametrize("accelerator", ["BVH", "BRUTE_FORCE", "VISIBILITY_FIELD"])
def test_frame_after_a_mesh_delete_equals_a_fresh_one_base(accelerator):
    settings = RenderSettings(mode="BASE", max_depth=3, accelerator=accelerator)
    sess = Session(_with_ball(), settings)
    sess.render()
    rep = sess.apply([ObjectDelete("Ball"), MeshDelete("ball")])
    assert rep.kinds == {"ObjectDelete": 1, "MeshDelete": 1} and not rep.full_frame
    frame = sess.render()
    assert frame.stats["incremental"] and 0 < frame.stats["dirty_pixels"] < 24 * 18
    fresh = Session(sess.scene.copy(), settings).render()
    np.testing.assert_array_equal(frame.radiance, fresh.radiance)
    # a geometry swap leaving "cube" unused by the three cubes' last user
    sess.apply([ObjectGeometry(k, "floor") for k in ("Cube0", "Cube1", "Cube2")]
               + [MeshDelete("cube")])
    frame = sess.render()
    np.testing.assert_array_equal(frame.radiance,
                                  Session(sess.scene.copy(), settings).render().radiance)
    # the slot is reused by a new mesh, and its object renders as in a fresh session
    sess.apply([MeshSet("ball2", shapes.icosphere(1, 0.4, name="ball2")),
                ObjectAdd("Ball2", "ball2", shapes.transform((1.0, -1.5, 0.5)), ("grey",))])
    assert sess.scene.mesh_id("ball2") == 0  # "cube"'s slot, the lowest free one
    frame = sess.render()
    np.testing.assert_array_equal(frame.radiance,
                                  Session(sess.scene.copy(), settings).render().radiance)


def test_frame_after_a_mesh_delete_within_epsilon_interpolant(monkeypatch):
    from rstrace_engine.interpolants.render import InterpolantRenderer

    # cells wherever the rays need them (the measured fallback only traces: exact)
    monkeypatch.setattr(InterpolantRenderer, "auto_fallback", False)
    eps = 0.05
    settings = RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=3)
    base = RenderSettings(mode="BASE", max_depth=3)
    sess = Session(_with_ball(96, 72), settings)
    sess.render()
    sess.apply([ObjectDelete("Ball"), MeshDelete("ball")])
    frame = sess.render()
    assert frame.stats["incremental"]
    ref = Session(sess.scene.copy(), base).render()
    m = image.compare(frame.radiance, ref.radiance, eps)
    assert m["max_error"] <= eps + 1e-6, m
    traced = (frame.pixel_class != CLASS_INTERPOLATED) & (frame.pixel_class != CLASS_REBUILT)
    np.testing.assert_allclose(frame.radiance[traced], ref.radiance[traced], atol=1e-6)
    assert np.count_nonzero(frame.pixel_class == CLASS_INTERPOLATED) > 0


def test_refused_mesh_delete_changes_nothing():
    sess = Session(_with_ball())
    before = sess.scene
    for batch in ([MeshDelete("ball")], [ObjectVisibility("Ball", False), MeshDelete("ball")],
                  [MeshDelete("nothing")]):
        with pytest.raises(SceneError):
            sess.apply(batch)
        assert sess.scene is before


def test_update_scene_diffs_a_vanished_mesh_into_mesh_delete():
    old = _with_ball()
    new = _with_ball()
    new.delete_instance(new.instance_slot("Ball"))
    new.delete_mesh(new.mesh_id("ball"))
    edits = diff_scenes(old, new)
    assert [type(e).__name__ for e in edits] == ["ObjectDelete", "MeshDelete"]
    sess = Session(old)
    sess.render()
    sess.update_scene(new)
    assert "ball" not in sess.scene.mesh_keys.slot
    np.testing.assert_array_equal(sess.render().radiance, Session(new).render().radiance)


def test_delete_add_loop_does_not_grow():
    """Adding a new mesh + object and deleting both, many times: the scene's mesh list, the
    packing and the BVH's per-mesh cache stay the same size (nothing is kept for a mesh
    that left)."""
    settings = RenderSettings(mode="BASE", max_depth=2)
    sess = Session(row_scene(16, 12), settings)
    sess.render()
    sizes = []
    for k in range(60):
        key = f"m{k}"  # a new datablock every time, as Blender's session_uids are
        mesh = shapes.icosphere(1, 0.2 + 0.005 * k, name=key)
        sess.apply([MeshSet(key, mesh),
                    ObjectAdd(("o", k), key, shapes.transform((0.0, -1.5, 0.5)), ("grey",))])
        sess.render()
        sess.apply([ObjectDelete(("o", k)), MeshDelete(key)])
        sess.render()
        sa = sess.scene.arrays()
        sizes.append((len(sess.scene.meshes), len(sess.scene.instances), len(sa.verts),
                      len(sa.tris), len(sess.accel._cache)))
    assert len(set(sizes)) == 1, sizes[:3]
    # meshes: cube, floor and the free slot; objects: 4 and the free slot; packed: the
    # cube's 8 vertices / 12 triangles and the floor's 4 / 2; mesh BVHs: cube, floor and
    # the empty slot's
    assert sizes[0] == (3, 5, 8 + 4, 12 + 2, 3)


@pytest.mark.parametrize("scene_name", ["room", "tori"])
def test_random_edits_with_mesh_deletes_base_exact(scene_name):
    """The seeded random edit sequences (every kind) with mesh and material deletes mixed
    in."""
    settings = RenderSettings(mode="BASE", max_depth=3)
    gen = EditGenerator(SOAK_SCENES[scene_name](24, 18), seed=7,
                        extra=EditGenerator.EXTRA_KINDS)
    sess = Session(gen.scene.copy(), settings)
    prev = sess.render()
    for _ in range(32):
        sess.apply(gen.step())
        prev, _ = check_base_step(sess, prev, settings)
    assert gen.kinds_done.get("mesh_delete", 0) >= 1, gen.kinds_done
    assert gen.kinds_done.get("material_delete", 0) >= 1, gen.kinds_done


def test_material_delete_tombstones_and_reuses_the_slot():
    settings = RenderSettings(mode="BASE", max_depth=3)
    sess = Session(_with_ball(), settings)
    sess.render()
    with pytest.raises(SceneError, match="red.*still used by object 'Cube1'"):
        sess.apply([ObjectMaterials("Cube1", ("red",)), MaterialDelete("red")])
    sess.apply([ObjectMaterials("Cube1", ("red",))])
    sess.render()
    rep = sess.apply([ObjectMaterials("Cube1", ("grey",)), MaterialDelete("red")])
    assert rep.kinds == {"ObjectMaterials": 1, "MaterialDelete": 1}
    sc = sess.scene
    mid = 1  # "red"'s slot
    assert sc.materials[mid] is None and "red" not in sc.material_keys.slot
    frame = sess.render()
    assert frame.stats["incremental"]
    np.testing.assert_array_equal(frame.radiance,
                                  Session(sc.copy(), settings).render().radiance)
    with pytest.raises(SceneError, match="unknown material id"):
        sc.copy().add_instance(0, np.eye(4), [mid], name="Orphan")
    sess.apply([MaterialSet("blue", Material("blue", diffuse=(0.1, 0.1, 0.8))),
                ObjectMaterials("Cube2", ("blue",))])
    assert sess.scene.material_id("blue") == mid  # the free slot, reused
    np.testing.assert_array_equal(sess.render().radiance,
                                  Session(sess.scene.copy(), settings).render().radiance)
    old, new = sess.scene, sess.scene.copy()
    new.set_instance_materials(new.instance_slot("Cube2"), [0])
    new.delete_material(mid)
    assert [type(e).__name__ for e in diff_scenes(old, new)] == ["ObjectMaterials",
                                                                  "MaterialDelete"]


def test_random_edits_with_deletes_interpolant_within_epsilon():
    eps = 0.05
    settings = RenderSettings(mode="INTERPOLANT", epsilon=eps, max_depth=3)
    base = RenderSettings(mode="BASE", max_depth=3)
    gen = EditGenerator(SOAK_SCENES["spheres"](96, 72), seed=3, camera=False,
                        extra=EditGenerator.EXTRA_KINDS)
    sess = Session(gen.scene.copy(), settings)
    sess.render()
    for _ in range(16):
        sess.apply(gen.step())
        frame = sess.render()
        ref = Session(sess.scene.copy(), base).render()
        m = image.compare(frame.radiance, ref.radiance, eps)
        assert m["max_error"] <= eps + 1e-6, (gen.kinds_done, m)
    assert gen.kinds_done.get("mesh_delete", 0) + gen.kinds_done.get("material_delete", 0)
