"""Depsgraph -> edits: what changed in Blender since the scene's core session was last
told, as :mod:`rstrace_engine.geometry.edits` edits (used by :mod:`.sync`).

:class:`SceneMirror` mirrors what the scene's core session holds (per key: objects, meshes,
materials, lights, world; not the camera, which each render names). A sync walks the
depsgraph into a snapshot (:func:`export.read_scene`, which re-reads only the datablocks the
updates name) and diffs it against the mirror:

* a moved, rotated or scaled object -> ``ObjectTransform``; new mesh data -> ``MeshSet``
  (that mesh only, read with ``foreach_get``); another mesh -> ``ObjectGeometry``; other
  material slots -> ``ObjectMaterials``; a changed material -> ``MaterialSet``; a light's
  data or transform -> ``LightSet``; the world -> ``WorldColor``;
* an object, instance or light that appears -> ``ObjectAdd`` / ``LightSet`` (collection
  links, instancers, geometry-node instances, duplicates, undo of a delete);
* one that vanishes -> ``ObjectVisibility(False)`` while the object still exists (hidden,
  excluded, unlinked: it may come back cheaply), else ``ObjectDelete`` / ``LightDelete``;
* a mesh or material no object (shown or hidden) uses any more -> ``MeshDelete`` /
  ``MaterialDelete``, after the object edits (its last user deleted, re-meshed or given
  other materials): the session frees it and the export cache drops it once the sync is
  committed (an undo reads it again).
  Deleted objects never appear in ``depsgraph.updates``: the mirror's key set is diffed
  against ``depsgraph.object_instances``.

Updates that cannot change the image are not edits: :func:`dirty_from_updates` returns None
for a batch holding only flag-less Scene updates (selection, colour management, frame and
other scene-only settings), so nothing is walked and nothing re-renders; anything else is
walked and yields edits only where the snapshot really differs (a shading flag from a
viewport display setting diffs to nothing).

Keys are ``session_uid``s (see :mod:`.export`), which survive undo and redo; no Blender ID is
held between syncs. The mirror changes only when :func:`.sync.sync` commits a diff (once
the session holds its edits); :meth:`SceneMirror.reset` forgets everything (the session was
dropped).

Layer: imports ``export`` and ``materials`` (no sync, session, viewport, engine or ui).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from rstrace_engine.geometry import edits as E
from rstrace_engine.geometry.scene import Material

from . import export
from .materials import image_changed

log = logging.getLogger(__name__)

#: ID types whose updates mean "re-read every material" (node groups, images, textures).
_ALL_MATERIALS = {"ShaderNodeTree", "GeometryNodeTree", "NodeTree", "Image", "Texture"}
#: ID types that never change what is rendered.
_IGNORED = {"WindowManager", "Screen", "WorkSpace", "Brush", "Palette", "Text", "Sound",
            "Library", "Workspace", "PaintCurve", "Mask", "MovieClip", "Speaker"}


def dirty_from_updates(updates) -> export.Dirty | None:
    """What a batch of ``depsgraph.updates`` may have changed; None when nothing.

    Objects with a geometry flag, mesh datablocks and materials are listed so that only
    those are re-read; node groups and images mark every material; the objects named are
    kept (``updated``) so that a batch that cannot have changed the set of instances reads
    just them. ``walk`` (the whole depsgraph is read) is set by what Blender sends for a
    change of the instance set, checked in bpy (``tests/blender/test_sync_cost.py``): a
    deletion comes as a Scene (and Collection) update with transform and geometry flags;
    an addition, a duplicate, (un)linking, hiding from renders or in the viewport and undo
    as a Collection update; excluding a collection or swapping an object's data as a
    flag-less Scene update *together with* object updates. A flag-less Scene update alone
    is a selection, colour management or another scene-only setting (or the eye icon's
    hide, which :meth:`SceneMirror.dirty` tells apart), and is no edit. Node groups and
    images (every material re-read) walk too. A material's, world's or light's own node
    tree (embedded data) comes with its owner and adds nothing.
    """
    dirty = export.Dirty()
    seen = scene_flagless = False
    data_of_objects: set = set()
    for u in updates:
        idb = u.id
        kind = type(idb).__name__
        if kind == "Scene":
            if u.is_updated_transform or u.is_updated_geometry:
                dirty.walk = seen = True
            else:
                scene_flagless = True
            continue
        if kind in _IGNORED or getattr(idb, "is_embedded_data", False):
            continue
        orig = idb.original
        uid = orig.session_uid
        seen = True
        if kind == "Object":
            dirty.updated[uid] = idb
            if u.is_updated_geometry:
                dirty.objects.add(uid)
            elif not u.is_updated_transform:
                dirty.shading_only.add(uid)
            if orig.data is not None:
                data_of_objects.add(orig.data.session_uid)
        elif kind == "Collection":
            dirty.walk = True
        elif kind == "Material":
            dirty.materials.add(uid)
            dirty.material_ids[uid] = idb
        elif kind in _ALL_MATERIALS or kind.endswith("NodeTree"):
            dirty.all_materials = dirty.walk = True
            if kind == "Image":
                image_changed(uid)
        elif u.is_updated_geometry:
            dirty.data.add(uid)  # Mesh, Curve, light data, ...
    if not seen:
        return None
    if scene_flagless or dirty.data - data_of_objects:
        dirty.walk = True  # (data whose users are not named: read them all)
    return dirty


def visibility_signature(depsgraph) -> frozenset:
    """session_uids of the view layer's objects hidden in the viewport (the eye icon, local
    view, hidden collections): a hide or unhide (H / Alt+H) sends only a flag-less Scene
    update, like a selection."""
    vl = depsgraph.view_layer
    return frozenset(ob.session_uid for ob in vl.objects if not ob.visible_get(view_layer=vl))


@dataclass
class MirrorDiff:
    """The edits of one sync and what the mirror becomes once the session holds them."""

    edits: list
    snapshot: export.Snapshot | None
    stats: dict = field(default_factory=dict)
    _mirror: dict | None = None


class SceneMirror:
    """The add-on side of one scene's session: export caches, the mirror of what the
    session holds, and the diff of a snapshot against it into edits."""

    def __init__(self) -> None:
        self.cache = export.ExportCache()
        #: False: walk every instance on every update (the cost before read_updated; for
        #: scripts/sync_bench.py's comparison)
        self.partial = True
        self.reset()

    def reset(self) -> None:
        """Forget what the session holds (it was dropped); the caches stay valid."""
        self.objects: dict[Hashable, export.ObjectRecord] = {}
        self.invisible: dict[Hashable, export.ObjectRecord] = {}
        self.meshes: dict[Hashable, object] = {}  # key -> the Mesh object last sent
        self.materials: dict[Hashable, Material] = {}
        self.lights: dict = {}
        self.world: tuple | None = None  # (colour, whether it lights surfaces)
        self.instancers: set = set()  # uids of objects making instances (last walk)
        self.instanced: set = set()  # uids of objects appearing as instances (last walk)
        self.hidden_in_view: frozenset | None = None  # visibility_signature (last walk)
        self.synced = False

    # -- syncing ---------------------------------------------------------------------

    def dirty(self, depsgraph) -> export.Dirty | None:
        """What ``depsgraph.updates`` may have changed (:func:`dirty_from_updates`); a batch
        that says nothing is still checked for a viewport hide (the eye icon), which
        Blender sends as a flag-less Scene update alone, like a selection."""
        dirty = dirty_from_updates(depsgraph.updates)
        if dirty is None and self.synced and self.hidden_in_view is not None:
            sig = visibility_signature(depsgraph)
            if sig != self.hidden_in_view:
                dirty = export.Dirty(walk=True)
        return dirty

    def read(self, depsgraph, dirty: export.Dirty | None, source: str, **kwargs
             ) -> export.Snapshot:
        """Read what ``dirty`` names (:func:`export.read_updated`) where the updates cannot
        have changed the set of instances, else walk ``depsgraph`` (see
        :func:`export.read_scene`); on a never-synced mirror ``dirty`` is ignored
        (everything unknown is read)."""
        cancel, progress = kwargs.pop("cancel", None), kwargs.pop("progress", None)
        if self._partial_ok(dirty, kwargs):
            snap = export.read_updated(depsgraph, self.cache, dirty, self.objects,
                                       self.lights, source)
            if snap is not None:
                return snap
        snap = export.read_scene(depsgraph, self.cache, dirty if self.synced else None,
                                 source=source, cancel=cancel, progress=progress, **kwargs)
        if source == "VIEWPORT":
            snap.hidden_in_view = visibility_signature(depsgraph)
        return snap

    def _partial_ok(self, dirty: export.Dirty | None, kwargs) -> bool:
        """True when the updates cannot have changed the set of instances: every object
        they name is a plain mesh object or light the session holds (or an object with
        nothing to render, whose children the updates name themselves), none makes
        instances or appears as one."""
        if (not self.partial or not self.synced or dirty is None or dirty.walk
                or kwargs.get("with_camera", True)):
            return False
        for uid, ob in dirty.updated.items():
            if uid in self.instancers or uid in self.instanced or ob.is_instancer:
                return False
            kind = ob.type
            if kind == "MESH":
                if uid not in self.objects or any(
                        m.type in ("NODES", "PARTICLE_SYSTEM") for m in ob.modifiers):
                    return False
            elif kind == "LIGHT":
                if uid not in self.lights:
                    return False
            elif kind not in ("EMPTY", "CAMERA"):
                return False
        return True

    def diff(self, snap: export.Snapshot, exists=None) -> MirrorDiff:
        """Edits turning the mirror into ``snap`` (its camera aside).

        exists() -> set of session_uids of objects still in the file (asked only when some
        object vanished), to tell hidden from deleted.
        """
        t0 = time.perf_counter()
        out: list = []
        cache = self.cache
        meshes, materials = dict(self.meshes), dict(self.materials)
        partial = snap.changed is not None  # (read_updated: only these keys were read)
        read = snap.objects if not partial else {
            k: snap.objects[k] for k in snap.changed if k in snap.objects}
        for mk in snap.changed_materials:  # (partial: re-read without their users)
            mat = cache.material(mk)
            if mk in materials and materials[mk] is not mat:
                if not E.same_material(materials[mk], mat):
                    out.append(E.MaterialSet(mk, mat))
                materials[mk] = mat
        for rec in read.values():
            mesh = cache.mesh(rec.mesh_key)
            if meshes.get(rec.mesh_key) is not mesh:
                meshes[rec.mesh_key] = mesh
                out.append(E.MeshSet(rec.mesh_key, mesh))
            for mk in rec.material_keys:
                mat = cache.material(mk)
                if materials.get(mk) is not mat:
                    if not E.same_material(materials.get(mk), mat):
                        out.append(E.MaterialSet(mk, mat))
                    materials[mk] = mat
        objects = dict(snap.objects)
        invisible = dict(self.invisible)
        for key, rec in read.items():
            old = self.objects.get(key)
            if old is None and key in invisible:
                old = invisible.pop(key)
                out.append(E.ObjectVisibility(key, True))
            if old is None:
                out.append(E.ObjectAdd(key, rec.mesh_key, rec.matrix, rec.material_keys,
                                       name=rec.name))
                continue
            if old.mesh_key != rec.mesh_key:
                out.append(E.ObjectGeometry(key, rec.mesh_key))
            if old.material_keys != rec.material_keys:
                out.append(E.ObjectMaterials(key, rec.material_keys))
            if not np.array_equal(old.matrix, rec.matrix):
                out.append(E.ObjectTransform(key, rec.matrix))
        gone = [] if partial else [k for k in self.objects if k not in objects]
        alive = None
        if gone or (invisible and not partial):
            alive = exists() if exists is not None else set()
        for key in gone:
            if key in snap.hidden or (not isinstance(key, tuple) and key in alive):
                invisible[key] = self.objects[key]
                out.append(E.ObjectVisibility(key, False))
            else:
                out.append(E.ObjectDelete(key))
        for key in [] if partial else [k for k in invisible if k not in snap.hidden and not (
                not isinstance(k, tuple) and k in alive)]:
            del invisible[key]
            out.append(E.ObjectDelete(key))
        # meshes and materials no object (shown or hidden) uses any more leave the session
        # and the export cache (the last user deleted, re-meshed or given other materials;
        # an undo reads them again)
        freed, freed_mats = [], []
        kept = [r for r in (*objects.values(), *invisible.values())]
        if not partial or any(self.objects[k].mesh_key != r.mesh_key for k, r in read.items()
                              if k in self.objects):
            used = {r.mesh_key for r in kept}
            freed = [k for k in meshes if k not in used]
        if not partial or any(self.objects[k].material_keys != r.material_keys
                              for k, r in read.items() if k in self.objects):
            used = {mk for r in kept for mk in r.material_keys}
            freed_mats = [k for k in materials if k not in used]
        for key in freed:
            del meshes[key]
            out.append(E.MeshDelete(key))
        for key in freed_mats:
            del materials[key]
            out.append(E.MaterialDelete(key))
        for key, light in snap.lights.items():
            if self.lights.get(key) != light:
                out.append(E.LightSet(key, light))
        out += [E.LightDelete(k) for k in self.lights if k not in snap.lights]
        world = (snap.world, snap.world_lights)
        if world != self.world:
            out.append(E.WorldColor(snap.world, lights=snap.world_lights))
        mirror = dict(objects=objects, invisible=invisible, meshes=meshes, freed=freed,
                      freed_materials=freed_mats,
                      walk=None if partial else (snap.instancers, snap.instanced,
                                                 snap.hidden_in_view),
                      materials=materials, lights=dict(snap.lights), world=world)
        kinds: dict = {}
        for e in out:
            kinds[type(e).__name__] = kinds.get(type(e).__name__, 0) + 1
        stats = dict(snap.stats, edits=len(out), edit_kinds=kinds,
                     diff_seconds=time.perf_counter() - t0)
        return MirrorDiff(out, snap, stats, mirror)

    def commit(self, result: MirrorDiff) -> None:
        """The session now holds ``result`` (applied or queued): the mirror follows."""
        m = result._mirror
        if m is None:
            return
        self.objects, self.invisible = m["objects"], m["invisible"]
        self.meshes, self.materials = m["meshes"], m["materials"]
        for key in m["freed"]:
            self.cache.meshes.pop(key, None)
        for key in m["freed_materials"]:
            if key != export.DEFAULT_MATERIAL_KEY:  # (made once, never read from Blender)
                self.cache.materials.pop(key, None)
        if m["freed_materials"]:
            self._drop_unused_textures()
        if m["walk"] is not None:
            self.instancers, self.instanced, sig = m["walk"]
            if sig is not None:  # (a viewport walk; F12's render depsgraph has none)
                self.hidden_in_view = sig
        self.lights, self.world = m["lights"], m["world"]
        self.synced = True

    def _drop_unused_textures(self) -> None:
        """Forget the cached pixels of images no cached material holds any more."""
        held = {k for e in self.cache.materials.values() for k in e.images}
        textures = self.cache.textures
        for key in [k for k in textures if k not in held]:
            del textures[key]

    def scene(self, snap: export.Snapshot, cancel=None):
        """A whole :class:`Scene` for ``snap`` (a new session; ``cancel``: a
        :class:`~rstrace_engine.cancel.CancelFlag` its meshes' checks poll)."""
        return export.build_scene(snap, self.cache, cancel=cancel)


def existing_objects() -> set:
    """session_uids of every object in the file (to tell hidden from deleted)."""
    import bpy

    return {ob.session_uid for ob in bpy.data.objects}
