"""Lights with an extent and the world's light: deterministic stratified shadow samples.

Seed 000's reference [4] (Cook, Porter, Carpenter 1984) renders soft light by sampling the
light's extent; here every shading point draws ``n`` samples per extended light (sphere,
sun with an angle, area) and ``n`` for the world when its colour is not black, each one
shadow ray. Their estimator of the light's reflected radiance is the usual one,
``sum_k V_k f(w_k) L_k cos_k / (pdf_k n)``; :class:`SoftSamples` carries everything but the
BRDF (``w``: cosine, spot and spread factors over the density and ``n``) so that the
tracer's shade kernel (:func:`~.whitted.shade`) evaluates the BRDF with the material it has
read anyway. Densities:

* sphere (POINT or SPOT with a radius, soft falloff off): uniform in the cone of directions
  that holds the sphere (sine ``r / d``), so that a sample below the horizon is simply zero
  (the sphere clipped by the surface); a point inside the sphere sees it over its whole
  hemisphere (cosine-weighted); with Blender's soft falloff (its default) Cycles' light is a
  disk of radius r through the centre facing the point: the cone of sine
  ``r / sqrt(r^2 + d^2)``, shadow rays ending on that disk;
* sun with an angle: uniform in its cone;
* area light: uniform over its area (rectangle or ellipse, concentric map for the latter);
* world: cosine-weighted about the shading normal (``f L pi / n``).

Less noise per ray (Heitz, Hill and McGuire 2018, the ratio estimator): where the
unshadowed light has a closed form -- a sphere's or a sun's cone above the horizon
(``pi sin^2(alpha) cos(theta)``), a rectangle above it (Lambert's formula) -- the diffuse
part of the BRDF gets that closed form times the samples' visibility ratio
``sum V w / sum w`` (exact and noise-free wherever the light is fully visible or fully
hidden); the glossy remainder keeps the plain estimator. Ellipses, spreads, spot cones and
lights crossing the horizon use the plain estimator throughout.

Sample points are a Fibonacci lattice of ``n`` points in the unit square, rotated
(Cranley-Patterson) by a hash of the node's seed and the light: stratified within a pixel,
decorrelated between pixels. A node's seed comes from its *global sample id* (pixel sample
and the frame's seed, :func:`sample_seeds`) and its ray-tree path (:func:`node_seeds`), never
from batch order, so an incremental frame equals a fresh one bit for bit and the same pixel
sample is the same in every mode that traces it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .. import tolerances as tol
from ..geometry.scene import LIGHT_AREA, LIGHT_SPOT, LIGHT_SUN, SceneArrays
from ..views import fields, view_type
from .shading import dot3, far_origin, normalize3, onb, rough_interface, spot_falloff

#: The ratio estimator (Heitz, Hill and McGuire 2018) for the diffuse part where a closed
#: form exists: measured in docs/SOFT_LIGHT.md (a module switch for that measurement).
RATIO_ESTIMATOR = True

#: shadow-ray state of a (point, light) row whose light is sampled (see whitted's states)
SH_SOFT = 2
#: ``RayTree.node_occluder`` of a sampled light: its visibility is a fraction, no occluder
OCC_SOFT = -3
#: the id the world's row of a point hashes its samples by (:func:`row_hash`): a light's
#: row hashes by its slot ``j >= 0``, so no light can take it, whatever the number of slots
WORLD_ROW = -1

_GOLDEN = 0.6180339887498949


@njit(cache=True, nogil=True, inline="always")
def spot_cosine(sa, j, lx, ly, lz):
    """The cosine spot ``j``'s cone falloff is taken at for unit direction ``l`` from a
    point toward the light: the angle from the spot's axis, or for a reshaped cone
    (``light_spot_scaled``) the z of the direction taken into the spot's scaled frame and
    normalised, as Cycles' ``spot_light_attenuation`` (elliptical for a non-uniform
    scale)."""
    if not sa.light_spot_scaled[j]:
        return -dot3(lx, ly, lz, sa.light_dir[j, 0], sa.light_dir[j, 1], sa.light_dir[j, 2])
    f = sa.light_spot_frame[j]
    a = -(f[0, 0] * lx + f[0, 1] * ly + f[0, 2] * lz)
    b = -(f[1, 0] * lx + f[1, 1] * ly + f[1, 2] * lz)
    c = -(f[2, 0] * lx + f[2, 1] * ly + f[2, 2] * lz)
    ln = math.sqrt(a * a + b * b + c * c)
    return c / ln if ln > 0.0 else -1.0
_FACING_SLACK = 1e-9  # relative: extent_faces errs on the side of sampling
_INV_2_53 = 1.0 / 9007199254740992.0


class SoftSamples(NamedTuple):
    """The shadow samples of ``n`` shading points, point by point."""

    start: np.ndarray  # (n + 1,) int64: samples of point i are start[i]:start[i + 1]
    light: np.ndarray  # (k,) int32 light j, L (the number of light slots) for the world's row
    d: np.ndarray  # (k, 3) float64 unit direction toward the light
    w: np.ndarray  # (k,) float64 estimator weight without BRDF and radiance; 0: no ray
    vis: np.ndarray  # (k,) bool the shadow ray reached the light
    exact: np.ndarray  # (k // n,) float64 per (point, light) row: the closed form of the
    # unshadowed sum of w (irradiance over radiance), -1 where there is none
    n: np.ndarray  # (1,) int64 samples per row


def no_samples(n: int) -> SoftSamples:
    """No soft samples for ``n`` points."""
    return SoftSamples(np.zeros(n + 1, np.int64), np.zeros(0, np.int32), np.zeros((0, 3)),
                       np.zeros(0), np.zeros(0, np.bool_), np.zeros(0), np.ones(1, np.int64))


def has_soft_light(sa: SceneArrays) -> bool:
    """Whether the scene has a light with an extent or a world that lights."""
    return bool(np.any(sa.light_ext & (sa.light_kind >= 0))) or world_lights(sa)


def world_lights(sa: SceneArrays) -> bool:
    """Whether the world lights surfaces (a colour that lights, not black)."""
    return bool(np.any(np.asarray(sa.world_light) > 0.0))


# ----------------------------------------------------------------------------- seeds


@njit(cache=True, nogil=True, inline="always")
def mix64(x):
    """SplitMix64's finaliser: a bijective hash of a uint64."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def _sample_seeds(gids, seed, out):
    s = mix64(np.uint64(seed) + np.uint64(0x9E3779B97F4A7C15))
    for k in range(gids.shape[0]):
        out[k] = mix64(np.uint64(gids[k]) ^ s)


def sample_seeds(gids: np.ndarray, seed: int) -> np.ndarray:
    """(k,) uint64 seeds of the pixel samples with global ids ``gids`` (k,) int64
    (``sample * width * height + pixel``) for the frame's ``seed``."""
    g = np.ascontiguousarray(gids, np.int64)
    out = np.empty(len(g), np.uint64)
    _sample_seeds(g, int(seed) & 0xFFFFFFFFFFFFFFFF, out)
    return out


@njit(cache=True, nogil=True)
def _node_seeds(root, src, path, out):
    for k in range(src.shape[0]):
        out[k] = mix64(root[src[k]] ^ mix64(np.uint64(path[k])))


def node_seeds(root: np.ndarray, src: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(m,) uint64 seeds of ray-tree nodes from their input ray's seed ``root[src]`` and
    their ``path`` (root 1, reflect child 2p, refract child 2p + 1)."""
    out = np.empty(len(src), np.uint64)
    _node_seeds(root, np.ascontiguousarray(src, np.int64),
                np.ascontiguousarray(path, np.int64), out)
    return out


# ----------------------------------------------------------------------------- directions


@njit(cache=True, nogil=True, inline="always")
def _cone_dir(ax, ay, az, omc, u, v):
    """Direction uniform in the cone about unit ``a`` with ``1 - cos(half angle) = omc``."""
    t = u * omc
    ct = 1.0 - t
    st = math.sqrt(max(0.0, t * (2.0 - t)))
    phi = 2.0 * math.pi * v
    tx, ty, tz, bx, by, bz = onb(ax, ay, az)
    cp = st * math.cos(phi)
    sp = st * math.sin(phi)
    return (ax * ct + tx * cp + bx * sp, ay * ct + ty * cp + by * sp,
            az * ct + tz * cp + bz * sp)


@njit(cache=True, nogil=True, inline="always")
def _cosine_dir(nx, ny, nz, u, v):
    """Cosine-weighted direction about unit ``n``."""
    r = math.sqrt(u)
    phi = 2.0 * math.pi * v
    tx, ty, tz, bx, by, bz = onb(nx, ny, nz)
    x = r * math.cos(phi)
    y = r * math.sin(phi)
    z = math.sqrt(max(0.0, 1.0 - u))
    return (nx * z + tx * x + bx * y, ny * z + ty * x + by * y, nz * z + tz * x + bz * y)


@njit(cache=True, nogil=True, inline="always")
def _concentric(u, v):
    """Shirley-Chiu map of the unit square onto the unit disk (keeps strata compact)."""
    a = 2.0 * u - 1.0
    b = 2.0 * v - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r = a
        phi = 0.25 * math.pi * (b / a)
    else:
        r = b
        phi = 0.5 * math.pi - 0.25 * math.pi * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


@njit(cache=True, nogil=True, inline="always")
def _sphere_exit(ox, oy, oz, wx, wy, wz, cx, cy, cz, r):
    """Distance along unit w from o to the sphere's first surface crossing ahead."""
    vx, vy, vz = cx - ox, cy - oy, cz - oz
    b = vx * wx + vy * wy + vz * wz
    c = vx * vx + vy * vy + vz * vz - r * r
    disc = b * b - c
    if disc < 0.0:
        return max(b, 0.0)
    sq = math.sqrt(disc)
    if c > 0.0:  # outside: the near crossing
        return max(b - sq, 0.0)
    return b + sq  # inside: the way out


# ----------------------------------------------------------------------------- samples


@njit(cache=True, nogil=True, inline="always")
def extent_faces(sa, j, qx, qy, qz, gx, gy, gz):
    """False when no point of light j can light the side of geometric normal g at q: its
    bounding sphere (or a sun's cone) lies wholly below the tangent plane, or q is behind
    the area light's emitting side. (Every sample would have weight 0; skipping them
    changes no pixel, and the ray trees then record the light as not facing.)"""
    if sa.light_kind[j] == LIGHT_SUN:
        sin_h = math.sin(sa.light_half[j])
        return -dot3(gx, gy, gz, sa.light_dir[j, 0], sa.light_dir[j, 1],
                     sa.light_dir[j, 2]) > -sin_h - _FACING_SLACK
    vx = sa.light_pos[j, 0] - qx
    vy = sa.light_pos[j, 1] - qy
    vz = sa.light_pos[j, 2] - qz
    bound = sa.light_bound[j] * (1.0 + _FACING_SLACK)
    if sa.light_kind[j] == LIGHT_AREA and dot3(vx, vy, vz, sa.light_dir[j, 0],
                                               sa.light_dir[j, 1], sa.light_dir[j, 2]) > 0.0:
        return False  # on the back of the one-sided emitter (or in its plane)
    return dot3(vx, vy, vz, gx, gy, gz) > -bound - _FACING_SLACK * math.sqrt(
        vx * vx + vy * vy + vz * vz)



@njit(cache=True, nogil=True, inline="always")
def _sample_one(sa, j, qx, qy, qz, u, v):
    """One sample of light ``j`` seen from ``q``: ``(dx, dy, dz, tmax, weight)`` with the
    weight before the cosine at the surface and the 1 / n factor (0: no light)."""
    kind = sa.light_kind[j]
    if kind == LIGHT_SUN:
        omc = 2.0 * math.sin(0.5 * sa.light_half[j]) ** 2  # 1 - cos, without cancelling
        dx, dy, dz = _cone_dir(-sa.light_dir[j, 0], -sa.light_dir[j, 1], -sa.light_dir[j, 2],
                               omc, u, v)
        return dx, dy, dz, np.inf, 2.0 * math.pi * omc
    cx, cy, cz = sa.light_pos[j, 0], sa.light_pos[j, 1], sa.light_pos[j, 2]
    if kind == LIGHT_AREA:
        su = sa.light_size[j, 0]
        sv = sa.light_size[j, 1]
        if sa.light_ellipse[j]:
            x, y = _concentric(u, v)
            x *= 0.5 * su
            y *= 0.5 * sv
            area = 0.25 * math.pi * su * sv
        else:
            x = (u - 0.5) * su
            y = (v - 0.5) * sv
            area = su * sv
        px = cx + x * sa.light_u[j, 0] + y * sa.light_v[j, 0]
        py = cy + x * sa.light_u[j, 1] + y * sa.light_v[j, 1]
        pz = cz + x * sa.light_u[j, 2] + y * sa.light_v[j, 2]
        dx, dy, dz, dist = normalize3(px - qx, py - qy, pz - qz)
        if not dist > 0.0:
            return dx, dy, dz, 0.0, 0.0
        cos_l = -dot3(dx, dy, dz, sa.light_dir[j, 0], sa.light_dir[j, 1], sa.light_dir[j, 2])
        if cos_l <= 0.0:
            return dx, dy, dz, 0.0, 0.0  # behind the one-sided emitter
        wgt = area * cos_l / (dist * dist)
        tan_half = sa.light_spread[j, 0]
        if tan_half < np.inf:
            tan_a = math.sqrt(max(0.0, 1.0 - cos_l * cos_l)) / cos_l
            wgt *= max((tan_half - tan_a) * sa.light_spread[j, 1], 0.0)
        return dx, dy, dz, dist * (1.0 - tol.SHADOW_END_REL), wgt
    # a sphere (POINT or SPOT with a radius)
    r = sa.light_radius[j]
    ax, ay, az, dist = normalize3(cx - qx, cy - qy, cz - qz)
    s2 = _sphere_sin2(r, dist, sa.light_soft[j])
    if s2 < 0.0:
        s2 = 1.0  # inside the sphere: its whole hemisphere (see _soft_kernel)
    omc = s2 / (1.0 + math.sqrt(max(0.0, 1.0 - s2)))
    dx, dy, dz = _cone_dir(ax, ay, az, omc, u, v)
    if sa.light_soft[j]:
        # Cycles' soft falloff: a disk of radius r through the centre, facing the point
        t = dist / max(dot3(dx, dy, dz, ax, ay, az), 1e-300)
    else:
        t = _sphere_exit(qx, qy, qz, dx, dy, dz, cx, cy, cz, r)
    wgt = 2.0 * math.pi * omc
    if kind == LIGHT_SPOT:
        wgt *= spot_falloff(spot_cosine(sa, j, dx, dy, dz), sa.light_cos_outer[j],
                            sa.light_cos_inner[j])
    return dx, dy, dz, t * (1.0 - tol.SHADOW_END_REL), wgt


@njit(cache=True, nogil=True, inline="always")
def _sphere_sin2(r, dist, soft):
    """Squared sine of the cone a sphere light of radius ``r`` at distance ``dist`` subtends
    (with ``soft`` falloff: Cycles' disk of radius r facing the point); -1 inside the sphere."""
    if soft:
        return r * r / (r * r + dist * dist)
    if dist > r:
        return (r / dist) ** 2
    return -1.0


@njit(cache=True, nogil=True, inline="always")
def _cap_exact(ax, ay, az, s2, gx, gy, gz, sx, sy, sz):
    """``pi sin^2(alpha) cos(theta)``: the projected solid angle of a cone (axis a, sine
    squared s2) above both normals' horizons; -1 when it crosses one."""
    sin_a = math.sqrt(s2)
    cs = dot3(sx, sy, sz, ax, ay, az)
    if cs < sin_a or dot3(gx, gy, gz, ax, ay, az) < sin_a:
        return -1.0
    return math.pi * s2 * cs


@njit(cache=True, nogil=True, inline="always")
def _corner(sa, j, k, qx, qy, qz):
    """Corner k (0..3, in order around it) of rectangle light j, from q."""
    a = -0.5 * sa.light_size[j, 0] if k == 0 or k == 3 else 0.5 * sa.light_size[j, 0]
    b = -0.5 * sa.light_size[j, 1] if k < 2 else 0.5 * sa.light_size[j, 1]
    return (sa.light_pos[j, 0] + a * sa.light_u[j, 0] + b * sa.light_v[j, 0] - qx,
            sa.light_pos[j, 1] + a * sa.light_u[j, 1] + b * sa.light_v[j, 1] - qy,
            sa.light_pos[j, 2] + a * sa.light_u[j, 2] + b * sa.light_v[j, 2] - qz)


@njit(cache=True, nogil=True, inline="always")
def _polygon_exact(sa, j, qx, qy, qz, gx, gy, gz, sx, sy, sz):
    """Lambert's formula for a rectangle light seen from q: its projected solid angle
    ``1/2 |sum_i beta_i gamma_i . n|`` when it lies above both normals' horizons, else -1.
    (Scalars only: this runs per shading point and light inside a parallel loop.)"""
    tot = 0.0
    for k in range(4):
        ax, ay, az = _corner(sa, j, k, qx, qy, qz)
        if dot3(ax, ay, az, sx, sy, sz) <= 0.0 or dot3(ax, ay, az, gx, gy, gz) <= 0.0:
            return -1.0
        bx, by, bz = _corner(sa, j, (k + 1) % 4, qx, qy, qz)
        ax, ay, az, _ = normalize3(ax, ay, az)
        bx, by, bz, _ = normalize3(bx, by, bz)
        c = min(1.0, max(-1.0, dot3(ax, ay, az, bx, by, bz)))
        gxx, gyy, gzz, gl = normalize3(ay * bz - az * by, az * bx - ax * bz,
                                       ax * by - ay * bx)
        if gl > 0.0:
            tot += math.acos(c) * dot3(gxx, gyy, gzz, sx, sy, sz)
    return 0.5 * abs(tot)


@njit(cache=True, nogil=True, inline="always")
def _row_exact(sa, j, qx, qy, qz, gx, gy, gz, sx, sy, sz):
    """The closed form of the unshadowed light j at q over its radiance (the sum the
    samples' weights estimate), for the ratio estimator; -1 where there is none here (a
    spot's cone, an ellipse, a spread, a light crossing the horizon, the inside of a
    sphere)."""
    kind = sa.light_kind[j]
    if kind == LIGHT_SPOT:
        return -1.0
    if kind == LIGHT_SUN:
        return _cap_exact(-sa.light_dir[j, 0], -sa.light_dir[j, 1], -sa.light_dir[j, 2],
                          math.sin(sa.light_half[j]) ** 2, gx, gy, gz, sx, sy, sz)
    cx, cy, cz = sa.light_pos[j, 0], sa.light_pos[j, 1], sa.light_pos[j, 2]
    if kind == LIGHT_AREA:
        if sa.light_ellipse[j] or sa.light_spread[j, 0] < np.inf:
            return -1.0
        if dot3(qx - cx, qy - cy, qz - cz, sa.light_dir[j, 0], sa.light_dir[j, 1],
                sa.light_dir[j, 2]) <= 0.0:
            return -1.0  # behind the emitter: every sample is 0 anyway
        return _polygon_exact(sa, j, qx, qy, qz, gx, gy, gz, sx, sy, sz)
    r = sa.light_radius[j]
    ax, ay, az, dist = normalize3(cx - qx, cy - qy, cz - qz)
    s2 = _sphere_sin2(r, dist, sa.light_soft[j])
    if s2 < 0.0:
        return -1.0
    return _cap_exact(ax, ay, az, s2, gx, gy, gz, sx, sy, sz)


_SoftScene = view_type("_SoftScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ellipse", "light_half",
    "light_kind", "light_pos", "light_radius", "light_size", "light_soft",
    "light_spot_frame", "light_spot_scaled", "light_spread", "light_u", "light_v",
    "mat_ior", "mat_model", "mat_roughness", "mat_transmission", "scene_extent"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def _soft_kernel(sa, P, Q, NG, NS, MAT, seeds, row_pt, row_light, n, ratio, o, d, tmax, w,
                 exact):
    """The ``n`` samples of every (point, light) row: origins o, unit directions d (k, 3),
    tmax (k,) and weights w (k,) (0: the sample carries no light, no ray is traced); with
    ``ratio``, ``exact`` (m,) the closed form of each row's unshadowed weight sum (-1:
    none, :func:`_row_exact`). At a rough interface (material ``MAT[i]``,
    :func:`~.shading.rough_interface`) a light's sample below the surface counts too (its
    transmission lobe): its ray leaves from the far side (:func:`~.shading.far_origin`)."""
    sa = _SoftScene(*fields(sa, _SoftScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    inv_n = 1.0 / n
    for r in prange(row_pt.shape[0]):
        i = row_pt[r]
        j = row_light[r]
        h = row_hash(seeds[i], j, L)
        r1 = float(h >> np.uint64(11)) * _INV_2_53
        r2 = float(mix64(h) >> np.uint64(11)) * _INV_2_53
        qx, qy, qz = Q[i, 0], Q[i, 1], Q[i, 2]
        gx, gy, gz = NG[i, 0], NG[i, 1], NG[i, 2]
        sx, sy, sz = NS[i, 0], NS[i, 1], NS[i, 2]
        exact[r] = -1.0
        if ratio and j < L:
            exact[r] = _row_exact(sa, j, qx, qy, qz, NG[i, 0], NG[i, 1], NG[i, 2],
                                  NS[i, 0], NS[i, 1], NS[i, 2])
        far = j < L and rough_interface(sa, MAT[i])
        fx, fy, fz = qx, qy, qz
        if far:
            fx, fy, fz = far_origin(sa, P[i, 0], P[i, 1], P[i, 2], gx, gy, gz)
        inside = False
        if j < L and sa.light_kind[j] != LIGHT_SUN and sa.light_kind[j] != LIGHT_AREA:
            rr = sa.light_radius[j]
            vx = sa.light_pos[j, 0] - qx
            vy = sa.light_pos[j, 1] - qy
            vz = sa.light_pos[j, 2] - qz
            inside = (not sa.light_soft[j]) and vx * vx + vy * vy + vz * vz <= rr * rr
        for s in range(n):
            k = r * n + s
            u = (s + 0.5) * inv_n + r1
            u -= math.floor(u)
            v = (s + 0.5) * _GOLDEN + r2
            v -= math.floor(v)
            o[k, 0] = qx
            o[k, 1] = qy
            o[k, 2] = qz
            if j >= L or inside:
                # the world, or a point inside a sphere light: cosine-weighted directions
                dx, dy, dz = _cosine_dir(sx, sy, sz, u, v)
                if j >= L:
                    t = np.inf
                else:
                    t = _sphere_exit(qx, qy, qz, dx, dy, dz, sa.light_pos[j, 0],
                                     sa.light_pos[j, 1], sa.light_pos[j, 2],
                                     sa.light_radius[j]) * (1.0 - tol.SHADOW_END_REL)
                wgt = math.pi
                cs = 1.0  # the cosine is in the density
            else:
                dx, dy, dz, t, wgt = _sample_one(sa, j, qx, qy, qz, u, v)
                cs = dot3(sx, sy, sz, dx, dy, dz)
            d[k, 0] = dx
            d[k, 1] = dy
            d[k, 2] = dz
            tmax[k] = t
            w[k], below = sample_weight(far, wgt, cs, dot3(gx, gy, gz, dx, dy, dz),
                                        dot3(sx, sy, sz, dx, dy, dz), t, inv_n)
            if below:
                o[k, 0] = fx
                o[k, 1] = fy
                o[k, 2] = fz


@njit(cache=True, nogil=True, inline="always")
def sample_weight(far, wgt, cs, cg, cn, t, inv_n):
    """``(weight, below)`` of one sample of a (point, light) row: its density-weighted
    ``wgt``, its cosine factor ``cs`` (1 where the density holds it), the cosines ``cg``,
    ``cn`` of its direction with the geometric and the shading normal, its ``tmax`` ``t``.
    Above both horizons ``wgt cs / n``; at a rough interface (``far``) below both, ``-wgt
    cs / n`` and ``below`` (its ray leaves from the far side, :func:`~.shading.far_origin`);
    else 0 (no ray). The tracer (:func:`_soft_kernel`) and the records that regenerate its
    samples (:mod:`.sample_rays`) both decide by this."""
    if far and wgt > 0.0 and cs < 0.0 and cg < 0.0 and t > 0.0:
        return -wgt * cs * inv_n, True
    if wgt > 0.0 and cs > 0.0 and cg > 0.0 and cn > 0.0 and t > 0.0:
        return wgt * cs * inv_n, False
    return 0.0, False


@njit(cache=True, nogil=True, inline="always")
def row_hash(seed, j, L):
    """The hash the row of light ``j`` of ``L`` light slots (``j == L``: the world) of a
    point with node ``seed`` rotates its samples by, as :func:`_soft_kernel` draws it. The
    world's row takes the fixed id :data:`WORLD_ROW`, which no light slot can take: its
    samples do not depend on the number of light slots, so adding or deleting a light
    keeps them (the added light is shaded alone and recombined, not the frame re-traced)."""
    if j >= L:
        return world_row_hash(seed)
    return mix64(seed + np.uint64(j + 1) * np.uint64(0x9E3779B97F4A7C15))


@njit(cache=True, nogil=True, inline="always")
def world_row_hash(seed):
    """:func:`row_hash` of the world's row of a point with node ``seed``."""
    return mix64(seed + np.uint64(WORLD_ROW + 1) * np.uint64(0x9E3779B97F4A7C15))


@njit(cache=True, nogil=True, inline="always")
def row_uv(h, n, s):
    """Sample ``s`` of ``n`` in the unit square of a row with hash ``h`` (:func:`row_hash`):
    :func:`_soft_kernel`'s rotated Fibonacci lattice, for the pixel records to regenerate
    a point's shadow rays."""
    r1 = float(h >> np.uint64(11)) * _INV_2_53
    r2 = float(mix64(h) >> np.uint64(11)) * _INV_2_53
    u = (s + 0.5) * (1.0 / n) + r1
    u -= math.floor(u)
    v = (s + 0.5) * _GOLDEN + r2
    v -= math.floor(v)
    return u, v


@njit(cache=True, nogil=True, inline="always")
def world_sample_dir(h, n, s, sx, sy, sz):
    """Direction of the world's sample ``s`` of ``n`` at a point with shading normal ``s*``
    whose row hash is ``h``."""
    u, v = row_uv(h, n, s)
    return _cosine_dir(sx, sy, sz, u, v)


def soft_rays(sa: SceneArrays, surf, seeds: np.ndarray, n: int, sh_state: np.ndarray):
    """The soft shadow samples of the surface points ``surf`` (:class:`~.whitted.Surfaces`)
    with node ``seeds`` (nb,) uint64, ``n`` per sampled light (rows of ``sh_state`` that
    are :data:`SH_SOFT`) and ``n`` for the world when it lights.

    Returns ``(SoftSamples (vis all False), origins (k, 3), tmax (k,), rows (m,) int64)``:
    ``rows`` the (point, light) rows ``i * L + j`` of the sampled lights, in sample order
    (``-1 - i`` for the world's row of point i)."""
    nb = len(surf.P)
    L = len(sa.light_kind)
    soft = np.flatnonzero(sh_state == SH_SOFT)
    pt = soft // max(L, 1)
    lj = soft - pt * L
    rows = soft
    if world_lights(sa):
        wp = np.flatnonzero(surf.mat >= 0)
        pt = np.concatenate([pt, wp])
        lj = np.concatenate([lj, np.full(len(wp), L)])
        rows = np.concatenate([rows, -1 - wp])
        order = np.argsort(pt * (L + 1) + lj, kind="stable")
        pt, lj, rows = pt[order], lj[order], rows[order]
    m = len(pt)
    k = m * n
    start = np.zeros(nb + 1, np.int64)
    np.cumsum(np.bincount(pt, minlength=nb) * n, out=start[1:])
    o, d, tmax, w = np.empty((k, 3)), np.empty((k, 3)), np.empty(k), np.empty(k)
    exact = np.empty(m)
    if m:
        _soft_kernel(sa, surf.P, surf.Q, surf.NG, surf.NS, surf.mat,
                     np.ascontiguousarray(seeds, np.uint64),
                     pt.astype(np.int64), lj.astype(np.int32), int(n), bool(RATIO_ESTIMATOR),
                     o, d, tmax, w, exact)
    return (SoftSamples(start, np.repeat(lj, n).astype(np.int32), d, w,
                        np.zeros(k, np.bool_), exact, np.array([n], np.int64)),
            o, tmax, rows)


def soft_visibility(sa, surf, seeds, n: int, sh_state, occluded, counters=None,
                    proven: np.ndarray | None = None, own: np.ndarray | None = None):
    """Trace the soft samples of ``surf`` (:func:`soft_rays`) with ``occluded(origins,
    directions, tmax, rows) -> (k,) bool`` (``rows`` the samples' (point, light) rows as
    :func:`soft_rays` numbers them). ``proven`` (n L,) bool: the (point, light) rows whose
    every sample is proven unoccluded (:func:`~.shaft_skip.proven_rows`): their samples
    are visible without a ray (``counters["shadow_skipped"]`` counts them). ``own`` (nb,)
    int32: per point an instance its samples' rays leave out (-1: none;
    :func:`~.shaft_skip.own_instances`), handed to ``occluded(..., skip)``
    (``counters["shadow_own_skip"]`` counts those rays). Returns
    ``(SoftSamples, lit_rows, any_vis)``: the samples with their visibility, the (point,
    light) rows of the sampled lights and whether each has a visible sample."""
    soft, o, tmax, rows = soft_rays(sa, surf, seeds, n, sh_state)
    go = soft.w > 0.0
    if proven is not None and len(rows):
        skip = go & np.repeat(proven[np.maximum(rows, 0)] & (rows >= 0), n)
        soft.vis[skip] = True
        go &= ~skip
        if counters is not None:
            counters["shadow_skipped"] = counters.get("shadow_skipped", 0) + int(skip.sum())
    go = np.flatnonzero(go)
    if len(go):
        # take, not fancy indexing: half the time for these (k, 3) rows (8% of a glossy
        # frame before); a sample's row is its group's, go // n
        r = rows[go // n]
        ray = (np.take(o, go, axis=0), np.take(soft.d, go, axis=0), np.take(tmax, go), r)
        if own is not None and (own >= 0).any():
            L = max(len(sa.light_kind), 1)
            ray += (own[np.where(r >= 0, r // L, -1 - r)],)
            if counters is not None:
                counters["shadow_own_skip"] = (counters.get("shadow_own_skip", 0)
                                               + int(np.count_nonzero(ray[4] >= 0)))
        soft.vis[go] = ~np.asarray(occluded(*ray), np.bool_)
        if counters is not None:
            counters["shadow"] = counters.get("shadow", 0) + len(go)
    any_vis = soft.vis.reshape(len(rows), n).any(axis=1) if len(rows) else np.zeros(0, bool)
    return soft, rows, any_vis


def soft_direct(sa: SceneArrays, surf, seeds: np.ndarray, light_samples: int,
                vis: np.ndarray, occluded, counters: dict | None = None,
                occ: np.ndarray | None = None,
                proven: np.ndarray | None = None,
                own: np.ndarray | None = None) -> SoftSamples:
    """The shadow samples of the lights with an extent and of the world at ``surf`` (the
    base tracer's :class:`~.shader.Surfaces`), traced with ``occluded(origins,
    directions, tmax, rows) -> (k,) bool``; ``seeds`` (n,) uint64 the points' node seeds;
    ``proven`` (n L,) bool the rows whose samples are all proven unoccluded
    (:func:`~.shaft_skip.proven_rows`: not traced); ``own`` as :func:`soft_visibility`'s.
    Sets ``vis`` (n L,) of a sampled
    light's row when one of its samples reached it, and ``occ`` (when given) to
    :data:`OCC_SOFT` there (its visibility is a fraction). Returns the samples for
    :func:`~.whitted.shade`."""
    soft, rows, any_vis = soft_visibility(sa, surf, seeds, light_samples, surf.sh_state,
                                          occluded, counters, proven, own)
    lit = rows >= 0
    vis[rows[lit]] = any_vis[lit]
    if occ is not None:
        occ[rows[lit]] = OCC_SOFT
    return soft
