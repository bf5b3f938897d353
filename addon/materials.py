"""Blender materials -> :class:`rstrace_engine.geometry.scene.Material` (export's material half).

Reads the Principled BSDF (or a Diffuse, Emission, Glossy, Metallic or Glass BSDF) feeding
the material output, with one Image Texture read into a numpy texture: into a colour input
(Base Color, Emission Color, Specular Tint, a BSDF's Color), its texel multiplies that
colour's weights at each hit as Cycles' closure weights do; anything else falls back to the
material's viewport colour. Problems go to the export's :class:`Notes`.

Layer: imports no add-on module; imported by ``export`` and the readers it uses (``snapshot``,
``cameras``, ``lights``) and by ``depsgraph_diff`` (``image_changed``).
"""

from __future__ import annotations

import logging

import bpy
import numpy as np
from mathutils import Euler

from rstrace_engine import tolerances as tol
from rstrace_engine.geometry.principled import conductor_f82, principled_material
from rstrace_engine.geometry.scene import (
    TEX_CLIP,
    TEX_CLOSEST,
    TEX_EMISSION,
    TEX_EXTEND,
    TEX_GENERATED,
    TEX_MAP_IDENTITY,
    TEX_NO_BASE,
    TEX_OBJECT,
    TEX_SAMPLING,
    TEX_SPECULAR,
    TEX_SRGB,
    Material,
    Scene,
    SceneError,
)

log = logging.getLogger(__name__)

def default_material(model: str = "PRINCIPLED") -> Material:
    """Cycles' default surface, for empty material slots and objects without materials: a
    Principled BSDF with every input at its default (Base Color 0.8 grey, Roughness 0.5,
    IOR 1.5, Specular IOR Level 0.5: ``ShaderManager::add_default``), in the render's
    shading ``model``."""
    material, _ = principled_material("default", (0.8, 0.8, 0.8), metallic=0.0,
                                      roughness=0.5, ior=1.5, specular_level=0.5,
                                      model=model)
    return material


#: The default surface of the default (Principled-like) shading model.
DEFAULT_MATERIAL = default_material()



class Notes:
    """Problems found during export, grouped so that each kind is reported once.

    ``warn(kind, name)`` collects object names under one message per kind;
    ``skip(message)`` records an object that was left out; ``info`` is for the stats only.
    """

    def __init__(self) -> None:
        self._kinds: dict[str, list[str]] = {}
        self.skipped: list[str] = []
        self.info: list[str] = []

    def warn(self, kind: str, name: str | None = None) -> None:
        names = self._kinds.setdefault(kind, [])
        if name is not None and name not in names:
            names.append(name)

    def skip(self, message: str) -> None:
        if message not in self.skipped:
            self.skipped.append(message)

    def recorded(self) -> list[tuple]:
        """Every ``warn`` call as ``(kind, name)``, to be replayed into another Notes."""
        return [(kind, name) for kind, names in self._kinds.items()
                for name in (names or [None])]

    def replay(self, recorded: list[tuple]) -> None:
        for kind, name in recorded:
            self.warn(kind, name)

    @property
    def warnings(self) -> list[str]:
        """One line per kind of problem, then one per skipped object."""
        out = []
        for kind, names in self._kinds.items():
            if names:
                shown = ", ".join(f"'{n}'" for n in names[:6])
                more = f" and {len(names) - 6} more" if len(names) > 6 else ""
                out.append(f"{kind}: {shown}{more}")
            else:
                out.append(kind)
        return out + self.skipped



def rgb(value) -> np.ndarray:
    return np.clip(np.array(value[:3], dtype=np.float64), 0.0, None)


# ----------------------------------------------------------------------------- materials


def follow_link(socket):
    """The node and output socket feeding ``socket`` (through reroutes), or (None, None)."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None, None
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            seen += 1
            continue
        return node, link.from_socket
    return None, None


class MaterialReader:
    """Converts Blender materials to :class:`Material` (each once per export)."""

    def __init__(self, scene: Scene | None, notes: Notes, model: str = "PRINCIPLED",
                 textures: dict | None = None) -> None:
        self.scene = scene
        self.notes = notes
        self.model = model  # shading model of the Principled conversions
        self.textures = textures  # image session_uid -> (generation, pixels): kept by caller
        self.images: set = set()  # session_uids of the images read (textures cache keys)
        self.uv_maps: set = set()  # UV maps named by UV Map nodes (checked per mesh)
        self._ids: dict[int, int] = {}
        self._default_id: int | None = None
        #: the last material converted is a Holdout shader (a hole for camera rays, black
        #: elsewhere): the export holds it out (tracing.camera_passes)
        self.holdout = False

    def default_id(self) -> int:
        if self._default_id is None:
            self._default_id = self.scene.add_material(default_material(self.model))
        return self._default_id

    def material_id(self, mat) -> int:
        if mat is None:
            return self.default_id()
        key = mat.original.session_uid
        mid = self._ids.get(key)
        if mid is None:
            try:
                mid = self.scene.add_material(self.read(mat))
            except SceneError as exc:  # conversion produced something invalid: say so
                self.notes.warn(f"material unusable, rendered with the default ({exc})",
                                mat.name)
                mid = self.default_id()
            self._ids[key] = mid
        return mid

    def read(self, mat) -> Material:
        """:meth:`convert`, noting emission the renderer leaves out (at or above the
        radiance limit)."""
        converted = self.convert(mat)
        if max(converted.emission) >= tol.RADIANCE_MAX:
            self.notes.warn(f"emission at or above the radiance limit "
                            f"{tol.RADIANCE_MAX:g}: samples that see it are left out "
                            f"(black)", mat.name)
        return converted

    # -- conversion --------------------------------------------------------------------

    def convert(self, mat) -> Material:
        name = mat.name
        tree = mat.node_tree if uses_nodes(mat) else None
        if tree is None:
            return self._viewport(mat)
        out = tree.get_output_node("CYCLES")
        if out is None:
            self.notes.warn("materials without an active Material Output node use their "
                            "viewport colour", name)
            return self._viewport(mat)
        disp = out.inputs.get("Displacement")
        if disp is not None and disp.is_linked:
            self.notes.warn("material displacement is not supported (ignored)", name)
        vol = out.inputs.get("Volume")
        if vol is not None and vol.is_linked:
            self.notes.warn("volume shaders (Volume Absorption, Volume Scatter, Principled "
                            "Volume) are not supported (ignored: the surface alone renders)",
                            name)
        self.holdout = False
        node, _ = follow_link(out.inputs["Surface"])
        if node is None:
            self.notes.warn("materials with nothing connected to Surface use their viewport "
                            "colour", name)
            return self._viewport(mat)
        kind = node.bl_idname
        if kind == "ShaderNodeHoldout":
            # Cycles: a transparent hole for camera rays; seen in reflections or refractions
            # it has no closure (black), and it casts shadows
            self.holdout = True
            return self._mix(name, base=(0.0, 0.0, 0.0), specular_level=0.0)
        if kind == "ShaderNodeBsdfPrincipled":
            return self._principled(name, node)
        if kind == "ShaderNodeBsdfDiffuse":
            colour, tex = self._colour(name, node.inputs["Color"])
            self._diffuse_roughness(name, node.inputs.get("Roughness"))
            pixels, flags, tmap = tex if tex is not None else (None, 0, TEX_MAP_IDENTITY)
            return Material(name, diffuse=tuple(np.clip(colour, 0, 1)), texture=pixels,
                            texture_flags=flags, texture_map=tmap)
        if kind == "ShaderNodeEmission":
            colour, tex = self._colour(name, node.inputs["Color"])
            strength = self._value(name, node.inputs["Strength"])
            pixels, flags, tmap = _emission_texture(tex) if tex is not None else \
                (None, 0, TEX_MAP_IDENTITY)
            return Material(name, diffuse=(0.0,) * 3, emission=tuple(colour * strength),
                            texture=pixels, texture_flags=flags, texture_map=tmap)
        if kind in ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic",
                    "ShaderNodeBsdfMetallic"):
            sock = node.inputs.get("Color") or node.inputs.get("Base Color")
            # (an image: the metal colour per hit; a Physical Conductor has no Base Color)
            colour, tex = self._colour(name, sock) if sock is not None else (np.ones(3), None)
            rough = self._value(name, node.inputs["Roughness"])
            aniso = node.inputs.get("Anisotropy")
            if aniso is not None and (aniso.is_linked or float(aniso.default_value) != 0.0):
                self.notes.warn("glossy anisotropy is not supported: rendered isotropic",
                                name)
            edge = None
            if kind == "ShaderNodeBsdfMetallic":
                colour, edge, tex = self._conductor(name, node, colour, tex)
            return self._mix(name, base=colour, metallic=1.0, roughness=rough, texture=tex,
                             metal_tint=edge)
        if kind == "ShaderNodeBsdfGlass":
            colour, tex = self._colour(name, node.inputs["Color"])
            rough = self._value(name, node.inputs["Roughness"])
            ior = self._value(name, node.inputs["IOR"])
            # Cycles' Glass BSDF tints every crossing by its Color (no square root); an
            # image: by the texel at each crossing
            return self._mix(name, base=colour, roughness=rough, ior=ior, transmission=1.0,
                             tint_per_crossing=True, texture=tex)
        self.notes.warn(f"'{node.bl_label}' shaders are not supported; the material's "
                        f"viewport colour is used", name)
        return self._viewport(mat)

    def _conductor(self, name: str, node, colour, tex):
        """A Metallic BSDF's reflectance as Cycles': ``(F0, F82 tint, texture)``. F82 mode:
        the Base Color and the Edge Tint (Cycles' F82-tint curve). Physical Conductor: the
        exact conductor Fresnel of IOR ``n`` and Extinction ``k`` fitted by the F82 model
        through its values at normal incidence and at cos = 1/7 (as Cycles fits it for the
        energy its multiple scattering keeps; the fit is within 0.025 of the exact curve for
        gold, copper, aluminium, iron: tests/test_metal_f82.py), a Base Color image then left
        out (reported)."""
        mode = getattr(node, "fresnel_type", "F82")
        if mode == "PHYSICAL_CONDUCTOR":
            n = np.array(self._vector(name, node.inputs["IOR"]), np.float64)
            k = np.array(self._vector(name, node.inputs["Extinction"]), np.float64)
            f0, tint = conductor_f82(n, k)
            if tex is not None:
                self.notes.warn("an Image Texture into a Physical Conductor's Base Color "
                                "does nothing in Cycles (it uses IOR and Extinction): left "
                                "out", name)
            return f0, tint, None
        edge, etex = self._colour(name, node.inputs["Edge Tint"])
        if etex is not None:
            self.notes.warn("an Image Texture into the Edge Tint is not supported: the "
                            "Edge Tint's own value is used", name)
            edge = rgb(node.inputs["Edge Tint"].default_value)
        return colour, np.clip(edge, 0.0, 1.0), tex

    def _vector(self, name: str, socket) -> tuple:
        node, _ = follow_link(socket)
        if node is not None:
            self.notes.warn(f"inputs driven by '{node.bl_label}' nodes use the socket's own "
                            f"value", name)
        return tuple(float(x) for x in socket.default_value)

    def _diffuse_roughness(self, name: str, sock) -> None:
        """Cycles' Oren-Nayar diffuse (roughness above 0) flattens and darkens the shading;
        the diffuse here is Lambertian, so a rough one is reported."""
        if sock is not None and (sock.is_linked or float(sock.default_value) > 0.0):
            self.notes.warn("diffuse roughness is not supported (rendered as Lambertian)",
                            name)

    def _viewport(self, mat) -> Material:
        return self._mix(mat.name, base=rgb(mat.diffuse_color), metallic=mat.metallic,
                         roughness=mat.roughness)

    def _principled(self, name: str, node) -> Material:
        inp = node.inputs
        base, tex = self._colour(name, inp["Base Color"])
        metallic = self._value(name, inp["Metallic"])
        rough = self._value(name, inp["Roughness"])
        ior = self._value(name, inp["IOR"])
        trans = self._value(name, inp["Transmission Weight"])
        level = self._value(name, inp["Specular IOR Level"])
        owner = "Base Color" if tex is not None else None  # the input holding the image
        emit, etex = self._colour(name, inp["Emission Color"])
        if etex is not None:
            tex, emit, owner = self._also(name, tex, owner, etex, inp["Emission Color"],
                                          TEX_EMISSION)
        tint, ttex = self._colour(name, inp["Specular Tint"])
        if ttex is not None:
            tex, tint, owner = self._also(name, tex, owner, ttex, inp["Specular Tint"],
                                          TEX_SPECULAR)
            if metallic > 0.0:
                self.notes.warn("an Image Texture into the Specular Tint of a metallic "
                                "material tints its dielectric layer only: the metal's F82 "
                                "edge tint is white", name)
        strength = self._value(name, inp["Emission Strength"])
        for label, sock in (("subsurface", "Subsurface Weight"), ("coat", "Coat Weight"),
                            ("sheen", "Sheen Weight"), ("thin film", "Thin Film Thickness"),
                            ("anisotropy", "Anisotropic")):
            s = inp.get(sock)
            if s is not None and (s.is_linked or float(s.default_value) > 0.0):
                self.notes.warn(f"Principled {label} is not supported (ignored)", name)
        self._diffuse_roughness(name, inp.get("Diffuse Roughness"))
        alpha = inp.get("Alpha")
        if alpha is not None and (alpha.is_linked or alpha.default_value < 1.0):
            self.notes.warn("transparency (Principled alpha) is not supported: rendered "
                            "opaque", name)
        normal = inp.get("Normal")
        if normal is not None and normal.is_linked:
            self.notes.warn("normal and bump maps are not supported (ignored)", name)
        return self._mix(name, base=base, metallic=metallic, roughness=rough, ior=ior,
                         transmission=trans, specular_level=level, specular_tint=tint,
                         emission=emit * strength, texture=tex)

    def _mix(self, name: str, base, metallic: float = 0.0, roughness: float = 0.5,
             ior: float = 1.5, transmission: float = 0.0, specular_level: float = 0.5,
             specular_tint=(1.0, 1.0, 1.0), emission=(0.0, 0.0, 0.0),
             texture: tuple | None = None, tint_per_crossing: bool = False,
             metal_tint=None) -> Material:
        """Principled parameters -> a material of the render's shading model (see
        :func:`rstrace_engine.geometry.principled.principled_material`); what had to be
        approximated goes to the notes. ``texture``: ``(pixels, TEX_* flags, texture map)``
        (see :meth:`_image`) or None."""
        pixels, flags, tmap = texture if texture is not None else (None, 0, TEX_MAP_IDENTITY)
        material, messages = principled_material(
            name, base, metallic=metallic, roughness=roughness, ior=ior,
            transmission=transmission, specular_level=specular_level,
            specular_tint=specular_tint, emission=emission, texture=pixels, model=self.model,
            tint_per_crossing=tint_per_crossing, texture_flags=flags, texture_map=tmap,
            metal_tint=metal_tint)
        for message in messages:
            self.notes.warn(message, name)
        return material

    # -- sockets -------------------------------------------------------------------------

    def _also(self, name: str, tex: tuple | None, owner: str | None, other: tuple, socket,
              bits: int):
        """The material's one texture when an image (``other``, of :meth:`_image`) feeds
        ``socket`` too, its texel multiplying what the TEX_* ``bits`` say: the texture so far
        (of input ``owner``) where it is the same image sampled alike, or the new one alone
        (not the base colour) where there is none; ``(texture, the socket's colour, owner)``.
        Two different images are not supported (reported: the socket's own value is used)."""
        label = socket.name
        if tex is None:
            return (other[0], other[1] | bits | TEX_NO_BASE, other[2]), np.ones(3), label
        same = ((tex[1] & TEX_SAMPLING) == (other[1] & TEX_SAMPLING) and tex[2] == other[2]
                and (tex[0] is other[0] or np.array_equal(tex[0], other[0])))
        if same:
            return (tex[0], tex[1] | bits, tex[2]), np.ones(3), owner
        self.notes.warn(f"an Image Texture into the {label} besides another into the {owner} "
                        f"is not supported: the {label}'s own value is used", name)
        return tex, rgb(socket.default_value), owner

    def _value(self, name: str, socket) -> float:
        node, out = follow_link(socket)
        if node is None:
            return float(socket.default_value)
        if node.bl_idname == "ShaderNodeValue":
            return float(out.default_value)
        self.notes.warn(f"inputs driven by '{node.bl_label}' nodes use the socket's own value",
                        name)
        return float(socket.default_value)

    def _colour(self, name: str, socket) -> tuple[np.ndarray, tuple | None]:
        """(linear RGB, optional texture of :meth:`_image`) for a colour socket: white and
        the texture where an Image Texture's Color feeds it."""
        node, out = follow_link(socket)
        if node is None:
            return rgb(socket.default_value), None
        if node.bl_idname == "ShaderNodeRGB":
            return rgb(out.default_value), None
        if node.bl_idname == "ShaderNodeTexImage" and out.name == "Color":
            tex = self._image(name, node)
            if tex is not None:
                return np.ones(3), tex
            return rgb(socket.default_value), None
        self.notes.warn(f"colours driven by '{node.bl_label}' nodes use the socket's own "
                        f"value", name)
        return rgb(socket.default_value), None

    def _coordinates(self, name: str, node) -> tuple[int, tuple]:
        """``(TEX_* coordinate flag, 2 x 4 texture map)`` of what feeds an Image Texture's
        Vector: nothing, a Texture Coordinate node's UV, Object or Generated output, or a
        UV Map node (its map is checked per mesh by the export: ``uv_maps``), through any
        chain of Mapping nodes (Point, Texture, Vector: affine, composed here). Anything
        else is reported naming the nodes, and the render UV map is used."""
        def render_uv(what: str) -> tuple[int, tuple]:
            self.notes.warn(f"{what}: the render UV map is used", name)
            return 0, TEX_MAP_IDENTITY

        affine = np.eye(4)
        sock = node.inputs["Vector"]
        mapped = False
        for _ in range(64):
            vec, out = follow_link(sock)
            if vec is None or vec.bl_idname != "ShaderNodeMapping":
                break
            step = _mapping_affine(vec)
            if step is None:
                return render_uv(f"Mapping nodes of type '{vec.vector_type.title()}' or with "
                                 f"linked inputs are not supported (node '{vec.name}' into "
                                 f"Image Texture '{node.name}')")
            affine = affine @ step
            sock = vec.inputs["Vector"]
            mapped = True
        flag = 0
        if vec is None:
            if mapped:  # a Mapping node's own (unlinked) Vector
                return render_uv(f"a Mapping node with nothing linked into its Vector is "
                                 f"not supported (Image Texture '{node.name}')")
        elif vec.bl_idname == "ShaderNodeTexCoord":
            if vec.from_instancer:
                return render_uv(f"texture coordinates from the instancer are not supported "
                                 f"(node '{vec.name}')")
            if out.name == "Object" and vec.object is not None:
                return render_uv(f"Object texture coordinates in another object's space are "
                                 f"not supported (node '{vec.name}' names "
                                 f"'{vec.object.name}')")
            flag = {"UV": 0, "Object": TEX_OBJECT, "Generated": TEX_GENERATED}.get(out.name)
            if flag is None:
                return render_uv(f"texture coordinates from the Texture Coordinate node's "
                                 f"'{out.name}' output are not supported (Image Texture "
                                 f"'{node.name}')")
        elif vec.bl_idname == "ShaderNodeUVMap":
            if vec.from_instancer:
                self.notes.warn(f"texture coordinates from the instancer are not supported "
                                f"(node '{vec.name}'): the render UV map is used", name)
            if vec.uv_map:
                self.uv_maps.add(vec.uv_map)
        else:
            return render_uv(f"texture coordinates from '{vec.bl_label}' nodes are not "
                             f"supported (node '{vec.name}' into Image Texture "
                             f"'{node.name}')")
        return flag, tuple(tuple(float(x) for x in row) for row in affine[:2])

    def _image(self, name: str, node) -> tuple | None:
        """``(pixels, TEX_* flags, 2 x 4 texture map)`` of an Image Texture node (see
        :class:`~rstrace_engine.geometry.elements.Material`), or None (reported)."""
        img = node.image
        if img is None:
            self.notes.warn("image texture nodes without an image are ignored", name)
            return None
        coords, texture_map = self._coordinates(name, node)
        if node.projection != "FLAT":
            self.notes.warn(f"image projection '{node.projection.title()}' is not supported "
                            f"(node '{node.name}'): flat is used", name)
        flags = {"EXTEND": TEX_EXTEND, "CLIP": TEX_CLIP}.get(node.extension, 0)
        if node.extension not in ("REPEAT", "EXTEND", "CLIP"):
            self.notes.warn(f"image extension '{node.extension.title()}' is not supported "
                            f"(node '{node.name}'): Repeat is used", name)
        if node.interpolation == "Closest":
            flags |= TEX_CLOSEST
        elif node.interpolation != "Linear":
            self.notes.warn(f"image interpolation '{node.interpolation}' is not supported "
                            f"(node '{node.name}'): Linear is used", name)
        if self.textures is None:
            read = read_image(img, self.notes)
        else:
            key = img.original.session_uid
            self.images.add(key)
            gen = _IMAGE_GENERATION.get(key, 0)
            hit = self.textures.get(key)
            if hit is not None and hit[0] == gen and hit[2] == _image_signature(img):
                read = hit[1]
            else:
                read = read_image(img, self.notes)
                self.textures[key] = (gen, read, _image_signature(img))
        if read is None:
            return None
        pixels, srgb = read
        return pixels, flags | coords | (TEX_SRGB if srgb else 0), texture_map


#: image session_uid -> generation, bumped by :func:`image_changed` (depsgraph updates).
_IMAGE_GENERATION: dict[int, int] = {}


def image_changed(key: int) -> None:
    """Forget cached pixels of the image with session_uid ``key`` (painted, reloaded)."""
    _IMAGE_GENERATION[key] = _IMAGE_GENERATION.get(key, 0) + 1


def _image_signature(img) -> tuple:
    return (tuple(img.size), img.channels, img.filepath, img.colorspace_settings.name,
            img.is_dirty, img.source)


def read_image(img, notes: Notes) -> tuple[np.ndarray, bool] | None:
    """An image's pixels as a (h, w, 3) float32 array, bottom row first, and whether they are
    sRGB-encoded (a byte image in an sRGB colour space: kept encoded, to be decoded after
    interpolation as Cycles does, :data:`TEX_SRGB`); else linear RGB. None: not loadable."""
    w, h = img.size
    if w == 0 or h == 0 or not img.has_data and not _try_load(img):
        notes.warn("images that could not be loaded are ignored", img.name)
        return None
    w, h = img.size
    ch = img.channels
    px = np.empty(w * h * ch, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, ch)
    rgb = np.repeat(px[:, :, :1], 3, axis=2) if ch < 3 else px[:, :, :3]
    space = img.colorspace_settings.name
    srgb = False
    if not img.is_float:
        if space == "sRGB":
            srgb = True
        elif space not in ("Non-Color", "Linear Rec.709", "Linear", "Raw"):
            notes.warn(f"image colour space '{space}' is read as sRGB", img.name)
            srgb = True
    if not np.all(np.isfinite(rgb)):
        notes.warn("images with NaN or infinite pixels have them replaced by 0", img.name)
        rgb = np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)
    if float(rgb.max(initial=0.0)) > 1.0:
        notes.warn("texture values above 1 are clipped (energy conservation)", img.name)
    return np.ascontiguousarray(np.clip(rgb, 0.0, 1.0), dtype=np.float32), srgb


def _try_load(img) -> bool:
    try:
        img.reload()
        _ = img.pixels[0]
    except (RuntimeError, IndexError, ReferenceError):
        return False
    return img.size[0] > 0 and img.size[1] > 0


def _emission_texture(tex: tuple) -> tuple:
    """A texture (:meth:`MaterialReader._image`) multiplying the emission only."""
    return tex[0], tex[1] | TEX_EMISSION | TEX_NO_BASE, tex[2]


def _mapping_affine(node) -> np.ndarray | None:
    """A Mapping node as a 4 x 4 affine matrix (Blender's ``mapping`` of its vector type:
    Point ``R (S v) + L``, Texture ``R^-1 (v - L) / S``, Vector ``R (S v)``), or None
    where it is not affine (Normal) or an input other than Vector is linked."""
    kind = node.vector_type
    if kind not in ("POINT", "TEXTURE", "VECTOR"):
        return None
    values = {}
    for key in ("Location", "Rotation", "Scale"):
        sock = node.inputs.get(key)
        if sock is None:  # (Vector type has no Location)
            values[key] = np.zeros(3) if key != "Scale" else np.ones(3)
            continue
        if sock.is_linked:
            return None
        values[key] = np.array(sock.default_value[:3], np.float64)
    rot = np.array(Euler(values["Rotation"], "XYZ").to_matrix(), np.float64)
    out = np.eye(4)
    if kind == "TEXTURE":
        scale = values["Scale"]
        inv_s = np.where(scale != 0.0, 1.0 / np.where(scale != 0.0, scale, 1.0), 0.0)
        out[:3, :3] = inv_s[:, None] * rot.T
        out[:3, 3] = -out[:3, :3] @ values["Location"]
        return out
    out[:3, :3] = rot * values["Scale"][None, :]
    if kind == "POINT":
        out[:3, 3] = values["Location"]
    return out


def uses_nodes(idblock) -> bool:
    # use_nodes is deprecated (always on) from Blender 5.0; reading it there warns
    if bpy.app.version >= (5, 0, 0):
        return idblock.node_tree is not None
    return bool(idblock.use_nodes) and idblock.node_tree is not None
