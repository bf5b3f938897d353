"""Blender materials -> :class:`rstrace_engine.geometry.scene.Material` (export's material half).

Reads the Principled BSDF (or a Diffuse, Emission, Glossy or Glass BSDF) feeding the material
output, with an Image Texture on Base Color read into a numpy texture; anything else falls
back to the material's viewport colour. Problems go to the export's :class:`Notes`.

Layer: imports no add-on module; imported by ``export`` and the readers it uses (``snapshot``,
``cameras``, ``lights``) and by ``depsgraph_diff`` (``image_changed``).
"""

from __future__ import annotations

import logging

import bpy
import numpy as np

from rstrace_engine import tolerances as tol
from rstrace_engine.geometry.principled import principled_material
from rstrace_engine.geometry.scene import Material, Scene, SceneError

log = logging.getLogger(__name__)

#: Used for empty material slots and objects without materials (Cycles' default surface).
DEFAULT_MATERIAL = Material("default", diffuse=(0.8, 0.8, 0.8))



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



def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted (IEC 61966-2-1)."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


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
        self._ids: dict[int, int] = {}
        self._default_id: int | None = None

    def default_id(self) -> int:
        if self._default_id is None:
            self._default_id = self.scene.add_material(DEFAULT_MATERIAL)
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
        node, _ = follow_link(out.inputs["Surface"])
        if node is None:
            self.notes.warn("materials with nothing connected to Surface use their viewport "
                            "colour", name)
            return self._viewport(mat)
        kind = node.bl_idname
        if kind == "ShaderNodeBsdfPrincipled":
            return self._principled(name, node)
        if kind == "ShaderNodeBsdfDiffuse":
            colour, tex = self._colour(name, node.inputs["Color"])
            self._diffuse_roughness(name, node.inputs.get("Roughness"))
            return Material(name, diffuse=tuple(np.clip(colour, 0, 1)), texture=tex)
        if kind == "ShaderNodeEmission":
            colour, _ = self._colour(name, node.inputs["Color"])
            strength = self._value(name, node.inputs["Strength"])
            return Material(name, diffuse=(0.0,) * 3, emission=tuple(colour * strength))
        if kind in ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic",
                    "ShaderNodeBsdfMetallic"):
            sock = node.inputs.get("Color") or node.inputs.get("Base Color")
            colour, _ = self._colour(name, sock)
            rough = self._value(name, node.inputs["Roughness"])
            aniso = node.inputs.get("Anisotropy")
            if aniso is not None and (aniso.is_linked or float(aniso.default_value) != 0.0):
                self.notes.warn("glossy anisotropy is not supported: rendered isotropic",
                                name)
            return self._mix(name, base=colour, metallic=1.0, roughness=rough)
        if kind == "ShaderNodeBsdfGlass":
            colour, _ = self._colour(name, node.inputs["Color"])
            rough = self._value(name, node.inputs["Roughness"])
            ior = self._value(name, node.inputs["IOR"])
            # Cycles' Glass BSDF tints every crossing by its Color (no square root)
            return self._mix(name, base=colour, roughness=rough, ior=ior, transmission=1.0,
                             tint_per_crossing=True)
        self.notes.warn(f"'{node.bl_label}' shaders are not supported; the material's "
                        f"viewport colour is used", name)
        return self._viewport(mat)

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
        tint, _ = self._colour(name, inp["Specular Tint"])
        emit, _ = self._colour(name, inp["Emission Color"])
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
             texture: np.ndarray | None = None, tint_per_crossing: bool = False) -> Material:
        """Principled parameters -> a material of the render's shading model (see
        :func:`rstrace_engine.geometry.principled.principled_material`); what had to be
        approximated goes to the notes."""
        material, messages = principled_material(
            name, base, metallic=metallic, roughness=roughness, ior=ior,
            transmission=transmission, specular_level=specular_level,
            specular_tint=specular_tint, emission=emission, texture=texture, model=self.model,
            tint_per_crossing=tint_per_crossing)
        for message in messages:
            self.notes.warn(message, name)
        return material

    # -- sockets -------------------------------------------------------------------------

    def _value(self, name: str, socket) -> float:
        node, out = follow_link(socket)
        if node is None:
            return float(socket.default_value)
        if node.bl_idname == "ShaderNodeValue":
            return float(out.default_value)
        self.notes.warn(f"inputs driven by '{node.bl_label}' nodes use the socket's own value",
                        name)
        return float(socket.default_value)

    def _colour(self, name: str, socket) -> tuple[np.ndarray, np.ndarray | None]:
        """(linear RGB, optional (h, w, 3) texture) for a colour socket."""
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

    def _image(self, name: str, node) -> np.ndarray | None:
        img = node.image
        if img is None:
            self.notes.warn("image texture nodes without an image are ignored", name)
            return None
        vec, _ = follow_link(node.inputs["Vector"])
        if vec is not None and vec.bl_idname not in ("ShaderNodeUVMap", "ShaderNodeTexCoord"):
            self.notes.warn(f"texture coordinates from '{vec.bl_label}' nodes are not "
                            f"supported: the render UV map is used", name)
        if node.projection != "FLAT" or node.extension not in ("REPEAT", "EXTEND", "CLIP"):
            self.notes.warn("image projections other than flat UV are not supported", name)
        if self.textures is None:
            return read_image(img, self.notes)
        key = img.original.session_uid
        self.images.add(key)
        gen = _IMAGE_GENERATION.get(key, 0)
        hit = self.textures.get(key)
        if hit is not None and hit[0] == gen and hit[2] == _image_signature(img):
            return hit[1]
        pixels = read_image(img, self.notes)
        self.textures[key] = (gen, pixels, _image_signature(img))
        return pixels


#: image session_uid -> generation, bumped by :func:`image_changed` (depsgraph updates).
_IMAGE_GENERATION: dict[int, int] = {}


def image_changed(key: int) -> None:
    """Forget cached pixels of the image with session_uid ``key`` (painted, reloaded)."""
    _IMAGE_GENERATION[key] = _IMAGE_GENERATION.get(key, 0) + 1


def _image_signature(img) -> tuple:
    return (tuple(img.size), img.channels, img.filepath, img.colorspace_settings.name,
            img.is_dirty, img.source)


def read_image(img, notes: Notes) -> np.ndarray | None:
    """An image's pixels as a (h, w, 3) float32 linear RGB array, bottom row first."""
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
    if not img.is_float:
        if space == "sRGB":
            rgb = srgb_to_linear(rgb)
        elif space not in ("Non-Color", "Linear Rec.709", "Linear", "Raw"):
            notes.warn(f"image colour space '{space}' is read as sRGB", img.name)
            rgb = srgb_to_linear(rgb)
    if not np.all(np.isfinite(rgb)):
        notes.warn("images with NaN or infinite pixels have them replaced by 0", img.name)
        rgb = np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)
    if float(rgb.max(initial=0.0)) > 1.0:
        notes.warn("texture values above 1 are clipped (energy conservation)", img.name)
    return np.ascontiguousarray(np.clip(rgb, 0.0, 1.0), dtype=np.float32)


def _try_load(img) -> bool:
    try:
        img.reload()
        _ = img.pixels[0]
    except (RuntimeError, IndexError, ReferenceError):
        return False
    return img.size[0] > 0 and img.size[1] > 0


def uses_nodes(idblock) -> bool:
    # use_nodes is deprecated (always on) from Blender 5.0; reading it there warns
    if bpy.app.version >= (5, 0, 0):
        return idblock.node_tree is not None
    return bool(idblock.use_nodes) and idblock.node_tree is not None
