"""Watertight ray/triangle intersection (Woop, Benthin, Wald, JCGT 2013), in float64.

The ray is sheared so that its direction becomes +Z; each triangle edge is then tested with
a 2D edge function computed from the *transformed vertex coordinates* alone. A shared edge of
two triangles yields exactly opposite edge-function values in both (IEEE products and
differences are sign-symmetric), so a ray can never slip between two triangles that share an
edge or a vertex: it hits at least one of them. Both sides of a triangle are hit (no culling).

Usage from numba kernels::

    kx, ky, kz, sx, sy, sz = ray_shear(dx, dy, dz)           # once per ray (per space)
    hit, t, u, v = intersect(ox, oy, oz, kx, ky, kz, sx, sy, sz,
                             ax, ay, az, bx, by, bz, cx, cy, cz, tmin, tmax)

``u`` and ``v`` are the barycentric weights of vertices 1 (b) and 2 (c); the hit point is
``(1 - u - v) * a + u * b + v * c`` and equals ``o + t * d`` for the (not necessarily unit)
direction ``d`` the shear was computed from.

These functions are inlined into the cached kernels of :mod:`.bvh` and :mod:`.accelerators`;
numba's cache does not track that dependency, so after editing this file delete those
modules' ``__pycache__/*.nbi`` / ``*.nbc`` files (or run with a fresh ``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def ray_shear(dx, dy, dz):
    """Axis permutation and shear constants of a ray direction (float64 scalars).

    Returns ``(kx, ky, kz, sx, sy, sz)``: ``kz`` is the dominant axis of ``d``; ``kx, ky``
    the other two (swapped when ``d[kz] < 0`` to keep the winding); ``sx = d[kx] / d[kz]``,
    ``sy = d[ky] / d[kz]``, ``sz = 1 / d[kz]``. A zero direction gives ``sz = inf`` and
    every test misses.
    """
    ax_, ay_, az_ = abs(dx), abs(dy), abs(dz)
    if ax_ >= ay_ and ax_ >= az_:
        kz = 0
    elif ay_ >= az_:
        kz = 1
    else:
        kz = 2
    kx = kz + 1
    if kx == 3:
        kx = 0
    ky = kx + 1
    if ky == 3:
        ky = 0
    dkz = dx if kz == 0 else (dy if kz == 1 else dz)
    if dkz < 0.0:
        kx, ky = ky, kx
    dkx = dx if kx == 0 else (dy if kx == 1 else dz)
    dky = dx if ky == 0 else (dy if ky == 1 else dz)
    if dkz == 0.0:
        return kx, ky, kz, 0.0, 0.0, float("inf")
    sz = 1.0 / dkz
    return kx, ky, kz, dkx * sz, dky * sz, sz


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _pick(k, x, y, z):
    return x if k == 0 else (y if k == 1 else z)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _sheared_uvw(akx, aky, akz, bkx, bky, bkz, ckx, cky, ckz, okx, oky, okz, sx, sy):
    """The sheared vertices' heights ``a2, b2, c2`` and the scaled barycentrics ``U, V, W``
    (U weighs a, V weighs b, W weighs c) of :func:`intersect_sheared` and
    :func:`solve_sheared`: one arithmetic, so both give a hit the very same bits."""
    a2 = akz - okz
    b2 = bkz - okz
    c2 = ckz - okz
    Ax = (akx - okx) - sx * a2
    Ay = (aky - oky) - sy * a2
    Bx = (bkx - okx) - sx * b2
    By = (bky - oky) - sy * b2
    Cx = (ckx - okx) - sx * c2
    Cy = (cky - oky) - sy * c2
    return (a2, b2, c2, Cx * By - Cy * Bx, Ax * Cy - Ay * Cx, Bx * Ay - By * Ax)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def intersect_sheared(akx, aky, akz, bkx, bky, bkz, ckx, cky, ckz, okx, oky, okz,
                      sx, sy, sz, tmin, tmax):
    """The watertight test on coordinates already permuted by ``(kx, ky, kz)``.

    ``akx = a[kx]`` etc. for the three vertices and the ray origin (float64 scalars); the
    other arguments as :func:`intersect`. Returns ``(hit, t, u, v)``.
    """
    a2, b2, c2, U, V, W = _sheared_uvw(akx, aky, akz, bkx, bky, bkz, ckx, cky, ckz,
                                       okx, oky, okz, sx, sy)
    # bitwise, not short-circuit: one branch instead of up to six unpredictable ones
    # (the same truth value; 20 -> 9 ns a test on random rays, docs/bench-raycast.md)
    if ((U < 0.0) | (V < 0.0) | (W < 0.0)) & ((U > 0.0) | (V > 0.0) | (W > 0.0)):
        return False, 0.0, 0.0, 0.0
    det = U + V + W
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    t = (U * a2 + V * b2 + W * c2) * sz / det
    if not (t >= tmin and t <= tmax):  # also rejects NaN
        return False, 0.0, 0.0, 0.0
    inv = 1.0 / det
    return True, t, V * inv, W * inv


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def intersect(ox, oy, oz, kx, ky, kz, sx, sy, sz,
              ax, ay, az, bx, by, bz, cx, cy, cz, tmin, tmax):
    """Watertight test of one ray against triangle ``(a, b, c)`` (all float64 scalars).

    Returns ``(hit, t, u, v)``; ``hit`` is True when the ray meets the triangle at
    ``tmin <= t <= tmax`` (inclusive bounds, so a hit exactly at a bound is kept).
    """
    return intersect_sheared(_pick(kx, ax, ay, az), _pick(ky, ax, ay, az), _pick(kz, ax, ay, az),
                             _pick(kx, bx, by, bz), _pick(ky, bx, by, bz), _pick(kz, bx, by, bz),
                             _pick(kx, cx, cy, cz), _pick(ky, cx, cy, cz), _pick(kz, cx, cy, cz),
                             _pick(kx, ox, oy, oz), _pick(ky, ox, oy, oz), _pick(kz, ox, oy, oz),
                             sx, sy, sz, tmin, tmax)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def solve_sheared(akx, aky, akz, bkx, bky, bkz, ckx, cky, ckz, okx, oky, okz, sx, sy, sz):
    """:func:`intersect_sheared`'s distance and barycentrics *without* its inside test and
    bounds (the same arithmetic, so an inside hit gets the very same bits).

    For refining a hit another (float32) test found on this triangle: a ray through a shared
    edge may lie a float64 hair outside it. Returns ``(ok, t, u, v)``; ``ok`` is False when
    the ray is parallel to the triangle's plane (or the distance is not finite).
    """
    a2, b2, c2, U, V, W = _sheared_uvw(akx, aky, akz, bkx, bky, bkz, ckx, cky, ckz,
                                       okx, oky, okz, sx, sy)
    det = U + V + W
    if det == 0.0:
        return False, 0.0, 0.0, 0.0
    t = (U * a2 + V * b2 + W * c2) * sz / det
    if not (t > -np.inf and t < np.inf):  # also rejects NaN
        return False, 0.0, 0.0, 0.0
    inv = 1.0 / det
    return True, t, V * inv, W * inv
