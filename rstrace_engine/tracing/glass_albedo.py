"""The single-scattering albedo of a rough dielectric interface by quadrature: the source of
the tables the shader reads (``scripts/ggx_glass_tables.py`` writes
:mod:`.ggx_glass_tables`; :func:`~.multiscatter.ggx_glass_albedo` reads them)."""

from __future__ import annotations

import math

from numba import njit

from .. import tolerances as tol
from .ggx_sampling import ggx_vndf, ggx_weight
from .shading import fresnel_dielectric, refract


@njit(cache=True, nogil=True)
def ggx_glass_albedo_quadrature(cos_o, alpha, eta, n):
    """Albedo ``E`` of a rough dielectric interface (GGX, reflection plus refraction) seen
    from ``cos_o``, ``eta = n1 / n2`` (the side the view is on over the other), as Cycles
    tabulates it: the mean over visible normals of ``F G2 / G1`` (reflected; a reflection
    below the macro surface counts 0) and ``(1 - F) G2 / G1`` (refracted, *wherever it
    goes*), by a deterministic quadrature: an ``n`` x ``n`` midpoint lattice over the
    sampler's unit square. Cycles' multiscatter GGX glass (Principled's default) scales its
    lobe by ``1 / E`` (``microfacet_ggx_preserve_energy``) read from its tables
    ``ggx_glass_E`` / ``ggx_glass_inv_E``; so does the shader, from the tables
    ``scripts/ggx_glass_tables.py`` computes with this
    (:func:`~.multiscatter.ggx_glass_albedo`). Cycles' tables count a refracted direction
    that leaves on the viewer's side of the macro surface (its sampler drops it now, as
    the glossy rays do): seen from inside glass at grazing angles such directions are
    common, and the single-scattering albedo without them is lower (IOR 1.5, roughness 1,
    cos 1/15: 0.55 against Cycles' 0.73, which this reproduces within 0.001; docs/glossy.md,
    "The rim of rough glass"). From outside they are rare (the tables agree either way)."""
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
                # a refracted direction on the viewer's side counts too, as in Cycles'
                # tables (module docstring); the glossy rays drop it
                acc += (1.0 - f) * ggx_weight(co, tz, alpha)
            rz = 2.0 * ch * hz - co  # the reflected direction's cosine
            if rz > 0.0:
                acc += f * ggx_weight(co, rz, alpha)
    return acc / (n * n)
