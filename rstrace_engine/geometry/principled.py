"""Principled BSDF parameters -> :class:`~.scene.Material` (what a Blender material becomes).

:func:`principled_material` takes the inputs of Blender's Principled BSDF (Base Color,
Metallic, Roughness, IOR, Transmission Weight, Specular IOR Level, Specular Tint, Emission)
and returns a material of either shading model, with the problems it had to approximate as
messages (the add-on reports them once per render):

``"PRINCIPLED"`` (default; follows Cycles' layering in direct light)
    a Lambertian base ``(1 - metallic)(1 - transmission) base`` under a GGX layer: the
    dielectric part reflects with the exact Fresnel of the IOR (adjusted by the specular IOR
    level as Cycles does: ``F0 = F0(IOR) 2 level``), tinted; the metallic part reflects its
    base colour with Cycles' F82-tint curve (Schlick's toward white, pulled down to the
    Specular Tint times Schlick's value near 82 degrees:
    :func:`~..tracing.shading.principled_fresnel`). Lights light the whole layer; the layer
    reflects the scene through one mirror ray below roughness 0.05 (GGX alpha
    ``tolerances.GLOSSY_ALPHA_MIN``) and through glossy rays drawn from its GGX lobe above
    (``tracing.glossy_rays.is_glossy``, docs/glossy.md); so does rough transmission.

``"WARD"`` (seed 000's model)
    a constant F0 split between a Whitted mirror (smooth) and Ward's lobe (rough) with a
    linear blend between the two roughnesses (no glossy rays: ``ROUGH_REFLECTION_NOTE``).

Both models give the transmissive part to refraction *undivided*: the tracer's dielectric
Fresnel splits it into reflection and refraction at each interface. (Giving it a mirror
weight F0 and a refraction weight 1 - F0 as well applied the Fresnel twice: a glass slab
transmitted 0.926 of Cycles' light.)
"""

from __future__ import annotations

import math

import numpy as np

from .elements import (
    TEX_EMISSION,
    TEX_MAP_IDENTITY,
    TEX_METAL,
    TEX_NO_BASE,
    TEX_NONLINEAR,
    TEX_SPECULAR,
    TEX_TRANSMISSION,
    TEX_TRANSMISSION_SQRT,
    texture_linear,
)
from .scene import Material, SceneError

#: WARD model: roughness below which reflection is a Whitted mirror, above which Ward's
#: lobe; linear blend in between.
MIRROR_ROUGHNESS = 0.1
GLOSSY_ROUGHNESS = 0.3

#: Reported for a WARD-model material rougher than a mirror: it draws no glossy rays, so
#: what it reflects of other objects (not the lights' highlights, which are shaded exactly)
#: is blended toward a sharp mirror or left out. (PRINCIPLED materials draw glossy rays.)
ROUGH_REFLECTION_NOTE = (
    f"rough reflections are not traced: other objects are reflected as in a sharp mirror "
    f"at roughness {MIRROR_ROUGHNESS:g}-{GLOSSY_ROUGHNESS:g} and not at all above (the "
    f"lights' highlights are shaded)")

#: IORs the tracer handles; others are clamped into it, with a message.
IOR_RANGE = (1.0, 10.0)


def f0_from_ior(ior: float) -> float:
    """Reflectance of a dielectric at normal incidence: ``((ior - 1) / (ior + 1))^2``."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_from_f0(f0: float) -> float:
    """The IOR whose normal-incidence reflectance is ``f0`` (in [0, 1))."""
    r = math.sqrt(min(max(f0, 0.0), 0.99))
    return (1.0 + r) / (1.0 - r)


def _scalar(name: str, label: str, value) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise SceneError(f"material '{name}': input '{label}' is {v} (not a "
                         f"finite number)")
    return v


def _rgb(name: str, label: str, value) -> np.ndarray:
    arr = np.asarray(value, np.float64).reshape(-1)[:3]
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"material '{name}': input '{label}' has NaN or infinite "
                         f"values ({arr.tolist()})")
    return arr


def principled_material(name: str, base, metallic: float = 0.0, roughness: float = 0.5,
                        ior: float = 1.5, transmission: float = 0.0,
                        specular_level: float = 0.5, specular_tint=(1.0, 1.0, 1.0),
                        emission=(0.0, 0.0, 0.0), texture: np.ndarray | None = None,
                        model: str = "PRINCIPLED", tint_per_crossing: bool = False,
                        texture_flags: int = 0, texture_map: tuple = TEX_MAP_IDENTITY,
                        anisotropic: float = 0.0, metal_tint=None
                        ) -> tuple[Material, list[str]]:
    """A material from Principled BSDF inputs, and messages about what was approximated.

    The transmitted light is tinted per interface crossing by ``sqrt(base)``, as Cycles'
    Principled BSDF does (``transmission_tint = sqrt(base_color)``), so that light through a
    closed object (in and out: two crossings) is tinted by the base colour once; the tracer
    multiplies ``transmission`` in at every crossing. ``tint_per_crossing`` instead tints
    every crossing by the full colour: Cycles' Glass BSDF node.

    Raises :class:`~.scene.SceneError` naming the input when one is NaN or infinite.
    Roughness outside [0, 1] is clamped into it and an ``anisotropic`` value other than 0
    is rendered isotropic, each with a message.
    ``texture`` (h, w, 3) multiplies the base colour at each hit (``TEX_NO_BASE`` in
    ``texture_flags``: not), in the PRINCIPLED model the metal colour and the transmission
    tint too (``TEX_METAL``, ``TEX_TRANSMISSION*`` are added), and the Specular Tint where
    ``texture_flags`` has ``TEX_SPECULAR``; the WARD model takes the texture's mean for
    those (with a message). ``texture_flags``, ``texture_map``: what it multiplies and how it
    is sampled (:class:`~.elements.Material`).
    """
    notes: list[str] = []
    raw = _rgb(name, "Base Color", base)
    if np.any(raw > 1.0):
        notes.append(f"Base Color above 1 ({', '.join(f'{c:g}' for c in raw)}) is clipped to "
                     f"1 (energy conservation; Cycles reflects more light than it receives)")
    base = np.clip(raw, 0.0, 1.0)
    metallic = _scalar(name, "Metallic", metallic)
    roughness = _scalar(name, "Roughness", roughness)
    if not 0.0 <= roughness <= 1.0:
        notes.append(f"Roughness {roughness:g} is outside [0, 1]: rendered with "
                     f"{min(max(roughness, 0.0), 1.0):g}")
    anisotropic = _scalar(name, "Anisotropic", anisotropic)
    if anisotropic != 0.0:
        notes.append(f"Anisotropic {anisotropic:g} is not modelled: the glossy lobe is "
                     f"rendered isotropic")
    ior = _scalar(name, "IOR", ior)
    transmission = _scalar(name, "Transmission Weight", transmission)
    specular_level = _scalar(name, "Specular IOR Level", specular_level)
    tint = np.clip(_rgb(name, "Specular Tint", specular_tint), 0.0, 1.0)
    # the metal's F82 tint: Cycles' min(Specular Tint, 1) (a Metallic BSDF's Edge Tint, or
    # a conductor's F82 fit, given as metal_tint)
    edge = tuple(float(x) for x in (tint if metal_tint is None else np.clip(
        _rgb(name, "Edge Tint", metal_tint), 0.0, None)))
    emission = np.clip(_rgb(name, "Emission", emission), 0.0, None)
    lo, hi = IOR_RANGE
    if not lo <= ior <= hi:
        clamped = min(max(ior, lo), hi)
        notes.append(f"IOR {ior:g} is outside [{lo:g}, {hi:g}]: rendered with IOR "
                     f"{clamped:g}")
        ior = clamped
    m = float(np.clip(metallic, 0.0, 1.0))
    t = float(np.clip(transmission, 0.0, 1.0))
    r = float(np.clip(roughness, 0.0, 1.0))
    tex_mean = metal_colour = base_factor = base
    flags = int(texture_flags)
    if texture is not None and model == "PRINCIPLED":
        # Cycles weights each closure by its colour at the hit: the Base Color's texel
        # multiplies the metal colour and the transmission tint (per crossing: its square
        # root for the Principled BSDF, all of it for the Glass BSDF) as it does the diffuse
        if not flags & TEX_NO_BASE and m > 0.0:
            flags |= TEX_METAL
        if not flags & TEX_NO_BASE and (1 - m) * t > 0.0:
            flags |= TEX_TRANSMISSION if tint_per_crossing else TEX_TRANSMISSION_SQRT
    elif texture is not None:  # WARD: one mirror and lobe weight, the metal's among them
        mean = np.clip(texture_linear(texture, flags).reshape(-1, 3).mean(axis=0), 0.0, 1.0)
        if not flags & TEX_NO_BASE:
            if m > 0.0:
                notes.append("a textured metallic colour is approximated by the texture's "
                             "average")
            if t > 0.0:
                notes.append("textured transmission is approximated by the texture's average")
            tex_mean, metal_colour, base_factor = mean, mean, np.ones(3)
        if flags & TEX_SPECULAR:
            notes.append("a textured Specular Tint is approximated by the texture's average")
            tint = tint * mean
    if model == "WARD":
        flags &= ~TEX_NONLINEAR
        if texture is not None and flags & TEX_NO_BASE and not flags & TEX_EMISSION:
            texture, flags = None, 0  # (it multiplied the specular tint alone)
    refract = (1 - m) * t * (tex_mean if tint_per_crossing else np.sqrt(tex_mean))
    if model == "WARD" and t > 0.0 and r > MIRROR_ROUGHNESS:
        notes.append("rough transmission is rendered as smooth refraction")
    # Cycles' specular IOR level: F0 scaled by 2 level, the IOR of the reflection adjusted
    level = float(np.clip(specular_level, 0.0, 1.0))
    if specular_level > 1.0:
        notes.append(f"Specular IOR Level {specular_level:g} is clipped to 1")
    f0 = f0_from_ior(ior) * 2.0 * level
    sharp = float(np.clip((GLOSSY_ROUGHNESS - r) / (GLOSSY_ROUGHNESS - MIRROR_ROUGHNESS),
                          0.0, 1.0))
    if model == "WARD" and r > MIRROR_ROUGHNESS and (
            m > 0.0 or (f0 > 0.0 and m < 1.0 and t < 1.0)):
        notes.append(ROUGH_REFLECTION_NOTE)
    alpha = float(np.clip(r * r, 1e-4, 1.0))
    emission_t = tuple(emission)
    if model == "PRINCIPLED":
        layer = (1 - m) * (1 - t)
        spec_ior = min(ior_from_f0(f0), hi) if f0 > 0.0 else 1.0
        spec = layer * tint if spec_ior > 1.0 else np.zeros(3)
        return Material(
            name, diffuse=tuple(layer * base_factor), specular=tuple(np.clip(spec, 0, 1)),
            roughness=alpha, mirror=(1.0,) * 3, transmission=tuple(refract), ior=ior,
            emission=emission_t, texture=texture, model="PRINCIPLED", metallic=m,
            metal=tuple(metal_colour), specular_ior=spec_ior,
            texture_flags=flags, texture_map=texture_map,
            specular_tint_max=float(np.max(tint)) if spec_ior > 1.0 else 1.0,
            metal_tint=edge), notes
    if model != "WARD":
        raise SceneError(f"material '{name}': unknown shading model {model!r}")
    f0c = np.clip(f0 * tint, 0.0, 1.0)
    diffuse = (1 - m) * (1 - t) * base_factor * (1 - f0c)
    reflect = m * metal_colour + (1 - m) * (1 - t) * f0c
    total = diffuse + refract + reflect
    scale = np.where(total > 1.0, 1.0 / np.maximum(total, 1e-12), 1.0)  # rounding guard
    return Material(
        name, diffuse=tuple(diffuse * scale), specular=tuple(reflect * (1 - sharp) * scale),
        roughness=float(np.clip(r * r, 1e-3, 1.0)), mirror=tuple(reflect * sharp * scale),
        transmission=tuple(refract * scale), ior=ior, emission=emission_t, texture=texture,
        model="WARD", texture_flags=flags, texture_map=texture_map), notes


def conductor_fresnel(c, n, k):
    """The exact unpolarised Fresnel reflectance of a conductor of complex index ``n + i k``
    (per channel, arrays) in air at cosine ``c`` (Cycles' ``fresnel_conductor_polarized``)."""
    n = np.asarray(n, np.float64)
    k = np.asarray(k, np.float64)
    c = np.asarray(c, np.float64)
    t1 = n * n - k * k - (1.0 - c * c)
    t2 = np.sqrt(t1 * t1 + (2.0 * n * k) ** 2)
    u2 = np.maximum(0.5 * (t2 + t1), 0.0)
    v2 = np.maximum(0.5 * (t2 - t1), 0.0)
    u, v = np.sqrt(u2), np.sqrt(v2)
    rs = ((c - u) ** 2 + v2) / np.maximum((c + u) ** 2 + v2, 1e-300)
    t3 = (n * n - k * k) * c
    t4 = 2.0 * n * k * c
    rp = ((t3 - u) ** 2 + (t4 - v) ** 2) / np.maximum((t3 + u) ** 2 + (t4 + v) ** 2, 1e-300)
    return 0.5 * (rs + rp)


def conductor_f82(n, k):
    """A Metallic BSDF's Physical Conductor (IOR ``n``, Extinction ``k``, 3 channels) as the
    F82-tint model: ``(F0, tint)``, the exact reflectance at normal incidence and the tint
    that makes the model's value at cos = 1/7 the exact one (Cycles fits its conductors so
    for their multiple-scattering energy; the curve between is the model's)."""
    n = np.maximum(np.asarray(n, np.float64), 0.0)
    k = np.maximum(np.asarray(k, np.float64), 0.0)
    f0 = np.clip(conductor_fresnel(1.0, n, k), 0.0, 1.0)
    f82 = conductor_fresnel(1.0 / 7.0, n, k)
    schlick = f0 + (1.0 - f0) * (6.0 / 7.0) ** 5
    return f0, np.maximum(f82 / np.maximum(schlick, 1e-12), 0.0)

