"""Lights seen directly: the radiance a ray gathers from the lights' own surfaces, as Cycles.

Cycles shows a light with an extent to the rays its ray visibility names: camera rays
(``visible_camera``, off for a new light), mirror reflection rays (``visible_glossy``) and
smooth refraction rays (``visible_transmission``). What a ray sees (checked against Cycles
5.0 renders, tests/blender/test_seen_lights.py):

* an **area light** (rectangle, square, disk, ellipse) from its emitting side only: its
  radiance ``c P / (pi A)`` times the spread attenuation at the ray's angle to its normal
  (:class:`~..geometry.lights.ExtendedLights`);
* a **sphere light** (POINT, SPOT with a radius): a ball of radiance ``c P / (4 pi^2
  r^2)``; with soft falloff a disk of radius ``r`` through its centre facing the ray's
  start (Cycles' oriented disk; a camera ray starts on the clip-start plane); a spot
  only where the ray comes toward it, times its cone falloff at the direction from the
  light to the ray's origin (its blend included);
* a **sun** with an angle, to rays that hit nothing: ``c S / (pi sin^2(a / 2))`` over its
  cone of directions.

Lights are not opaque in Cycles: a ray passes on through a light (what is behind it adds),
so a light adds its radiance where the ray crosses it before its hit (the sun where it
hits nothing) and changes nothing else. Rays drawn from a rough surface's lobe see no light
(that light is the surface's direct light, sampled from the lights: :mod:`.shader`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..geometry.scene import LIGHT_AREA, LIGHT_NONE, LIGHT_SPOT, LIGHT_SUN, SceneArrays
from ..views import fields, view_type
from .shading import dot3, spot_falloff
from .soft_lights import spot_cosine

#: Which ray sees: the column of ``SceneArrays.light_vis`` (none: -1).
SEEN_NONE, SEEN_GLOSSY, SEEN_CAMERA, SEEN_TRANSMISSION = -1, 1, 2, 3


def seen_lights(sa, column: int) -> np.ndarray:
    """(L,) bool: the lights rays of ``column`` (``SEEN_*``) can see (a light with an extent
    whose visibility for them is on)."""
    vis = np.asarray(sa.light_vis)
    if vis.shape[1] <= column or column < 0:
        return np.zeros(len(sa.light_kind), np.bool_)
    return (np.asarray(sa.light_ext, np.bool_) & (np.asarray(sa.light_kind) != LIGHT_NONE)
            & (vis[:, column] > 0.0))


def any_seen(sa, columns=(SEEN_CAMERA, SEEN_GLOSSY, SEEN_TRANSMISSION)) -> bool:
    """Whether rays of any of ``columns`` can see a light."""
    return any(bool(seen_lights(sa, c).any()) for c in columns)


def first_seen_below(old_sa, sa) -> bool:
    """Whether mirror or refraction rays can see some light's surface in ``sa`` and none in
    ``old_sa``."""
    seen = (SEEN_GLOSSY, SEEN_TRANSMISSION)
    return any_seen(sa, seen) and not any_seen(old_sa, seen)


@njit(cache=True, nogil=True)
def _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, t0, t1):
    """First parameter in (t0, t1) where ray ``o + t d`` meets the sphere, else -1."""
    px, py, pz = ox - cx, oy - cy, oz - cz
    a = dx * dx + dy * dy + dz * dz
    b = px * dx + py * dy + pz * dz
    c = px * px + py * py + pz * pz - r * r
    disc = b * b - a * c
    if not (disc >= 0.0 and a > 0.0):
        return -1.0
    s = math.sqrt(disc)
    # the roots without cancellation
    q = -(b + math.copysign(s, b))
    ta, tb = (q / a, c / q) if q != 0.0 else (0.0, 0.0)
    lo, hi = min(ta, tb), max(ta, tb)
    if t0 < lo < t1:
        return lo
    if t0 < hi < t1:
        return hi
    return -1.0


@njit(cache=True, nogil=True)
def _disk_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, nx, ny, nz, r, t0, t1):
    """Parameter in (t0, t1) where the ray meets the disk of centre ``c``, unit normal ``n``
    and radius ``r``, else -1."""
    den = dx * nx + dy * ny + dz * nz
    if den == 0.0:
        return -1.0
    t = ((cx - ox) * nx + (cy - oy) * ny + (cz - oz) * nz) / den
    if not (t0 < t < t1):
        return -1.0
    hx, hy, hz = ox + t * dx - cx, oy + t * dy - cy, oz + t * dz - cz
    return t if hx * hx + hy * hy + hz * hz <= r * r else -1.0


@njit(cache=True, nogil=True)
def seen_one(sa, j, ox, oy, oz, dx, dy, dz, t0, t1, miss):
    """The radiance factor (times ``light_radiance[j]``) ray ``o + t d`` (t in (t0, t1))
    gathers from light ``j``'s surface; ``miss``: the ray hits no geometry (a sun is
    seen only then). 0 where it does not meet the light."""
    kind = sa.light_kind[j]
    if kind == LIGHT_NONE or not sa.light_ext[j]:
        return 0.0
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not ln > 0.0:
        return 0.0
    ux, uy, uz = dx / ln, dy / ln, dz / ln
    lx, ly, lz = sa.light_dir[j, 0], sa.light_dir[j, 1], sa.light_dir[j, 2]
    if kind == LIGHT_SUN:
        if not miss:
            return 0.0
        return 1.0 if -dot3(ux, uy, uz, lx, ly, lz) >= math.cos(sa.light_half[j]) else 0.0
    cx, cy, cz = sa.light_pos[j, 0], sa.light_pos[j, 1], sa.light_pos[j, 2]
    if kind == LIGHT_AREA:
        cos_l = -dot3(ux, uy, uz, lx, ly, lz)
        if not cos_l > 0.0:
            return 0.0  # one-sided: seen from its emitting side only
        t = ((cx - ox) * lx + (cy - oy) * ly + (cz - oz) * lz) / (dx * lx + dy * ly + dz * lz)
        if not (t0 < t < t1):
            return 0.0
        hx, hy, hz = ox + t * dx - cx, oy + t * dy - cy, oz + t * dz - cz
        x = 2.0 * dot3(hx, hy, hz, sa.light_u[j, 0], sa.light_u[j, 1], sa.light_u[j, 2])
        y = 2.0 * dot3(hx, hy, hz, sa.light_v[j, 0], sa.light_v[j, 1], sa.light_v[j, 2])
        su, sv = sa.light_size[j, 0], sa.light_size[j, 1]
        if sa.light_ellipse[j]:
            if (x / su) ** 2 + (y / sv) ** 2 > 1.0:
                return 0.0
        elif abs(x) > su or abs(y) > sv:
            return 0.0
        tan_half = sa.light_spread[j, 0]
        if tan_half < np.inf:
            tan_a = math.sqrt(max(0.0, 1.0 - cos_l * cos_l)) / cos_l
            return max((tan_half - tan_a) * sa.light_spread[j, 1], 0.0)
        return 1.0
    # a sphere (POINT, SPOT with a radius)
    r = sa.light_radius[j]
    px, py, pz = ox - cx, oy - cy, oz - cz
    if kind == LIGHT_SPOT and dx * px + dy * py + dz * pz >= 0.0:
        return 0.0  # a spot is seen only by rays coming toward it (Cycles: one-sided)
    if sa.light_soft[j]:
        # the disk faces the ray's start ``o + t0 d`` (Cycles' ray->P: a camera ray starts
        # on the clip-start plane, which matters for a light a few radii from the eye)
        qx, qy, qz = px + t0 * dx, py + t0 * dy, pz + t0 * dz
        ql = math.sqrt(qx * qx + qy * qy + qz * qz)
        if not ql > 0.0:
            return 0.0
        t = _disk_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, qx / ql, qy / ql, qz / ql, r, t0, t1)
    else:
        t = _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r, t0, t1)
    if t < 0.0:
        return 0.0
    if kind == LIGHT_SPOT and px * px + py * py + pz * pz > r * r:
        # the cone's falloff at the direction from the light to the ray's origin
        return spot_falloff(spot_cosine(sa, j, ux, uy, uz), sa.light_cos_outer[j],
                            sa.light_cos_inner[j])
    return 1.0


_SeenScene = view_type("_SeenScene", SceneArrays, (
    "light_cos_inner", "light_cos_outer", "light_dir", "light_ellipse", "light_ext",
    "light_half", "light_kind", "light_pos", "light_radiance", "light_radius",
    "light_size", "light_soft", "light_spot_frame", "light_spot_scaled", "light_spread",
    "light_u", "light_v", "light_vis"), __name__)


@njit(cache=True, nogil=True, parallel=True)
def seen_radiance(sa, o, d, t0, t1, miss, column, weight, out):
    """``out[i] = weight[i] * sum_j light_radiance[j] * seen_one(...)`` over the lights
    ray i's ``column[i]`` (``SEEN_*``, -1 none) sees, within (t0[i], t1[i]) (t1: its hit,
    or its bound on a miss, ``miss[i]``). o, d (n, 3) float64; out (n, 3) float64."""
    sa = _SeenScene(*fields(sa, _SeenScene))  # the fields its loop reads
    L = sa.light_kind.shape[0]
    for i in prange(o.shape[0]):
        r = 0.0
        g = 0.0
        b = 0.0
        c = column[i]
        if c >= 0:
            for j in range(L):
                if sa.light_vis[j, c] <= 0.0:
                    continue
                f = seen_one(sa, j, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2],
                             t0[i], t1[i], miss[i])
                if f > 0.0:
                    f *= sa.light_vis[j, c]
                    r += f * sa.light_radiance[j, 0]
                    g += f * sa.light_radiance[j, 1]
                    b += f * sa.light_radiance[j, 2]
        out[i, 0] = weight[i, 0] * r
        out[i, 1] = weight[i, 1] * g
        out[i, 2] = weight[i, 2] * b


def seen(sa, o, d, t0, t1, miss, column, weight) -> np.ndarray:
    """(n, 3) float64: the radiance rays gather from the lights they see
    (:func:`seen_radiance`)."""
    n = len(o)
    out = np.empty((n, 3))
    if n:
        seen_radiance(sa, np.ascontiguousarray(o, np.float64),
                      np.ascontiguousarray(d, np.float64),
                      np.ascontiguousarray(t0, np.float64),
                      np.ascontiguousarray(t1, np.float64),
                      np.ascontiguousarray(miss, np.bool_),
                      np.ascontiguousarray(column, np.int8),
                      np.ascontiguousarray(weight, np.float64), out)
    return out
