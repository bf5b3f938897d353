"""Glossy rays: a rough surface's reflected and refracted rays drawn from its GGX lobe
(issue 24, docs/glossy.md), for the shade kernel (:mod:`.shader`).

Which materials draw them (:func:`is_glossy`; how many per point, by lobe at a path's
first rough bounce -- Glossy Samples pairs on a transmissive lobe, up to twice as many
reflections on one without -- and one deeper, :func:`glossy_counts`), and the rays themselves
(:func:`_glossy_rays`): microfacet normals from GGX's visible normals, stratified like the
soft lights' samples, weighted as Cycles' microfacet GGX weights them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import MODEL_PRINCIPLED
from .ggx_sampling import ggx_sample_at, ggx_sample_frame, ggx_weight_lo
from .memo import Memo
from .shading import (
    dot3,
    fresnel_dielectric,
    ggx_lambda,
    principled_fresnel,
    reflect,
    refract,
)
from .soft_lights import mix64

#: hashed into a node's seed for its glossy samples (the soft lights hash in their light)
GLOSSY_SALT = np.uint64(0xD1B54A32D192ED03)
#: hashed into a deeper rough bounce's node seed for its rays' Russian roulette
ROULETTE_SALT = np.uint64(0x8CB92BA72F3D8DD7)
#: Russian roulette of the deeper rough bounces' weak rays (:func:`roulette`; a module
#: switch: tests compare frames with and without it)
ROULETTE = True
#: a path's first rough bounce on a lobe without transmission draws twice Glossy Samples
#: reflections, times the square root of a dielectric layer's share of the albedo
#: (:func:`glossy_counts`; a module switch: tests compare both sides)
LOBE_COUNTS = True
GOLDEN = 0.6180339887498949
INV_2_53 = 1.0 / 9007199254740992.0


@njit(cache=True, nogil=True)
def is_glossy(sa, m):
    """Whether material ``m`` reflects or refracts the scene through sampled glossy rays: a
    Principled-like material at GGX alpha ``>= tolerances.GLOSSY_ALPHA_MIN`` (roughness
    0.05; below it a mirror, one ray) with a reflecting layer or transmission."""
    # branch-free past m < 0 (| and &, not or and and): short-circuits between reads of
    # ``sa`` kept numba from pruning the reference counts of its ~60 arrays, ~350 ns a
    # call, 18 ms per 50k points in the shade kernel (docs/bench-frame.md)
    if m < 0:
        return False
    refl = ((sa.mat_mirror[m, 0] > 0.0) | (sa.mat_mirror[m, 1] > 0.0)
            | (sa.mat_mirror[m, 2] > 0.0)) & (
        (sa.mat_metallic[m] > 0.0) | (sa.mat_specular[m, 0] > 0.0)
        | (sa.mat_specular[m, 1] > 0.0) | (sa.mat_specular[m, 2] > 0.0))
    # IOR 1 is no interface: such a transmission passes straight on (as through a mirror's
    # one refracted ray), whatever the roughness
    trans = (sa.mat_ior[m] != 1.0) & ((sa.mat_transmission[m, 0] > 0.0)
                                      | (sa.mat_transmission[m, 1] > 0.0)
                                      | (sa.mat_transmission[m, 2] > 0.0))
    return ((sa.mat_model[m] == MODEL_PRINCIPLED)
            & (not sa.mat_roughness[m] < tol.GLOSSY_ALPHA_MIN) & (refl | trans))


def interface_materials(sa) -> np.ndarray:
    """(NM,) bool: the materials of ``sa`` that are rough dielectric interfaces
    (:func:`~.shading.rough_interface`: lights on their far side reach the viewer through
    their transmission lobe)."""
    return ((np.asarray(sa.mat_model) == MODEL_PRINCIPLED)
            & (np.asarray(sa.mat_roughness) >= tol.GLOSSY_ALPHA_MIN)
            & (np.asarray(sa.mat_ior) != 1.0)
            & (np.asarray(sa.mat_transmission) > 0).any(axis=1))


def glossy_materials(sa) -> np.ndarray:
    """(NM,) bool: the materials of ``sa`` that draw glossy rays
    (:func:`is_glossy`)."""
    refl = (sa.mat_mirror > 0).any(axis=1) & (
        (sa.mat_metallic > 0) | (sa.mat_specular > 0).any(axis=1))
    return ((sa.mat_model == MODEL_PRINCIPLED) & (sa.mat_roughness >= tol.GLOSSY_ALPHA_MIN)
            & (refl | ((sa.mat_transmission > 0).any(axis=1) & (sa.mat_ior != 1.0))))


def layer_materials(sa) -> np.ndarray:
    """(NM,) bool: the glossy materials (:func:`glossy_materials`) whose lobe is a
    dielectric layer over a diffuse base alone (no metal, no transmission, some diffuse
    albedo: a plastic), whose glossy rays carry the layer's albedo, a few percent."""
    return (glossy_materials(sa) & ~(sa.mat_metallic > 0)
            & ~(sa.mat_transmission > 0).any(axis=1) & (sa.mat_diffuse > 0).any(axis=1))


def reflecting_materials(sa) -> np.ndarray:
    """(NM,) bool: the glossy materials (:func:`glossy_materials`) without transmission:
    each glossy sample one reflected ray (a metal, a plastic), where a transmissive one's
    is a reflected and a refracted ray."""
    return glossy_materials(sa) & ~(sa.mat_transmission > 0).any(axis=1)


#: the material fields :func:`glossy_materials`, :func:`interface_materials`,
#: :func:`layer_materials` and :func:`reflecting_materials` read
_MAT_FIELDS = ("mat_model", "mat_roughness", "mat_ior", "mat_transmission", "mat_mirror",
               "mat_metallic", "mat_specular", "mat_diffuse")


class MaterialFlags(NamedTuple):
    """A scene's material flags, each (NM + 1,) with a False (a 0) appended (index -1: a
    miss), and whether any material is glossy or an interface."""

    glossy: np.ndarray  # bool, glossy_materials
    interface: np.ndarray  # bool, interface_materials
    any_glossy: bool
    any_interface: bool
    layer: np.ndarray  # bool, layer_materials
    diffuse_max: np.ndarray  # float64, the largest channel of the diffuse albedo
    reflecting: np.ndarray  # bool, reflecting_materials


def _material_flags(sa) -> MaterialFlags:
    glossy, iface = glossy_materials(sa), interface_materials(sa)
    return MaterialFlags(
        np.append(glossy, False), np.append(iface, False), bool(np.any(glossy)),
        bool(np.any(iface)), np.append(layer_materials(sa), False),
        np.append(np.asarray(sa.mat_diffuse, np.float64).max(axis=1, initial=0.0), 0.0),
        np.append(reflecting_materials(sa), False))


#: :func:`_material_flags` per scene's materials: asked for at every depth level, computed
#: once per set of material arrays (:class:`~.memo.Memo`)
MATERIAL_FLAGS = Memo(_MAT_FIELDS, _material_flags)


def has_glossy(sa) -> bool:
    """Whether any material of ``sa`` draws glossy rays (:func:`is_glossy`)."""
    return MATERIAL_FLAGS.get(sa).any_glossy


def glossy_counts(sa, mat: np.ndarray, fresh: np.ndarray, samples: int, ediel: np.ndarray):
    """Ray pairs per point of a level (:func:`~.shader._shade_kernel`'s ``gstart``): ``samples``
    (by lobe with :data:`LOBE_COUNTS`, below) at a glossy point (``mat`` (n,) its material,
    -1 a miss) whose path has not been split yet (``fresh`` (n,) bool), 1 elsewhere (a
    deeper glossy bounce draws one direction).
    Returns ``(counts (n,) int64, glossy (n,) bool)``. From the materials' flags, once per
    level: a parallel kernel calling ``is_glossy`` at every point took ~17 ms per 50k points
    on one thread, a quarter of a rough_materials frame (docs/bench-frame.md).

    With :data:`LOBE_COUNTS` a fresh point of a lobe without transmission
    (:func:`reflecting_materials`: one reflected ray a sample, where a glass's sample is a
    reflected and a refracted ray) draws ``max(1, ceil(2 samples sqrt(w)))``: twice
    ``samples`` (a glass point's rays) where ``w`` is 1, a metal's lobe; for a dielectric
    layer over a diffuse base (:func:`layer_materials`: a plastic) ``w = E / (E + (1 - E)
    d)``, the layer's share of the point's albedo (``E`` its dielectric albedo toward the
    viewer, ``ediel`` (n,) float64 as the shade kernel reads it, times the specular tint's
    largest channel; ``d`` the base's largest diffuse channel). Measured at equal time
    (docs/glossy.md, "session 43 (lobes)"): a metal's rays were the cheapest error to
    buy, a plastic's few percent were at their balance already. Each of a point's ``n``
    samples weighs ``1 / n`` (:func:`_glossy_rays`): unbiased whatever ``n``; ``n`` is a
    function of the point alone (deterministic, the same in every mode)."""
    flags = MATERIAL_FLAGS.get(sa)
    glossy = flags.glossy[mat]  # the appended False: -1, a miss
    counts = np.where(glossy & fresh, np.int64(samples), np.int64(1))
    if LOBE_COUNTS:
        part = np.flatnonzero(flags.reflecting[mat] & fresh)
        if len(part):
            m = mat[part]
            w = np.ones(len(part))
            lay = flags.layer[m]
            if lay.any():
                ml = m[lay]
                e = ediel[part[lay]] * sa.mat_tint_max[ml]
                wl = e / (e + (1.0 - e) * flags.diffuse_max[ml])
                w[lay] = np.where(wl >= 0.0, np.minimum(wl, 1.0), 1.0)  # (a NaN: as 1)
            counts[part] = np.maximum(np.ceil(2.0 * samples * np.sqrt(w)), 1.0).astype(np.int64)
    return counts, glossy


@njit(cache=True, nogil=True)
def _put(c_o, c_d, c_w, c_ok, k, ox, oy, oz, dx, dy, dz, wr, wg, wb):
    """Spawned ray slot ``k`` (of the :class:`Spawned` arrays)."""
    c_ok[k] = True
    c_o[k, 0] = ox
    c_o[k, 1] = oy
    c_o[k, 2] = oz
    c_d[k, 0] = dx
    c_d[k, 1] = dy
    c_d[k, 2] = dz
    c_w[k, 0] = wr
    c_w[k, 1] = wg
    c_w[k, 2] = wb


@njit(cache=True, nogil=True)
def _glossy_rays(i, gstart, seeds, lat, px, py, pz, gx, gy, gz, sx, sy, sz, dx, dy, dz, off,
                 w0, w1, w2, rr, rg, rb, tr, tg, tb, ur, ug, ub, sr, sg, sb, eta_s, metallic,
                 mr, mg, mb, qr, qg, qb, z, alpha, eta, ke, c_o, c_d, c_w, c_ok):
    """The glossy rays of point ``i`` (mirror share ``r*``, transmission ``t*`` refracted and
    ``u*`` reflected, the metal's tint ``q*``): ``ns = gstart[i + 1] - gstart[i]`` microfacet
    normals drawn from GGX's visible normals about the shading normal (the geometric one where
    the shading normal faces away from the viewer), stratified (a Fibonacci lattice rotated by
    a hash of the node's seed, as the soft lights' samples; or, with ``lat`` (n, 4) uint64
    rows, points ``lat[i, 1] + s lat[i, 2]`` of a lattice of ``lat[i, 3]`` points rotated by
    ``lat[i, 0]``, shared by a pixel's samples: :mod:`.glossy_strata`), each a reflected and
    a refracted ray. A sample's reflection carries the layer's Fresnel at ``i . h`` with the
    direct light's multiple-scattering factors ``z`` (the shade kernel's
    :func:`~.multiscatter.multiscatter_factors` of the point, where the layer has a lobe;
    ``(1, 1, 1, 1)`` where not, whose Fresnel is 0 then) plus the dielectric Fresnel ``F``
    of the transmissive part, its refraction ``(1 - F)`` of it, each times ``G2 / G1`` and
    ``1 / ns`` (:func:`~.ggx_sampling.ggx_weight`); a direction below the geometric surface
    (reflection) or above it (refraction) is dropped, a microfacet with total internal
    reflection reflects all
    of the transmissive part. What the samples share (the lobe's frame about the view,
    Smith's Lambda of the view) is computed once: the same bits as per sample."""
    k0 = gstart[i]
    ns = gstart[i + 1] - k0
    wmin = tol.PATH_WEIGHT_MIN
    ox, oy, oz = -dx, -dy, -dz
    nx, ny, nz = sx, sy, sz
    co = dot3(ox, oy, oz, nx, ny, nz)
    if co <= 0.0:
        nx, ny, nz = gx, gy, gz
        co = dot3(ox, oy, oz, nx, ny, nz)
    co = max(co, tol.GGX_COS_MIN)
    refl = rr > 0.0 or rg > 0.0 or rb > 0.0
    trans = ur > 0.0 or ug > 0.0 or ub > 0.0
    zd, zr, zg, zb = z
    inv = 1.0 / ns
    if lat.shape[0] and lat[i, 3] > 0:  # a pixel's lattice (glossy_strata.lattices)
        h = lat[i, 0]
        j0, jstep, inv_lat = np.int64(lat[i, 1]), np.int64(lat[i, 2]), 1.0 / float(lat[i, 3])
    else:  # the point's own
        h = mix64(seeds[i] ^ GLOSSY_SALT)
        j0, jstep, inv_lat = np.int64(0), np.int64(1), inv
    r1 = float(h >> np.uint64(11)) * INV_2_53
    r2 = float(mix64(h) >> np.uint64(11)) * INV_2_53
    # what every sample's normal and weight share (ggx_sample_normal's, ggx_weight's)
    frame = ggx_sample_frame(nx, ny, nz, ox, oy, oz, alpha)
    a2 = alpha * alpha
    lo = ggx_lambda(co, a2)
    for s in range(ns):
        slot = 2 * (k0 + s)
        j = j0 + s * jstep
        u = (j + 0.5) * inv_lat + r1
        u -= math.floor(u)
        v = (j + 0.5) * GOLDEN + r2
        v -= math.floor(v)
        hx, hy, hz = ggx_sample_at(frame, nx, ny, nz, alpha, u, v)
        ch = dot3(ox, oy, oz, hx, hy, hz)
        if ch <= 0.0:
            continue
        ar = ag = ab = 0.0
        if refl:
            fr, fg, fb = principled_fresnel(ch, sr * zd, sg * zd, sb * zd, eta_s, metallic, mr,
                                            mg, mb, qr, qg, qb, zr, zg, zb)
            ar = rr * fr
            ag = rg * fg
            ab = rb * fb
        if trans and eta == 1.0:  # no interface: straight on
            cr = w0 * tr * inv
            cg = w1 * tg * inv
            cb = w2 * tb * inv
            if max(cr, cg, cb) * ns > wmin:
                _put(c_o, c_d, c_w, c_ok, slot + 1, px - gx * off, py - gy * off,
                     pz - gz * off, dx, dy, dz, cr, cg, cb)
        elif trans:
            ok, tx, ty, tz = refract(dx, dy, dz, hx, hy, hz, eta)
            if ok:
                f = fresnel_dielectric(ch, eta) * ke
                ar += f * ur
                ag += f * ug
                ab += f * ub
                ci = dot3(tx, ty, tz, nx, ny, nz)
                if ci < 0.0 and dot3(tx, ty, tz, gx, gy, gz) < 0.0:
                    q = (ke - f) * ggx_weight_lo(lo, ci, a2) * inv
                    cr = w0 * tr * q
                    cg = w1 * tg * q
                    cb = w2 * tb * q
                    if max(cr, cg, cb) * ns > wmin:
                        _put(c_o, c_d, c_w, c_ok, slot + 1, px - gx * off, py - gy * off,
                             pz - gz * off, tx, ty, tz, cr, cg, cb)
            else:  # total internal reflection at this microfacet
                ar += ur * ke
                ag += ug * ke
                ab += ub * ke
        qx, qy, qz = reflect(dx, dy, dz, hx, hy, hz)
        ci = dot3(qx, qy, qz, nx, ny, nz)
        if ci <= 0.0 or dot3(qx, qy, qz, gx, gy, gz) <= 0.0:
            continue
        q = ggx_weight_lo(lo, ci, a2) * inv
        cr = w0 * ar * q
        cg = w1 * ag * q
        cb = w2 * ab * q
        if max(cr, cg, cb) * ns > wmin:
            _put(c_o, c_d, c_w, c_ok, slot, px + gx * off, py + gy * off, pz + gz * off,
                 qx, qy, qz, cr, cg, cb)


def roulette(gstart: np.ndarray, glossy: np.ndarray, fresh: np.ndarray, seeds: np.ndarray,
             weight: np.ndarray, kids) -> None:
    """Russian roulette of the rays a level's *deeper* rough bounces spawned (points
    ``glossy`` (n,) bool whose path is not ``fresh``: one reflected and one refracted ray
    each, :func:`glossy_counts`), in place on ``kids`` (:class:`~.shader.Spawned`; point
    i's slots ``2 gstart[i]:2 gstart[i + 1]``): a ray carrying a fraction ``r`` (largest
    channel) of its point's path weight ``weight`` (n, 3) below
    :data:`~.tolerances.GLOSSY_ROULETTE_REL` goes on with probability ``p = r /
    GLOSSY_ROULETTE_REL``, its weight divided by ``p``; the others stop. Unbiased (a ray's
    expected weight is unchanged), deterministic (the draw hashes the point's node seed
    ``seeds`` and the slot). What it stops: inside a rough glass ball the internal
    reflection at each exit carries the interface's Fresnel (a few percent) and costs a
    whole ray tree below it (rough_materials: ~15k such rays per level down to the depth
    budget, a third of the frame, for ~4% of the ball's light; docs/glossy.md, session
    33). A path's first rough bounce (its glossy samples, :func:`glossy_counts`) and every
    smooth surface's rays are untouched: a scene without rough surfaces traces what it
    traced."""
    if ROULETTE and len(glossy):
        _roulette(gstart, glossy, fresh, seeds, weight, kids.w, kids.ok,
                  float(tol.GLOSSY_ROULETTE_REL))


@njit(cache=True, nogil=True)
def _roulette(gstart, glossy, fresh, seeds, weight, w, ok, rel):
    for i in range(glossy.shape[0]):
        if not glossy[i] or fresh[i]:
            continue
        wi = max(weight[i, 0], weight[i, 1], weight[i, 2])
        if not wi > 0.0:
            continue
        k0 = 2 * gstart[i]
        for k in range(k0, 2 * gstart[i + 1]):
            if not ok[k]:
                continue
            p = max(w[k, 0], w[k, 1], w[k, 2]) / (wi * rel)
            if p >= 1.0:
                continue
            h = mix64(seeds[i] ^ ROULETTE_SALT ^ np.uint64(k - k0 + 1))
            if float(h >> np.uint64(11)) * INV_2_53 < p:
                w[k, 0] /= p
                w[k, 1] /= p
                w[k, 2] /= p
            else:
                ok[k] = False
