"""Evaluated depsgraph -> a :class:`Snapshot` of the scene, with per-datablock caches.

One pass over ``depsgraph.object_instances`` (:func:`read_scene`) reads every object's key,
world matrix and material keys, and reads a mesh (``meshes.mesh_arrays``) or a material
(``materials.MaterialReader``) only when its cache entry is missing or stale: the caller
says which datablocks changed (:class:`Dirty`, from ``depsgraph.updates``), or, where no
updates are known (F12, animation frames), a mesh is taken from the cache where the
journal (:mod:`.journal`) says nothing can have changed it since it was read, and else
re-read only when its raw-attribute fingerprint changed (the fingerprint and the read
share the arrays: each is read once). Lights and the world colour are re-read every time
(a few values).
Where the updates cannot have changed the set of instances (an object moved, a material or
a light changed), :func:`read_updated` re-reads only the objects they name, so that a small
edit in a big scene costs what it touched (the caller, :class:`.depsgraph_diff.SceneMirror`,
decides).

Keys are stable across updates and undo: ``id.original.session_uid`` for objects and
materials; ``(instancer uid, persistent_id)`` for instances; meshes by the key of the data
they come from (``("data", mesh uid)`` for an unmodified mesh object, shared by its linked
duplicates; ``("obj", object uid)`` for an object whose modifiers make its own mesh;
``("inst", instancer uid, persistent_id)`` for geometry made by an instancer). No ID
reference outlives the pass.

:func:`build_scene` turns a snapshot and the caches into a :class:`Scene` (keys given where
the scene takes them); :func:`export_scene` is the one-shot export of a whole depsgraph.
Anything the renderer cannot represent is noted (:class:`Notes`), never silently dropped.

Layer: imports ``materials``, ``meshes``, ``lights``, ``cameras`` (no session, engine, ui).
"""

from __future__ import annotations

import time
from collections.abc import Hashable
from contextlib import contextmanager
from types import SimpleNamespace

import numpy as np

from rstrace_engine import tolerances as tol
from rstrace_engine.geometry.mesh_math import proper_triangles
from rstrace_engine.geometry.scene import (
    MAX_LIGHTS,
    TEX_GENERATED,
    Light,
    SceneError,
    check_matrix,
)

from . import journal
from .cameras import camera_from_object
from .lights import read_light, world_colour, world_lights
from .materials import MaterialReader, Notes, default_material
from .meshes import mesh_fingerprint, read_mesh, same_mesh
from .snapshot import (
    DEFAULT_MATERIAL_KEY,
    Dirty,
    ExportCache,
    Exported,
    MaterialEntry,
    MeshEntry,
    ObjectRecord,
    Snapshot,
    build_scene,
)

#: Object types whose evaluated geometry arrives as MESH instances in ``object_instances``
#: (so the object itself is skipped), and types with nothing to render.
_MESH_VIA_INSTANCES = {"CURVE", "SURFACE", "FONT", "META"}
_NOTHING_TO_RENDER = {"EMPTY", "CAMERA", "ARMATURE", "LATTICE", "SPEAKER", "LIGHT_PROBE"}

#: What the tracer does not model, said once per render where the scene has it: an emissive
#: mesh is not a light source (its light would have to be sampled like an area light's over
#: its triangles, and the interpolants' predicate bounds only lights it knows the extent of).
#: The world's uniform colour does light surfaces (sampled with occlusion, as Cycles' world).
NOT_MODELLED_EMISSION = ("emissive objects are seen directly and in mirrors but light no "
                         "other surface (emissive meshes are not light sources)")

# ----------------------------------------------------------------------------- keys


def object_key(inst) -> Hashable:
    """The stable key of an entry of ``depsgraph.object_instances``."""
    if inst.is_instance and inst.parent is not None:
        return (inst.parent.original.session_uid, tuple(inst.persistent_id))
    return inst.object.original.session_uid


def _mesh_key(inst, ob) -> Hashable:
    orig = ob.original
    parent = inst.parent.original if inst.is_instance and inst.parent is not None else None
    if parent is not None and orig == parent:  # geometry made by the instancer itself
        return ("inst", parent.session_uid, tuple(inst.persistent_id))
    if orig.type == "MESH" and orig.data is not None and len(orig.modifiers) == 0:
        return ("data", orig.data.session_uid)
    return ("obj", orig.session_uid)


def instance_name(inst) -> str:
    ob = inst.object
    if inst.is_instance and inst.parent is not None:
        return f"{inst.parent.name}/{ob.name}"
    return ob.name


def _matrix(m) -> np.ndarray:
    """A mathutils 4x4 matrix as a float64 array (a copy: instance matrices are transient)."""
    return np.array(m, dtype=np.float64)


# ----------------------------------------------------------------------------- reading


def render_size(render) -> tuple[int, int]:
    """Blender's output size: resolution x percentage (at least one pixel)."""
    pct = render.resolution_percentage
    return (max(1, render.resolution_x * pct // 100), max(1, render.resolution_y * pct // 100))


NO_FACES = "has no faces"


#: Triangles tested first for an area: a mesh with one is accepted without testing the rest
#: (the core drops its degenerate triangles, and says how many, when it builds the scene).
_AREA_PROBE = 4096


def _has_area(v: np.ndarray, tris: np.ndarray) -> bool:
    """Whether any triangle has an area (the core's test, ``proper_triangles``), testing
    the first :data:`_AREA_PROBE` triangles before the rest: on their own vertices only
    (the same float64 values, so the same answers; the core's test converts every vertex
    it is given to float64)."""
    probe = tris[:_AREA_PROBE]
    corners = v[probe.reshape(-1)]
    if np.any(proper_triangles(corners, np.arange(len(corners), dtype=np.int32)
                               .reshape(-1, 3))):
        return True
    return len(tris) > _AREA_PROBE and bool(np.any(proper_triangles(v, tris[_AREA_PROBE:])))


class Cancelled(Exception):  # noqa: N818 (a request, not an error)
    """The user cancelled (Esc) while meshes were being read: nothing was committed."""


def _read_mesh(me, name: str, source: str, fingerprint: bytes | None = None,
               raw: dict | None = None) -> MeshEntry:
    """Read ``me`` once (its fingerprint from the same arrays, unless given, hashed beside
    the read: :func:`.meshes.read_mesh`; ``raw``: the raw arrays already read for it)."""
    raw = {} if raw is None else raw
    mesh, fingerprint = read_mesh(me, name, raw, fingerprint)
    entry = _checked(mesh, name, fingerprint, source)
    entry.vertex_count = len(me.vertices)
    return entry


def _checked(mesh, name: str, fingerprint: bytes, source: str) -> MeshEntry:
    if mesh is None:
        return MeshEntry(None, f"its mesh '{name}' {NO_FACES}", fingerprint, source)
    v = mesh.vertices
    # (numpy's min and max: two passes, no temporaries; NaN or infinity reach them)
    lo, hi = float(v.min()), float(v.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return MeshEntry(None, f"mesh '{name}': NaN or infinite vertex coordinates",
                         fingerprint, source)
    if max(-lo, hi) > tol.COORD_MAX:
        return MeshEntry(None, f"mesh '{name}': vertex coordinates exceed {tol.COORD_MAX:g}",
                         fingerprint, source)
    if not _has_area(v, mesh.triangles):
        return MeshEntry(None, f"mesh '{name}': all {len(mesh.triangles)} triangles are "
                         f"degenerate (zero area)", fingerprint, source)
    return MeshEntry(mesh, None, fingerprint, source)


class _Reader:
    """One pass over a depsgraph, filling a :class:`Snapshot` from the caches."""

    def __init__(self, cache: ExportCache, dirty: Dirty | None, source: str,
                 depsgraph=None, cancel=None, progress=None) -> None:
        self.cache = cache
        self.dirty = dirty
        self.source = source
        self.cancel = cancel  # () -> bool: stop between meshes (Cancelled)
        self.progress = progress  # (message) -> None: what is being read
        # what journal.Journal.trusted compares: the stamp reads get, the render's view
        # and frame
        self.stamp = journal.JOURNAL.stamp()
        self.view = self.frame = None
        self.view_layer = getattr(depsgraph, "view_layer", None)
        if depsgraph is not None:
            sc = depsgraph.scene
            self.view = (sc.original.session_uid, depsgraph.view_layer.name)
            self.frame = (int(sc.frame_current), float(sc.frame_subframe))
        # (on the main thread, a render of the window's own view layer only: another
        # scene's or layer's depsgraph may hold updates not yet reported)
        ctx = journal.context_view()
        self.journal = (dirty is None and self.view is not None and journal.listening()
                        and (ctx is None or ctx == self.view))
        self.meshes_trusted = 0
        self.notes = Notes()
        self.mesh_by_pointer: dict[int, Hashable] = {}
        # an Edit Mode object's conversion, read once per walk (:func:`_edit_mode_read`)
        self.edit_reads: dict[int, _EditRead] = {}
        self.depsgraph = depsgraph
        self.materials_seen: set = set()
        self.meshes_read = 0
        self.materials_read = 0
        self.t_mesh = 0.0
        # the view layer's material override: every slot of every mesh uses it (Cycles)
        layer = getattr(depsgraph, "view_layer", None)
        self.override = getattr(layer, "material_override", None)

    def material_key(self, mat) -> Hashable:
        if mat is None:
            return DEFAULT_MATERIAL_KEY
        key = mat.original.session_uid
        if key in self.materials_seen:
            return key
        self.materials_seen.add(key)
        entry = self.cache.materials.get(key)
        d = self.dirty
        if entry is None or d is None or d.all_materials or key in d.materials:
            notes = Notes()
            reader = MaterialReader(None, notes, self.cache.model, textures=self.cache.textures)
            try:
                material = reader.read(mat).validated()
            except SceneError as exc:  # conversion produced something invalid: say so
                notes.warn(f"material unusable, rendered with the default ({exc})", mat.name)
                material = default_material(self.cache.model).validated()
            entry = MaterialEntry(material, notes.recorded(), frozenset(reader.images),
                                  frozenset(reader.uv_maps), holdout=reader.holdout)
            self.cache.materials[key] = entry
            self.materials_read += 1
        self.notes.replay(entry.notes)
        return key

    def mesh_key(self, inst, ob, me) -> Hashable | None:
        """The key of ``me`` (evaluated), reading it if its cache entry is stale."""
        pointer = me.as_pointer()
        key = self.mesh_by_pointer.get(pointer)
        if key is not None:
            return key
        key = _mesh_key(inst, ob)
        self.mesh_by_pointer[pointer] = key
        entry = self.cache.meshes.get(key)
        d = self.dirty
        fingerprint = None
        raw: dict = {}  # raw arrays the fingerprint read, not read again by the mesh read
        stale = entry is None
        if not stale and key[0] != "data" and entry.source != self.source:
            stale = True  # modifiers may evaluate differently for viewport and render
        if not stale and d is not None:
            orig = ob.original
            stale = (orig.session_uid in d.objects or (orig.data is not None and
                     orig.data.session_uid in d.data) or (inst.parent is not None and
                     inst.parent.original.session_uid in d.objects))
        t0 = time.perf_counter()
        if not stale and d is None:
            if self.journal and self._unchanged(entry, key, inst, ob, me):
                self.meshes_trusted += 1
            else:  # updated since it was read, or the journal cannot say: the exact check
                # (an update need not change it: a linked duplicate added tags the mesh)
                fingerprint = mesh_fingerprint(me, raw)
                stale = fingerprint != entry.fingerprint
            if not stale:
                entry.stamp, entry.frame = self.stamp, self.frame
        if stale:
            if self.cancel is not None and self.cancel():
                raise Cancelled
            if self.progress is not None:
                self.progress(f"reading mesh '{me.name}' ({len(me.polygons):,} faces)")
            new = _read_mesh(me, me.name, self.source, fingerprint, raw)
            if entry is not None and entry.mesh is not None and same_mesh(entry.mesh,
                                                                          new.mesh):
                new.mesh = entry.mesh  # unchanged content: the session needs no MeshSet
            new.stamp, new.frame = self.stamp, self.frame
            self.cache.meshes[key] = new
            self.meshes_read += 1
        self.t_mesh += time.perf_counter() - t0
        return key

    def _unchanged(self, entry: MeshEntry, key, inst, ob, me) -> bool:
        """The journal's word that the mesh of ``entry`` is unchanged since it was read
        (see :mod:`.journal` for what it relies on)."""
        orig = ob.original
        uids = [orig.session_uid]
        static = False
        if key[0] == "data":
            data = orig.data
            uids.append(data.session_uid)
            static = data.shape_keys is None and data.animation_data is None
        if inst.parent is not None:
            uids.append(inst.parent.original.session_uid)
        j = journal.JOURNAL
        return (j.trusted(entry.stamp, entry.frame, self.view, static, self.frame)
                and not j.touched(entry.stamp, uids)
                and len(me.vertices) == entry.vertex_count)


def read_scene(depsgraph, cache: ExportCache, dirty: Dirty | None = None,
               camera_object=None, width: int | None = None, height: int | None = None,
               source: str = "RENDER", with_camera: bool = True, cancel=None,
               progress=None) -> Snapshot:
    """Walk the evaluated ``depsgraph`` into a :class:`Snapshot`, refreshing ``cache``.

    dirty : what changed since the last walk with this cache (None: unknown, meshes are
        checked by fingerprint and materials re-read)
    camera_object : the camera to render through (default: the scene's active camera)
    width, height : output size in pixels (default: resolution x percentage)
    with_camera : False for the viewport, whose camera comes from the view
    cancel : () -> bool, asked before each mesh read (True: :class:`Cancelled` is raised;
        what was read stays in ``cache``, valid)
    progress : (message) -> None, told which mesh is being read

    Without ``dirty`` (F12, animation), a cached mesh is taken as it is where the journal
    says it cannot have changed (:mod:`.journal`), else checked by fingerprint.

    Raises :class:`SceneError` for a camera that leaves nothing sensible to render.
    """
    t0 = time.perf_counter()
    bscene = depsgraph.scene_eval
    render = bscene.render
    if width is None or height is None:
        width, height = render_size(render)
    # the original scene's settings: the evaluated copy's property group is not refreshed
    # when only a setting changes (as render_settings reads them)
    props = getattr(getattr(depsgraph, "scene", None) or bscene, "rstrace", None)
    model = getattr(props, "shading_model", "PRINCIPLED")
    if cache.model != model:  # every material converts differently: re-read them all
        cache.set_model(model)
    r = _Reader(cache, dirty, source, depsgraph, cancel, progress)
    notes = r.notes
    cache.override = None if r.override is None else r.material_key(r.override)
    camera = None
    if with_camera:
        cam = camera_object if camera_object is not None else bscene.camera
        cam_eval = cam.evaluated_get(depsgraph) if cam is not None else None
        camera = camera_from_object(cam_eval, width, height, render, notes)
    world = tuple(float(c) for c in world_colour(bscene.world, notes))
    lights_from_world = world_lights(bscene.world, notes, world)

    objects: dict = {}
    hidden: set = set()
    lights: dict = {}
    instancers: set = set()
    instanced: set = set()
    # objects whose own mesh has no faces, reported after the walk unless they instance
    # something (a vertex-instancing parent, a geometry-nodes instancer): their instances
    # are what renders, as in Cycles, so "no faces" would be a false alarm
    faceless: list = []
    _check_view_layer(depsgraph, notes)
    for inst in depsgraph.object_instances:
        ob = inst.object
        kind = ob.type
        if inst.is_instance and inst.parent is not None:
            instancers.add(inst.parent.original.session_uid)
            instanced.add(ob.original.session_uid)
        if kind == "MESH":
            key = object_key(inst)
            if not inst.show_self:
                continue
            if not inst.is_instance and ob.original.hide_render:
                hidden.add(key)
                continue
            rec = _mesh_object(r, inst, faceless)
            if rec is not None:
                objects[key] = rec
        elif kind == "LIGHT":
            if not inst.is_instance and ob.original.hide_render:
                continue
            light = read_light(ob, instance_name(inst), _matrix(inst.matrix_world), notes)
            if light is None:
                continue
            if len(lights) >= MAX_LIGHTS:
                notes.skip(f"light '{instance_name(inst)}' skipped: at most {MAX_LIGHTS} "
                           f"lights are supported (MAX_LIGHTS)")
                continue
            lights[object_key(inst)] = light
        elif kind in _MESH_VIA_INSTANCES or kind in _NOTHING_TO_RENDER:
            continue
        else:
            notes.warn(f"{kind.lower().replace('_', ' ')} objects are not supported (skipped)",
                       instance_name(inst))
    for uid, message in faceless:
        if uid not in instancers:
            notes.skip(message)
    if not lights:
        notes.warn("the scene has no lights: only the world's light and emission are seen")
    stats = dict(objects=len(objects), lights=len(lights), meshes_read=r.meshes_read,
                 meshes_trusted=r.meshes_trusted,
                 materials_read=r.materials_read, mesh_read_seconds=r.t_mesh,
                 export_seconds=time.perf_counter() - t0, walked=True,
                 objects_read=len(objects) + len(hidden) + len(lights))
    return Snapshot(objects, hidden, lights, world, camera, notes, width, height, stats,
                    instancers=instancers, instanced=instanced, world_lights=lights_from_world)


def _mesh_object(r: _Reader, inst, faceless: list | None = None) -> ObjectRecord | None:
    """The record of a shown mesh object (or instance); None when it is skipped (noted).
    A mesh without faces goes to ``faceless`` as ``(object uid, message)`` when given (the
    caller reports it unless the object turns out to be an instancer), else is noted."""
    ob = inst.object
    cache, notes = r.cache, r.notes
    name = instance_name(inst)
    matrix = _matrix(inst.matrix_world)
    key = object_key(inst)
    raw = matrix.tobytes()
    if cache.matrices.get(key) != raw:
        try:
            check_matrix(name, matrix)
        except SceneError as exc:
            notes.skip(f"skipped {exc}")
            return None
        cache.matrices[key] = raw
    if not ob.data.is_editmode:
        return _mesh_record(r, inst, ob, ob.data, name, matrix, faceless)
    read = _edit_mode_read(r, inst, ob)
    return _mesh_record(r, inst, ob, read, name, matrix, faceless, read.key)


def _made(inst, ob) -> bool:
    """Whether ``ob`` (an instance's object) is geometry its instancer made (geometry
    nodes: its original is the instancer)."""
    return inst.is_instance and inst.parent is not None and ob.original == inst.parent.original


class _EditRead:
    """What a walk reads of an Edit Mode object's conversion (:func:`_edit_mode_mesh`):
    its mesh key (the mesh read, or checked, into the cache) and what the object's record
    asks of the mesh (name, materials, UV maps); the conversion itself is freed."""

    def __init__(self, key: Hashable, me) -> None:
        self.key, self.name = key, me.name
        self.materials = list(me.materials)
        self.uv_layers = [SimpleNamespace(name=u.name, active_render=u.active_render)
                          for u in me.uv_layers]


def _edit_mode_read(r: _Reader, inst, ob) -> _EditRead:
    """The read of Edit Mode object ``ob``'s conversion, made once per walk for all the
    instances of the object (particles, collection or geometry-nodes instances: each
    converted and fingerprinted the one real evaluated object, whose edit mesh does not
    change within a walk). Geometry an instancer made is converted per instance."""
    uid = None if _made(inst, ob) else ob.original.session_uid
    read = r.edit_reads.get(uid) if uid is not None else None
    if read is None:
        with _edit_mode_mesh(r, inst, ob) as me:
            read = _EditRead(r.mesh_key(inst, ob, me), me)
        if uid is not None:
            r.edit_reads[uid] = read
    return read


@contextmanager
def _edit_mode_mesh(r: _Reader, inst, ob):
    """The mesh to read of ``ob``, in Edit Mode. Its evaluated mesh is then Blender's
    wrapper of the edit mesh, which has no vertices or faces of its own (read as it is, the
    object was skipped as faceless): Blender's conversion of it is read instead
    (``to_mesh``: the edit mesh as of the last depsgraph update, what Cycles reads there),
    under the mesh's own name (the conversion is called 'Mesh'), and freed on exit. Only
    the evaluated object is asked: no mode switch, nothing written to the user's mesh. The
    conversion is made on the real evaluated object (an instance's object may be a
    temporary copy) -- except for geometry its instancer made (geometry nodes: the
    object's original is the instancer, whose own mesh is not this one), converted from
    the instance's own object -- and forgotten by :meth:`_Reader.mesh_key` when freed
    (the next conversion may get its address). The journal is not asked about it (a cached read is
    checked by fingerprint): a script may change the edit mesh with no depsgraph update
    (``bmesh.from_edit_mesh`` without ``update_edit_mesh``), which a fresh render
    depsgraph, and so Cycles' F12, shows."""
    made = _made(inst, ob)
    real = ob if made else ob.original.evaluated_get(r.depsgraph)
    converted = real.to_mesh()
    journal, r.journal = r.journal, False  # (see below)
    try:
        yield _Named(converted, (ob if made else ob.original).data.name)
    finally:
        r.journal = journal
        r.mesh_by_pointer.pop(converted.as_pointer(), None)
        real.to_mesh_clear()


class _Named:
    """A mesh under another name (everything else is the mesh's own)."""

    def __init__(self, me, name: str) -> None:
        self._me, self.name = me, name

    def __getattr__(self, attr: str):
        return getattr(self._me, attr)


def _mesh_record(r: _Reader, inst, ob, me, name: str, matrix: np.ndarray,
                 faceless: list | None, mesh_key: Hashable | None = None
                 ) -> ObjectRecord | None:
    """:func:`_mesh_object`'s record of ``ob`` with its mesh ``me`` (its matrix checked;
    ``mesh_key``: the mesh already read, an Edit Mode object's)."""
    cache, notes = r.cache, r.notes
    if mesh_key is None:
        mesh_key = r.mesh_key(inst, ob, me)
    entry = cache.meshes[mesh_key]
    if entry.mesh is None:
        message = f"skipped object '{name}': {entry.reason}"
        if faceless is not None and entry.reason.endswith(NO_FACES):
            faceless.append((ob.original.session_uid, message))
        else:
            notes.skip(message)
        return None
    slots = ob.material_slots
    nslots = max(len(me.materials), 1)
    if r.override is not None:
        mats = [r.material_key(r.override)] * max(nslots, len(slots))
    else:
        mats = [r.material_key(s.material) for s in slots] if len(slots) else \
            [r.material_key(m) for m in me.materials]
    mats += [DEFAULT_MATERIAL_KEY] * (nslots - len(mats))
    _check_visibility(ob, name, notes)
    _check_hair(ob, name, notes)
    holdout = _is_holdout(inst, r.view_layer)
    held = holdout or any(getattr(cache.materials[k], "holdout", False) for k in mats)
    if r.source == "VIEWPORT" and held:
        notes.warn("holdouts are drawn as ordinary objects in the viewport (final renders "
                   "cut them out: alpha 0)", name)
    if any(max(cache.material(k).emission) > 0.0 for k in mats):
        notes.warn(NOT_MODELLED_EMISSION, name)
    if len(me.uv_layers) == 0 and any(cache.material(k).texture is not None for k in mats):
        notes.warn("textured objects without a UV map sample their texture at (0, 0)", name)
    _check_texture_coordinates(ob, me, name, [cache.materials[k] for k in mats], notes)
    return ObjectRecord(name, mesh_key, matrix, tuple(mats), holdout=holdout)


def _check_hair(ob, name: str, notes: Notes) -> None:
    """Particle hair (rendered by Cycles as curves from the emitter) is not modelled."""
    for ps in getattr(ob, "particle_systems", ()):
        part = ps.settings
        if part is not None and part.type == "HAIR" and part.render_type == "PATH":
            notes.warn("particle hair is not supported (not rendered)", name)
            return


def _is_holdout(inst, view_layer) -> bool:
    """Whether the object is a holdout in the view layer (its own Holdout setting or a
    holdout collection), as Cycles asks it: of the instancer for an instance."""
    ob = inst.parent if inst.is_instance and inst.parent is not None else inst.object
    orig = getattr(ob, "original", ob)
    if view_layer is None:
        return bool(getattr(orig, "is_holdout", False))
    try:
        return bool(orig.holdout_get(view_layer=view_layer))
    except (AttributeError, TypeError, RuntimeError, ReferenceError):
        return bool(getattr(orig, "is_holdout", False))


#: Modifiers that leave every vertex where it is (Generated coordinates of the evaluated mesh
#: are those of the undeformed one), and subdivision (Cycles subdivides the undeformed
#: coordinates along with the mesh).
_GENERATED_SAFE_MODIFIERS = {"SUBSURF", "TRIANGULATE", "EDGE_SPLIT", "WEIGHTED_NORMAL"}


def _check_texture_coordinates(ob, me, name: str, entries: list, notes: Notes) -> None:
    """Report what the texture coordinates cannot follow: UV Map nodes naming a map other
    than the mesh's render UV map (the one exported), and Generated coordinates of a mesh
    deformed by modifiers or shape keys or with a manual texture space (they come from the
    evaluated mesh's own bounding box here, from the undeformed mesh in Cycles)."""
    if any(e.material.texture_flags & TEX_GENERATED for e in entries):
        orig = getattr(ob, "original", ob)
        data = getattr(orig, "data", None)
        moved = [m.name for m in orig.modifiers if m.show_render
                 and m.type not in _GENERATED_SAFE_MODIFIERS]
        if moved or getattr(data, "shape_keys", None) is not None \
                or not getattr(data, "use_auto_texspace", True):
            notes.warn("Generated texture coordinates of a deformed mesh (modifiers, shape "
                       "keys) or a manual texture space follow the evaluated mesh's bounding "
                       "box, not the undeformed mesh", name)
    active = next((u.name for u in me.uv_layers if u.active_render), None)
    for entry in entries:
        for uv in sorted(entry.uv_maps):
            if uv != active:
                notes.warn(f"UV Map nodes naming a UV map other than the render UV map "
                           f"are not supported (material '{entry.material.name}' names "
                           f"'{uv}'): the render UV map is used", name)


class _Own:
    """An object standing for its own (non-instance) entry of ``object_instances``."""

    is_instance = False
    parent = None
    show_self = True
    persistent_id = ()

    def __init__(self, ob) -> None:
        self.object = ob
        self.matrix_world = ob.matrix_world


def read_updated(depsgraph, cache: ExportCache, dirty: Dirty, objects: dict, lights: dict,
                 source: str = "VIEWPORT") -> Snapshot | None:
    """Re-read only the objects ``dirty.updated`` names, without walking
    ``depsgraph.object_instances``: the others are taken from ``objects`` / ``lights`` (what
    the session holds). For updates that cannot have changed the set of instances (the
    caller checks: every named object a plain, shown mesh or light the session holds, no
    instancer, not instanced). Returns None when one of them cannot be read this way (now
    hidden from renders, skipped, or no longer a light): the caller walks everything.
    """
    t0 = time.perf_counter()
    r = _Reader(cache, dirty, source, depsgraph)
    if (None if r.override is None else r.override.original.session_uid) != cache.override:
        return None  # the material override changed: every object's materials did
    objects, lights = dict(objects), dict(lights)
    changed = set()
    for mat in dirty.material_ids.values():
        r.material_key(mat)  # re-read (named in dirty.materials)
    for uid, ob in dirty.updated.items():
        if uid in dirty.shading_only and uid in objects:
            continue  # a user of a changed material: its assignment did not change
        if ob.original.hide_render:
            return None
        if ob.type == "MESH":
            rec = _mesh_object(r, _Own(ob))
            if rec is None:
                return None
            objects[uid] = rec
        elif ob.type == "LIGHT":
            light = read_light(ob, ob.name, _matrix(ob.matrix_world), r.notes)
            if light is None:
                return None
            lights[uid] = light
        else:
            return None
        changed.add(uid)
    bscene = depsgraph.scene_eval
    world = tuple(float(c) for c in world_colour(bscene.world, r.notes))
    lights_from_world = world_lights(bscene.world, r.notes, world)
    width, height = render_size(bscene.render)
    stats = dict(objects=len(objects), lights=len(lights), meshes_read=r.meshes_read,
                 materials_read=r.materials_read, mesh_read_seconds=r.t_mesh,
                 export_seconds=time.perf_counter() - t0, walked=False,
                 objects_read=len(changed))
    return Snapshot(objects, set(), lights, world, None, r.notes, width, height, stats,
                    changed=changed, changed_materials=set(dirty.material_ids),
                    world_lights=lights_from_world)


def _check_visibility(ob, name: str, notes: Notes) -> None:
    if not (ob.visible_camera and ob.visible_shadow and ob.visible_glossy
            and ob.visible_transmission):
        notes.warn("per-object ray visibility is not supported (objects are visible to all "
                   "rays)", name)
    # Cycles renders these differently; rstrace renders the object as an ordinary one, so
    # say so rather than render it silently wrong (issue 23)
    orig = getattr(ob, "original", ob)
    if getattr(orig, "is_shadow_catcher", False):
        notes.warn("shadow catchers are not supported (rendered as ordinary objects)", name)


def _check_view_layer(depsgraph, notes: Notes) -> None:
    """What the view layer asks for that is not modelled: collections set to indirect only
    (reported by collection name). Holdout collections are modelled (:func:`_is_holdout`);
    the material override is honoured (:class:`_Reader`)."""
    layer = getattr(depsgraph, "view_layer", None)
    if layer is None:
        return

    def walk(lc):
        for child in lc.children:
            if child.exclude:
                continue
            if child.indirect_only:
                notes.warn("indirect only collections are not supported (rendered as "
                           "ordinary objects)", child.name)
            walk(child)

    root = getattr(layer, "layer_collection", None)
    if root is not None:
        walk(root)


def export_scene(depsgraph, camera_object=None, width: int | None = None,
                 height: int | None = None) -> Exported:
    """Export the evaluated ``depsgraph`` (a render or viewport depsgraph) whole.

    Raises :class:`SceneError` for problems that leave nothing sensible to render (no
    camera, a broken camera, no visible mesh); everything else is skipped or noted.
    """
    cache = ExportCache()
    snap = read_scene(depsgraph, cache, None, camera_object, width, height)
    t0 = time.perf_counter()
    scene = build_scene(snap, cache)
    stats = dict(snap.stats, meshes=len(scene.meshes), materials=len(scene.materials),
                 triangles=scene.triangle_count, mesh_add_seconds=time.perf_counter() - t0)
    return Exported(scene, snap.notes, snap.width, snap.height, stats)


__all__ = ["Cancelled", "Dirty", "ExportCache", "Exported", "Light", "MeshEntry", "ObjectRecord",
           "Snapshot", "build_scene", "export_scene", "object_key", "read_scene",
           "read_updated", "render_size"]
