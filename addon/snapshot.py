"""What an export knows, as plain values: per-datablock caches (meshes, materials, textures)
that survive between exports of a scene, the snapshot of one depsgraph walk, and building a
whole :class:`Scene` from them.

No Blender reference is ever stored here (keys are ``session_uid`` values, see ``export``).

Layer: imported by ``export`` and ``depsgraph_diff`` (imports ``materials`` only).
"""

from __future__ import annotations

import inspect
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from rstrace_engine.geometry.scene import Camera, Material, Mesh, Scene, SceneError

from .materials import DEFAULT_MATERIAL, Notes, default_material

DEFAULT_MATERIAL_KEY = "default"


@dataclass
class ObjectRecord:
    """One rendered object (or instance) as the renderer sees it."""

    name: str
    mesh_key: Hashable
    matrix: np.ndarray  # (4, 4) float64
    material_keys: tuple
    holdout: bool = False  # the object (or its collection) is a holdout in the view layer


@dataclass
class MeshEntry:
    mesh: Mesh | None  # None: cannot be rendered (``reason`` says why)
    reason: str | None
    fingerprint: bytes
    source: str  # "VIEWPORT" or "RENDER": which depsgraph it was read from
    #: journal.JOURNAL's number when read or last found unchanged; the frame then
    #: (frame_current, subframe); the evaluated mesh's vertex count (journal.py)
    stamp: int = -1
    frame: tuple | None = None
    vertex_count: int = -1


@dataclass
class MaterialEntry:
    material: Material
    notes: list  # (kind, name) warnings its conversion produced, re-reported every export
    images: frozenset = frozenset()  # keys of the textures (ExportCache.textures) it uses
    uv_maps: frozenset = frozenset()  # UV maps its UV Map nodes name (checked per mesh)
    holdout: bool = False  # a Holdout shader (tracing.camera_passes holds it out)


@dataclass
class Dirty:
    """What ``depsgraph.updates`` said changed: session_uids of objects with new geometry,
    mesh datablocks, and materials; ``all_materials`` after node-group or image updates.

    ``walk``: the updates may have changed the set of instances (an object added or
    deleted, a collection or visibility change, undo, ...): the whole depsgraph is walked.
    ``updated``: session_uid -> the evaluated ``Object`` of every object the updates name,
    valid only while the updates are being handled (no reference is kept beyond that).
    ``shading_only``: those with only the shading flag (the users of a changed material:
    a material *assignment* comes with a Scene update, and walks); ``material_ids``: the
    changed materials themselves (evaluated, same lifetime).
    """

    objects: set = field(default_factory=set)
    data: set = field(default_factory=set)
    materials: set = field(default_factory=set)
    all_materials: bool = False
    walk: bool = False
    updated: dict = field(default_factory=dict)
    shading_only: set = field(default_factory=set)  # of updated: only the shading flag
    material_ids: dict = field(default_factory=dict)  # uid -> evaluated Material (same)


@dataclass
class Snapshot:
    """The scene as one depsgraph showed it (keys -> plain values, no Blender references)."""

    objects: dict  # key -> ObjectRecord
    hidden: set  # keys of objects present but hidden from renders
    lights: dict  # key -> Light
    world: tuple
    camera: Camera | None
    notes: Notes
    width: int
    height: int
    stats: dict = field(default_factory=dict)
    #: None: a walk of every instance; else the keys of the objects and lights re-read
    #: (the others are the mirror's, unchanged)
    changed: set | None = None
    changed_materials: set = field(default_factory=set)  # (with changed) materials re-read
    instancers: set = field(default_factory=set)  # uids of objects that make instances
    instanced: set = field(default_factory=set)  # uids of objects that appear as instances
    hidden_in_view: frozenset | None = None  # viewport walks: depsgraph_diff.visibility_signature
    world_lights: bool = True  # False: the world is a background only (its ray visibility)

    @property
    def warnings(self) -> list[str]:
        return self.notes.warnings


class ExportCache:
    """Per-datablock caches that survive between exports of one scene."""

    def __init__(self) -> None:
        self.meshes: dict[Hashable, MeshEntry] = {}
        self.materials: dict[Hashable, MaterialEntry] = {
            DEFAULT_MATERIAL_KEY: MaterialEntry(DEFAULT_MATERIAL.validated(), [])}
        self.textures: dict = {}
        #: object key -> the bytes of its world matrix last found valid (check_matrix is
        #: not run again on a matrix that did not change: most of a walk's cost per object)
        self.matrices: dict[Hashable, bytes] = {}
        self.model = "PRINCIPLED"  # the shading model the cached materials were converted to
        #: the material key of the view layer's material override the last walk used (None:
        #: no override); an update-only export under another one walks everything instead
        self.override: Hashable | None = None

    def set_model(self, model: str) -> None:
        """Another shading model: the cached materials are stale (textures are not)."""
        self.model = model
        self.materials = {DEFAULT_MATERIAL_KEY: MaterialEntry(
            default_material(model).validated(), [])}

    def mesh(self, key: Hashable) -> Mesh:
        return self.meshes[key].mesh

    def material(self, key: Hashable) -> Material:
        return self.materials[key].material


def _takes_key(method) -> bool:
    try:
        return "key" in inspect.signature(method).parameters
    except (TypeError, ValueError):
        return False


def build_scene(snap: Snapshot, cache: ExportCache, camera: Camera | None = None,
                cancel=None) -> Scene:
    """A :class:`Scene` holding everything ``snap`` renders (keys given where supported).

    ``cancel``: a ``() -> bool`` the meshes' checks poll (``Scene.add_mesh``), raising
    :class:`~rstrace_engine.cancel.Cancelled`. Raises :class:`SceneError` when nothing is
    left to render.
    """
    if not snap.objects:
        raise SceneError("nothing to render: the scene has no visible mesh objects"
                         + (f" ({'; '.join(snap.notes.skipped)})" if snap.notes.skipped
                            else ""))
    scene = Scene()
    keyed = _takes_key(scene.add_mesh)

    def add(method, value, key):
        return method(value, key=key) if keyed else method(value)

    mesh_ids: dict = {}
    mat_ids: dict = {}
    for key, rec in snap.objects.items():
        if rec.mesh_key not in mesh_ids:
            mesh_ids[rec.mesh_key] = (
                scene.add_mesh(cache.mesh(rec.mesh_key), key=rec.mesh_key, cancel=cancel)
                if keyed else scene.add_mesh(cache.mesh(rec.mesh_key)))
        ids = []
        for mk in rec.material_keys:
            if mk not in mat_ids:
                mat_ids[mk] = add(scene.add_material, cache.material(mk), mk)
            ids.append(mat_ids[mk])
        if keyed:
            scene.add_instance(mesh_ids[rec.mesh_key], rec.matrix, ids, name=rec.name,
                               key=key)
        else:
            scene.add_instance(mesh_ids[rec.mesh_key], rec.matrix, ids, name=rec.name)
    for key, light in snap.lights.items():
        add(scene.add_light, light, key)
    scene.set_world_color(snap.world, lights=snap.world_lights)
    cam = camera if camera is not None else snap.camera
    if cam is not None:
        scene.set_camera(cam)
    return scene


@dataclass
class Exported:
    """The result of :func:`export_scene`."""

    scene: Scene
    notes: Notes
    width: int
    height: int
    stats: dict = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        return self.notes.warnings + self.scene.warnings
