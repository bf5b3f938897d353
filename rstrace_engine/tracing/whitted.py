"""The base tracer: wavefront Whitted ray tracing that also records ray trees.

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
* A ray that misses returns the world colour.

The wavefront: every depth level intersects its batch of rays, runs a surface kernel (hit
point, normals, material, one shadow ray per light), intersects the shadow rays, runs a shade
kernel (direct light, reflection/refraction rays into preallocated slots), compacts the
spawned rays and goes on with them. Each spawned ray carries the index of the input ray it
contributes to and its path weight; it is not spawned when that weight is below
``tolerances.PATH_WEIGHT_MIN``. ``max_depth`` counts reflection/refraction bounces (0: primary
rays and direct light only). The three stages are public (:func:`surfaces`,
:func:`shadow_rays`, :func:`shade`) for the RI-tree renderer, whose levels find their hits
and shadow visibility otherwise but are shaded alike.

With ``record=True`` the ray tree of every input ray is returned as a :class:`RayTree`; its
shadow rays then use ``closest_hit`` so that each occluder's instance id is known.
"""

from __future__ import annotations

import logging
import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..accel.accelerators import Hits, create_accelerator, per_ray
from ..cancel import bound, cancelled
from ..frame import CLASS_BACKGROUND, LIGHT_SAMPLES_DEFAULT, Frame, RenderSettings
from ..geometry.cameras import camera_params, camera_rays
from ..geometry.scene import LIGHT_SPOT, LIGHT_SUN, MODEL_PRINCIPLED, Scene, SceneArrays
from .batches import TILE_RAYS, accumulate, frame_batches, scatter_add, threads_for
from .shading import (
    INV_PI,
    dot3,
    fresnel_dielectric,
    geometric_normal,
    ggx_albedo,
    normalize3,
    principled_brdf,
    principled_fresnel,
    reflect,
    refract,
    shading_normal,
    spawn_offset,
    spot_falloff,
    surface_uv,
    texture_lookup,
    ward_brdf,
)
from .soft_lights import (
    OCC_SOFT,
    SH_SOFT,
    SoftSamples,
    extent_faces,
    has_soft_light,
    no_samples,
    node_seeds,
    sample_seeds,
    soft_visibility,
)

log = logging.getLogger(__name__)

# shadow-ray states (per hit and light), also the codes in RayTree.node_occluder
_SH_TRACE = 1
OCC_NONE = -1  # light unoccluded
OCC_NOT_FACING = -2  # light behind the surface, outside its cone, or the ray missed


class RayTree(NamedTuple):
    """Ray trees of a batch of rays, one row per node (see docs/CONTRACTS.md).

    Rows are ordered by depth level; the first ``n`` rows are the input rays (row i is
    ray i). ``node_occluder[k, j]`` is the occluding instance of light ``j`` (``-1``
    unoccluded, ``-2`` light not facing, outside its cone, or the node is a miss).
    """

    node_ray: np.ndarray  # (Nn,) int32 input ray index
    node_parent: np.ndarray  # (Nn,) int32 parent row, -1 for roots
    node_path: np.ndarray  # (Nn,) int64 root 1, reflect child 2p, refract child 2p + 1
    node_inst: np.ndarray  # (Nn,) int32 instance hit, -1 = miss
    node_tri: np.ndarray  # (Nn,) int32 global triangle, -1 on miss
    node_origin: np.ndarray  # (Nn, 3) float64 segment start
    node_point: np.ndarray  # (Nn, 3) float64 hit point; far beyond the scene on a miss
    node_light_mask: np.ndarray  # (Nn,) uint64 bit j: light j contributes
    node_occluder: np.ndarray  # (Nn, L) int32


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
          metallic, mr, mg, mb, alpha, e_white, e_diel):
    """The material's BRDF (Principled-like or Ward) for light direction ``l`` and view
    direction ``o`` about shading normal ``s``: the hard lights' and the soft samples' one
    evaluation."""
    if principled:
        return principled_brdf(sx, sy, sz, lx, ly, lz, ox, oy, oz, dr, dg, db, sr, sg, sb,
                               eta_s, metallic, mr, mg, mb, alpha, e_white, e_diel)
    return ward_brdf(sx, sy, sz, lx, ly, lz, ox, oy, oz, dr, dg, db, sr, sg, sb, alpha)


@njit(cache=True, nogil=True)
def _material_of(sa, inst, tri):
    """Material id of triangle ``tri`` on instance ``inst`` (slot clamped to the list)."""
    s0 = sa.inst_mat_start[inst]
    cnt = sa.inst_mat_start[inst + 1] - s0
    slot = sa.tri_slot[tri]
    if slot >= cnt:
        slot = cnt - 1
    return sa.inst_mat[s0 + slot]


@njit(cache=True, nogil=True, inline="always")
def light_state(sa, j, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz):
    """Shadow-ray state of light ``j`` at a surface point (see :func:`light_states`)."""
    if sa.light_kind[j] < 0:
        return -2  # a deleted light's slot (LIGHT_NONE)
    if sa.light_ext[j]:
        # sampled (each sample checks its own facing), unless the whole light is below
        # the surface's horizon or behind an area light: then every sample would be 0
        if extent_faces(sa, j, qx, qy, qz, gx, gy, gz):
            return SH_SOFT
        return -2
    if sa.light_kind[j] == LIGHT_SUN:
        lx = -sa.light_dir[j, 0]
        ly = -sa.light_dir[j, 1]
        lz = -sa.light_dir[j, 2]
        if dot3(gx, gy, gz, lx, ly, lz) > 0.0 and dot3(sx, sy, sz, lx, ly, lz) > 0.0:
            return _SH_TRACE
        return -2
    lx, ly, lz, dist = normalize3(sa.light_pos[j, 0] - px, sa.light_pos[j, 1] - py,
                                  sa.light_pos[j, 2] - pz)
    if not (dist > 0.0 and dot3(gx, gy, gz, lx, ly, lz) > 0.0
            and dot3(sx, sy, sz, lx, ly, lz) > 0.0):
        return -2
    if sa.light_kind[j] == LIGHT_SPOT:
        ca = -dot3(lx, ly, lz, sa.light_dir[j, 0], sa.light_dir[j, 1], sa.light_dir[j, 2])
        if spot_falloff(ca, sa.light_cos_outer[j], sa.light_cos_inner[j]) <= 0.0:
            return -2
    wx, wy, wz, wl = normalize3(sa.light_pos[j, 0] - qx, sa.light_pos[j, 1] - qy,
                                sa.light_pos[j, 2] - qz)
    if not (wl > 0.0 and dot3(gx, gy, gz, wx, wy, wz) > 0.0):
        return -2  # the light sits within the offset of the surface
    return _SH_TRACE


@njit(cache=True, nogil=True, inline="always")
def light_states(sa, i, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, sh_state):
    """Shadow-ray states of surface point ``i`` (rows ``i * L + j``): ``_SH_TRACE`` when
    light ``j`` faces the point (geometric and shading normal ``g``, ``s`` turned toward
    the viewer; spot cone) and is not within the offset of shadow origin ``q``;
    ``SH_SOFT`` for a light with an extent that is not wholly below the horizon; else
    -2."""
    L = sa.light_kind.shape[0]
    for j in range(L):
        sh_state[i * L + j] = light_state(sa, j, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy,
                                          qz)


@njit(cache=True, nogil=True, parallel=True)
def _surface_kernel(sa, o, d, tmax, hits, surf):
    """Surface points of a batch of ``n`` rays and their shadow rays (one per light).

    Inputs: o, d (n, 3) float64; tmax (n,) float64; hits : :class:`Hits` of the rays.
    Output: surf, a :class:`Surfaces`. Its sh_state at row ``i * L + j``: 1 trace a shadow
    ray from point i to light j (:func:`_shadow_kernel` makes it), -2 light not facing /
    outside cone.
    """
    t, inst, prim, bu, bv = hits.t, hits.inst, hits.prim, hits.u, hits.v
    P, NG, NS, VD, ENTER, MAT, Q, sh_state = surf
    n = o.shape[0]
    L = sa.light_kind.shape[0]
    ext = sa.scene_extent
    cx = 0.5 * (sa.scene_aabb[0, 0] + sa.scene_aabb[1, 0])
    cy = 0.5 * (sa.scene_aabb[0, 1] + sa.scene_aabb[1, 1])
    cz = 0.5 * (sa.scene_aabb[0, 2] + sa.scene_aabb[1, 2])
    for i in prange(n):
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
        sx, sy, sz = shading_normal(sa.tri_normals, nm, tri, bu[i], bv[i], gx, gy, gz)
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
        light_states(sa, i, px, py, pz, gx, gy, gz, sx, sy, sz, qx, qy, qz, sh_state)


@njit(cache=True, nogil=True, parallel=True)
def _shadow_kernel(sa, Q, todo, sh_o, sh_d, sh_tmax):
    """Shadow rays for the (point, light) rows ``todo`` (k,) int64 (row = i * L + j).

    Q : (n, 3) float64 origins from :func:`_surface_kernel`. Outputs sh_o, sh_d (k, 3)
    float64 (unit directions), sh_tmax (k,) float64: just short of a point or spot light,
    infinite for a sun.
    """
    L = sa.light_kind.shape[0]
    for k in prange(todo.shape[0]):
        i = todo[k] // L
        j = todo[k] - i * L
        sh_o[k, 0] = Q[i, 0]
        sh_o[k, 1] = Q[i, 1]
        sh_o[k, 2] = Q[i, 2]
        if sa.light_kind[j] == LIGHT_SUN:
            sh_d[k, 0] = -sa.light_dir[j, 0]
            sh_d[k, 1] = -sa.light_dir[j, 1]
            sh_d[k, 2] = -sa.light_dir[j, 2]
            sh_tmax[k] = np.inf
        else:
            wx, wy, wz, wl = normalize3(sa.light_pos[j, 0] - Q[i, 0],
                                        sa.light_pos[j, 1] - Q[i, 1],
                                        sa.light_pos[j, 2] - Q[i, 2])
            sh_d[k, 0] = wx
            sh_d[k, 1] = wy
            sh_d[k, 2] = wz
            sh_tmax[k] = wl * (1.0 - tol.SHADOW_END_REL)


@njit(cache=True, nogil=True, parallel=True)
def _shade_kernel(sa, hits, surf, vis, weight, spawn, soft, contrib, out, tv, tp):
    """Direct light and secondary rays of a batch of ``n`` surface points.

    One loop body on purpose: the material's twenty-odd values are read once per point and
    used by both the light loop and the spawned rays (split into functions, they would be
    passed on in long argument lists or read twice).

    hits : the :class:`Hits` (prim, u, v for texture coordinates); surf : the
    :class:`Surfaces` of :func:`_surface_kernel`. vis : (n L,) bool light j visible from
    point i (row ``i * L + j``; lights with an extent are skipped there); weight : (n, 3)
    float64 path weights; spawn : whether reflection/refraction rays may be spawned; soft :
    the :class:`~.soft_lights.SoftSamples` of the points (their lights and the world's).
    Outputs: contrib (n, 3) weighted radiance to add to each ray's input ray; out, the
    :class:`Spawned` rays; with ``tv`` (n, L + 2, 3) float64 and ``tp`` (n, L + 2) bool
    (empty: not kept) each point's *light terms* (:mod:`.light_records`), what it adds to
    its radiance before the path weight without the light's intensity or radiance:
    column j light j (present where added), L the world's light, L + 1 the emission (a
    miss: 1, for the world colour).
    """
    prim, bu, bv = hits.prim, hits.u, hits.v
    P, NG, NS, VD, ENTER, MAT = surf.P, surf.NG, surf.NS, surf.VD, surf.enter, surf.mat
    c_o, c_d, c_w, c_ok = out
    n = P.shape[0]
    L = sa.light_kind.shape[0]
    ext = sa.scene_extent
    wmin = tol.PATH_WEIGHT_MIN
    terms = tv.shape[0] > 0
    for i in prange(n):
        c_ok[2 * i] = False
        c_ok[2 * i + 1] = False
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
        tex = sa.mat_tex[m]
        if tex >= 0:
            u, v = surface_uv(sa.tri_uvs, prim[i], bu[i], bv[i])
            xr, xg, xb = texture_lookup(sa.tex_data, sa.tex_start, sa.tex_size, tex, u, v)
            dr *= xr
            dg *= xg
            db *= xb
        lr = sa.mat_emission[m, 0]
        lg = sa.mat_emission[m, 1]
        lb = sa.mat_emission[m, 2]
        if terms:
            tv[i, L + 1, 0] = lr
            tv[i, L + 1, 1] = lg
            tv[i, L + 1, 2] = lb
        sr = sa.mat_specular[m, 0]
        sg = sa.mat_specular[m, 1]
        sb = sa.mat_specular[m, 2]
        alpha = sa.mat_roughness[m]
        principled = sa.mat_model[m] == MODEL_PRINCIPLED
        eta_s = sa.mat_specular_ior[m]
        metallic = sa.mat_metallic[m]
        mr = sa.mat_metal[m, 0]
        mg = sa.mat_metal[m, 1]
        mb = sa.mat_metal[m, 2]
        e_white = 1.0
        e_diel = 0.0
        if principled:
            e_white, e_diel = ggx_albedo(-dot3(dx, dy, dz, sx, sy, sz), alpha, eta_s)
        for j in range(L):
            if not vis[i * L + j] or sa.light_ext[j]:
                continue
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
                    ca = -dot3(lx, ly, lz, sa.light_dir[j, 0], sa.light_dir[j, 1],
                               sa.light_dir[j, 2])
                    e *= spot_falloff(ca, sa.light_cos_outer[j], sa.light_cos_inner[j])
            if e <= 0.0:
                continue
            fr, fg, fb = _brdf(principled, sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, dr, dg, db,
                               sr, sg, sb, eta_s, metallic, mr, mg, mb, alpha, e_white,
                               e_diel)
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
                fr, fg, fb = _brdf(principled, sx, sy, sz, lx, ly, lz, -dx, -dy, -dz, dr, dg, db,
                                   sr, sg, sb, eta_s, metallic, mr, mg, mb, alpha, e_white,
                                   e_diel)
                e = soft.w[k]
                if ex >= 0.0:
                    sum_vw += e
                    fr -= kr
                    fg -= kg
                    fb -= kb
                ar += fr * e
                ag += fg * e
                ab += fb * e
            if ex >= 0.0 and sum_w > 0.0:
                t = ex * sum_vw / sum_w
                ar += kr * t
                ag += kg * t
                ab += kb * t
            j = soft.light[k0]
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
        if principled and (rr > 0.0 or rg > 0.0 or rb > 0.0):
            fr, fg, fb = principled_fresnel(-dot3(dx, dy, dz, sx, sy, sz), sr, sg, sb, eta_s,
                                            metallic, mr, mg, mb)
            rr *= fr
            rg *= fg
            rb *= fb
        tr = sa.mat_transmission[m, 0]
        tg = sa.mat_transmission[m, 1]
        tb = sa.mat_transmission[m, 2]
        off = spawn_offset(px, py, pz, ext)
        if tr > 0.0 or tg > 0.0 or tb > 0.0:
            ior = sa.mat_ior[m]
            eta = 1.0 / ior if ENTER[i] else ior
            nx, ny, nz = sx, sy, sz
            if dot3(dx, dy, dz, nx, ny, nz) >= 0.0:
                nx, ny, nz = gx, gy, gz
            ok, tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, eta)
            if ok and dot3(tx, ty, tz, gx, gy, gz) >= 0.0:
                # the shading normal would send the ray back out: refract about g instead
                nx, ny, nz = gx, gy, gz
                ok, tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, eta)
            if ok:
                f = fresnel_dielectric(-dot3(dx, dy, dz, nx, ny, nz), eta)
                rr += f * tr
                rg += f * tg
                rb += f * tb
                cr = w0 * (1.0 - f) * tr
                cg = w1 * (1.0 - f) * tg
                cb = w2 * (1.0 - f) * tb
                if max(cr, cg, cb) > wmin:
                    k = 2 * i + 1
                    c_ok[k] = True
                    c_o[k, 0] = px - gx * off
                    c_o[k, 1] = py - gy * off
                    c_o[k, 2] = pz - gz * off
                    c_d[k, 0] = tx
                    c_d[k, 1] = ty
                    c_d[k, 2] = tz
                    c_w[k, 0] = cr
                    c_w[k, 1] = cg
                    c_w[k, 2] = cb
            else:  # total internal reflection
                rr += tr
                rg += tg
                rb += tb
        cr = w0 * rr
        cg = w1 * rg
        cb = w2 * rb
        if max(cr, cg, cb) > wmin:
            qx, qy, qz = reflect(dx, dy, dz, sx, sy, sz)
            if dot3(qx, qy, qz, gx, gy, gz) <= 0.0:
                qx, qy, qz = reflect(dx, dy, dz, gx, gy, gz)
            k = 2 * i
            c_ok[k] = True
            c_o[k, 0] = px + gx * off
            c_o[k, 1] = py + gy * off
            c_o[k, 2] = pz + gz * off
            c_d[k, 0] = qx
            c_d[k, 1] = qy
            c_d[k, 2] = qz
            c_w[k, 0] = cr
            c_w[k, 1] = cg
            c_w[k, 2] = cb


# ----------------------------------------------------------------------------- stages


def _as_hits(h: Hits) -> Hits:
    return Hits(np.ascontiguousarray(h.t, np.float64), np.ascontiguousarray(h.inst, np.int32),
                np.ascontiguousarray(h.prim, np.int32), np.ascontiguousarray(h.u, np.float64),
                np.ascontiguousarray(h.v, np.float64))


def surfaces(sa: SceneArrays, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
             hits: Hits) -> Surfaces:
    """The surface points of ``n`` rays ``o, d`` (n, 3) float64 with bounds ``tmax`` (n,)
    and their ``hits``: :class:`Surfaces` (the shadow-ray states of every light
    included)."""
    n = len(o)
    surf = Surfaces(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
                    np.empty(n, np.bool_), np.empty(n, np.int32), np.empty((n, 3)),
                    np.empty(n * len(sa.light_kind), np.int8))
    _surface_kernel(sa, o, d, tmax, _as_hits(hits), surf)
    return surf


def shadow_rays(sa: SceneArrays, surf: Surfaces):
    """The shadow rays of ``surf``: ``(todo (k,) int64, origins (k, 3), directions (k, 3),
    tmax (k,))``, ``todo`` their (point, light) rows ``i * L + j``."""
    todo = np.flatnonzero(surf.sh_state == _SH_TRACE)
    k = len(todo)
    so, sd, st = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
    if k:
        _shadow_kernel(sa, surf.Q, todo, so, sd, st)
    return todo, so, sd, st


def shade(sa: SceneArrays, hits: Hits, surf: Surfaces, vis: np.ndarray, weight: np.ndarray,
          spawn: bool, soft: SoftSamples | None = None, terms: bool = False):
    """Direct light of ``surf`` (``vis`` (n L,) bool: light j visible from point i; ``soft``
    the samples of the lights with an extent and of the world, :func:`soft_direct`) times
    the path ``weight`` (n, 3), and the reflection and refraction rays when ``spawn``:
    ``(contrib (n, 3) float64, Spawned)``; with ``terms`` also the points' light terms
    ``(values (n, L + 2, 3) float64, present (n, L + 2) bool)`` (see :func:`_shade_kernel`)."""
    n = len(surf.P)
    contrib = np.empty((n, 3))
    out = Spawned(np.empty((2 * n, 3)), np.empty((2 * n, 3)), np.empty((2 * n, 3)),
                  np.empty(2 * n, np.bool_))
    c = len(sa.light_kind) + 2
    tv = np.empty((n if terms else 0, c, 3))
    tp = np.empty((n if terms else 0, c), np.bool_)
    _shade_kernel(sa, _as_hits(hits), surf, vis, weight, spawn,
                  no_samples(n) if soft is None else soft, contrib, out, tv, tp)
    if terms:
        return contrib, out, (tv, tp)
    return contrib, out


def soft_direct(sa: SceneArrays, surf: Surfaces, seeds: np.ndarray, light_samples: int,
                vis: np.ndarray, occluded, counters: dict | None = None,
                occ: np.ndarray | None = None) -> SoftSamples:
    """The shadow samples of the lights with an extent and of the world at ``surf``
    (:mod:`.soft_lights`), traced with ``occluded(origins, directions, tmax, rows) -> (k,)
    bool``; ``seeds`` (n,) uint64 the points' node seeds. Sets ``vis`` (n L,) of a sampled
    light's row when one of its samples reached it, and ``occ`` (when given) to
    ``OCC_SOFT`` there (its visibility is a fraction). Returns the samples for
    :func:`shade`."""
    soft, rows, any_vis = soft_visibility(sa, surf, seeds, light_samples, surf.sh_state,
                                          occluded, counters)
    lit = rows >= 0
    vis[rows[lit]] = any_vis[lit]
    if occ is not None:
        occ[rows[lit]] = OCC_SOFT
    return soft


# ----------------------------------------------------------------------------- driver


class _Front(NamedTuple):
    """The rays of one depth level and where they come from."""

    o: np.ndarray  # (nb, 3) float64
    d: np.ndarray  # (nb, 3) float64
    t0: np.ndarray  # (nb,) float64
    t1: np.ndarray  # (nb,) float64
    src: np.ndarray  # (nb,) int32 input ray
    weight: np.ndarray  # (nb, 3) float64 path weight
    parent: np.ndarray  # (nb,) int32 parent node row (-1: roots)
    path: np.ndarray  # (nb,) int64 root 1, reflect child 2p, refract child 2p + 1


def _count(counters: dict | None, key: str, n: int) -> None:
    if counters is not None:
        counters[key] = counters.get(key, 0) + int(n)


def _input_front(origins, directions, tmin, tmax, primary: Hits | None) -> _Front:
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    n = o.shape[0]
    if d.shape != o.shape:
        raise ValueError(f"trace: origins {o.shape} and directions {d.shape} differ")
    t0 = per_ray(tmin, n, np.float64)  # writeable: one numba type for every caller
    t1 = per_ray(tmax, n, np.float64)
    if primary is not None and len(primary.t) != n:
        raise ValueError(f"trace: primary hits for {len(primary.t)} rays, {n} rays given")
    return _Front(o, d, t0, t1, np.arange(n, dtype=np.int32), np.ones((n, 3)),
                  np.full(n, -1, np.int32), np.ones(n, np.int64))


def _next_front(front: _Front, kids: Spawned, rows: np.ndarray | None) -> _Front:
    """The spawned rays, compacted; ``rows``: the level's node rows (None: no ray trees
    kept, parents are not followed)."""
    k = np.flatnonzero(kids.ok)
    which = k // 2
    parent = front.parent
    if rows is not None:
        parent = rows[which]
    path = front.path[which] * 2 + (k & 1)  # also seeds the soft lights' samples
    return _Front(kids.o[k], kids.d[k], np.zeros(len(k)), np.full(len(k), np.inf),
                  front.src[which], kids.w[k], parent, path)


def _visibility(sa, accel, surf: Surfaces, occluders: bool, counters):
    """Light visibility of the level's points, ``(vis (nb L,) bool, occ (nb L,) int32 or
    None, traced)``: ``occ`` (with ``occluders``, closest-hit shadow rays) names each
    light's occluder (``OCC_NONE``, ``OCC_NOT_FACING``); ``traced``: shadow rays were
    traced."""
    todo, so, sd, st = shadow_rays(sa, surf)
    vis = np.zeros(len(surf.sh_state), np.bool_)
    occ_inst = None
    if len(todo):
        zero = np.zeros(len(todo))
        if occluders:
            occ_inst = accel.closest_hit(so, sd, zero, st).inst
            vis[todo] = occ_inst < 0
        else:
            vis[todo] = ~np.asarray(accel.any_hit(so, sd, zero, st), np.bool_)
        _count(counters, "shadow", len(todo))
    occ = None
    if occluders:
        occ = np.full(len(vis), OCC_NOT_FACING, np.int32)
        if len(todo):
            occ[todo] = np.where(occ_inst < 0, OCC_NONE, occ_inst).astype(np.int32)
    return vis, occ, len(todo) > 0


def _occluded_by(accel):
    """``occluded(origins, directions, tmax, rows)`` of :func:`soft_direct` by any hit."""
    def occluded(o, d, tmax, rows):
        return accel.any_hit(o, d, np.zeros(len(o)), tmax)
    return occluded


@njit(cache=True, nogil=True)
def _light_masks(sh_state, vis, L, traced, lit):
    """Per point: bit j of ``traced`` when a shadow ray to light j was traced, of ``lit``
    when light j is visible. sh_state, vis : (n L,); traced, lit : (n,) uint64 outputs."""
    for i in range(traced.shape[0]):
        a = np.uint64(0)
        b = np.uint64(0)
        for j in range(L):
            bit = np.uint64(1) << np.uint64(j)
            if sh_state[i * L + j] == _SH_TRACE or sh_state[i * L + j] == SH_SOFT:
                a |= bit
            if vis[i * L + j]:
                b |= bit
        traced[i] = a
        lit[i] = b


def _segments(front: _Front, hits: Hits, surf: Surfaces, vis, L: int) -> dict:
    """The level's compact ray-tree nodes for the pixel records (see :func:`trace`)."""
    nb = len(front.src)
    traced = np.empty(nb, np.uint64)
    lit = np.empty(nb, np.uint64)
    _light_masks(surf.sh_state, vis, L, traced, lit)
    return dict(ray=front.src, parent=front.parent, inst=hits.inst, point=surf.P,
                dir=surf.VD, traced=traced, lit=lit)


def _light_terms(front: _Front, hits: Hits, surf: Surfaces, seeds, tvp) -> dict:
    """A level's nodes for :mod:`.light_records`: the path weight and light terms
    (:func:`shade`'s), and what shading one light again needs (the surface point, its
    normals, the ray direction, shadow origin, material, texture coordinates, seed)."""
    return dict(weight=front.weight, t_val=tvp[0], t_on=tvp[1], NG=surf.NG, NS=surf.NS,
                Q=surf.Q, enter=surf.enter, mat=surf.mat, prim=hits.prim, u=hits.u, v=hits.v,
                seed=seeds)


def _tree_level(front: _Front, hits: Hits, surf: Surfaces, vis, occ, L: int) -> dict:
    nb = len(front.src)
    bits = np.left_shift(np.uint64(1), np.arange(L, dtype=np.uint64))
    mask = (vis.reshape(nb, L).astype(np.uint64) * bits).sum(axis=1, dtype=np.uint64)
    return dict(ray=front.src, parent=front.parent, path=front.path, inst=hits.inst,
                tri=hits.prim, origin=front.o, point=surf.P, mask=mask,
                occ=occ.reshape(nb, L))


def _ray_tree(levels: list[dict], L: int) -> RayTree:
    cat = np.concatenate
    total = sum(len(lv["ray"]) for lv in levels)
    return RayTree(
        node_ray=cat([lv["ray"] for lv in levels]).astype(np.int32),
        node_parent=cat([lv["parent"] for lv in levels]).astype(np.int32),
        node_path=cat([lv["path"] for lv in levels]).astype(np.int64),
        node_inst=cat([lv["inst"] for lv in levels]).astype(np.int32),
        node_tri=cat([lv["tri"] for lv in levels]).astype(np.int32),
        node_origin=cat([lv["origin"] for lv in levels]).reshape(total, 3),
        node_point=cat([lv["point"] for lv in levels]).reshape(total, 3),
        node_light_mask=cat([lv["mask"] for lv in levels]).astype(np.uint64),
        node_occluder=cat([lv["occ"] for lv in levels]).reshape(total, L).astype(np.int32),
    )


def trace(sa: SceneArrays, accel, origins, directions, tmin, tmax, max_depth: int,
          record: bool = False, primary: Hits | None = None, counters: dict | None = None,
          segments: list | None = None, cancel=None, seeds: np.ndarray | None = None,
          light_samples: int = LIGHT_SAMPLES_DEFAULT, terms: bool = False):
    """Whitted radiance of a batch of ``n`` rays, and optionally their ray trees.

    sa : the scene's :class:`~.geometry.scene.SceneArrays`; accel : an accelerator over
    it (:func:`~rstrace_engine.accel.accelerators.create_accelerator`).
    origins, directions : (n, 3) float64 (directions need not be unit); tmin, tmax : (n,)
    float64 (or scalars) bounds of the input rays. max_depth : reflection/refraction
    bounces (0: direct light only). record : also return the :class:`RayTree`.
    primary : optional :class:`~rstrace_engine.accel.accelerators.Hits` of the input rays (e.g.
    from ``intersect_object``), used instead of ``accel.closest_hit`` for the first level.
    counters : optional dict; ``primary``, ``secondary`` and ``shadow`` ray counts are added.
    segments : optional list; for every depth level a dict of arrays is appended, the compact
    ray-tree nodes the per-pixel records keep (:mod:`.pixel_records`): ``ray`` (input ray),
    ``parent`` (row of the parent node, rows numbered level after level, -1 for roots),
    ``inst`` (-1: a miss), ``point`` (hit point), ``dir`` (unit ray direction), ``traced``
    and ``lit`` (uint64 light bits: shadow ray traced / light visible). Cheaper than
    ``record`` (shadow rays stay any-hit queries).
    cancel : optional ``cancel() -> bool``, polled between the queries of every depth level:
    once it says stop, the rest is skipped and the result is incomplete (the caller polls
    ``cancel()`` itself and discards it; see :mod:`rstrace_engine.cancel`).
    seeds : (n,) uint64 seeds of the input rays for the samples of lights with an extent
    and of the world (:func:`~.soft_lights.sample_seeds` of their global sample ids; by
    default the rays' indices, which makes the samples depend on the batch);
    light_samples : shadow samples per such light and point. terms : with ``segments``, its
    dicts also hold each node's light terms and what re-shading one light needs
    (:func:`_light_terms`, for :mod:`.light_records`).

    Returns ``(radiance (n, 3) float64, RayTree or None)``.
    """
    front = _input_front(origins, directions, tmin, tmax, primary)
    max_depth = int(max_depth)
    if max_depth < 0:
        raise ValueError(f"trace: max_depth {max_depth} < 0")
    L = len(sa.light_kind)
    radiance = np.zeros((len(front.src), 3))
    nodes = record or segments is not None  # ray-tree node rows are followed
    soft_on = has_soft_light(sa)
    terms = terms and segments is not None
    if soft_on or terms:
        root = (sample_seeds(np.arange(len(front.src)), 0) if seeds is None
                else np.ascontiguousarray(seeds, np.uint64))
        if len(root) != len(front.src):
            raise ValueError(f"trace: {len(root)} seeds for {len(front.src)} rays")
    levels: list[dict] = []
    n_nodes = 0
    for level in range(max_depth + 1):
        nb = len(front.src)
        if nb == 0 or cancelled(cancel):
            break
        if level == 0 and primary is not None:
            hits = _as_hits(primary)
        else:
            hits = _as_hits(accel.closest_hit(front.o, front.d, front.t0, front.t1))
        _count(counters, "primary" if level == 0 else "secondary", nb)
        surf = surfaces(sa, front.o, front.d, front.t1, hits)
        vis, occ, traced = _visibility(sa, accel, surf, record, counters)
        soft = None
        nseeds = node_seeds(root, front.src, front.path) if soft_on or terms else None
        if soft_on:
            soft = soft_direct(sa, surf, nseeds, int(light_samples), vis, _occluded_by(accel),
                               counters, occ)
            traced = traced or len(soft.w) > 0
        if traced and cancelled(cancel):
            break
        spawn = level < max_depth
        shaded = shade(sa, hits, surf, vis, front.weight, spawn, soft, terms)
        contrib, kids = shaded[0], shaded[1]
        scatter_add(radiance, front.src, contrib)
        if segments is not None:
            segments.append(_segments(front, hits, surf, vis, L))
            if terms:
                segments[-1].update(_light_terms(front, hits, surf, nseeds, shaded[2]))
        if record:
            levels.append(_tree_level(front, hits, surf, vis, occ, L))
        if not spawn:
            break
        rows = np.arange(n_nodes, n_nodes + nb, dtype=np.int32) if nodes else None
        front = _next_front(front, kids, rows)
        n_nodes += nb
    return radiance, (_ray_tree(levels, L) if record else None)


def trace_pixels(sa: SceneArrays, accel, cp, pixels: np.ndarray, jitter: np.ndarray,
                 max_depth: int, cancel=None, counters: dict | None = None,
                 segments: list | None = None, gids: np.ndarray | None = None,
                 seed: int = 0, light_samples: int = LIGHT_SAMPLES_DEFAULT,
                 terms: bool = False):
    """Whitted radiance of the camera rays through ``pixels`` (k,) int64 at ``jitter``
    (k, 2) float64 (``cp``: the camera's :class:`~.geometry.cameras.CameraParams`), a
    frame's tile: small tiles run on one thread, and ``cancel`` is bound to ``accel``
    (:func:`trace` for ``counters``, ``segments`` and ``cancel``). Returns ``(radiance
    (k, 3) float64, primary instance (k,) int32)``. ``gids`` (k,) int64: the samples'
    global ids (``sample * width * height + pixel``; default: sample 0 of each pixel),
    which with ``seed`` seed the soft lights' samples (:func:`~.soft_lights.sample_seeds`);
    ``terms``: the segments keep the light terms too (:func:`trace`)."""
    if gids is None:
        gids = pixels
    with threads_for(len(pixels)), bound(accel, cancel):
        o, d, tmin, tmax = camera_rays(cp, pixels, jitter)
        hits = accel.closest_hit(o, d, tmin, tmax)
        rad, _ = trace(sa, accel, o, d, tmin, tmax, max_depth, primary=hits,
                       counters=counters, segments=segments, cancel=cancel,
                       seeds=sample_seeds(gids, seed), light_samples=light_samples,
                       terms=terms)
    return rad, np.ascontiguousarray(hits.inst, np.int32)


def render(scene: Scene, settings: RenderSettings | None = None, accel=None, progress=None,
           cancel=None, records=None, pixels: np.ndarray | None = None,
           base: Frame | None = None) -> Frame:
    """Render ``scene``'s camera with the base tracer, in tiles of rows.

    settings : :class:`~rstrace_engine.frame.RenderSettings` (``max_depth``, ``samples``,
    ``seed``, ``accelerator`` are used; the mode is not looked at). accel : an accelerator
    over ``scene.arrays()``; built from ``settings.accelerator`` when omitted.
    progress(fraction, message) is called after every tile; cancel() -> bool is polled
    before every tile and between the queries within one, and a cancelled frame keeps the
    tiles completed before it (``stats["cancelled"]``; the tile in progress is dropped,
    and its records too). With a :class:`~rstrace_engine.cancel.CancelFlag` the BVH's
    traversal stops within a few dozen rays of it being set. Returns a
    :class:`~rstrace_engine.frame.Frame`: radiance (h, w, 3)
    float32, rows bottom-up; pixel_class ``CLASS_TRACED`` where a primary ray hit,
    ``CLASS_BACKGROUND`` elsewhere. Samples whose radiance is NaN, infinite or above
    ``tolerances.RADIANCE_MAX`` are left out of the pixel average and counted in
    ``stats["nonfinite_samples"]``.

    Incremental frames: with ``pixels`` ((h * w,) bool) only those pixels are traced (every
    sample, with the same jitter as a full frame, so they come out bit for bit as a full
    frame's) and the others are copied from ``base``, the previous frame of the same camera.
    records : optional :class:`~.pixel_records.PixelRecords` that receives the ray trees of
    every traced sample (then ``records.finish`` folds them in, replacing the old trees of
    the traced pixels).
    """
    settings = (settings or RenderSettings()).validated()
    t_start = time.perf_counter()
    sa = scene.arrays()
    build_s = 0.0
    if accel is None:
        tb = time.perf_counter()
        accel = create_accelerator(settings.accelerator, sa, **settings.accelerator_options())
        build_s = time.perf_counter() - tb
    cp = camera_params(scene.camera)
    w, h = cp.width, cp.height
    spp = int(settings.samples)
    depth = int(settings.max_depth)
    rows_per_tile = max(1, TILE_RAYS // max(1, w * spp))
    if pixels is not None:
        if base is None or base.radiance.shape[:2] != (h, w):
            raise ValueError("render: an incremental frame needs the previous frame of the "
                             "same camera as base")
        pixels = np.asarray(pixels, bool).reshape(h * w)
        image = base.radiance.reshape(h * w, 3).copy()
        pclass = base.pixel_class.reshape(h * w).copy()
    else:
        image = np.zeros((h * w, 3), np.float32)
        pclass = np.full(h * w, CLASS_BACKGROUND, np.uint8)
    # per-light records kept (tracing.light_records; not when over their cap)
    terms = (records is not None and records.light is not None
             and records.light.overflow is None)
    counters: dict = {}
    bad_total = 0
    cancelled_ = False
    rows_done = 0
    traced_pixels = 0
    for pix, jitter, y1 in frame_batches(w, h, spp, int(settings.seed), rows_per_tile, pixels):
        if cancelled(cancel):
            cancelled_ = True
            break
        npx = len(pix)
        if npx == 0:
            rows_done = y1
            continue
        segs = [] if records is not None else None
        gids = (np.arange(spp, dtype=np.int64)[:, None] * (w * h) + pix[None, :]).ravel()
        rad, inst = trace_pixels(sa, accel, cp, np.tile(pix, spp), jitter.reshape(-1, 2),
                                 depth, cancel, counters, segs, gids, int(settings.seed),
                                 int(settings.light_samples), terms)
        if cancelled(cancel):  # the tile is incomplete: keep nothing of it
            cancelled_ = True
            break
        traced_pixels += npx
        with threads_for(npx * spp):
            if records is not None:
                records.add(gids, segs)
            out = np.empty((npx, 3), np.float32)
            pc = np.empty(npx, np.uint8)
            bad_total += accumulate(rad, inst, spp, out, pc)
        image[pix] = out
        pclass[pix] = pc
        rows_done = y1
        if progress is not None:
            progress(y1 / h, f"traced {y1}/{h} rows")
    elapsed = time.perf_counter() - t_start
    rays = sum(counters.values())
    if bad_total:
        log.warning("render: %d sample(s) with NaN/infinite radiance left out", bad_total)
    stats = dict(
        time_s=elapsed, accel_build_s=build_s, accelerator=getattr(accel, "name", "?"),
        rays_traced=rays, primary_rays=counters.get("primary", 0),
        secondary_rays=counters.get("secondary", 0), shadow_rays=counters.get("shadow", 0),
        rays_per_s=rays / elapsed if elapsed > 0 else 0.0,
        width=w, height=h, samples=spp, max_depth=depth, rows_done=rows_done,
        cancelled=cancelled_, nonfinite_samples=bad_total,
        triangles=scene.triangle_count, instances=scene.n_instances,
        degenerate_triangles=int(scene.stats.get("degenerate_triangles", 0)),
        warnings=list(scene.warnings), incremental=pixels is not None,
        traced_pixels=traced_pixels,
    )
    return Frame(image.reshape(h, w, 3), pclass.reshape(h, w), stats)
