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
``MaterialSet``        a material added or its parameters changed
``LightSet``           a light added or changed (position, power, colour, cone, kind)
``LightDelete``        a light removed
``WorldColor``         the world (background) colour
``CameraChange``       the camera: invalidates nothing (interpolants are view-independent)
=====================  ===============================================================
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

from .scene import Camera, Light, Material, Mesh


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


@dataclass(frozen=True)
class ObjectDelete:
    key: Hashable


@dataclass(frozen=True)
class MeshSet:
    key: Hashable
    mesh: Mesh


@dataclass(frozen=True)
class MaterialSet:
    key: Hashable
    material: Material


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


@dataclass(frozen=True)
class CameraChange:
    camera: Camera


Edit = (ObjectTransform | ObjectGeometry | ObjectMaterials | ObjectVisibility | ObjectAdd
        | ObjectDelete | MeshSet | MaterialSet | LightSet | LightDelete | WorldColor
        | CameraChange)


@dataclass
class EditReport:
    """What :meth:`Session.apply` did, for the status line and the benchmarks."""

    edits: int = 0  # edits applied
    kinds: dict = field(default_factory=dict)  # edit class name -> count
    invalidated_interpolants: int = 0
    dirty_pixels: int = 0  # pixels the next frame re-renders (fixed camera), else -1
    dirty_fraction: float = 0.0
    camera_changed: bool = False
    rst_query_ms: float = 0.0  # RST traversal + membership + invalidation
    apply_ms: float = 0.0  # everything apply() did
    messages: list = field(default_factory=list)
