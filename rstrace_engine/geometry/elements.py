"""Scene elements as a host authors them: materials, meshes, lights, cameras.

Small Python objects validated when they are added to a :class:`~.scene.Scene` (every error
names the object, raising :class:`~rstrace_engine.errors.SceneError`); also the checks
shared with the scene (:func:`check_matrix`). Conventions (units, light power, materials)
are in :mod:`.scene`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import tolerances as tol
from ..errors import SceneError

LIGHT_POINT, LIGHT_SUN, LIGHT_SPOT, LIGHT_AREA = 0, 1, 2, 3
LIGHT_NONE = -1  # a deleted light's slot (tombstone): skipped by every tracer
LIGHT_KINDS = {"POINT": LIGHT_POINT, "SUN": LIGHT_SUN, "SPOT": LIGHT_SPOT,
               "AREA": LIGHT_AREA}
#: Area light shapes; SQUARE and RECTANGLE pack as a rectangle, DISK and ELLIPSE as an ellipse.
AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")

#: light slots a scene may hold: light sets take a uint64 word per 64 slots
#: (tracing.light_bits), so the limit is cost, not layout -- every surface point shades every
#: light, and a frame's batches keep (rays, lights) arrays
MAX_LIGHTS = 1024
MAX_LIGHT_POWER = 1e12  # W (W/m2 for a sun): above it a value is taken as broken input


# ----------------------------------------------------------------------------- checks


def _finite_array(name: str, what: str, value, shape_tail, dtype=np.float64) -> np.ndarray:
    try:
        arr = np.array(value, dtype=dtype)  # a copy: the caller may change its array later
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
    m = np.array(matrix, dtype=np.float64)  # a copy: the caller may change its array later
    if m.shape != (4, 4):
        raise SceneError(f"object '{name}': world matrix must be 4x4, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise SceneError(f"object '{name}': world matrix has NaN or infinite entries")
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), rtol=0, atol=tol.MATRIX_AFFINE_ATOL):
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

#: :attr:`Material.texture_flags` bits, how a texture is sampled (Cycles' Image Texture):
#: nearest texel instead of bilinear (Interpolation *Closest*); texels stored sRGB-encoded
#: and decoded after interpolation (a byte sRGB image, as Cycles interpolates its bytes);
#: extension *Extend* (edge texels repeat) or *Clip* (black outside [0, 1]); neither: *Repeat*.
TEX_CLOSEST, TEX_SRGB, TEX_EXTEND, TEX_CLIP = 1, 2, 4, 8
#: Where the texture coordinates come from (Cycles' Texture Coordinate node): neither bit,
#: the mesh uvs (UV); the object-space position (Object); the object-space position
#: normalised to the mesh's bounding box, Blender's automatic texture space (Generated).
TEX_OBJECT, TEX_GENERATED = 16, 32
#: What the texel multiplies: the base colour (unless ``TEX_NO_BASE``), and the emission
#: with ``TEX_EMISSION`` (an image into Emission Color, or an Emission shader's Color).
TEX_EMISSION, TEX_NO_BASE = 64, 128
#: ... and, as Cycles' closure weights take the colour at the hit: the metal colour
#: (``TEX_METAL``: a metallic Principled's Base Color, a Glossy or Metallic BSDF's colour),
#: the dielectric layer's tint (``TEX_SPECULAR``: Specular Tint), the transmission tint per
#: crossing (``TEX_TRANSMISSION``: a Glass BSDF's colour; ``TEX_TRANSMISSION_SQRT``: its
#: square root, a transmissive Principled's Base Color).
TEX_METAL, TEX_SPECULAR, TEX_TRANSMISSION, TEX_TRANSMISSION_SQRT = 256, 512, 1024, 2048
#: The bits that say how a texture is sampled (two textures alike in these and in their
#: texels and map are one image read once).
TEX_SAMPLING = TEX_CLOSEST | TEX_SRGB | TEX_EXTEND | TEX_CLIP | TEX_OBJECT | TEX_GENERATED
#: The bits whose texel multiplies a weight other than the diffuse colour and the emission
#: (the radiance is then not always affine in it: ``interpolants.samples.nonlinear_roots``).
TEX_NONLINEAR = TEX_METAL | TEX_SPECULAR | TEX_TRANSMISSION | TEX_TRANSMISSION_SQRT
TEX_FLAGS_ALL = TEX_SAMPLING | TEX_EMISSION | TEX_NO_BASE | TEX_NONLINEAR
#: :attr:`Material.texture_map` of no mapping: ``(u, v)`` are the coordinates' x and y.
TEX_MAP_IDENTITY = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0))


def srgb_decode(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted (IEC 61966-2-1): encoded [0, 1] -> linear."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def texture_linear(texture: np.ndarray, flags: int) -> np.ndarray:
    """A texture's texels as linear RGB (decoded where ``flags`` has :data:`TEX_SRGB`)."""
    return srgb_decode(texture) if flags & TEX_SRGB else np.asarray(texture, np.float64)
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
    Fresnel reflectance that mirror rays carry (1 for a smooth surface, 0 for a rough one);
    ``specular_tint_max`` the tint's largest channel, which scales the layer's albedo that
    the base loses (Cycles' layering: under a darker tint more of the base shows).

    Both: ``transmission`` refracts with index ``ior``, the tracer's dielectric Fresnel
    splitting it into reflection and refraction; ``emission`` is radiance; ``texture`` is an
    optional ``(h, w, 3)`` RGB image that multiplies ``diffuse`` through the mesh uvs
    (``texture_flags``, ``TEX_*`` bits: how it is sampled -- interpolation, extension, sRGB
    encoding, coordinate source -- and what else the texel multiplies: the emission, the
    metal colour, the specular tint, the transmission); ``texture_map`` (2 x 4, affine)
    takes the coordinates ``(x, y, z)`` (uvs as ``(u, v, 0)``) to the image's ``(u, v)``
    (Mapping nodes, a flat projection).
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
    texture_flags: int = 0
    texture_map: tuple = TEX_MAP_IDENTITY
    specular_tint_max: float = 1.0
    metal_tint: tuple = (1.0, 1.0, 1.0)

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
        mt = _colour(n, f"material '{n}' metal edge tint", self.metal_tint, hi=None)
        mw = float(self.metallic)
        if not (math.isfinite(mw) and 0.0 <= mw <= 1.0):
            raise SceneError(f"material '{n}': metallic {mw} outside [0, 1]")
        if self.model == "WARD":
            if np.any(d + s + m + t > 1.0 + tol.MATERIAL_SUM_SLACK):
                raise SceneError(f"material '{n}': diffuse + specular + mirror + transmission "
                                 f"exceeds 1 in some channel (energy would be created)")
        elif (np.any(d + t + mw > 1.0 + tol.MATERIAL_SUM_SLACK)
              or np.any(s + t + mw > 1.0 + tol.MATERIAL_SUM_SLACK)):
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
        flags = int(self.texture_flags)
        if (flags & ~TEX_FLAGS_ALL or (flags & TEX_EXTEND and flags & TEX_CLIP)
                or (flags & TEX_OBJECT and flags & TEX_GENERATED)
                or (flags & TEX_TRANSMISSION and flags & TEX_TRANSMISSION_SQRT)):
            raise SceneError(f"material '{n}': texture flags {flags} are not a valid "
                             f"combination of TEX_* bits")
        stm = float(self.specular_tint_max)
        if not (math.isfinite(stm) and 0.0 <= stm <= 1.0):
            raise SceneError(f"material '{n}': specular tint maximum {stm} outside [0, 1]")
        tmap = np.asarray(self.texture_map, np.float64)
        if tmap.shape != (2, 4) or not np.all(np.isfinite(tmap)):
            raise SceneError(f"material '{n}': texture map must be 2 x 4 finite numbers")
        return Material(n, tuple(d), tuple(s), r, tuple(m), tuple(t), ior, tuple(e), tex,
                        self.model, mw, tuple(mc), sior, flags,
                        tuple(tuple(float(x) for x in row) for row in tmap), stm, tuple(mt))


@dataclass
class Mesh:
    """Triangle mesh in object space.

    vertices : (n, 3) float64
    triangles : (m, 3) int, indices into ``vertices``
    corner_normals : (m, 3, 3) optional per-corner shading normals; when absent, smooth
        area-weighted vertex normals are computed (``smooth=False`` gives flat normals)
    corner_uvs : (m, 3, 2) optional per-corner texture coordinates
    slots : (m,) optional material slot per triangle (index into the instance's list)
    vertex_normals : (n, 3) optional per-vertex shading normals (float32), every corner
        reading its vertex's (what Blender's POINT normals domain gives): the same as
        corner normals ``vertex_normals[triangles]``, without that (m, 3, 3) array; not
        with ``corner_normals``
    owned : the caller hands the arrays over and never changes them (the add-on's fresh
        exports): the scene keeps them without copying where their dtype is already the
        stored one, and keeps the validation with this object, so adding the same Mesh
        to another scene checks nothing again (:mod:`.mesh_check`)
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    corner_normals: np.ndarray | None = None
    corner_uvs: np.ndarray | None = None
    slots: np.ndarray | None = None
    smooth: bool = True
    vertex_normals: np.ndarray | None = None
    owned: bool = False
    #: (mesh dict, dropped triangles) of an ``owned`` mesh's validation
    _checked: tuple | None = field(default=None, init=False, repr=False, compare=False)


@dataclass
class Light:
    """A point, sun, spot or area light, as Blender and Cycles define them. ``power`` is
    watts (point, spot, area) or W/m^2 (sun).

    ``direction`` is the direction the light points (sun, spot) or emits (area: one-sided,
    toward ``direction``), world space. ``spot_size`` is the full cone angle in radians,
    ``spot_blend`` Blender's blend in [0, 1].

    Extent (0 everywhere: a point or a parallel sun, one shadow ray, as before):

    * ``radius`` (POINT, SPOT): Blender's ``shadow_soft_size``, a sphere light of that
      radius; ``soft_falloff`` Blender's ``use_soft_falloff``.
    * ``angle`` (SUN): the full angular diameter of the sun's cone of directions (radians,
      below pi).
    * ``shape``, ``axis``, ``size``, ``spread`` (AREA): ``"SQUARE"``, ``"RECTANGLE"``,
      ``"DISK"`` or ``"ELLIPSE"``; ``axis`` the world unit vector of the emitter's local +X
      (orthogonal to ``direction``); ``size`` the full world extents along ``axis`` and along
      ``cross(-direction, axis)``; ``spread`` Blender's spread angle in (0, pi].

    What the light reaches, as Cycles' ray visibility and light linking say:

    * ``diffuse``, ``glossy``: whether the light's direct light reaches the diffuse base
      and the glossy (specular and metallic) lobe of surfaces (Blender's ``visible_diffuse``
      and ``visible_glossy``).
    * ``spot_frame`` (SPOT): ``()`` for a round cone, else the 9 values of the light's world
      matrix's 3 x 3 part (row-major, scale included), whose scale reshapes the cone as
      Cycles reshapes it (elliptical for a non-uniform scale).
    * ``receivers``, ``blockers``: light and shadow linking, ``((object name, include),
      ...)``: ``()`` every object; with some included, only those; excluded never. Objects
      the light lights (receivers) and objects that cast its shadows (blockers).
    * ``camera``, ``glossy``, ``transmission``: whether camera rays, mirror reflection rays
      and smooth refraction rays see the light's own surface (a light with an extent), as
      Cycles (Blender's ``visible_camera``, off for a new light, ``visible_glossy``,
      ``visible_transmission``): :mod:`~rstrace_engine.tracing.seen_lights`.
    """

    name: str = "light"
    kind: str = "POINT"
    color: tuple = (1.0, 1.0, 1.0)
    power: float = 1000.0
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, -1.0)
    spot_size: float = math.radians(45.0)
    spot_blend: float = 0.15
    radius: float = 0.0
    soft_falloff: bool = True
    angle: float = 0.0
    shape: str = "SQUARE"
    axis: tuple = (1.0, 0.0, 0.0)
    size: tuple = (1.0, 1.0)
    spread: float = math.pi
    diffuse: bool = True
    glossy: bool = True
    spot_frame: tuple = ()
    receivers: tuple = ()
    blockers: tuple = ()
    camera: bool = False
    transmission: bool = True

    @property
    def extended(self) -> bool:
        """Whether the light has an extent (it is then sampled, not one shadow ray)."""
        if self.kind == "AREA":
            return True
        if self.kind == "SUN":
            return self.angle > 0.0
        return self.radius > 0.0


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


# ----------------------------------------------------------------------------- validation


def checked_camera(camera: Camera) -> Camera:
    """A validated copy of ``camera`` (float64 matrix, plain floats); raises
    :class:`SceneError` naming the bad setting."""
    c = camera
    m = np.array(c.matrix, dtype=np.float64)
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
    return Camera(m, c.kind, float(c.lens), float(c.sensor_width), float(c.sensor_height),
                  c.sensor_fit, float(c.shift_x), float(c.shift_y), float(c.clip_start),
                  float(c.clip_end), float(c.ortho_scale), int(c.width), int(c.height))
