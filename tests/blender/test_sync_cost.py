"""A small edit costs what it touched: the viewport sync walks ``depsgraph.object_instances``
only when the updates can have changed the set of instances, and otherwise re-reads just
the objects they name (``export.read_updated``). The walk is counted, not timed
(``scripts/sync_bench.py`` times it on 2,000 objects).

Checked here in bpy, on a scene of many linked duplicates: what each change sends and
whether it walks -- a move, a light's power and a material colour never walk; a deletion,
an addition, the eye icon's hide (a flag-less Scene update alone, like a selection), a
collection unlink, an excluded collection and undo always do, and give the right edits.
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from . import builders as b

N_OBJECTS = 300


@pytest.fixture
def big():
    """N_OBJECTS linked duplicates of one small sphere (one material), a light, a camera;
    a SceneMirror fed by depsgraph_update_post as view_update feeds it; walks counted."""
    import addon

    b.setup_render(32, 24)
    mat = b.principled("Grey", (0.6, 0.6, 0.6))
    me = b.uv_sphere("Ball", 0.2, 8, 4)
    me.materials.append(mat)
    for k in range(N_OBJECTS):
        b.add_object(f"Ball{k}", me, (0.5 * (k % 20), 0.5 * (k // 20), 0.2))
    b.point_light("Key", (0.0, -4.0, 6.0), 800.0)
    b.camera((5.0, -12.0, 8.0), (5.0, 4.0, 0.0))
    bpy.context.view_layer.update()

    walks = [0]

    class Sync:
        @property
        def walks(self):
            return walks[0]

        def __init__(self):
            self.sync = addon.depsgraph_diff.SceneMirror()
            self.batches = []
            self.stats = []
            self._sync(bpy.context.evaluated_depsgraph_get(), None)
            bpy.app.handlers.depsgraph_update_post.append(self.handler)

        def _sync(self, dg, dirty):
            snap = self.sync.read(dg, dirty, "VIEWPORT", with_camera=False)
            result = self.sync.diff(snap, exists=addon.depsgraph_diff.existing_objects)
            self.sync.commit(result)
            self.stats.append(result.stats)
            return result.edits

        def handler(self, _scene, dg):
            dirty = self.sync.dirty(dg)
            self.batches.append([] if dirty is None else self._sync(dg, dirty))

        def step(self, change):
            """Make a change; (edit kinds, edits, walks it caused, objects re-read)."""
            n, w, s = len(self.batches), self.walks, len(self.stats)
            change()
            bpy.context.view_layer.update()
            out = [e for batch in self.batches[n:] for e in batch]
            read = sum(st.get("objects_read", 0) for st in self.stats[s:])
            return sorted(type(e).__name__ for e in out), out, self.walks - w, read

    real = addon.export.read_scene

    def counted(*args, **kwargs):
        walks[0] += 1
        return real(*args, **kwargs)

    addon.export.read_scene = counted
    try:
        yield Sync(), mat
    finally:
        addon.export.read_scene = real


def test_a_move_in_a_big_scene_reads_one_object(big):
    s, mat = big
    assert s.walks == 1  # the first sync reads everything
    ob = bpy.data.objects["Ball7"]
    kinds, out, walks, read = s.step(lambda: setattr(ob.location, "z", 0.6))
    assert kinds == ["ObjectTransform"] and walks == 0 and read == 1
    assert out[0].key == ob.session_uid
    np.testing.assert_allclose(out[0].matrix, np.array(ob.matrix_world))
    lamp = bpy.data.objects["Key"]
    kinds, out, walks, read = s.step(lambda: setattr(lamp.data, "energy", 400.0))
    assert kinds == ["LightSet"] and walks == 0 and read == 1
    # a colour: one MaterialSet; Blender names every user of the material (shading flag
    # only), whose assignments cannot have changed: the material alone is re-read
    bsdf = mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"]
    kinds, out, walks, read = s.step(lambda: setattr(bsdf, "default_value",
                                                     (0.9, 0.2, 0.1, 1)))
    assert kinds == ["MaterialSet"] and walks == 0 and read == 0
    assert out[0].key == mat.session_uid and out[0].material.diffuse[0] > 0.5
    # a material assignment comes with a Scene update: a walk, and ObjectMaterials
    other = b.principled("Other", (0.1, 0.1, 0.9))
    kinds, _, walks, _ = s.step(lambda: setattr(ob, "active_material", other))
    assert "MaterialSet" in kinds and walks == 1
    # a selection: nothing at all
    assert s.step(lambda: ob.select_set(True))[::2] == ([], 0)


def test_changes_of_the_instance_set_walk(big):
    s, _ = big
    sc = bpy.context.scene
    victim = bpy.data.objects["Ball3"]
    uid = victim.session_uid
    bpy.ops.ed.undo_push(message="before")
    kinds, out, walks, _ = s.step(lambda: bpy.data.objects.remove(victim))
    assert kinds == ["ObjectDelete"] and out[0].key == uid and walks == 1
    bpy.ops.ed.undo_push(message="deleted")
    kinds, out, walks, _ = s.step(lambda: b.add_object("Box", b.grid("BoxMesh", 1.0),
                                                        (0, 0, 2.0)))
    assert "ObjectAdd" in kinds and walks == 1
    ob = bpy.data.objects["Ball9"]
    # the eye icon (H): Blender sends a flag-less Scene update alone, as for a selection
    kinds, out, walks, _ = s.step(lambda: ob.hide_set(True))
    assert kinds == ["ObjectVisibility"] and not out[0].visible and walks == 1
    kinds, out, walks, _ = s.step(lambda: ob.hide_set(False))
    assert kinds == ["ObjectVisibility"] and out[0].visible and walks == 1
    # unlinked from the scene (the object still exists): hidden, not deleted
    other = bpy.data.objects["Ball11"]
    kinds, out, walks, _ = s.step(lambda: sc.collection.objects.unlink(other))
    assert kinds == ["ObjectVisibility"] and walks == 1
    # an excluded collection: a flag-less Scene update with object updates
    coll = bpy.data.collections.new("Props")
    sc.collection.children.link(coll)
    coll.objects.link(bpy.data.objects["Ball12"])
    sc.collection.objects.unlink(bpy.data.objects["Ball12"])
    bpy.context.view_layer.update()
    lc = bpy.context.view_layer.layer_collection.children["Props"]
    kinds, _, walks, _ = s.step(lambda: setattr(lc, "exclude", True))
    assert kinds == ["ObjectVisibility"] and walks == 1
    # undo back to before the delete: the deleted ball returns
    kinds, out, walks, _ = s.step(lambda: bpy.ops.ed.undo())
    assert walks >= 1 and uid in {e.key for e in out if type(e).__name__ == "ObjectAdd"}
    # after all that, a move still reads one object
    ob = bpy.data.objects["Ball20"]
    kinds, _, walks, read = s.step(lambda: setattr(ob.location, "x", 3.3))
    assert kinds == ["ObjectTransform"] and walks == 0 and read == 1
