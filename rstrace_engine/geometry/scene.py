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
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .. import tolerances as tol

log = logging.getLogger(__name__)

LIGHT_POINT, LIGHT_SUN, LIGHT_SPOT = 0, 1, 2
LIGHT_KINDS = {"POINT": LIGHT_POINT, "SUN": LIGHT_SUN, "SPOT": LIGHT_SPOT}

MAX_LIGHTS = 64  # light visibility is recorded as a 64-bit mask per ray-tree node


class SceneError(ValueError):
    """Invalid scene input. The message names the offending object or setting."""


# ----------------------------------------------------------------------------- checks


def _finite_array(name: str, what: str, value, shape_tail, dtype=np.float64) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{what} '{name}': cannot read as numbers ({exc})") from None
    if shape_tail is not None:
        tail = tuple(shape_tail)
        if arr.ndim != len(tail) + 1 or arr.shape[1:] != tail:
            raise SceneError(f"{what} '{name}': expected shape (n, {', '.join(map(str, tail))}),"
                             f" got {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise SceneError(f"{what} '{name}': {bad} NaN or infinite value(s)")
    return arr


def _colour(name: str, what: str, value, lo: float = 0.0, hi: float | None = 1.0) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3:
        raise SceneError(f"{what}: expected an RGB triple, got {arr.size} values ({name})")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what}: NaN or infinite value ({name})")
    if np.any(arr < lo) or (hi is not None and np.any(arr > hi)):
        rng = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise SceneError(f"{what}: {arr.tolist()} is outside {rng} ({name})")
    return arr


def check_matrix(name: str, matrix) -> np.ndarray:
    """Validate a 4x4 affine object-to-world matrix; return it as float64."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError(f"object '{name}': world matrix must be 4x4, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise SceneError(f"object '{name}': world matrix has NaN or infinite entries")
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), rtol=0, atol=1e-9):
        raise SceneError(f"object '{name}': world matrix is projective (bottom row "
                         f"{m[3].tolist()}), only affine transforms are supported")
    lin = m[:3, :3]
    norms = np.linalg.norm(lin, axis=0)
    det = float(np.linalg.det(lin))
    if np.min(norms) == 0.0 or abs(det) <= tol.SINGULAR_DET_REL * float(np.prod(norms)):
        raise SceneError(f"object '{name}': world matrix is singular (zero scale on some "
                         f"axis, scale {norms.tolist()})")
    if np.max(np.abs(m[:3, 3])) > tol.COORD_MAX or np.max(norms) > tol.COORD_MAX:
        raise SceneError(f"object '{name}': world matrix magnitude exceeds {tol.COORD_MAX:g}")
    return m


# ----------------------------------------------------------------------------- authoring


#: Shading models of :class:`Material` (their codes in ``SceneArrays.mat_model``).
MODEL_WARD, MODEL_PRINCIPLED = 0, 1
SHADING_MODELS = {"WARD": MODEL_WARD, "PRINCIPLED": MODEL_PRINCIPLED}


@dataclass
class Material:
    """A Ward or Principled-like material plus Whitted mirror and refraction. Colours are
    linear RGB in [0, 1].

    ``model`` ``"WARD"`` (seed 000's model, the default here): ``diffuse`` Lambertian albedo,
    ``specular`` Ward's rho_s with ``roughness`` Ward's alpha (RMS slope) in (0, 1], ``mirror``
    a constant mirror reflectance.

    ``model`` ``"PRINCIPLED"`` (what Blender materials export to by default): ``diffuse`` the
    base under a GGX layer (scaled in the tracer by one minus that layer's albedo toward the
    viewer), ``specular`` the dielectric layer's weight times its tint, with the exact Fresnel
    of index ``specular_ior`` (1: no dielectric reflection), ``metallic`` the conductor's
    weight and ``metal`` its colour at normal incidence; ``roughness`` is GGX alpha. Lights
    make highlights through the GGX lobe; ``mirror`` (in [0, 1]) is the share of the layer's
    Fresnel reflectance that mirror rays carry (1 for a smooth surface, 0 for a rough one).

    Both: ``transmission`` refracts with index ``ior``, the tracer's dielectric Fresnel
    splitting it into reflection and refraction; ``emission`` is radiance; ``texture`` is an
    optional ``(h, w, 3)`` linear RGB image that multiplies ``diffuse`` through the mesh uvs.
    """

    name: str = "material"
    diffuse: tuple = (0.8, 0.8, 0.8)
    specular: tuple = (0.0, 0.0, 0.0)
    roughness: float = 0.2
    mirror: tuple = (0.0, 0.0, 0.0)
    transmission: tuple = (0.0, 0.0, 0.0)
    ior: float = 1.45
    emission: tuple = (0.0, 0.0, 0.0)
    texture: np.ndarray | None = None
    model: str = "WARD"
    metallic: float = 0.0
    metal: tuple = (0.0, 0.0, 0.0)
    specular_ior: float = 1.5

    def validated(self) -> Material:
        n = self.name
        if self.model not in SHADING_MODELS:
            raise SceneError(f"material '{n}': unknown shading model {self.model!r} "
                             f"(expected one of {sorted(SHADING_MODELS)})")
        d = _colour(n, f"material '{n}' diffuse", self.diffuse)
        s = _colour(n, f"material '{n}' specular", self.specular)
        m = _colour(n, f"material '{n}' mirror", self.mirror)
        t = _colour(n, f"material '{n}' transmission", self.transmission)
        e = _colour(n, f"material '{n}' emission", self.emission, hi=None)
        mc = _colour(n, f"material '{n}' metal", self.metal)
        mw = float(self.metallic)
        if not (math.isfinite(mw) and 0.0 <= mw <= 1.0):
            raise SceneError(f"material '{n}': metallic {mw} outside [0, 1]")
        if self.model == "WARD":
            if np.any(d + s + m + t > 1.0 + 1e-6):
                raise SceneError(f"material '{n}': diffuse + specular + mirror + transmission "
                                 f"exceeds 1 in some channel (energy would be created)")
        elif np.any(d + t + mw > 1.0 + 1e-6) or np.any(s + t + mw > 1.0 + 1e-6):
            raise SceneError(f"material '{n}': diffuse (or specular) + transmission + "
                             f"metallic exceeds 1 in some channel (energy would be created)")
        r = float(self.roughness)
        if not (math.isfinite(r) and 1e-4 <= r <= 1.0):
            raise SceneError(f"material '{n}': roughness {r} outside [1e-4, 1]")
        ior = float(self.ior)
        if not (math.isfinite(ior) and 1.0 <= ior <= 10.0):
            raise SceneError(f"material '{n}': IOR {ior} outside [1, 10]")
        sior = float(self.specular_ior)
        if not (math.isfinite(sior) and 1.0 <= sior <= 10.0):
            raise SceneError(f"material '{n}': specular IOR {sior} outside [1, 10]")
        tex = None
        if self.texture is not None:
            tex = _finite_array(n, f"material '{n}' texture", self.texture, None, np.float32)
            if tex.ndim != 3 or tex.shape[2] < 3 or tex.shape[0] < 1 or tex.shape[1] < 1:
                raise SceneError(f"material '{n}': texture must be (h, w, 3), got {tex.shape}")
            tex = np.ascontiguousarray(tex[:, :, :3])
        return Material(n, tuple(d), tuple(s), r, tuple(m), tuple(t), ior, tuple(e), tex,
                        self.model, mw, tuple(mc), sior)


@dataclass
class Mesh:
    """Triangle mesh in object space.

    vertices : (n, 3) float64
    triangles : (m, 3) int, indices into ``vertices``
    corner_normals : (m, 3, 3) optional per-corner shading normals; when absent, smooth
        area-weighted vertex normals are computed (``smooth=False`` gives flat normals)
    corner_uvs : (m, 3, 2) optional per-corner texture coordinates
    slots : (m,) optional material slot per triangle (index into the instance's list)
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    corner_normals: np.ndarray | None = None
    corner_uvs: np.ndarray | None = None
    slots: np.ndarray | None = None
    smooth: bool = True


@dataclass
class Light:
    """A point, sun or spot light. ``power`` is watts (point, spot) or W/m^2 (sun).

    ``direction`` is the direction the light points (sun, spot), world space.
    ``spot_size`` is the full cone angle in radians, ``spot_blend`` Blender's blend in [0, 1].
    """

    name: str = "light"
    kind: str = "POINT"
    color: tuple = (1.0, 1.0, 1.0)
    power: float = 1000.0
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, -1.0)
    spot_size: float = math.radians(45.0)
    spot_blend: float = 0.15


@dataclass
class Camera:
    """A Blender-style camera. ``matrix`` is camera-to-world (looks down local -Z, +Y up).

    ``kind`` is ``"PERSP"`` or ``"ORTHO"``. Lens and sensor are in millimetres; ``sensor_fit``
    is ``"AUTO"``, ``"HORIZONTAL"`` or ``"VERTICAL"``; shifts are in units of the larger
    image dimension, as in Blender.
    """

    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: str = "PERSP"
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    shift_x: float = 0.0
    shift_y: float = 0.0
    clip_start: float = 1e-3
    clip_end: float = 1e6
    ortho_scale: float = 7.0
    width: int = 640
    height: int = 480


# ----------------------------------------------------------------------------- packed


class SceneArrays(NamedTuple):
    """The scene as flat arrays, for numba kernels. ``T`` triangles, ``I`` instances."""

    verts: np.ndarray  # (V, 3) float64, object space, all meshes concatenated
    tris: np.ndarray  # (T, 3) int32, global indices into verts
    tri_normals: np.ndarray  # (T, 3, 3) float32 per-corner shading normals, object space
    tri_uvs: np.ndarray  # (T, 3, 2) float32 per-corner uvs
    tri_slot: np.ndarray  # (T,) int32 material slot
    mesh_tri_start: np.ndarray  # (M + 1,) int32: mesh k owns tris[start[k]:start[k+1]]
    inst_mesh: np.ndarray  # (I,) int32
    inst_xform: np.ndarray  # (I, 4, 4) float64 object -> world
    inst_inv: np.ndarray  # (I, 4, 4) float64 world -> object
    inst_nmat: np.ndarray  # (I, 3, 3) float64 normal matrix (inverse transpose)
    inst_aabb: np.ndarray  # (I, 2, 3) float64 world bounds
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
    tex_data: np.ndarray  # (X, 3) float32 texels, all textures row-major concatenated
    tex_start: np.ndarray  # (NT + 1,) int64
    tex_size: np.ndarray  # (NT, 2) int32 (width, height)
    light_kind: np.ndarray  # (L,) int32
    light_pos: np.ndarray  # (L, 3) float64
    light_dir: np.ndarray  # (L, 3) float64 unit, the way the light points
    light_intensity: np.ndarray  # (L, 3) W/sr (point, spot) or W/m^2 (sun)
    light_cos_outer: np.ndarray  # (L,) spot cone cosines (1.0 / -1.0 otherwise)
    light_cos_inner: np.ndarray  # (L,)
    world_color: np.ndarray  # (3,) float64
    scene_aabb: np.ndarray  # (2, 3) float64 bounds of all instances
    scene_extent: float  # length of the scene box diagonal (> 0)


def _transform_aabb(lo: np.ndarray, hi: np.ndarray, m: np.ndarray) -> np.ndarray:
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    w = corners @ m[:3, :3].T + m[:3, 3]
    return np.stack([w.min(axis=0), w.max(axis=0)])


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted smooth vertex normals, (n, 3) float64, unit (or zero where isolated)."""
    v = vertices[triangles]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    acc = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(acc, triangles[:, k], fn)
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, ln, out=np.zeros_like(acc), where=ln > 0)


class Scene:
    """A mutable scene that validates on input and packs to :class:`SceneArrays`.

    ``stats`` collects counts of tolerated problems (dropped degenerate triangles, ...);
    ``warnings`` collects one message per distinct problem, for the host to report once.
    """

    def __init__(self) -> None:
        self.meshes: list[dict] = []
        self.materials: list[Material] = []
        self.instances: list[dict] = []
        self.lights: list[Light] = []
        self.camera: Camera = Camera()
        self.world_color = np.zeros(3)
        self.stats: dict[str, int] = {"degenerate_triangles": 0}
        self.warnings: list[str] = []
        self._arrays: SceneArrays | None = None
        self._mesh_arrays = None  # packed geometry, reused while meshes are unchanged

    # -- authoring -------------------------------------------------------------------

    def warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)
            log.warning(message)

    def add_material(self, material: Material) -> int:
        self.materials.append(material.validated())
        self._arrays = None
        return len(self.materials) - 1

    def add_mesh(self, mesh: Mesh) -> int:
        """Validate and store a mesh; degenerate triangles are dropped and counted."""
        n = mesh.name
        verts = _finite_array(n, "mesh", mesh.vertices, (3,))
        tris = np.asarray(mesh.triangles)
        if tris.size == 0 or verts.shape[0] == 0:
            raise SceneError(f"mesh '{n}': has no triangles")
        if tris.ndim != 2 or tris.shape[1] != 3 or tris.dtype.kind not in "iu":
            raise SceneError(f"mesh '{n}': triangles must be (m, 3) integers, got "
                             f"{tris.shape} {tris.dtype}")
        if tris.min() < 0 or tris.max() >= len(verts):
            raise SceneError(f"mesh '{n}': triangle index out of range [0, {len(verts)})")
        if np.max(np.abs(verts)) > tol.COORD_MAX:
            raise SceneError(f"mesh '{n}': vertex coordinates exceed {tol.COORD_MAX:g}")
        tris = tris.astype(np.int32)
        m = len(tris)
        normals = uvs = slots = None
        if mesh.corner_normals is not None:
            normals = _finite_array(n, "mesh normals", mesh.corner_normals, (3, 3), np.float32)
            if len(normals) != m:
                raise SceneError(f"mesh '{n}': {len(normals)} corner normal triples for {m} "
                                 f"triangles")
        if mesh.corner_uvs is not None:
            uvs = _finite_array(n, "mesh uvs", mesh.corner_uvs, (3, 2), np.float32)
            if len(uvs) != m:
                raise SceneError(f"mesh '{n}': {len(uvs)} corner uv triples for {m} triangles")
        if mesh.slots is not None:
            slots = np.asarray(mesh.slots, dtype=np.int32).reshape(-1)
            if len(slots) != m or (m and slots.min() < 0):
                raise SceneError(f"mesh '{n}': material slots must be {m} non-negative ints")

        v = verts[tris]
        e0, e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], v[:, 2] - v[:, 1]
        area2 = np.linalg.norm(np.cross(e0, e1), axis=1)
        longest = np.max(np.stack([np.einsum("ij,ij->i", e, e) for e in (e0, e1, e2)]), axis=0)
        keep = (area2 > tol.DEGENERATE_AREA_REL * longest) & (longest > 0)
        dropped = int(m - np.count_nonzero(keep))
        if dropped:
            self.stats["degenerate_triangles"] += dropped
            self.warn(f"mesh '{n}': dropped {dropped} degenerate triangle(s)")
        if not np.any(keep):
            raise SceneError(f"mesh '{n}': all {m} triangles are degenerate (zero area)")
        tris = tris[keep]
        if normals is None:
            if mesh.smooth:
                vn = vertex_normals(verts, tris)
                normals = vn[tris].astype(np.float32)
            else:
                fv = verts[tris]
                fn = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
                fn /= np.linalg.norm(fn, axis=1, keepdims=True)
                normals = np.repeat(fn[:, None, :], 3, axis=1).astype(np.float32)
        else:
            normals = normals[keep]
        uvs = np.zeros((len(tris), 3, 2), np.float32) if uvs is None else uvs[keep]
        slots = np.zeros(len(tris), np.int32) if slots is None else slots[keep]
        self.meshes.append(dict(name=n, verts=verts, tris=tris, normals=normals, uvs=uvs,
                                slots=slots, lo=verts.min(axis=0), hi=verts.max(axis=0)))
        self._arrays = None
        self._mesh_arrays = None
        return len(self.meshes) - 1

    def add_instance(self, mesh_id: int, matrix, materials=(0,), name: str | None = None) -> int:
        """Place mesh ``mesh_id`` with object-to-world ``matrix`` and per-slot materials."""
        name = name or f"instance{len(self.instances)}"
        if not 0 <= mesh_id < len(self.meshes):
            raise SceneError(f"object '{name}': unknown mesh id {mesh_id}")
        mats = [int(x) for x in materials] or [0]
        for mid in mats:
            if not 0 <= mid < len(self.materials):
                raise SceneError(f"object '{name}': unknown material id {mid} (add "
                                 f"materials first)")
        m = check_matrix(name, matrix)
        self.instances.append(dict(name=name, mesh=mesh_id, matrix=m, materials=mats))
        self._arrays = None
        return len(self.instances) - 1

    def set_instance_matrix(self, index: int, matrix) -> None:
        """Move an instance (an edit): only its transform and bounds are repacked."""
        inst = self.instances[index]
        inst["matrix"] = check_matrix(inst["name"], matrix)
        self._arrays = None

    def add_light(self, light: Light) -> int:
        n = light.name
        if light.kind not in LIGHT_KINDS:
            raise SceneError(f"light '{n}': unknown kind {light.kind!r} "
                             f"(expected one of {sorted(LIGHT_KINDS)})")
        if len(self.lights) >= MAX_LIGHTS:
            raise SceneError(f"light '{n}': at most {MAX_LIGHTS} lights are supported")
        col = _colour(n, f"light '{n}' colour", light.color, hi=None)
        p = float(light.power)
        if not (math.isfinite(p) and 0.0 <= p <= 1e12):
            raise SceneError(f"light '{n}': power {p} outside [0, 1e12]")
        pos = _colour(n, f"light '{n}' position", light.position, lo=-tol.COORD_MAX,
                      hi=tol.COORD_MAX)
        d = np.asarray(light.direction, dtype=np.float64).reshape(3)
        ln = float(np.linalg.norm(d)) if np.all(np.isfinite(d)) else 0.0
        if ln == 0.0:
            raise SceneError(f"light '{n}': direction is zero, NaN or infinite")
        size = float(light.spot_size)
        blend = float(light.spot_blend)
        if light.kind == "SPOT" and not (0.0 < size <= math.pi and 0.0 <= blend <= 1.0):
            raise SceneError(f"light '{n}': spot size {size} / blend {blend} out of range")
        self.lights.append(Light(n, light.kind, tuple(col), p, tuple(pos), tuple(d / ln),
                                 size, blend))
        self._arrays = None
        return len(self.lights) - 1

    def set_camera(self, camera: Camera) -> None:
        c = camera
        m = np.asarray(c.matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise SceneError("camera: matrix must be a finite 4x4")
        check_matrix("camera", m)
        if c.kind not in ("PERSP", "ORTHO"):
            raise SceneError(f"camera: unsupported type {c.kind!r} (PERSP or ORTHO)")
        if c.sensor_fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
            raise SceneError(f"camera: unknown sensor fit {c.sensor_fit!r}")
        for label, v, lo, hi in (("lens", c.lens, 1e-3, 1e6),
                                 ("sensor width", c.sensor_width, 1e-3, 1e6),
                                 ("sensor height", c.sensor_height, 1e-3, 1e6),
                                 ("ortho scale", c.ortho_scale, 1e-9, 1e12),
                                 ("clip start", c.clip_start, 0.0, 1e12),
                                 ("shift x", c.shift_x, -100, 100),
                                 ("shift y", c.shift_y, -100, 100)):
            # Blender stores these as float32: a limit typed in Blender arrives rounded
            # (1e-9 as 9.99999997e-10), so the limits allow for that rounding
            slack = tol.FLOAT32_INPUT_REL
            if not (math.isfinite(v) and lo - slack * abs(lo) <= v <= hi + slack * abs(hi)):
                side = (f"is below the minimum {lo:g}" if v < lo else
                        f"is above the maximum {hi:g}" if v > hi else "is not a number")
                raise SceneError(f"camera: {label} {v:.9g} {side}")
        if not (math.isfinite(c.clip_end) and c.clip_end > c.clip_start):
            raise SceneError(f"camera: clip end {c.clip_end} must exceed clip start "
                             f"{c.clip_start}")
        if not (1 <= int(c.width) <= 65536 and 1 <= int(c.height) <= 65536):
            raise SceneError(f"camera: resolution {c.width}x{c.height} outside 1..65536")
        self.camera = Camera(m, c.kind, float(c.lens), float(c.sensor_width),
                             float(c.sensor_height), c.sensor_fit, float(c.shift_x),
                             float(c.shift_y), float(c.clip_start), float(c.clip_end),
                             float(c.ortho_scale), int(c.width), int(c.height))

    def set_world_color(self, color) -> None:
        self.world_color = _colour("world", "world colour", color, hi=None)
        self._arrays = None

    # -- packing ---------------------------------------------------------------------

    def _pack_meshes(self):
        if self._mesh_arrays is None:
            if not self.meshes:
                raise SceneError("scene has no meshes")
            vstart = np.cumsum([0] + [len(m["verts"]) for m in self.meshes])
            tstart = np.cumsum([0] + [len(m["tris"]) for m in self.meshes]).astype(np.int32)
            self._mesh_arrays = dict(
                verts=np.ascontiguousarray(np.concatenate([m["verts"] for m in self.meshes])),
                tris=np.ascontiguousarray(np.concatenate(
                    [m["tris"] + np.int32(vs)
                     for m, vs in zip(self.meshes, vstart[:-1], strict=True)]).astype(np.int32)),
                tri_normals=np.ascontiguousarray(np.concatenate(
                    [m["normals"] for m in self.meshes])),
                tri_uvs=np.ascontiguousarray(np.concatenate([m["uvs"] for m in self.meshes])),
                tri_slot=np.ascontiguousarray(np.concatenate([m["slots"] for m in self.meshes])),
                mesh_tri_start=tstart,
            )
        return self._mesh_arrays

    def arrays(self) -> SceneArrays:
        """Pack (or return the cached packing of) the scene. Raises :class:`SceneError`."""
        if self._arrays is not None:
            return self._arrays
        if not self.instances:
            raise SceneError("scene has no objects to render")
        if not self.materials:
            raise SceneError("scene has no materials")
        geo = self._pack_meshes()
        # C order whatever the host gave (Blender's matrices arrive column-major): kernels
        # are compiled per array layout, so one layout means one compile and one cache entry
        xf = np.ascontiguousarray(np.stack([i["matrix"] for i in self.instances]))
        inv = np.linalg.inv(xf)
        nmat = np.transpose(inv[:, :3, :3], (0, 2, 1)).copy()
        aabb = np.stack([_transform_aabb(self.meshes[i["mesh"]]["lo"],
                                         self.meshes[i["mesh"]]["hi"], i["matrix"])
                         for i in self.instances])
        mat_start = np.cumsum([0] + [len(i["materials"]) for i in self.instances])
        mats = self.materials
        tex_list = [m.texture for m in mats if m.texture is not None]
        tex_ids, k = [], 0
        for m in mats:
            tex_ids.append(k if m.texture is not None else -1)
            k += m.texture is not None
        tex_size = np.array([[t.shape[1], t.shape[0]] for t in tex_list], np.int32).reshape(-1, 2)
        tex_start = np.cumsum([0] + [t.shape[0] * t.shape[1] for t in tex_list]).astype(np.int64)
        tex_data = (np.concatenate([t.reshape(-1, 3) for t in tex_list]).astype(np.float32)
                    if tex_list else np.zeros((1, 3), np.float32))
        lights = self.lights
        nl = len(lights)
        intensity = np.zeros((nl, 3))
        cos_outer = np.full(nl, -1.0)
        cos_inner = np.full(nl, -1.0)
        for j, li in enumerate(lights):
            c = np.asarray(li.color)
            intensity[j] = c * li.power if li.kind == "SUN" else c * li.power / (4 * math.pi)
            if li.kind == "SPOT":
                half = 0.5 * li.spot_size
                cos_outer[j] = math.cos(half)
                # Cycles: smoothstep((cos - cos_outer) / ((1 - cos_outer) * blend))
                cos_inner[j] = cos_outer[j] + (1.0 - cos_outer[j]) * li.spot_blend
        lo, hi = aabb[:, 0].min(axis=0), aabb[:, 1].max(axis=0)
        extent = float(np.linalg.norm(hi - lo))
        if not extent > 0.0:
            extent = max(float(np.max(np.abs(hi))), 1.0)
        f64 = np.float64
        self._arrays = SceneArrays(
            verts=geo["verts"], tris=geo["tris"], tri_normals=geo["tri_normals"],
            tri_uvs=geo["tri_uvs"], tri_slot=geo["tri_slot"],
            mesh_tri_start=geo["mesh_tri_start"],
            inst_mesh=np.array([i["mesh"] for i in self.instances], np.int32),
            inst_xform=xf, inst_inv=inv, inst_nmat=nmat, inst_aabb=aabb,
            inst_mat_start=mat_start.astype(np.int32),
            inst_mat=np.array([x for i in self.instances for x in i["materials"]], np.int32),
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
            tex_data=tex_data, tex_start=tex_start, tex_size=tex_size,
            light_kind=np.array([LIGHT_KINDS[li.kind] for li in lights], np.int32),
            light_pos=np.array([li.position for li in lights], f64).reshape(nl, 3),
            light_dir=np.array([li.direction for li in lights], f64).reshape(nl, 3),
            light_intensity=intensity, light_cos_outer=cos_outer, light_cos_inner=cos_inner,
            world_color=np.asarray(self.world_color, f64),
            scene_aabb=np.stack([lo, hi]), scene_extent=extent,
        )
        return self._arrays

    @property
    def triangle_count(self) -> int:
        """Triangles in the world (instances count their mesh's triangles each)."""
        return sum(len(self.meshes[i["mesh"]]["tris"]) for i in self.instances)
