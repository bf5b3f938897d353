"""The base tracer's kernels: surface points, shadow rays and shading of one depth level.

Radiance of a ray that hits a surface point ``p`` (shading normal ``n`` and geometric normal
``g``, both turned to the side the ray comes from, so every surface is two-sided)::

    L = emission + sum_j V_j f(l_j, -d) E_j + R * L(reflect) + T * L(refract)

* ``f`` is the material's BRDF: Ward (seed 000's model) or the Principled-like GGX layer
  over a Lambertian base (:func:`~.shading.principled_brdf`).

* ``E_j`` is the irradiance light ``j`` would give: ``I cos / r^2`` for point lights (times
  the spot falloff for spots), ``strength * cos`` for suns, ``cos = n . l_j``. A light counts
  only when it is on the lit side of the *geometric* surface and of the shading normal (it
  never leaks through a surface via an interpolated normal). ``V_j`` is a hard shadow ray:
  any occluder blocks.
* Mirror reflectance ``M`` (Principled-like: the material's mirror share times the layer's
  Fresnel reflectance toward the viewer) and transmission ``T_m`` with index of refraction
  ``ior``: with the dielectric Fresnel factor ``F`` at the interface, ``R = M + F T_m`` and
  ``T = (1-F) T_m`` (the tracer's Fresnel alone splits the transmissive part);
  on total internal reflection ``R = M + T_m`` and nothing is refracted. Whether the ray enters
  (``eta = 1 / ior``) or leaves (``eta = ior``) is decided by the geometric normal's winding.
* A rough Principled-like surface (:func:`is_glossy`) instead spreads ``R`` and ``T`` over
  its GGX lobe: N microfacet normals drawn from the visible normals, each a reflected and a
  refracted ray weighted ``F G2 / G1 / N`` (:func:`_glossy_rays`, docs/glossy.md).
* At a rough dielectric interface (:func:`~.shading.rough_interface`) a light on the far
  side of the surface (geometric and shading normal alike) counts too, through the GGX
  transmission lobe (:func:`~.shading.ggx_btdf`) instead of ``f``: its shadow-ray state is
  ``SH_FAR`` and its shadow ray leaves from the far side (:func:`~.shading.far_origin`).
* A ray that misses returns the world colour.

The stages and the wavefront that drive these kernels are :mod:`.whitted`'s; the shade
kernel also writes each point's light terms for :mod:`.light_records` when asked.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.attributes import slot_of
from ..geometry.scene import (
    LIGHT_SPOT,
    LIGHT_SUN,
    MODEL_PRINCIPLED,
    TEX_EMISSION,
    TEX_METAL,
    TEX_NO_BASE,
    TEX_SPECULAR,
    TEX_TRANSMISSION,
    TEX_TRANSMISSION_SQRT,
    SceneArrays,
)
from ..stripes import stripe_item, stripe_len
from ..views import fields, view_type
from .glossy_rays import _glossy_rays, _put, is_glossy
from .multiscatter import ggx_e, multiscatter_factors
from .shading import (
    INV_PI,
    dot3,
    far_origin,
    fresnel_dielectric,
    geometric_normal,
    ggx_btdf,
    ggx_glass_albedo,
    ggx_lobe,
    mirror_dir,
    normalize3,
    principled_brdf_z,
    principled_fresnel,
    rough_interface,
    shading_normal,
    spawn_offset,
    spot_falloff,
    texel_weight,
    texture_lookup,
    texture_uv,
    transmit,
    ward_brdf,
)
from .soft_lights import SH_SOFT, extent_faces, spot_cosine

# shadow-ray states (per hit and light), also the codes in RayTree.node_occluder
_SH_TRACE = 1
#: a hard light on the far side of a rough interface (:func:`~.shading.rough_interface`):
#: its shadow ray leaves from the far side, its light comes through the transmission lobe
SH_FAR = 3
OCC_NONE = -1  # light unoccluded
OCC_NOT_FACING = -2  # light behind the surface, outside its cone, or the ray missed


class Surfaces(NamedTuple):
    """Surface points of a batch of ``n`` rays (:func:`surfaces`), normals turned toward
    the incoming ray."""

    P: np.ndarray  # (n, 3) float64 hit point; on a miss a point far beyond the scene
    NG: np.ndarray  # (n, 3) float64 geometric normal
    NS: np.ndarray  # (n, 3) float64 shading normal
    VD: np.ndarray  # (n, 3) float64 unit ray direction
    enter: np.ndarray  # (n,) bool: the ray enters the surface's inside
    mat: np.ndarray  # (n,) int32 material, -1 on a miss
    Q: np.ndarray  # (n, 3) float64 shadow-ray origin (P moved off the surface, lit side)
    sh_state: np.ndarray  # (n L,) int8 at row i * L + j: _SH_TRACE or OCC_NOT_FACING


class Spawned(NamedTuple):
    """Reflection (slot ``2 i``) and refraction (slot ``2 i + 1``) rays of ``n`` surface
    points (:func:`shade`); a slot holds a ray where ``ok``."""

    o: np.ndarray  # (2n, 3) float64 origin
    d: np.ndarray  # (2n, 3) float64 direction
    w: np.ndarray  # (2n, 3) float64 path weight
    ok: np.ndarray  # (2n,) bool


# ----------------------------------------------------------------------------- kernels


@njit(cache=True, nogil=True, inline="always")
def _brdf(principled, sx, sy, sz, lx, ly, lz, ox, oy, oz, dr, dg, db, sr, sg, sb, eta_s,
          metallic, mr, mg, mb, alpha, z, e_diel, kr, kg, kb):
    """The material's BRDF (Principled-like or Ward) for light direction ``l`` and view
    direction ``o`` about shading normal ``s``: the hard lights' and the soft samples' one
    evaluation (``k*``: the metal's F82 tint, ``z`` the point's
    :func:`~.multiscatter.multiscatter_factors`: :func:`principled_brdf`'s)."""
    if principled:
        return principled_brdf_z(sx, sy, sz, lx, ly, lz, ox, oy, oz, dr, dg, db, sr, sg, sb,
                                 eta_s, metallic, mr, mg, mb, alpha, e_diel, kr, kg, kb, z[0],
                                 z[1], z[2], z[3])
    return ward_brdf(sx, sy, sz, lx, ly, lz, ox, oy, oz, dr, dg, db, sr, sg, sb, alpha)


@njit(cache=True, nogil=True, inline="always")
def _glass_lobe(sx, sy, sz, lx, ly, lz, ox, oy, oz, alpha, eta, ke):
    """The rough dielectric's reflection lobe (Cycles' GGX glass seen from the light's side)
    for light direction ``l`` and view ``o``: ``F(l . h) D G2 / (4 cos_l cos_o) / E``
    (``ke = 1 / E``, :func:`~.shading.ggx_glass_albedo`), to be tinted by the
    transmission; 0 where ``eta`` is 1 (not a rough interface)."""
    if eta == 1.0:
        return 0.0
    lobe, ch = ggx_lobe(sx, sy, sz, lx, ly, lz, ox, oy, oz, alpha)
    if lobe <= 0.0:
        return 0.0
    return lobe * fresnel_dielectric(ch, eta) * ke


@njit(cache=True, nogil=True)
def _material_of(sa, inst, tri):
    """Material id of triangle ``tri`` on instance ``inst`` (slot clamped to the list)."""
    s0 = sa.inst_mat_start[inst]
    cnt = sa.inst_mat_start[inst + 1] - s0
    slot = slot_of(sa, sa.inst_mesh[inst], tri)
    if slot >= cnt:
        slot = cnt - 1
    return sa.inst_mat[s0 + slot]


@njit(cache=True, nogil=True, inline="always")
def light_state(sa, j, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, far):
    """Shadow-ray state of light ``j`` at a surface point (see :func:`light_states`);
    ``far``: the point is a rough interface (lights on its far side count)."""
    if sa.light_kind[j] < 0:
        return -2  # a deleted light's slot (LIGHT_NONE)
    if sa.light_ext[j]:
        # sampled (each sample checks its own facing), unless the whole light is below
        # the surface's horizon (and, at a rough interface, above it seen from its far
        # side) or behind an area light: then every sample would be 0
        if extent_faces(sa, j, qx, qy, qz, gx, gy, gz):
            return SH_SOFT
        if far:
            fx, fy, fz = far_origin(sa, px, py, pz, gx, gy, gz)
            if extent_faces(sa, j, fx, fy, fz, -gx, -gy, -gz):
                return SH_SOFT
        return -2
    if sa.light_kind[j] == LIGHT_SUN:
        lx = -sa.light_dir[j, 0]
        ly = -sa.light_dir[j, 1]
        lz = -sa.light_dir[j, 2]
        cg = dot3(gx, gy, gz, lx, ly, lz)
        cs = dot3(sx, sy, sz, lx, ly, lz)
        if cg > 0.0 and cs > 0.0:
            return _SH_TRACE
        if far and cg < 0.0 and cs < 0.0:
            return SH_FAR
        return -2
    lx, ly, lz, dist = normalize3(sa.light_pos[j, 0] - px, sa.light_pos[j, 1] - py,
                                  sa.light_pos[j, 2] - pz)
    if not dist > 0.0:
        return -2
    cg = dot3(gx, gy, gz, lx, ly, lz)
    cs = dot3(sx, sy, sz, lx, ly, lz)
    state = _SH_TRACE
    if not (cg > 0.0 and cs > 0.0):
        if not (far and cg < 0.0 and cs < 0.0):
            return -2
        state = SH_FAR
    if sa.light_kind[j] == LIGHT_SPOT:
        ca = spot_cosine(sa, j, lx, ly, lz)
        if spot_falloff(ca, sa.light_cos_outer[j], sa.light_cos_inner[j]) <= 0.0:
            return -2
    if state == SH_FAR:
        qx, qy, qz = far_origin(sa, px, py, pz, gx, gy, gz)
        gx, gy, gz = -gx, -gy, -gz
    wx, wy, wz, wl = normalize3(sa.light_pos[j, 0] - qx, sa.light_pos[j, 1] - qy,
                                sa.light_pos[j, 2] - qz)
    if not (wl > 0.0 and dot3(gx, gy, gz, wx, wy, wz) > 0.0):
        return -2  # the light sits within the offset of the surface
    return state


@njit(cache=True, nogil=True, inline="always")
def light_states(sa, i, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, m, sh_state):
    """Shadow-ray states of surface point ``i`` (rows ``i * L + j``) of material ``m``:
    ``_SH_TRACE`` when light ``j`` faces the point (geometric and shading normal ``g``,
    ``s`` turned toward the viewer; spot cone) and is not within the offset of shadow
    origin ``q``; at a rough interface (:func:`~.shading.rough_interface`) ``SH_FAR`` when
    it faces the far side alike (its shadow ray leaves from :func:`far_origin`);
    ``SH_SOFT`` for a light with an extent that is not wholly below the horizon (or, at a
    rough interface, wholly above it); else -2."""
    L = sa.light_kind.shape[0]
    far = rough_interface(sa, m)
    for j in range(L):
        sh_state[i * L + j] = light_state(sa, j, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy,
                                          qz, far)


_SurfaceScene = view_type("_SurfaceScene", SceneArrays, (
    "inst_mat", "inst_mat_start", "inst_nmat", "light_bound", "light_cos_inner",
    "light_cos_outer", "light_dir", "light_ext", "light_half", "light_kind",
    "light_pos", "light_recv", "light_spot_frame", "light_spot_scaled", "mat_ior",
    "mat_model", "mat_roughness", "mat_transmission", "scene_aabb", "scene_extent",
    "inst_mesh", "mesh_nrm", "normals", "mesh_slot", "tri_slot", "tris", "verts"), __name__)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _surface_kernel(sa, o, d, tmax, hits, surf, first, step):
    """Surface points of a batch of ``n`` rays and their shadow rays (one per light).

    Inputs: o, d (n, 3) float64; tmax (n,) float64; hits : :class:`Hits` of the rays.
    Output: surf, a :class:`Surfaces`. Its sh_state at row ``i * L + j``: 1 trace a shadow
    ray from point i to light j (:func:`_shadow_kernel` makes it), -2 light not facing /
    outside cone.
    """
    sa = _SurfaceScene(*fields(sa, _SurfaceScene))  # the fields its loop reads
    t, inst, prim, bu, bv = hits.t, hits.inst, hits.prim, hits.u, hits.v
    P, NG, NS, VD, ENTER, MAT, Q, sh_state = surf
    n = o.shape[0]
    L = sa.light_kind.shape[0]
    ext = sa.scene_extent
    cx = 0.5 * (sa.scene_aabb[0, 0] + sa.scene_aabb[1, 0])
    cy = 0.5 * (sa.scene_aabb[0, 1] + sa.scene_aabb[1, 1])
    cz = 0.5 * (sa.scene_aabb[0, 2] + sa.scene_aabb[1, 2])
    for stripe_q in range(stripe_len(n, first, step)):  # stripes.run
        i = stripe_item(stripe_q, first, step)
        if i >= n:
            break
        ux, uy, uz, dl = normalize3(d[i, 0], d[i, 1], d[i, 2])
        VD[i, 0] = ux
        VD[i, 1] = uy
        VD[i, 2] = uz
        k = inst[i]
        if k < 0:
            # a point past the scene box along the ray (segment end for shafts)
            far = 2.0 * (math.sqrt((o[i, 0] - cx) ** 2 + (o[i, 1] - cy) ** 2
                                   + (o[i, 2] - cz) ** 2) + ext)
            s = far / dl if dl > 0.0 else 0.0
            if tmax[i] < s:
                s = tmax[i]
            P[i, 0] = o[i, 0] + d[i, 0] * s
            P[i, 1] = o[i, 1] + d[i, 1] * s
            P[i, 2] = o[i, 2] + d[i, 2] * s
            MAT[i] = -1
            ENTER[i] = False
            for j in range(L):
                sh_state[i * L + j] = -2
            continue
        tri = prim[i]
        px = o[i, 0] + d[i, 0] * t[i]
        py = o[i, 1] + d[i, 1] * t[i]
        pz = o[i, 2] + d[i, 2] * t[i]
        P[i, 0] = px
        P[i, 1] = py
        P[i, 2] = pz
        nm = sa.inst_nmat[k]
        gx, gy, gz = geometric_normal(sa.verts, sa.tris, nm, tri)
        sx, sy, sz = shading_normal(sa, sa.inst_mesh[k], nm, tri, bu[i], bv[i], gx, gy, gz)
        enter = dot3(ux, uy, uz, gx, gy, gz) < 0.0
        if not enter:
            gx, gy, gz = -gx, -gy, -gz
            sx, sy, sz = -sx, -sy, -sz
        ENTER[i] = enter
        NG[i, 0] = gx
        NG[i, 1] = gy
        NG[i, 2] = gz
        NS[i, 0] = sx
        NS[i, 1] = sy
        NS[i, 2] = sz
        MAT[i] = _material_of(sa, k, tri)
        off = spawn_offset(px, py, pz, ext)
        qx = px + gx * off
        qy = py + gy * off
        qz = pz + gz * off
        Q[i, 0] = qx
        Q[i, 1] = qy
        Q[i, 2] = qz
        light_states(sa, i, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, MAT[i],
                     sh_state)
        if sa.light_recv.shape[0] > 0:
            unlinked_lights(sa, i, k, sh_state)


@njit(cache=True, nogil=True, inline="always")
def unlinked_lights(sa, i, k, sh_state):
    """Light linking: the lights that do not light instance ``k`` get state -2 at point
    ``i`` (no shadow ray, no light)."""
    L = sa.light_kind.shape[0]
    for j in range(L):
        if sa.light_recv[j, k] == 0:
            sh_state[i * L + j] = -2


_ShadowScene = view_type("_ShadowScene", SceneArrays, (
    "light_dir", "light_kind", "light_pos", "scene_extent"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def _shadow_kernel(sa, P, NG, Q, sh_state, todo, sh_o, sh_d, sh_tmax):
    """Shadow rays for the (point, light) rows ``todo`` (k,) int64 (row = i * L + j).

    P, NG, Q : (n, 3) float64 points, geometric normals and shadow origins, sh_state (n L,)
    the rows' states from :func:`_surface_kernel` (an ``SH_FAR`` row's ray leaves from
    :func:`far_origin`). Outputs sh_o, sh_d (k, 3) float64 (unit directions), sh_tmax (k,)
    float64: just short of a point or spot light, infinite for a sun.
    """
    sa = _ShadowScene(*fields(sa, _ShadowScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    for k in prange(todo.shape[0]):
        i = todo[k] // L
        j = todo[k] - i * L
        if sh_state[todo[k]] == SH_FAR:
            ox, oy, oz = far_origin(sa, P[i, 0], P[i, 1], P[i, 2], NG[i, 0], NG[i, 1],
                                    NG[i, 2])
        else:
            ox, oy, oz = Q[i, 0], Q[i, 1], Q[i, 2]
        sh_o[k, 0] = ox
        sh_o[k, 1] = oy
        sh_o[k, 2] = oz
        if sa.light_kind[j] == LIGHT_SUN:
            sh_d[k, 0] = -sa.light_dir[j, 0]
            sh_d[k, 1] = -sa.light_dir[j, 1]
            sh_d[k, 2] = -sa.light_dir[j, 2]
            sh_tmax[k] = np.inf
        else:
            wx, wy, wz, wl = normalize3(sa.light_pos[j, 0] - ox, sa.light_pos[j, 1] - oy,
                                        sa.light_pos[j, 2] - oz)
            sh_d[k, 0] = wx
            sh_d[k, 1] = wy
            sh_d[k, 2] = wz
            sh_tmax[k] = wl * (1.0 - tol.SHADOW_END_REL)


_ShadeScene = view_type("_ShadeScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ext", "light_intensity",
    "light_kind", "light_pos", "light_radiance", "light_recv", "light_spot_frame",
    "light_spot_scaled", "light_vis", "mat_diffuse", "mat_emission", "mat_ior",
    "mat_metal", "mat_metal_tint", "mat_metallic", "mat_mirror", "mat_model",
    "mat_roughness", "mat_specular", "mat_specular_ior", "mat_tex", "mat_tint_max",
    "mat_transmission", "mesh_gen", "mesh_tri_start", "scene_extent", "tex_data",
    "tex_map", "tex_size", "tex_start", "mesh_uv", "uvs", "tris", "verts", "world_color",
    "world_light"), __name__)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _shade_kernel(sa, hits, surf, vis, weight, spawn, soft, gstart, seeds, lat, ediel, contrib,
                  out, tv, tp, first, step):
    """Direct light and secondary rays of a batch of ``n`` surface points.

    One loop body on purpose: the material's twenty-odd values are read once per point and
    used by both the light loop and the spawned rays (split into functions, they would be
    passed on in long argument lists or read twice).

    hits : the :class:`Hits` (prim, u, v for texture coordinates); surf : the
    :class:`Surfaces` of :func:`_surface_kernel`. vis : (n L,) bool light j visible from
    point i (row ``i * L + j``; lights with an extent are skipped there); weight : (n, 3)
    float64 path weights; spawn : whether reflection/refraction rays may be spawned; soft :
    the :class:`~.soft_lights.SoftSamples` of the points (their lights and the world's);
    gstart : (n + 1,) int64, point i's rays are the slot pairs ``gstart[i]:gstart[i + 1]``
    (its reflection at ``2 s``, its refraction at ``2 s + 1``): one pair for a mirror,
    glass or a matte surface, one per glossy sample where the point is glossy
    (:func:`~.glossy_rays.glossy_counts`); seeds : (n,) uint64 the points' node seeds (the glossy
    samples'; empty: no glossy rays); lat : (n, 4) uint64 the glossy samples' lattices
    (:func:`~.glossy_strata.lattices`; empty: each point's own); ediel (n,) float64 the
    Principled points' dielectric albedos (:func:`~.dielectric_albedo.dielectric_albedos`:
    ``ggx_albedo``'s, bit for bit). Outputs: contrib (n, 3)
    weighted radiance to add to
    each ray's input ray; out, the :class:`Spawned` rays; with ``tv`` (n, L + 2, 3)
    float64 and ``tp`` (n, L + 2) bool (empty: not kept) each point's *light terms*
    (:mod:`.light_records`), what it adds to its radiance before the path weight without
    the light's intensity or radiance: column j light j (present where added), L the
    world's light, L + 1 the emission (a miss: 1, for the world colour).
    """
    sa = _ShadeScene(*fields(sa, _ShadeScene))  # the fields its loop reads
    prim, bu, bv, hinst = hits.prim, hits.u, hits.v, hits.inst
    P, NG, NS, VD, ENTER, MAT = surf.P, surf.NG, surf.NS, surf.VD, surf.enter, surf.mat
    linked = sa.light_recv.shape[0] > 0
    c_o, c_d, c_w, c_ok = out
    n = P.shape[0]
    L = sa.light_kind.shape[0]
    ext = sa.scene_extent
    wmin = tol.PATH_WEIGHT_MIN
    terms = tv.shape[0] > 0
    for stripe_q in range(stripe_len(n, first, step)):  # stripes.run
        i = stripe_item(stripe_q, first, step)
        if i >= n:
            break
        slot = 2 * gstart[i]
        for k in range(slot, 2 * gstart[i + 1]):
            c_ok[k] = False
        w0 = weight[i, 0]
        w1 = weight[i, 1]
        w2 = weight[i, 2]
        m = MAT[i]
        if terms:
            for j in range(L + 2):
                tp[i, j] = False
            tp[i, L + 1] = True
        if m < 0:
            contrib[i, 0] = w0 * sa.world_color[0]
            contrib[i, 1] = w1 * sa.world_color[1]
            contrib[i, 2] = w2 * sa.world_color[2]
            if terms:
                tv[i, L + 1, 0] = 1.0
                tv[i, L + 1, 1] = 1.0
                tv[i, L + 1, 2] = 1.0
            continue
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        gx, gy, gz = NG[i, 0], NG[i, 1], NG[i, 2]
        sx, sy, sz = NS[i, 0], NS[i, 1], NS[i, 2]
        dx, dy, dz = VD[i, 0], VD[i, 1], VD[i, 2]
        dr = sa.mat_diffuse[m, 0]
        dg = sa.mat_diffuse[m, 1]
        db = sa.mat_diffuse[m, 2]
        lr = sa.mat_emission[m, 0]
        lg = sa.mat_emission[m, 1]
        lb = sa.mat_emission[m, 2]
        tex = sa.mat_tex[m]
        tf = 0  # the texture's TEX_* bits: what its texel x* multiplies (here the base
        xr = xg = xb = 1.0  # colour and the emission; the other weights as they are read)
        if tex >= 0:
            tf = sa.tex_size[tex, 2]
            u, v = texture_uv(sa, tex, prim[i], bu[i], bv[i])
            xr, xg, xb = texture_lookup(sa.tex_data, sa.tex_start, sa.tex_size, tex, u, v)
            if not tf & TEX_NO_BASE:
                dr *= xr
                dg *= xg
                db *= xb
            if tf & TEX_EMISSION:
                lr *= xr
                lg *= xg
                lb *= xb
        if terms:
            tv[i, L + 1, 0] = lr
            tv[i, L + 1, 1] = lg
            tv[i, L + 1, 2] = lb
        sr, sg, sb = texel_weight(tf, TEX_SPECULAR, sa.mat_specular[m, 0],
                                  sa.mat_specular[m, 1], sa.mat_specular[m, 2], xr, xg, xb)
        alpha = sa.mat_roughness[m]
        principled = sa.mat_model[m] == MODEL_PRINCIPLED
        eta_s = sa.mat_specular_ior[m]
        metallic = sa.mat_metallic[m]
        mr, mg, mb = texel_weight(tf, TEX_METAL, sa.mat_metal[m, 0], sa.mat_metal[m, 1],
                                  sa.mat_metal[m, 2], xr, xg, xb)
        qr, qg, qb = sa.mat_metal_tint[m, 0], sa.mat_metal_tint[m, 1], sa.mat_metal_tint[m, 2]
        e_diel = 0.0
        # a glossy point's rays carry the world's glossy reflection: its samples of the
        # world light the diffuse part only (no light counted twice)
        glossy = spawn and seeds.shape[0] > 0 and is_glossy(sa, m)
        z = (1.0, 1.0, 1.0, 1.0)
        if principled:
            if alpha >= tol.GLOSSY_ALPHA_MIN and (sr > 0.0 or sg > 0.0 or sb > 0.0
                                                  or metallic > 0.0):  # (a lobe: the BRDF's)
                e_white = ggx_e(min(max(-dot3(dx, dy, dz, sx, sy, sz), tol.GGX_COS_MIN),
                                    1.0), alpha)  # (e_diel, ggx_albedo's pair: ediel)
                z = multiscatter_factors(alpha, e_white, eta_s, mr, mg, mb, qr, qg, qb)
            e_diel = ediel[i]
            # Cycles: the base under the layer's tinted albedo (the tint's largest channel)
            e_diel *= sa.mat_tint_max[m]
            if tf & TEX_SPECULAR:
                e_diel *= max(xr, xg, xb, 0.0)
        ki = hinst[i]
        # the transmissive part refracted (t*) and reflected (u*): an image into a Glass
        # BSDF's colour tints both, a Principled's Base Color (its square root) the refracted
        # part alone (Cycles: the reflection takes the Specular Tint)
        ur = sa.mat_transmission[m, 0]
        ug = sa.mat_transmission[m, 1]
        ub = sa.mat_transmission[m, 2]
        tr, tg, tb = texel_weight(tf, TEX_TRANSMISSION | TEX_TRANSMISSION_SQRT, ur, ug, ub,
                                  xr, xg, xb)
        if not tf & TEX_TRANSMISSION_SQRT:
            ur, ug, ub = tr, tg, tb
        # a rough interface (Cycles' multiscatter GGX glass): its lobe, reflected and
        # refracted, scaled by 1 / E, E its single-scattering albedo toward the viewer
        eta = 1.0
        ke = 1.0
        eta_g = 1.0  # the rough interface's (its lights' highlight); 1: none
        if ur > 0.0 or ug > 0.0 or ub > 0.0:
            ior = sa.mat_ior[m]
            eta = 1.0 / ior if ENTER[i] else ior
            if principled and alpha >= tol.GLOSSY_ALPHA_MIN and eta != 1.0:
                cv = -dot3(dx, dy, dz, sx, sy, sz)
                if cv <= 0.0:
                    cv = -dot3(dx, dy, dz, gx, gy, gz)
                ke = 1.0 / max(ggx_glass_albedo(cv, alpha, eta), tol.GGX_ALBEDO_MIN)
                eta_g = eta
        for j in range(L):
            if not vis[i * L + j] or sa.light_ext[j]:
                continue
            if linked and sa.light_recv[j, ki] == 0:
                continue
            vd = sa.light_vis[j, 0]  # the light's diffuse and glossy ray visibility
            vg = sa.light_vis[j, 1]
            vi = max(vg, sa.light_vis[j, 3])  # a glass closure's (both must be off)
            if sa.light_kind[j] == LIGHT_SUN:
                lx = -sa.light_dir[j, 0]
                ly = -sa.light_dir[j, 1]
                lz = -sa.light_dir[j, 2]
                e = dot3(sx, sy, sz, lx, ly, lz)
            else:
                lx, ly, lz, dist = normalize3(sa.light_pos[j, 0] - px,
                                              sa.light_pos[j, 1] - py,
                                              sa.light_pos[j, 2] - pz)
                e = dot3(sx, sy, sz, lx, ly, lz) / (dist * dist)
                if sa.light_kind[j] == LIGHT_SPOT:
                    ca = spot_cosine(sa, j, lx, ly, lz)
                    e *= spot_falloff(ca, sa.light_cos_outer[j], sa.light_cos_inner[j])
            if e < 0.0 and dot3(gx, gy, gz, lx, ly, lz) < 0.0:
                # an SH_FAR row: the light through the rough interface's transmission lobe
                e = -e
                q = ggx_btdf(sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, alpha, eta_g) * ke * vi
                fr = q * tr
                fg = q * tg
                fb = q * tb
            elif e <= 0.0:
                continue
            else:
                fr, fg, fb = _brdf(principled, sx, sy, sz, lx, ly, lz, -dx, -dy, -dz,
                                   dr * vd, dg * vd, db * vd, sr * vg, sg * vg, sb * vg,
                                   eta_s, metallic * vg, mr, mg, mb, alpha, z, e_diel,
                                   qr, qg, qb)
                q = _glass_lobe(sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, alpha, eta_g, ke) * vi
                fr += q * ur
                fg += q * ug
                fb += q * ub
            lr += fr * e * sa.light_intensity[j, 0]
            lg += fg * e * sa.light_intensity[j, 1]
            lb += fb * e * sa.light_intensity[j, 2]
            if terms:
                tp[i, j] = True
                tv[i, j, 0] = fr * e
                tv[i, j, 1] = fg * e
                tv[i, j, 2] = fb * e
        # lights with an extent and the world, n samples per (point, light) row: the plain
        # estimator, or the ratio estimator for the diffuse part where the row has a
        # closed form (soft_lights.RATIO_ESTIMATOR)
        ns = soft.n[0]
        kdf = (1.0 - e_diel) * INV_PI if principled else INV_PI
        kr = dr * kdf
        kg = dg * kdf
        kb = db * kdf
        k0 = soft.start[i]
        while k0 < soft.start[i + 1]:
            j = soft.light[k0]
            vd = 1.0
            vg = 1.0
            vi = 1.0
            if j < L:
                if linked and sa.light_recv[j, ki] == 0:
                    k0 += ns
                    continue
                vd = sa.light_vis[j, 0]
                vg = sa.light_vis[j, 1]
                vi = max(vg, sa.light_vis[j, 3])
            ex = soft.exact[k0 // ns]
            ar = 0.0
            ag = 0.0
            ab = 0.0
            sum_w = 0.0
            sum_vw = 0.0
            for k in range(k0, k0 + ns):
                sum_w += soft.w[k]
                if not soft.vis[k]:
                    continue
                lx, ly, lz = soft.d[k, 0], soft.d[k, 1], soft.d[k, 2]
                if glossy and soft.light[k] >= L:
                    fr, fg, fb = kr, kg, kb
                elif dot3(gx, gy, gz, lx, ly, lz) < 0.0:
                    # a sample on the rough interface's far side: its transmission lobe
                    q = ggx_btdf(sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, alpha, eta_g) * ke * vi
                    fr = q * tr
                    fg = q * tg
                    fb = q * tb
                else:
                    fr, fg, fb = _brdf(principled, sx, sy, sz, lx, ly, lz, -dx, -dy, -dz,
                                       dr * vd, dg * vd, db * vd, sr * vg, sg * vg, sb * vg,
                                       eta_s, metallic * vg, mr, mg, mb, alpha, z, e_diel,
                                       qr, qg, qb)
                    q = _glass_lobe(sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, alpha, eta_g,
                                    ke) * vi
                    fr += q * ur
                    fg += q * ug
                    fb += q * ub
                e = soft.w[k]
                if ex >= 0.0:
                    sum_vw += e
                    fr -= kr * vd
                    fg -= kg * vd
                    fb -= kb * vd
                ar += fr * e
                ag += fg * e
                ab += fb * e
            if ex >= 0.0 and sum_w > 0.0:
                t = ex * sum_vw / sum_w * vd
                ar += kr * t
                ag += kg * t
                ab += kb * t
            if terms:
                tp[i, j] = True
                tv[i, j, 0] = ar
                tv[i, j, 1] = ag
                tv[i, j, 2] = ab
            if j < L:
                lr += ar * sa.light_radiance[j, 0]
                lg += ag * sa.light_radiance[j, 1]
                lb += ab * sa.light_radiance[j, 2]
            else:
                lr += ar * sa.world_light[0]
                lg += ag * sa.world_light[1]
                lb += ab * sa.world_light[2]
            k0 += ns
        contrib[i, 0] = w0 * lr
        contrib[i, 1] = w1 * lg
        contrib[i, 2] = w2 * lb
        if not spawn:
            continue
        rr = sa.mat_mirror[m, 0]
        rg = sa.mat_mirror[m, 1]
        rb = sa.mat_mirror[m, 2]
        off = spawn_offset(px, py, pz, ext)
        if glossy:
            # (i is unsigned in the loop's own function: as it is, _glossy_rays compiled twice;
            # the point's values passed, not ``sa``: its ~40 arrays as arguments, and the
            # factors z computed again there, were ~40% of a glossy point's cost)
            zq = z
            if ((sr < 0.0 or sg < 0.0 or sb < 0.0)
                    and not (sr > 0.0 or sg > 0.0 or sb > 0.0 or metallic > 0.0)
                    and (rr > 0.0 or rg > 0.0 or rb > 0.0)):
                # no lobe, yet a negative specular texel (TEX_SPECULAR; the engine takes
                # any finite texel): its Fresnel is not 0, and the rays' reflection carries
                # the layer's factor as before session 42 (z = 1 multiplies a zero Fresnel
                # only where every specular weight is +-0)
                e_white = ggx_e(min(max(-dot3(dx, dy, dz, sx, sy, sz), tol.GGX_COS_MIN),
                                    1.0), alpha)
                zq = multiscatter_factors(alpha, e_white, eta_s, mr, mg, mb, qr, qg, qb)
            _glossy_rays(np.int64(i), gstart, seeds, lat, px, py, pz, gx, gy, gz, sx, sy, sz,
                         dx, dy, dz, off, w0, w1, w2, rr, rg, rb, tr, tg, tb, ur, ug, ub, sr, sg,
                         sb, eta_s, metallic, mr, mg, mb, qr, qg, qb, zq, alpha, eta, ke, c_o,
                         c_d, c_w, c_ok)
            continue
        if principled and (rr > 0.0 or rg > 0.0 or rb > 0.0):
            fr, fg, fb = principled_fresnel(-dot3(dx, dy, dz, sx, sy, sz), sr, sg, sb, eta_s,
                                            metallic, mr, mg, mb, qr, qg, qb)
            rr *= fr
            rg *= fg
            rb *= fb
        if ur > 0.0 or ug > 0.0 or ub > 0.0:
            ok, tx, ty, tz, f = transmit(dx, dy, dz, sx, sy, sz, gx, gy, gz, eta)
            if ok:
                rr += f * ur
                rg += f * ug
                rb += f * ub
                cr = w0 * (1.0 - f) * tr
                cg = w1 * (1.0 - f) * tg
                cb = w2 * (1.0 - f) * tb
                if max(cr, cg, cb) > wmin:
                    _put(c_o, c_d, c_w, c_ok, slot + 1, px - gx * off, py - gy * off,
                         pz - gz * off, tx, ty, tz, cr, cg, cb)
            else:  # total internal reflection
                rr += ur
                rg += ug
                rb += ub
        cr = w0 * rr
        cg = w1 * rg
        cb = w2 * rb
        if max(cr, cg, cb) > wmin:
            qx, qy, qz = mirror_dir(dx, dy, dz, sx, sy, sz, gx, gy, gz)
            _put(c_o, c_d, c_w, c_ok, slot, px + gx * off, py + gy * off, pz + gz * off,
                 qx, qy, qz, cr, cg, cb)
