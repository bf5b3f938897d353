"""The scene model: meshes, instances, materials, lights, camera and world colour.

Authoring happens through small Python objects (:class:`Mesh`, :class:`Material`,
:class:`Light`, :class:`Camera`) added to a :class:`Scene`, which validates every input
when it is added (errors name the offending object) and packs everything into
:class:`SceneArrays`, a ``NamedTuple`` of flat numpy arrays that numba kernels take as an
argument. Instances of one mesh share its geometry.

Conventions
-----------
* Units and axes are Blender's: right-handed, Z up, the camera looks down its local -Z
  with +Y up.
* Radiance is linear RGB. A point or spot light of power ``P`` watts and colour ``c`` has
  radiant intensity ``I = c * P / (4 pi)`` (W/sr); a sun of strength ``S`` gives irradiance
  ``c * S`` (W/m^2) on a surface facing it. This is Blender's (and Cycles') convention:
  a Lambertian surface of albedo rho at distance r from a point light gets
  ``L = rho / pi * P / (4 pi r^2) * cos(theta)``.
* Materials are Ward isotropic (diffuse albedo, specular albedo, roughness alpha) or
  Principled-like (Lambertian base under a Fresnel-weighted GGX layer), plus Whitted mirror
  reflectance, transmission with an index of refraction, and emission.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from .. import linalg
from .. import tolerances as tol
from .elements import (  # noqa: F401 - re-exported, the scene model's public names
    AREA_SHAPES,
    LIGHT_AREA,
    LIGHT_KINDS,
    LIGHT_NONE,
    LIGHT_POINT,
    LIGHT_SPOT,
    LIGHT_SUN,
    MAX_LIGHT_POWER,
    MAX_LIGHTS,
    MODEL_PRINCIPLED,
    MODEL_WARD,
    SHADING_MODELS,
    TEX_CLIP,
    TEX_CLOSEST,
    TEX_EMISSION,
    TEX_EXTEND,
    TEX_GENERATED,
    TEX_MAP_IDENTITY,
    TEX_METAL,
    TEX_NO_BASE,
    TEX_NONLINEAR,
    TEX_OBJECT,
    TEX_SAMPLING,
    TEX_SPECULAR,
    TEX_SRGB,
    TEX_TRANSMISSION,
    TEX_TRANSMISSION_SQRT,
    Camera,
    Light,
    Material,
    Mesh,
    SceneError,
    _colour,
    _finite_array,
    check_matrix,
    checked_camera,
)
from .footprint import check_count, check_fits, estimate
from .lights import checked_light, pack_lights
from .mesh_check import checked_mesh
from .mesh_math import transform_aabb
from .packing import pack_meshes
from .slot_keys import SlotKeys

log = logging.getLogger(__name__)


class SceneArrays(NamedTuple):
    """The scene as flat arrays, for numba kernels. ``T`` triangles, ``I`` instance slots.

    Instance slots and light slots are stable across edits (see :class:`Scene`): a deleted or
    hidden object keeps its slot as a *tombstone* (``inst_alive`` False, an empty box
    ``lo > hi``, identity matrices) that no accelerator ever hits; a deleted light keeps its
    slot with kind ``LIGHT_NONE`` and zero intensity, and the tracers skip it.
    """

    verts: np.ndarray  # (V, 3) float64, object space, all meshes concatenated
    tris: np.ndarray  # (T, 3) int32, global indices into verts
    normals: np.ndarray  # (N, 3) float32 shading normal rows (:mod:`.attributes`), object space
    mesh_nrm: np.ndarray  # (M, 2) int64 (ATTR_* mode, row bias) of each mesh's normals
    uvs: np.ndarray  # (U, 2) float32 uv rows
    mesh_uv: np.ndarray  # (M, 2) int64 (ATTR_* mode, row bias) of each mesh's uvs
    tri_slot: np.ndarray  # (S,) int32 material slot rows (:mod:`.packing`)
    mesh_slot: np.ndarray  # (M, 2) int64 (constant slot or -1, row bias) of each mesh
    mesh_tri_start: np.ndarray  # (M + 1,) int32: mesh k owns tris[start[k]:start[k+1]]
    inst_mesh: np.ndarray  # (I,) int32
    inst_xform: np.ndarray  # (I, 4, 4) float64 object -> world
    inst_inv: np.ndarray  # (I, 4, 4) float64 world -> object
    inst_nmat: np.ndarray  # (I, 3, 3) float64 normal matrix (inverse transpose)
    inst_aabb: np.ndarray  # (I, 2, 3) float64 world bounds (empty, lo > hi, when dead)
    inst_mat_start: np.ndarray  # (I + 1,) int32 into inst_mat
    inst_mat: np.ndarray  # (K,) int32 material ids per slot
    mat_diffuse: np.ndarray  # (NM, 3) float64
    mat_specular: np.ndarray  # (NM, 3)
    mat_roughness: np.ndarray  # (NM,)
    mat_mirror: np.ndarray  # (NM, 3)
    mat_transmission: np.ndarray  # (NM, 3)
    mat_ior: np.ndarray  # (NM,)
    mat_emission: np.ndarray  # (NM, 3)
    mat_tex: np.ndarray  # (NM,) int32 texture id or -1
    mat_model: np.ndarray  # (NM,) int32 MODEL_WARD or MODEL_PRINCIPLED
    mat_metallic: np.ndarray  # (NM,) float64
    mat_metal: np.ndarray  # (NM, 3) float64
    mat_specular_ior: np.ndarray  # (NM,) float64
    mat_tint_max: np.ndarray  # (NM,) float64 the Principled layer's tint, largest channel
    mat_metal_tint: np.ndarray  # (NM, 3) float64 the metal's F82 tint (1: Schlick)
    tex_data: np.ndarray  # (X, 3) float32 texels, all textures row-major concatenated
    tex_start: np.ndarray  # (NT + 1,) int64
    tex_size: np.ndarray  # (NT, 3) int32 (width, height, TEX_* flags)
    tex_map: np.ndarray  # (NT, 2, 4) float64 affine: texture coordinates (x, y, z) -> (u, v)
    mesh_gen: np.ndarray  # (M, 2, 3) float64 Generated = (p - mesh_gen[k, 0]) / mesh_gen[k, 1]
    light_kind: np.ndarray  # (L,) int32, LIGHT_NONE for a deleted light's slot
    light_pos: np.ndarray  # (L, 3) float64
    light_dir: np.ndarray  # (L, 3) float64 unit, the way the light points
    light_intensity: np.ndarray  # (L, 3) W/sr (point, spot) or W/m^2 (sun)
    light_cos_outer: np.ndarray  # (L,) spot cone cosines (1.0 / -1.0 otherwise)
    light_cos_inner: np.ndarray  # (L,)
    world_color: np.ndarray  # (3,) float64
    world_light: np.ndarray  # (3,) float64 the world's light: its colour, or 0 (background only)
    scene_aabb: np.ndarray  # (2, 3) float64 bounds of all live instances
    scene_extent: float  # length of the scene box diagonal (> 0)
    inst_alive: np.ndarray  # (I,) bool: the slot holds a visible object
    # lights with an extent (:mod:`~rstrace_engine.tracing.soft_lights`); a light whose
    # light_ext is False is a point or a parallel sun (one shadow ray)
    light_ext: np.ndarray  # (L,) bool: sampled (sphere, sun with an angle, area)
    light_radiance: np.ndarray  # (L, 3) emitted radiance of an extended light, W/(m^2 sr)
    light_radius: np.ndarray  # (L,) sphere radius (POINT, SPOT), 0 otherwise
    light_soft: np.ndarray  # (L,) bool Blender's use_soft_falloff (spheres)
    light_half: np.ndarray  # (L,) SUN: half the angular diameter (0: none), radians
    light_u: np.ndarray  # (L, 3) AREA: unit +X of the emitter
    light_v: np.ndarray  # (L, 3) AREA: unit cross(-direction, +X)
    light_size: np.ndarray  # (L, 2) AREA: full extents along u and v
    light_ellipse: np.ndarray  # (L,) bool AREA: disk or ellipse
    light_spread: np.ndarray  # (L, 2) AREA: tan(spread / 2) (inf: pi), its normaliser
    light_bound: np.ndarray  # (L,) largest distance of an emitting point from light_pos
    # what each light reaches (:class:`~.lights.LightReach`)
    light_vis: np.ndarray  # (L, 4) float64 diffuse, glossy, camera, transmission (1 or 0)
    light_spot_scaled: np.ndarray  # (L,) bool SPOT: a reshaped (elliptical) cone
    light_spot_frame: np.ndarray  # (L, 3, 3) rows taking a direction into its scaled frame
    light_recv: np.ndarray  # (L, I) uint8 light linking: lights object; (0, 0) no linking
    light_block: np.ndarray  # (L, I) uint8 shadow linking: casts its shadow; (0, 0) none


def _footprint(mesh: dict) -> int:
    """Estimated peak bytes of a validated mesh (:func:`~.footprint.estimate`)."""
    return estimate(len(mesh["tris"]), len(mesh["verts"]))


#: What a tombstoned material slot packs as (no object uses it: never shaded).
_DEAD_MATERIAL = Material("<deleted>").validated()
#: The box of a dead instance slot: empty (lo > hi), finite, so no overlap test passes.
DEAD_AABB = np.array([[tol.COORD_MAX * 10] * 3, [-tol.COORD_MAX * 10] * 3])


class Scene:
    """A mutable scene that validates on input and packs to :class:`SceneArrays`.

    Items have stable *slots* and host *keys*. ``add_mesh / add_material / add_instance /
    add_light`` take ``key=`` (any hashable; by default the item's name when unused, else a
    generated key) and return the slot; ``mesh_id / material_id / instance_slot /
    light_slot(key)`` look a key up. Instance and light slots never move: a deleted one is a
    tombstone (``None`` in :attr:`instances` / :attr:`lights`) reused by a later addition,
    because instance ids are baked into interpolant keys, linetree roots and ray trees.
    ``set_mesh`` / ``set_material`` replace one in place. A mesh no object uses any more is
    removed with ``delete_mesh``: its slot becomes a tombstone (``None`` in :attr:`meshes`,
    no triangles in the packing) reused by a later ``add_mesh``, so mesh ids never move;
    likewise ``delete_material`` for a material no object uses.

    ``stats`` collects counts of tolerated problems (dropped degenerate triangles, ...);
    ``warnings`` collects one message per distinct problem, for the host to report once.
    """

    def __init__(self) -> None:
        self.meshes: list[dict | None] = []  # None: a tombstoned (deleted) mesh slot
        self.materials: list[Material | None] = []  # None: a tombstoned (deleted) slot
        self.instances: list[dict | None] = []  # None: a tombstoned slot
        self.lights: list[Light | None] = []  # None: a tombstoned slot
        self.camera: Camera = Camera()
        self.world_color = np.zeros(3)
        self.world_lights = True  # the world colour also lights surfaces (as in Cycles)
        self.stats: dict[str, int] = {"degenerate_triangles": 0}
        self.warnings: list[str] = []
        self.mesh_keys = SlotKeys("mesh")
        self.material_keys = SlotKeys("material")
        self.instance_keys = SlotKeys("object")
        self.light_keys = SlotKeys("light")
        self._arrays: SceneArrays | None = None
        self._counts = None  # (objects, triangles) of the packing in _arrays
        self._mesh_arrays = None  # packed geometry, reused while meshes are unchanged
        #: Bytes the meshes may need in all (:mod:`.footprint`); None: the memory available
        #: when a mesh is added.
        self.memory_limit: int | None = None
        self._mesh_bytes = 0  # the meshes' estimated footprint, in all
        self._mesh_tris = 0  # the meshes' triangles, in all (:func:`.footprint.check_count`)

    def copy(self) -> Scene:
        """An independent copy (item data are shared: they are replaced, never mutated)."""
        c = Scene.__new__(Scene)
        c.meshes = list(self.meshes)
        c.materials = list(self.materials)
        c.instances = [None if i is None else dict(i) for i in self.instances]
        c.lights = list(self.lights)
        c.camera = self.camera
        c.world_color = self.world_color.copy()
        c.world_lights = self.world_lights
        c.stats = dict(self.stats)
        c.warnings = list(self.warnings)
        c.mesh_keys = self.mesh_keys.copy()
        c.material_keys = self.material_keys.copy()
        c.instance_keys = self.instance_keys.copy()
        c.light_keys = self.light_keys.copy()
        c._arrays = self._arrays
        c._counts = self._counts
        c._mesh_arrays = self._mesh_arrays
        c.memory_limit = self.memory_limit
        c._mesh_bytes = self._mesh_bytes
        c._mesh_tris = self._mesh_tris
        return c

    # -- lookups -----------------------------------------------------------------------

    def mesh_id(self, key) -> int:
        return self.mesh_keys.lookup(key)

    def material_id(self, key) -> int:
        return self.material_keys.lookup(key)

    def instance_slot(self, key) -> int:
        return self.instance_keys.lookup(key)

    def light_slot(self, key) -> int:
        return self.light_keys.lookup(key)

    def live_instances(self):
        """``(slot, instance dict)`` of every object that is not tombstoned."""
        return [(k, i) for k, i in enumerate(self.instances) if i is not None]

    def live_lights(self):
        """``(slot, Light)`` of every light that is not tombstoned."""
        return [(k, li) for k, li in enumerate(self.lights) if li is not None]

    @property
    def n_instances(self) -> int:
        """Objects in the scene (tombstoned slots do not count)."""
        if self._arrays is not None and self._counts is not None:
            return self._counts[0]
        return sum(i is not None for i in self.instances)

    @property
    def n_lights(self) -> int:
        return sum(li is not None for li in self.lights)

    def instance_box(self, slot: int) -> np.ndarray:
        """World box (2, 3) of the object in ``slot`` (even when hidden)."""
        return self.instances[slot]["aabb"]

    # -- authoring -------------------------------------------------------------------

    def warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)
            log.warning(message)

    def add_material(self, material: Material, key=None) -> int:
        """Add a material; returns its id (the lowest tombstoned slot, else a new one)."""
        checked = material.validated()
        key = self.material_keys.new_key(key, material.name, len(self.materials))
        mid = self.material_keys.place(self.materials, checked, key)
        self._arrays = None
        return mid

    def set_material(self, material_id: int, material: Material) -> None:
        """Replace material ``material_id``'s parameters (validated first)."""
        if not self._live_material(material_id):
            raise SceneError(f"material '{material.name}': unknown material id {material_id}")
        self.materials[material_id] = material.validated()
        self._arrays = None

    def _live_material(self, mid: int) -> bool:
        return 0 <= mid < len(self.materials) and self.materials[mid] is not None

    def delete_material(self, material_id: int) -> None:
        """Remove a material no object uses (hidden ones included): its slot becomes a
        tombstone (packed as a plain grey no ray can meet), reused by :meth:`add_material`."""
        if not self._live_material(material_id):
            raise SceneError(f"material id {material_id}: no such material (deleted or never "
                             f"added)")
        users = [i["name"] for _, i in self.live_instances() if material_id in i["materials"]]
        if users:
            raise SceneError(f"material '{self.materials[material_id].name}': still used by "
                             f"object '{users[0]}' ({len(users)} user(s))")
        self.materials[material_id] = None
        key = next(k for k, v in self.material_keys.slot.items() if v == material_id)
        del self.material_keys.slot[key]
        self.material_keys.free.append(material_id)
        self._arrays = None

    def add_mesh(self, mesh: Mesh, key=None, cancel=None) -> int:
        """Validate and store a mesh; degenerate triangles are dropped and counted.

        Returns its id: the lowest tombstoned mesh slot, else a new one. ``cancel`` (a
        ``() -> bool``, e.g. a :class:`~rstrace_engine.cancel.CancelFlag`) is polled every
        :data:`~.mesh_math.PROPER_CHUNK` triangles of the area test; when it turns True,
        :class:`~rstrace_engine.cancel.Cancelled` is raised and the scene is unchanged.
        """
        self._check_footprint(mesh, None)
        checked = self._checked_mesh(mesh, cancel)
        self._mesh_bytes += _footprint(checked)
        self._mesh_tris += len(checked["tris"])
        key = self.mesh_keys.new_key(key, mesh.name, len(self.meshes))
        mid = self.mesh_keys.place(self.meshes, checked, key)
        self._arrays = None
        self._mesh_arrays = None
        return mid

    def _live_mesh(self, mesh_id: int) -> bool:
        return 0 <= mesh_id < len(self.meshes) and self.meshes[mesh_id] is not None

    def mesh_users(self, mesh_id: int) -> list[int]:
        """Slots of the objects (hidden ones included) that use mesh ``mesh_id``."""
        return [k for k, i in self.live_instances() if i["mesh"] == mesh_id]

    def delete_mesh(self, mesh_id: int) -> None:
        """Remove a mesh no object uses: its slot becomes a tombstone (no triangles),
        reused by a later :meth:`add_mesh`. Raises :class:`SceneError` while an object
        (hidden or not) still uses it."""
        if not self._live_mesh(mesh_id):
            raise SceneError(f"mesh id {mesh_id}: no such mesh (deleted or never added)")
        name = self.meshes[mesh_id]["name"]
        users = self.mesh_users(mesh_id)
        if users:
            raise SceneError(f"mesh '{name}': still used by object "
                             f"'{self.instances[users[0]]['name']}' (delete or re-mesh "
                             f"its {len(users)} user(s) first)")
        self._mesh_bytes -= _footprint(self.meshes[mesh_id])
        self._mesh_tris -= len(self.meshes[mesh_id]["tris"])
        self.meshes[mesh_id] = None
        key = next(k for k, v in self.mesh_keys.slot.items() if v == mesh_id)
        del self.mesh_keys.slot[key]
        self.mesh_keys.free.append(mesh_id)
        self._arrays = None
        self._mesh_arrays = None

    def set_mesh(self, mesh_id: int, mesh: Mesh, cancel=None) -> None:
        """Replace mesh ``mesh_id``'s data; every object using it follows (``cancel``: as
        for :meth:`add_mesh`)."""
        if not self._live_mesh(mesh_id):
            raise SceneError(f"mesh '{mesh.name}': unknown mesh id {mesh_id}")
        self._check_footprint(mesh, mesh_id)
        checked = self._checked_mesh(mesh, cancel)
        self._mesh_bytes += _footprint(checked) - _footprint(self.meshes[mesh_id])
        self._mesh_tris += len(checked["tris"]) - len(self.meshes[mesh_id]["tris"])
        self.meshes[mesh_id] = checked
        for i in self.instances:
            if i is not None and i["mesh"] == mesh_id:
                self._place(i)
        self._arrays = None
        self._mesh_arrays = None

    def _check_footprint(self, mesh: Mesh, replaced: int | None) -> None:
        """Refuse (before anything is copied) a mesh past the scene's triangle limit or the
        memory (:func:`~.footprint.check_count`, :func:`~.footprint.check_fits`, counting
        the other meshes but ``replaced``)."""
        try:
            m, v = int(np.shape(mesh.triangles)[0]), int(np.shape(mesh.vertices)[0])
        except (TypeError, ValueError, IndexError):
            return  # not arrays of rows: validation says what is wrong
        others, tris = self._mesh_bytes, self._mesh_tris
        if replaced is not None:
            others -= _footprint(self.meshes[replaced])
            tris -= len(self.meshes[replaced]["tris"])
        check_count(mesh.name, m, tris)
        check_fits(mesh.name, m, v, others, self.memory_limit)

    def _checked_mesh(self, mesh: Mesh, cancel=None) -> dict:
        """:func:`~.mesh_check.checked_mesh`, its dropped triangles counted and reported."""
        def dropped(count: int) -> None:
            self.stats["degenerate_triangles"] += count
            self.warn(f"mesh '{mesh.name}': dropped {count} degenerate triangle(s)")

        return checked_mesh(mesh, cancel, dropped)

    # objects

    def add_instance(self, mesh_id: int, matrix, materials=(0,), name: str | None = None,
                     key=None, visible: bool = True) -> int:
        """Place mesh ``mesh_id`` with object-to-world ``matrix`` and per-slot materials.

        Returns the object's slot: the lowest tombstoned slot, else a new one.
        """
        name = name or f"instance{len(self.instances)}"
        if not self._live_mesh(mesh_id):
            raise SceneError(f"object '{name}': unknown mesh id {mesh_id}")
        mats = self._checked_materials(name, materials)
        m = check_matrix(name, matrix)
        key = self.instance_keys.new_key(key, name, len(self.instances))
        inst = dict(name=name, key=key, mesh=mesh_id, matrix=m, materials=mats,
                    visible=bool(visible))
        self._place(inst)
        slot = self.instance_keys.place(self.instances, inst, key)
        self._arrays = None
        return slot

    def _checked_materials(self, name: str, materials) -> list[int]:
        mats = [int(x) for x in materials] or [0]
        for mid in mats:
            if not self._live_material(mid):
                raise SceneError(f"object '{name}': unknown material id {mid} (add "
                                 f"materials first)")
        return mats

    def _place(self, inst: dict) -> None:
        """Cache an instance's inverse, normal matrix and world box (packing stacks them)."""
        m = inst["matrix"]
        mesh = self.meshes[inst["mesh"]]
        inv = linalg.inv(m)  # (np.linalg.inv's bits, no OpenBLAS threads woken)
        inst["inv"] = inv
        inst["nmat"] = inv[:3, :3].T.copy()
        inst["aabb"] = transform_aabb(mesh["lo"], mesh["hi"], m)

    def _live(self, slot: int) -> dict:
        if not 0 <= slot < len(self.instances) or self.instances[slot] is None:
            raise SceneError(f"object slot {slot}: no such object (deleted or never added)")
        return self.instances[slot]

    def set_instance_matrix(self, index: int, matrix) -> None:
        """Move an instance (an edit): only its transform and bounds are repacked."""
        inst = self._live(index)
        m = check_matrix(inst["name"], matrix)
        inst["matrix"] = m
        self._place(inst)
        self._arrays = None

    def set_instance_mesh(self, index: int, mesh_id: int) -> None:
        inst = self._live(index)
        if not self._live_mesh(mesh_id):
            raise SceneError(f"object '{inst['name']}': unknown mesh id {mesh_id}")
        inst["mesh"] = int(mesh_id)
        self._place(inst)
        self._arrays = None

    def set_instance_materials(self, index: int, materials) -> None:
        inst = self._live(index)
        inst["materials"] = self._checked_materials(inst["name"], materials)
        self._arrays = None

    def set_instance_visible(self, index: int, visible: bool) -> None:
        inst = self._live(index)
        inst["visible"] = bool(visible)
        self._arrays = None

    def delete_instance(self, index: int) -> None:
        """Remove an object: its slot becomes a tombstone, reused by a later addition."""
        inst = self._live(index)
        self.instances[index] = None
        del self.instance_keys.slot[inst["key"]]
        self.instance_keys.free.append(index)
        self._arrays = None

    # lights

    def add_light(self, light: Light, key=None) -> int:
        """Add a light; returns its slot (the lowest tombstoned one, else a new one)."""
        li = checked_light(light)
        keys = self.light_keys
        if not keys.free and len(self.lights) >= MAX_LIGHTS:
            raise SceneError(f"light '{light.name}': the scene has {len(self.lights)} light "
                             f"slots, at most {MAX_LIGHTS} (MAX_LIGHTS) are supported")
        key = keys.new_key(key, light.name, len(self.lights))
        slot = keys.place(self.lights, li, key)
        self._arrays = None
        return slot

    def set_light(self, slot: int, light: Light) -> None:
        """Replace the light in ``slot`` (validated first)."""
        if not 0 <= slot < len(self.lights) or self.lights[slot] is None:
            raise SceneError(f"light '{light.name}': no light in slot {slot}")
        self.lights[slot] = checked_light(light)
        self._arrays = None

    def delete_light(self, slot: int) -> None:
        if not 0 <= slot < len(self.lights) or self.lights[slot] is None:
            raise SceneError(f"light slot {slot}: no such light (deleted or never added)")
        self.lights[slot] = None
        key = next(k for k, v in self.light_keys.slot.items() if v == slot)
        del self.light_keys.slot[key]
        self.light_keys.free.append(slot)
        self._arrays = None

    def light_key(self, slot: int):
        return next(k for k, v in self.light_keys.slot.items() if v == slot)

    def set_camera(self, camera: Camera) -> None:
        """Validate (:func:`~.elements.checked_camera`) and set the camera."""
        self.camera = checked_camera(camera)

    def set_world_color(self, color, lights: bool | None = None) -> None:
        """The world's uniform colour: what a ray that misses sees and, with ``lights``
        (the default for a new scene; None keeps the current setting), the radiance that
        lights every surface from its hemisphere, with occlusion (Cycles' world light with
        no bounces). ``lights=False`` is a background only, as Blender's world with its
        diffuse and glossy ray visibility off."""
        self.world_color = _colour("world", "world colour", color, hi=None)
        if lights is not None:
            self.world_lights = bool(lights)
        self._arrays = None

    # -- packing ---------------------------------------------------------------------

    def _pack_meshes(self):
        """The packing's geometry (:func:`~.packing.pack_meshes`: the meshes then held
        once, as views of it), kept while the meshes are unchanged."""
        if self._mesh_arrays is None:
            if all(m is None for m in self.meshes):
                raise SceneError("scene has no meshes")
            self._mesh_arrays = pack_meshes(self.meshes)
        return self._mesh_arrays

    def arrays(self) -> SceneArrays:
        """Pack (or return the cached packing of) the scene. Raises :class:`SceneError`."""
        if self._arrays is not None:
            return self._arrays
        live = [i is not None and i["visible"] for i in self.instances]
        if not any(i is not None for i in self.instances):
            raise SceneError("scene has no objects to render")
        if not self.materials:
            raise SceneError("scene has no materials")
        geo = self._pack_meshes()
        ni = len(self.instances)
        eye = np.eye(4)
        alive = np.array(live, bool)
        # C order whatever the host gave (Blender's matrices arrive column-major, and
        # np.stack keeps their layout): one layout, one compiled kernel
        xf = np.ascontiguousarray(
            np.stack([eye if i is None else i["matrix"] for i in self.instances]))
        inv = np.stack([eye if i is None else i["inv"] for i in self.instances])
        nmat = np.stack([eye[:3, :3] if i is None else i["nmat"] for i in self.instances])
        aabb = np.stack([i["aabb"] if ok else DEAD_AABB
                         for i, ok in zip(self.instances, live, strict=True)])
        inst_mats = [[0] if i is None else i["materials"] for i in self.instances]
        mat_start = np.cumsum([0] + [len(m) for m in inst_mats])
        mats = [_DEAD_MATERIAL if m is None else m for m in self.materials]
        tex_mats = [m for m in mats if m.texture is not None]
        tex_list = [m.texture for m in tex_mats]
        tex_ids, k = [], 0
        for m in mats:
            tex_ids.append(k if m.texture is not None else -1)
            k += m.texture is not None
        tex_size = np.array([[m.texture.shape[1], m.texture.shape[0], m.texture_flags]
                             for m in tex_mats], np.int32).reshape(-1, 3)
        tex_start = np.cumsum([0] + [t.shape[0] * t.shape[1] for t in tex_list]).astype(np.int64)
        tex_data = (np.concatenate([t.reshape(-1, 3) for t in tex_list]).astype(np.float32)
                    if tex_list else np.zeros((1, 3), np.float32))
        if alive.any():
            lo, hi = aabb[alive, 0].min(axis=0), aabb[alive, 1].max(axis=0)
        else:  # every object hidden: an empty picture of the world colour
            lo, hi = -np.ones(3), np.ones(3)
        extent = float(np.linalg.norm(hi - lo))
        if not extent > 0.0:
            extent = max(float(np.max(np.abs(hi))), 1.0)
        f64 = np.float64
        self._arrays = SceneArrays(
            verts=geo["verts"], tris=geo["tris"], normals=geo["normals"],
            mesh_nrm=geo["mesh_nrm"], uvs=geo["uvs"], mesh_uv=geo["mesh_uv"],
            tri_slot=geo["tri_slot"], mesh_slot=geo["mesh_slot"],
            mesh_tri_start=geo["mesh_tri_start"], mesh_gen=geo["mesh_gen"],
            inst_mesh=np.array([0 if i is None else i["mesh"] for i in self.instances],
                               np.int32).reshape(ni),
            inst_xform=xf, inst_inv=inv, inst_nmat=nmat, inst_aabb=aabb,
            inst_mat_start=mat_start.astype(np.int32),
            inst_mat=np.array([x for m in inst_mats for x in m], np.int32),
            mat_diffuse=np.array([m.diffuse for m in mats], f64),
            mat_specular=np.array([m.specular for m in mats], f64),
            mat_roughness=np.array([m.roughness for m in mats], f64),
            mat_mirror=np.array([m.mirror for m in mats], f64),
            mat_transmission=np.array([m.transmission for m in mats], f64),
            mat_ior=np.array([m.ior for m in mats], f64),
            mat_emission=np.array([m.emission for m in mats], f64),
            mat_tex=np.array(tex_ids, np.int32),
            mat_model=np.array([SHADING_MODELS[m.model] for m in mats], np.int32),
            mat_metallic=np.array([m.metallic for m in mats], f64),
            mat_metal=np.array([m.metal for m in mats], f64).reshape(-1, 3),
            mat_specular_ior=np.array([m.specular_ior for m in mats], f64),
            mat_tint_max=np.array([m.specular_tint_max for m in mats], f64),
            mat_metal_tint=np.array([m.metal_tint for m in mats], f64).reshape(-1, 3),
            tex_data=tex_data, tex_start=tex_start, tex_size=tex_size,
            tex_map=np.array([m.texture_map for m in tex_mats], f64).reshape(-1, 2, 4),
            scene_aabb=np.stack([lo, hi]), scene_extent=extent, inst_alive=alive,
            **self._light_fields(),
        )
        self._counts = (sum(i is not None for i in self.instances),
                        sum(len(self.meshes[i["mesh"]]["tris"]) for _, i in self.live_instances()))
        return self._arrays

    def _light_fields(self) -> dict:
        """The packing's fields that the lights and the world make."""
        f64 = np.float64
        return dict(world_color=np.asarray(self.world_color, f64),
                    world_light=(np.asarray(self.world_color, f64) if self.world_lights
                                 else np.zeros(3)),
                    **pack_lights(self.lights, [None if i is None else i["name"]
                                                for i in self.instances]))

    def repack_lights(self, packed: SceneArrays) -> None:
        """Pack the scene from ``packed``, the packing of a scene that differs from this
        one in its lights and world alone (a light or world edit: the instances, meshes and
        materials are not packed again)."""
        self._arrays = packed._replace(**self._light_fields())

    @property
    def triangle_count(self) -> int:
        """Triangles in the world (instances count their mesh's triangles each)."""
        if self._arrays is not None and self._counts is not None:
            return self._counts[1]
        return sum(len(self.meshes[i["mesh"]]["tris"]) for _, i in self.live_instances())
