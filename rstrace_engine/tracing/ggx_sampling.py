"""GGX's visible normals (Heitz 2018): the microfacet normals the glossy rays are drawn
from (:func:`~.glossy_rays._glossy_rays`) and the weight of a direction drawn through them.

:func:`ggx_sample_normal` is split in two: :func:`ggx_sample_frame`, what depends on the
normal and the view alone, computed once for a point's samples, and :func:`ggx_sample_at`,
one sample's normal from it (the same operations in the same order: the same bits as the
whole; session 42, docs/glossy.md). :func:`ggx_weight_lo` is :func:`ggx_weight` from Smith's
Lambda of the view, which a point's samples share. The glossy rays call the halves;
:func:`ggx_vndf` and :func:`ggx_weight` serve :mod:`.glass_albedo`'s quadrature, and
:func:`ggx_sample_normal` (the whole) is kept for the tests (no render calls it).
"""

from __future__ import annotations

import math

from numba import njit

from .shading import dot3, ggx_lambda, normalize3, onb


@njit(cache=True, nogil=True)
def ggx_vndf(ox, oy, oz, alpha, u1, u2):
    """A microfacet normal drawn from GGX's distribution of visible normals (Heitz 2018).

    ``o`` the unit view direction in the local frame (normal ``+z``, ``oz > 0``), ``alpha``
    GGX's roughness, ``u1, u2`` in [0, 1). Returns the local unit normal ``h``; its density
    is ``G1(o) max(o . h, 0) D(h) / oz``.
    """
    return _vndf_at(_vndf_frame(ox, oy, oz, alpha), alpha, u1, u2)


@njit(cache=True, nogil=True)
def _vndf_frame(ox, oy, oz, alpha):
    """What :func:`ggx_vndf` computes from the view alone: the stretched view ``v`` and
    the two tangents about it, ``(vx, vy, vz, t1x, t1y, t1z, t2x, t2y, t2z)``."""
    vx, vy, vz, _ = normalize3(alpha * ox, alpha * oy, oz)
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        il = 1.0 / math.sqrt(lensq)
        t1x, t1y, t1z = -vy * il, vx * il, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x = vy * t1z - vz * t1y
    t2y = vz * t1x - vx * t1z
    t2z = vx * t1y - vy * t1x
    return vx, vy, vz, t1x, t1y, t1z, t2x, t2y, t2z


@njit(cache=True, nogil=True)
def _vndf_at(f, alpha, u1, u2):
    """:func:`ggx_vndf`'s normal at ``u1, u2`` in the view's frame ``f``
    (:func:`_vndf_frame`)."""
    vx, vy, vz, t1x, t1y, t1z, t2x, t2y, t2z = f
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    nx = p1 * t1x + p2 * t2x + p3 * vx
    ny = p1 * t1y + p2 * t2y + p3 * vy
    nz = p1 * t1z + p2 * t2z + p3 * vz
    hx, hy, hz, _ = normalize3(alpha * nx, alpha * ny, max(nz, 0.0))
    return hx, hy, hz


@njit(cache=True, nogil=True)
def ggx_sample_normal(nx, ny, nz, ox, oy, oz, alpha, u1, u2):
    """World-space microfacet normal about unit normal ``n`` for the unit view direction
    ``o`` (``n . o > 0``) drawn by :func:`ggx_vndf`."""
    return ggx_sample_at(ggx_sample_frame(nx, ny, nz, ox, oy, oz, alpha), nx, ny, nz, alpha,
                         u1, u2)


@njit(cache=True, nogil=True)
def ggx_sample_frame(nx, ny, nz, ox, oy, oz, alpha):
    """What :func:`ggx_sample_normal` computes from the normal and the view alone, once for
    a point's samples: the normal's tangents and :func:`_vndf_frame` of the view in them,
    ``((t1x, t1y, t1z, t2x, t2y, t2z), vndf frame)``."""
    t = onb(nx, ny, nz)
    t1x, t1y, t1z, t2x, t2y, t2z = t
    lx = dot3(ox, oy, oz, t1x, t1y, t1z)
    ly = dot3(ox, oy, oz, t2x, t2y, t2z)
    lz = dot3(ox, oy, oz, nx, ny, nz)
    return t, _vndf_frame(lx, ly, lz, alpha)


@njit(cache=True, nogil=True)
def ggx_sample_at(f, nx, ny, nz, alpha, u1, u2):
    """:func:`ggx_sample_normal` at ``u1, u2`` from its :func:`ggx_sample_frame` ``f`` (the
    same bits)."""
    t1x, t1y, t1z, t2x, t2y, t2z = f[0]
    hx, hy, hz = _vndf_at(f[1], alpha, u1, u2)
    return (hx * t1x + hy * t2x + hz * nx, hx * t1y + hy * t2y + hz * ny,
            hx * t1z + hy * t2z + hz * nz)


@njit(cache=True, nogil=True)
def ggx_weight(cos_o, cos_i, alpha):
    """The weight ``f cos_i / pdf`` of a direction drawn through :func:`ggx_vndf`, without
    its Fresnel factor: ``G2(o, i) / G1(o)`` with the height-correlated Smith ``G2`` (the
    same for reflection and refraction; ``cos_i`` taken as ``|cos_i|``)."""
    a2 = alpha * alpha
    return ggx_weight_lo(ggx_lambda(cos_o, a2), cos_i, a2)


@njit(cache=True, nogil=True)
def ggx_weight_lo(lo, cos_i, a2):
    """:func:`ggx_weight` from ``lo = ggx_lambda(cos_o, a2)``, ``a2 = alpha^2`` (a point's
    samples share them; the same bits)."""
    return (1.0 + lo) / (1.0 + lo + ggx_lambda(abs(cos_i), a2))
