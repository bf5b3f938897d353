"""The single-scattering albedo of a rough dielectric interface by quadrature: the source of
the tables the shader reads (``scripts/ggx_glass_tables.py`` writes
:mod:`.ggx_glass_tables`; :func:`~.multiscatter.ggx_glass_albedo` reads them)."""

from __future__ import annotations

import math

from numba import njit

from .. import tolerances as tol
from .shading import fresnel_dielectric, ggx_vndf, ggx_weight, refract


@njit(cache=True, nogil=True)
def ggx_glass_albedo_quadrature(cos_o, alpha, eta, n):
    """Single-scattering albedo ``E`` of a rough dielectric interface (GGX, reflection plus
    refraction) seen from ``cos_o``, ``eta = n1 / n2`` (the side the view is on over the
    other): the mean over visible normals of ``F G2 / G1`` (reflected) and ``(1 - F) G2 /
    G1`` (refracted), a direction on the wrong side of the macro surface counting 0 -- what
    the glossy rays carry (:func:`~.glossy_rays._glossy_rays`), by a deterministic
    quadrature: an ``n`` x ``n`` midpoint lattice over the sampler's unit square. Cycles'
    multiscatter GGX glass (Principled's default) scales its lobe by ``1 / E``
    (``microfacet_ggx_preserve_energy``) read from tables; so does the shader, from the
    tables ``scripts/ggx_glass_tables.py`` computes with this
    (:func:`~.multiscatter.ggx_glass_albedo`)."""
    co = min(max(cos_o, tol.GGX_COS_MIN), 1.0)
    so = math.sqrt(max(0.0, 1.0 - co * co))
    acc = 0.0
    for a in range(n):
        for b in range(n):
            hx, hy, hz = ggx_vndf(so, 0.0, co, alpha, (a + 0.5) / n, (b + 0.5) / n)
            ch = so * hx + co * hz
            if ch <= 0.0:
                continue
            ok, tx, ty, tz = refract(-so, 0.0, -co, hx, hy, hz, eta)
            f = 1.0
            if ok:
                f = fresnel_dielectric(ch, eta)
                if tz < 0.0:
                    acc += (1.0 - f) * ggx_weight(co, tz, alpha)
            rz = 2.0 * ch * hz - co  # the reflected direction's cosine
            if rz > 0.0:
                acc += f * ggx_weight(co, rz, alpha)
    return acc / (n * n)
