"""The dielectric albedos of a batch's Principled points, many points at once.

:func:`~.shading.ggx_albedo`'s ``E_dielectric`` is a 8 x 4-sample quadrature per point
(about a third of a 320x240 frame's render, whatever the scene's size: session 36 in
docs/bench-scale-bpy.md). Computed one point at a time its square roots and divisions run
one after another; :func:`dielectric_albedos` runs each sample of the quadrature over all
the batch's Principled points (a stripe's, on each thread of :func:`~..stripes.run`) in an
inner loop that LLVM vectorises, each point's terms summed in the same order with the same
operations, so every value is ``ggx_albedo``'s bit for bit (a test compares them on random
cosines, roughnesses and indices, NaN included).
:func:`~.shader._shade_kernel` reads them instead of calling ``ggx_albedo``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import tolerances as tol
from ..geometry.scene import MODEL_PRINCIPLED
from ..stripes import stripe_item, stripe_len
from .shading import ALBEDO_SAMPLES_PHI, ALBEDO_SAMPLES_THETA, dot3


@njit(cache=True, nogil=True, error_model="numpy")
def dielectric_albedos(VD, NS, MAT, mat_model, mat_roughness, mat_specular_ior, mat_diffuse,
                       out, first, step):
    """``out[i]`` (n,) float64: ``ggx_albedo(-dot(VD[i], NS[i]), roughness, specular
    IOR)[1]`` of point ``i``'s material where it is Principled (``MAT[i] >= 0``), the
    other rows left as they are. A specular IOR of 1 (Specular 0: no dielectric layer)
    gives 0 without the quadrature (a matte floor or wall: most of a frame's points), and so
    does a diffuse albedo of 0 (``mat_diffuse`` (NM, 3): a metal, a glass), where the shade
    kernel reads the albedo only as ``(1 - E)`` times that albedo (times a texel), whose
    bits it leaves as they are (``+0`` times a finite factor, a NaN texel's NaN). VD, NS
    (n, 3) float64: the surfaces' view directions and shading normals
    (:class:`~.shader.Surfaces`). Striped (:func:`~..stripes.run`: the points of stripe
    ``first`` of ``step``), as the shade kernel that reads them is: run in one thread, it
    would add its whole cost to every batch's wall time on a many-core machine, where inside
    the shade kernel it was shared by every thread."""
    n = VD.shape[0]
    idx = np.empty(stripe_len(n, first, step), np.int64)
    k = 0
    for stripe_q in range(idx.shape[0]):
        i = stripe_item(stripe_q, first, step)
        if i >= n:
            break
        m = MAT[i]
        if m >= 0 and mat_model[m] == MODEL_PRINCIPLED:
            if mat_specular_ior[m] == 1.0:  # no dielectric layer: 0, whatever the cosine
                out[i] = 0.0
                continue
            if (mat_diffuse[m, 0] == 0.0 and mat_diffuse[m, 1] == 0.0
                    and mat_diffuse[m, 2] == 0.0):
                out[i] = 0.0  # (read only as (1 - E) times the diffuse albedo: 0 either way)
                continue
            idx[k] = i
            k += 1
    co = np.empty(k)
    so = np.empty(k)
    lo = np.empty(k)
    a2 = np.empty(k)
    ie = np.empty(k)
    ed = np.zeros(k)
    for q in range(k):
        i = idx[q]
        m = MAT[i]
        c = min(max(-dot3(VD[i, 0], VD[i, 1], VD[i, 2], NS[i, 0], NS[i, 1], NS[i, 2]),
                    tol.GGX_COS_MIN), 1.0)
        alpha = mat_roughness[m]
        a = alpha * alpha
        co[q] = c
        a2[q] = a
        so[q] = math.sqrt(max(0.0, 1.0 - c * c))
        c2 = c * c  # (ggx_lambda(c, a))
        lo[q] = 0.0 if c2 <= 0.0 else 0.5 * (math.sqrt(1.0 + a * (max(1.0 - c2, 0.0) / c2))
                                             - 1.0)
        ie[q] = 1.0 / mat_specular_ior[m]
    nu = ALBEDO_SAMPLES_THETA
    nphi = ALBEDO_SAMPLES_PHI
    for s in range(nu):
        u = (s + 0.5) / nu
        for j in range(nphi):
            cphi = math.cos(math.pi * (j + 0.5) / nphi)
            for q in range(k):  # (every lane computes; a skipped sample adds nothing)
                c = co[q]
                a = a2[q]
                ct = math.sqrt((1.0 - u) / (1.0 + (a - 1.0) * u))
                st = math.sqrt(max(0.0, 1.0 - ct * ct))
                voh = c * ct + so[q] * st * cphi
                nol = 2.0 * voh * ct - c
                n2 = nol * nol  # (ggx_lambda(nol, a))
                lam = 0.5 * (math.sqrt(1.0 + a * (max(1.0 - n2, 0.0) / n2)) - 1.0)
                lam = 0.0 if n2 <= 0.0 else lam
                w = voh / ((1.0 + lam + lo[q]) * ct * c)
                e = ie[q]  # (fresnel_dielectric(voh, e))
                ci = min(max(voh, 0.0), 1.0)
                sin2_t = e * e * (1.0 - ci * ci)
                cos_t = math.sqrt(1.0 - sin2_t)
                rs = (e * ci - cos_t) / (e * ci + cos_t)
                rp = (ci - e * cos_t) / (ci + e * cos_t)
                f = 1.0 if sin2_t >= 1.0 else 0.5 * (rs * rs + rp * rp)
                ed[q] += 0.0 if (voh <= 0.0 or nol <= 0.0) else w * f
    for q in range(k):
        i = idx[q]
        out[i] = min(ed[q] / (nu * nphi), 1.0)
