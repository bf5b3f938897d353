"""Edits: what a host says changed in a scene between two frames (seed 000, section 4).

An edit names what it changes by the host's *stable key* (any hashable: the Blender add-on
uses ``id.original.session_uid``, or ``(instancer uid, persistent_id)`` for instances). The
keys are given when objects, meshes, materials and lights are first added (``key=`` in the
``Scene.add_*`` calls) and stay valid across edits; they are never positions in a list.

:meth:`rstrace_engine.session.Session.apply` takes a sequence of edits, applies them all or
none (a bad edit raises :class:`~rstrace_engine.geometry.scene.SceneError` naming the object,
and the session keeps its previous state) and returns an :class:`EditReport`.
:meth:`~rstrace_engine.session.Session.update_scene` diffs a whole new export against the
current scene into the same edits, so both paths share one implementation.

Kinds, and what each may invalidate:

=====================  ===============================================================
``ObjectTransform``    an object moved/rotated/scaled: its old and new world boxes
``ObjectGeometry``     an object now uses another mesh (or its mesh was replaced)
``ObjectMaterials``    an object's per-slot material list changed
``ObjectVisibility``   an object hidden or shown (kept in the scene, not rendered)
``ObjectAdd``          a new object (mesh key, matrix, material keys)
``ObjectDelete``       an object removed (its slot is tombstoned and may be reused)
``MeshSet``            a mesh added or its data replaced (every object using it changes)
``MeshDelete``         a mesh no object uses any more removed (its slot is tombstoned and
                       reused): invalidates nothing, since no ray can have met it; the
                       packing, the accelerator's per-mesh structures and the interpolants'
                       surface classes follow (refused while an object, hidden or not,
                       still uses it: delete or re-mesh the users first, in the same batch)
``MaterialSet``        a material added or its parameters changed
``MaterialDelete``     a material no object uses any more removed (slot tombstoned and
                       reused; invalidates nothing; refused while an object uses it)
``LightSet``           a light added or changed (position, power, colour, cone, kind)
``LightDelete``        a light removed
``WorldColor``         the world (background) colour
``CameraChange``       the camera: invalidates nothing (interpolants are view-independent)
=====================  ===============================================================
"""

from __future__ import annotations

import dataclasses
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from .attributes import mesh_corners
from .cameras import same_camera
from .lights import seen_extent
from .packing import mesh_slots, mesh_triangles
from .scene import Camera, Light, Material, Mesh, Scene, SceneError


@dataclass(frozen=True)
class ObjectTransform:
    key: Hashable
    matrix: np.ndarray  # (4, 4) float64 object-to-world


@dataclass(frozen=True)
class ObjectGeometry:
    key: Hashable
    mesh_key: Hashable  # a mesh given earlier (or in the same batch) by MeshSet


@dataclass(frozen=True)
class ObjectMaterials:
    key: Hashable
    material_keys: tuple  # per material slot


@dataclass(frozen=True)
class ObjectVisibility:
    key: Hashable
    visible: bool


@dataclass(frozen=True)
class ObjectAdd:
    key: Hashable
    mesh_key: Hashable
    matrix: np.ndarray  # (4, 4) float64 object-to-world
    material_keys: tuple = ()
    name: str | None = None
    visible: bool = True


@dataclass(frozen=True)
class ObjectDelete:
    key: Hashable


@dataclass(frozen=True)
class MeshSet:
    key: Hashable
    mesh: Mesh


@dataclass(frozen=True)
class MeshDelete:
    key: Hashable


@dataclass(frozen=True)
class MaterialSet:
    key: Hashable
    material: Material


@dataclass(frozen=True)
class MaterialDelete:
    key: Hashable


@dataclass(frozen=True)
class LightSet:
    key: Hashable
    light: Light


@dataclass(frozen=True)
class LightDelete:
    key: Hashable


@dataclass(frozen=True)
class WorldColor:
    color: tuple  # linear RGB
    lights: bool | None = None  # whether it lights surfaces (None: as before)


@dataclass(frozen=True)
class CameraChange:
    camera: Camera


Edit = (ObjectTransform | ObjectGeometry | ObjectMaterials | ObjectVisibility | ObjectAdd
        | ObjectDelete | MeshSet | MeshDelete | MaterialSet | MaterialDelete | LightSet
        | LightDelete | WorldColor | CameraChange)


#: :attr:`EditEffects.parts`' tags: where an edited object was (a shadow ray it blocked
#: may now pass) and where it is (one that passed may now be blocked)
PART_OLD, PART_NEW = 1, 2


@dataclass
class EditEffects:
    """What a batch of edits touched, in the terms every structure works in: computed once
    by :func:`apply_edits` and handed down (interpolants, RI-trees, per-pixel records), so
    that no structure diffs the scene again.

    ``regions`` are world boxes (old and new box of every geometry-type edit, as two rows
    each, see :meth:`region_array`); ``objects`` the instance slots named, ``geometry`` the
    subset whose mesh, transform, box or visibility changed (or that were added or
    deleted); ``meshes`` the mesh ids whose triangles changed (set, added into a slot, or
    deleted); ``lights`` the light slots whose contribution changed, ``lights_moved`` the
    subset whose position, direction, cone, kind or extent changed (or that were added: they
    may now light any surface), ``materials`` the material ids whose parameters changed.
    """

    regions: list = field(default_factory=list)  # (2, 3) float64 world boxes
    objects: set = field(default_factory=set)
    geometry: set = field(default_factory=set)
    meshes: set = field(default_factory=set)
    lights: set = field(default_factory=set)
    lights_moved: set = field(default_factory=set)
    materials: set = field(default_factory=set)
    world: bool = False
    world_lights: bool = False  # the edited world colour is not black (it lights surfaces)
    camera: bool = False
    kinds: dict = field(default_factory=dict)
    #: world boxes of the edited lights' own surfaces that rays see (old and new: the
    #: camera's, mirror and refraction rays crossing them change, tracing/seen_lights)
    seen_regions: list = field(default_factory=list)
    #: per box of ``seen_regions``: camera rays see that light (else only mirror and
    #: refraction rays do: the view segments cannot cross it)
    seen_camera: list = field(default_factory=list)
    seen_sky: bool = False  # a sun with an angle that rays see changed: what misses changes
    #: the geometry-type edits' old and new objects apart: ``(box (2, 3), centre (3,),
    #: radius, tag)`` per visible one, its world box and a sphere holding its vertices (a
    #: ray whose result an edit changes meets one of them: both bounds hold its
    #: triangles); ``tag`` :data:`PART_OLD` where it was, :data:`PART_NEW` where it is now
    parts: list = field(default_factory=list)

    @property
    def lights_shading(self) -> set:
        """Lights whose power or colour alone changed, or that were deleted: only what they
        shaded changes."""
        return self.lights - self.lights_moved

    def part_arrays(self) -> tuple:
        """:attr:`parts` as arrays ``(lo (k, 3), hi (k, 3), centre (k, 3), radius (k,), tag
        (k,) int8)`` (effects made with :attr:`regions` alone: those boxes and their
        spheres, old and new both)."""
        parts = self.parts
        if not parts and self.regions:
            parts = [(b, 0.5 * (b[0] + b[1]), 0.5 * float(np.linalg.norm(b[1] - b[0])),
                      PART_OLD | PART_NEW)
                     for b in (np.asarray(r, np.float64) for r in self.regions)]
        if not parts:
            return (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                    np.zeros(0, np.int8))
        box, c, r, tag = zip(*parts, strict=True)
        box = np.stack(box)
        return (np.ascontiguousarray(box[:, 0], np.float64),
                np.ascontiguousarray(box[:, 1], np.float64),
                np.ascontiguousarray(np.stack(c), np.float64), np.asarray(r, np.float64),
                np.asarray(tag, np.int8))

    def region_array(self) -> np.ndarray:
        """(k, 2, 3) float64: one box per geometry-type edit (old box union new box)."""
        if not self.regions:
            return np.zeros((0, 2, 3))
        return np.ascontiguousarray(np.stack(self.regions), dtype=np.float64)

    @property
    def scene_content_changed(self) -> bool:
        return bool(self.regions or self.objects or self.lights or self.materials
                    or self.world)


@dataclass
class EditReport:
    """What :meth:`Session.apply` did, for the status line and the benchmarks."""

    edits: int = 0  # edits applied
    kinds: dict = field(default_factory=dict)  # edit class name -> count
    invalidated_interpolants: int = 0
    #: interpolants kept, rescaled by a light's power or colour change (interpolants/relight)
    rescaled_interpolants: int = 0
    #: of the invalidated ones: their radiance test failed after the rescale
    rescale_invalidated: int = 0
    dirty_pixels: int = 0  # pixels the next frame re-renders (fixed camera), else -1
    dirty_fraction: float = 0.0
    camera_changed: bool = False
    rst_query_ms: float = 0.0  # RST traversal + membership + invalidation
    records_query_ms: float = 0.0  # finding the dirty pixels in the per-pixel records
    apply_ms: float = 0.0  # everything apply() did
    messages: list = field(default_factory=list)
    regions: int = 0  # world boxes the geometry-type edits touched
    full_frame: bool = True  # the next frame renders every pixel (camera moved, no records)
    relight: bool = False  # light / world edits only: the next frame relights, no pixel dirty
    #: kept pixels (not in dirty_pixels) whose soft lights' shadow rays alone the edits may
    #: cross: the next frame shades those lights again there (tracing/shadow_reshade)
    reshade_pixels: int = 0


# ----------------------------------------------------------------------------- applying


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    if a is None:
        return b
    if b is None:
        return a
    return np.stack([np.minimum(a[0], b[0]), np.maximum(a[1], b[1])])


def _visible_box(scene: Scene, slot: int) -> tuple | None:
    """Object ``slot``'s world box, world bounding sphere (:attr:`EditEffects.parts`), or
    None where it draws nothing."""
    inst = scene.instances[slot]
    if inst is None or not inst["visible"]:
        return None
    box = inst["aabb"].copy()
    return box, *_bounding_sphere(scene.meshes[inst["mesh"]], inst["matrix"], box)


#: meshes with more vertices take their box's sphere (the vertices' sphere costs O(V) per edit)
SPHERE_MAX_VERTS = 200_000


def _bounding_sphere(mesh: dict, matrix: np.ndarray, box: np.ndarray) -> tuple:
    """``(centre (3,), radius)``: a world sphere holding the mesh's vertices under
    ``matrix`` (the object-space sphere about the mesh box's centre through its farthest
    vertex, scaled by the matrix's largest stretch), or the world box's own sphere where
    that is smaller (or the mesh is large)."""
    bc = 0.5 * (box[0] + box[1])
    br = 0.5 * float(np.linalg.norm(box[1] - box[0]))
    verts = np.asarray(mesh["verts"], np.float64)
    if len(verts) == 0 or len(verts) > SPHERE_MAX_VERTS:
        return bc, br
    c = 0.5 * (np.asarray(mesh["lo"], np.float64) + np.asarray(mesh["hi"], np.float64))
    r = float(np.sqrt(((verts - c) ** 2).sum(axis=1).max()))
    m = np.asarray(matrix, np.float64)
    wc = m[:3, :3] @ c + m[:3, 3]
    wr = r * float(np.linalg.norm(m[:3, :3], 2))
    return (wc, wr) if wr < br else (bc, br)


def _light_geometry(li: Light) -> tuple:
    """What decides where a light's shadow rays go and which surfaces face it: also its
    extent (radius, soft falloff, sun angle, area shape, axis, size, spread), which lobes
    it lights (its diffuse, glossy and transmission visibility -- rough glass takes the
    glossy or the transmission one: a light's term holds every lobe, so a change is
    shaded again, not rescaled) and which objects it lights and which cast its shadow
    (light and shadow linking)."""
    return (li.kind, tuple(li.position), tuple(li.direction), float(li.spot_size),
            float(li.spot_blend), float(li.radius), bool(li.soft_falloff), float(li.angle),
            li.shape, tuple(li.axis), tuple(li.size), float(li.spread), bool(li.diffuse),
            bool(li.glossy), bool(li.transmission), tuple(li.receivers), tuple(li.blockers),
            tuple(li.spot_frame))


def _light_seen(fx: EditEffects, li: Light | None) -> None:
    """Light ``li``'s own surface, if rays see it, changes what they gather there."""
    box = None if li is None else seen_extent(li)
    if box is None:
        return
    if box is True:
        fx.seen_sky = True
    else:
        fx.seen_regions.append(box)
        fx.seen_camera.append(bool(li.camera))


def _material_ids(scene: Scene, name: str, keys) -> list[int]:
    ids = []
    for k in keys:
        try:
            ids.append(scene.material_id(k))
        except SceneError:
            raise SceneError(f"object '{name}': unknown material key {k!r}") from None
    return ids


#: edits that change the lights' and the world's part of the packing alone
_LIGHTING = (LightSet, LightDelete, WorldColor, CameraChange)


def apply_edits(scene: Scene, edits) -> tuple[Scene, EditEffects]:
    """Apply ``edits`` in order to a *copy* of ``scene``; return ``(new scene, effects)``.

    All or nothing: any bad edit raises :class:`SceneError` naming the object (the given
    scene is never modified), and the new scene is packed (validated) before it is returned.
    """
    new = scene.copy()
    fx = EditEffects()
    for e in edits:
        name = type(e).__name__
        fx.kinds[name] = fx.kinds.get(name, 0) + 1
        _apply_one(new, e, fx)
    if (scene._arrays is not None and new._arrays is None
            and all(isinstance(e, _LIGHTING) for e in edits)):
        new.repack_lights(scene._arrays)  # (a light drag: only the lights packed again)
    new.arrays()  # validates the whole packing before anyone sees it
    return new, fx


def _object_changed(fx: EditEffects, slot: int, old, new) -> None:
    """Instance ``slot``'s geometry changed (mesh, transform, box, visibility, presence):
    ``old``, ``new`` its :func:`_visible_box` before and after."""
    box = _union(None if old is None else old[0], None if new is None else new[0])
    if box is not None:
        fx.regions.append(box)
    fx.parts.extend((*p, tag) for p, tag in ((old, PART_OLD), (new, PART_NEW))
                    if p is not None)
    fx.objects.add(slot)
    fx.geometry.add(slot)


def _apply_one(s: Scene, e, fx: EditEffects) -> None:
    if isinstance(e, CameraChange):
        s.set_camera(e.camera)
        fx.camera = True
    elif isinstance(e, WorldColor):
        s.set_world_color(e.color, e.lights)
        fx.world = True
        fx.world_lights = bool(s.world_lights and np.any(s.world_color > 0.0))
    elif isinstance(e, MeshSet):
        if e.key in s.mesh_keys.slot:
            mid = s.mesh_id(e.key)
            users = [k for k, i in s.live_instances() if i["mesh"] == mid]
            before = {k: _visible_box(s, k) for k in users}
            s.set_mesh(mid, e.mesh)
            fx.meshes.add(mid)
            for k in users:
                _object_changed(fx, k, before[k], _visible_box(s, k))
        else:
            fx.meshes.add(s.add_mesh(e.mesh, key=e.key))
    elif isinstance(e, MeshDelete):
        mid = s.mesh_id(e.key)
        s.delete_mesh(mid)  # no live object uses it: no interpolant to invalidate
        fx.meshes.add(mid)
    elif isinstance(e, MaterialSet):
        if e.key in s.material_keys.slot:
            mid = s.material_id(e.key)
            s.set_material(mid, e.material)
            fx.materials.add(mid)
        else:
            s.add_material(e.material, key=e.key)
    elif isinstance(e, MaterialDelete):
        s.delete_material(s.material_id(e.key))  # no live object uses it
    elif isinstance(e, ObjectAdd):
        try:
            mesh = s.mesh_id(e.mesh_key)
        except SceneError:
            raise SceneError(f"object '{e.name or e.key}': unknown mesh key "
                             f"{e.mesh_key!r}") from None
        mats = _material_ids(s, e.name or str(e.key), e.material_keys)
        slot = s.add_instance(mesh, e.matrix, mats, name=e.name or str(e.key), key=e.key,
                              visible=e.visible)
        _object_changed(fx, slot, None, _visible_box(s, slot))
    elif isinstance(e, ObjectDelete):
        slot = s.instance_slot(e.key)
        before = _visible_box(s, slot)
        s.delete_instance(slot)
        _object_changed(fx, slot, before, None)
    elif isinstance(e, ObjectTransform):
        slot = s.instance_slot(e.key)
        before = _visible_box(s, slot)
        old_matrix = s.instances[slot]["matrix"]
        s.set_instance_matrix(slot, e.matrix)
        if np.array_equal(old_matrix, s.instances[slot]["matrix"]):
            return  # not moved: nothing to invalidate
        _object_changed(fx, slot, before, _visible_box(s, slot))
    elif isinstance(e, ObjectGeometry):
        slot = s.instance_slot(e.key)
        inst = s.instances[slot]
        try:
            mesh = s.mesh_id(e.mesh_key)
        except SceneError:
            raise SceneError(f"object '{inst['name']}': unknown mesh key "
                             f"{e.mesh_key!r}") from None
        before = _visible_box(s, slot)
        s.set_instance_mesh(slot, mesh)
        _object_changed(fx, slot, before, _visible_box(s, slot))
    elif isinstance(e, ObjectMaterials):
        slot = s.instance_slot(e.key)
        inst = s.instances[slot]
        s.set_instance_materials(slot, _material_ids(s, inst["name"], e.material_keys))
        fx.objects.add(slot)
    elif isinstance(e, ObjectVisibility):
        slot = s.instance_slot(e.key)
        if s.instances[slot]["visible"] == bool(e.visible):
            return
        before = _visible_box(s, slot)
        s.set_instance_visible(slot, e.visible)
        _object_changed(fx, slot, before, _visible_box(s, slot))
    elif isinstance(e, LightSet):
        if e.key in s.light_keys.slot:
            j = s.light_slot(e.key)
            old = s.lights[j]
            s.set_light(j, e.light)
            fx.lights.add(j)
            if _light_geometry(old) != _light_geometry(s.lights[j]):
                fx.lights_moved.add(j)
            if old != s.lights[j]:
                _light_seen(fx, old)
                _light_seen(fx, s.lights[j])
        else:
            j = s.add_light(e.light, key=e.key)
            fx.lights.add(j)
            fx.lights_moved.add(j)
            _light_seen(fx, s.lights[j])
    elif isinstance(e, LightDelete):
        j = s.light_slot(e.key)
        _light_seen(fx, s.lights[j])
        s.delete_light(j)
        fx.lights.add(j)
    else:
        raise SceneError(f"edit {e!r}: not an edit (see rstrace_engine.geometry.edits)")


# ----------------------------------------------------------------------------- diffing


def _same_mesh(a: dict, b: dict) -> bool:
    if a is b:
        return True
    same_base = a.get("vert0", 0) == b.get("vert0", 0)  # (no copies to compare then)
    return (np.array_equal(a["tris"], b["tris"]) if same_base
            else np.array_equal(mesh_triangles(a), mesh_triangles(b))) and all(
        np.array_equal(a[k], b[k])
        for k in ("verts", "normals", "nmode", "uvs", "uvmode", "slots", "slot"))


def same_material(a: Material | None, b: Material) -> bool:
    """True when two materials shade alike: every field but the name (the shading model,
    the Principled layers' weights and colours included), textures by content."""
    if a is None:
        return False
    if a is b:
        return True
    if any(getattr(a, f.name) != getattr(b, f.name) for f in dataclasses.fields(Material)
           if f.name not in ("name", "texture")):
        return False
    if a.texture is None or b.texture is None:
        return a.texture is b.texture
    return a.texture is b.texture or (a.texture.shape == b.texture.shape
                                      and np.array_equal(a.texture, b.texture))


def _as_mesh(d: dict) -> Mesh:
    return Mesh(d["name"], d["verts"], mesh_triangles(d),
                corner_normals=mesh_corners(d, "normals"), corner_uvs=mesh_corners(d, "uvs"),
                slots=mesh_slots(d))


def diff_scenes(old: Scene, new: Scene) -> list:
    """The edits that turn ``old`` into ``new``, matching items by their keys.

    Meshes and materials first (objects refer to them), then deletions (their slots are
    reused by additions), then additions and changes, then the meshes and materials no
    object uses any more, then the world and the camera.
    """
    edits: list = []
    mesh_key = {v: k for k, v in new.mesh_keys.slot.items()}
    mat_key = {v: k for k, v in new.material_keys.slot.items()}
    old_mesh_key = {v: k for k, v in old.mesh_keys.slot.items()}
    old_mat_key = {v: k for k, v in old.material_keys.slot.items()}
    for key, mid in new.mesh_keys.slot.items():
        o = old.mesh_keys.slot.get(key)
        if o is None or not _same_mesh(old.meshes[o], new.meshes[mid]):
            edits.append(MeshSet(key, _as_mesh(new.meshes[mid])))
    for key, mid in new.material_keys.slot.items():
        o = old.material_keys.slot.get(key)
        if o is None or not same_material(old.materials[o], new.materials[mid]):
            edits.append(MaterialSet(key, new.materials[mid]))
    for key in old.light_keys.slot:
        if key not in new.light_keys.slot:
            edits.append(LightDelete(key))
    for key in old.instance_keys.slot:
        if key not in new.instance_keys.slot:
            edits.append(ObjectDelete(key))
    for key, slot in new.instance_keys.slot.items():
        ni = new.instances[slot]
        mats = tuple(mat_key[m] for m in ni["materials"])
        o = old.instance_keys.slot.get(key)
        if o is None:
            edits.append(ObjectAdd(key, mesh_key[ni["mesh"]], ni["matrix"], mats, ni["name"],
                                   ni["visible"]))
            continue
        oi = old.instances[o]
        if old_mesh_key[oi["mesh"]] != mesh_key[ni["mesh"]]:
            edits.append(ObjectGeometry(key, mesh_key[ni["mesh"]]))
        if not np.array_equal(oi["matrix"], ni["matrix"]):
            edits.append(ObjectTransform(key, ni["matrix"]))
        if tuple(old_mat_key[m] for m in oi["materials"]) != mats:
            edits.append(ObjectMaterials(key, mats))
        if oi["visible"] != ni["visible"]:
            edits.append(ObjectVisibility(key, ni["visible"]))
    for key, j in new.light_keys.slot.items():
        o = old.light_keys.slot.get(key)
        if o is None or old.lights[o] != new.lights[j]:
            edits.append(LightSet(key, new.lights[j]))
    for key in old.mesh_keys.slot:
        if key not in new.mesh_keys.slot:
            edits.append(MeshDelete(key))
    for key in old.material_keys.slot:
        if key not in new.material_keys.slot:
            edits.append(MaterialDelete(key))
    if not np.array_equal(old.world_color, new.world_color):
        edits.append(WorldColor(tuple(float(x) for x in new.world_color)))
    if not same_camera(old.camera, new.camera):
        edits.append(CameraChange(new.camera))
    return edits
